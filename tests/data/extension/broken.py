"""A user service file that fails to import (for the loader's refusals)."""

raise RuntimeError("this file is broken on purpose")
