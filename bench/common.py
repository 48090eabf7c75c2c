"""Shared bits of the benchmarks and tests: import this checkout as `ember`, medians."""
from __future__ import annotations

import importlib.util
import os
import statistics
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def import_ember():
    """Import this checkout as the package `ember` whatever its directory is called."""
    existing = sys.modules.get("ember")
    if existing is not None and os.path.realpath(os.path.dirname(existing.__file__)) == os.path.realpath(ROOT):
        return existing
    spec = importlib.util.spec_from_file_location("ember", os.path.join(ROOT, "__init__.py"),
                                                  submodule_search_locations=[ROOT])
    module = importlib.util.module_from_spec(spec)
    for name in [m for m in sys.modules if m == "ember" or m.startswith("ember.")]:
        del sys.modules[name]
    sys.modules["ember"] = module
    spec.loader.exec_module(module)
    return module


def median(values):
    return statistics.median(values)
