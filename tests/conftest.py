"""Make this checkout importable as the package `ember`, whatever its directory is called
(dev.py installs the same hook into .venv; this covers a plain `pytest` from another environment); and the
fixtures several test modules share."""
import os
import shutil
import subprocess
import sys

import pytest

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench.common import import_ember  # noqa: E402

import_ember()


@pytest.fixture
def small_disk(request, tmp_path):
    """A small file system (tmpfs; 1 MB, or the size a test's `small_disk_size` marker gives) mounted for the
    test and unmounted after it; the test is skipped where mounting is not permitted (it needs root)."""
    marker = request.node.get_closest_marker("small_disk_size")
    where = tmp_path / "small_disk"
    where.mkdir()
    if shutil.which("mount") is None:
        pytest.skip("no mount command here")
    mount = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={marker.args[0] if marker else '1m'}", "tmpfs",
                            str(where)], capture_output=True, text=True)
    if mount.returncode != 0:
        pytest.skip(f"cannot mount a small tmpfs here (needs root): {mount.stderr.strip()}")
    try:
        yield where
    finally:
        subprocess.run(["umount", str(where)], check=True)


def pytest_configure(config):
    config.addinivalue_line("markers", "small_disk_size(size): the size of the small_disk fixture's file system")
