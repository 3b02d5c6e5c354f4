"""The ``invent`` command line and the small zenoh tools.

- :mod:`~services.cli.main`: the parser of every subcommand and ``main`` (``invent``, ``python -m services.cli``);
- :mod:`~services.cli.tools`: ``invent router``, ``echo``, ``call``, ``status``, ``secrets``.

``invent up`` is in ``services/launch/``. Nothing but the command line imports it.
"""
