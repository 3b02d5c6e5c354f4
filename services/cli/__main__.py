"""``python -m services.cli``: the ``invent`` command (``invent up`` starts each service so)."""

import sys

try:
    from services.cli.main import main
except KeyboardInterrupt:
    # SIGINT while the command itself is imported (invent up stopping every service as one fails to
    # start, a loaded machine slow to import): a line, as main() says it once it runs. 130 is
    # ExitStatus.INTERRUPTED, which may not be imported yet.
    print("invent: interrupted while starting", file=sys.stderr)
    sys.exit(130)

sys.exit(main())
