"""Shared bits of the benchmarks: import the repository as `ember`, median timing."""
from __future__ import annotations

import os
import statistics
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def import_ember():
    """Import the repository as the package `ember` whatever its directory is called."""
    try:
        import ember
        if os.path.realpath(os.path.dirname(ember.__file__)) == os.path.realpath(ROOT):
            return ember
    except ImportError:
        pass
    link_dir = tempfile.mkdtemp(prefix="ember-bench-")
    os.symlink(ROOT, os.path.join(link_dir, "ember"))
    sys.path.insert(0, link_dir)
    for name in [m for m in sys.modules if m == "ember" or m.startswith("ember.")]:
        del sys.modules[name]
    import ember
    return ember


def median(values):
    return statistics.median(values)
