"""The ``invent`` command line, the launcher and the small zenoh tools.

- :mod:`~services.cli.main`: the parser of every subcommand and ``main`` (``invent``, ``python -m services.cli``);
- :mod:`~services.cli.up`: ``invent up``, the whole loop as child processes, and its run report;
- :mod:`~services.cli.composition`: ``invent up --composed``, the same services in one process;
- :mod:`~services.cli.tools`: ``invent router``, ``echo``, ``call``, ``status``, ``secrets``.
"""
