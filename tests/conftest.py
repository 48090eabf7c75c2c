"""Make the repository importable as the package `ember`, whatever its directory is called."""
import os
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _expose_as_ember() -> None:
    try:
        import ember  # noqa: F401  (already importable: installed by the setup script)
        if os.path.realpath(os.path.dirname(ember.__file__)) == os.path.realpath(ROOT):
            return
    except ImportError:
        pass
    link_dir = tempfile.mkdtemp(prefix="ember-import-")
    os.symlink(ROOT, os.path.join(link_dir, "ember"))
    sys.path.insert(0, link_dir)
    for name in [m for m in sys.modules if m == "ember" or m.startswith("ember.")]:
        del sys.modules[name]


_expose_as_ember()
