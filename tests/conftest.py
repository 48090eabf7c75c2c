"""Make this checkout importable as the package `ember`, whatever its directory is called
(dev.py installs the same hook into .venv; this covers a plain `pytest` from another environment)."""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench._common import import_ember  # noqa: E402

import_ember()
