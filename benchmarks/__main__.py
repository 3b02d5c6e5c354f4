"""``python -m benchmarks`` (``make bench``): see benchmarks/run.py and benchmarks/README.md."""

import sys

from benchmarks.run import main

sys.exit(main())
