"""The ``invent`` command line: a module per subcommand, each with its flags and its run.

- :mod:`~services.cli.main`: assembles the parser and runs ``main`` (``invent``, ``python -m services.cli``);
- :mod:`~services.cli.flags`: the shared flag groups, the argparse validators, flags to typed values;
- a module per subcommand (named as it is; what it holds: :class:`~services.cli.subcommand.SubcommandModule`), and per service
  (:class:`~services.cli.serve.ServiceCli`, listed in :mod:`~services.cli.services`);
- :mod:`~services.cli.tools`: the work of ``invent router``, ``echo``, ``call``, ``status``, ``secrets``.

Options become typed values here (nothing below imports argparse). Nothing but the command line imports it.
"""
