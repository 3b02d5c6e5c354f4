"""``python -m services.cli``: the ``invent`` command (``invent up`` starts each service so)."""

import sys

from services.cli.main import main

sys.exit(main())
