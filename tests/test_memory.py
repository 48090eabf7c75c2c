"""kernels.memory: NumPy's huge-page advice is off while a scene is built, and comes back after."""
from __future__ import annotations

import os
import threading

import numpy as np
import pytest

from ember.kernels import memory

pytestmark = pytest.mark.skipif(memory._SWITCH is None, reason="NumPy has no huge-page switch here (not Linux)")


def advice() -> bool:
    return bool(memory._SWITCH[0]())


@pytest.fixture(autouse=True)
def no_free_huge_pages(monkeypatch):
    """The machine state where the advice would stall (tests that want the other one patch it back)."""
    monkeypatch.setattr(memory, "huge_pages_ready", lambda: False)


def test_the_advice_stays_on_where_huge_pages_come_without_compaction(monkeypatch):
    monkeypatch.setattr(memory, "huge_pages_ready", lambda: True)
    memory._SWITCH[1](True)
    with memory.small_pages():
        assert advice()
    assert advice()


BUDDYINFO = """Node 0, zone      DMA      0      0      0      0      0      0      0      0      1      1      3
Node 0, zone    DMA32      1      1      4      2      5      4      3      3      4      2    752
Node 0, zone   Normal  15237  15075  11140   5372   1857   1249   1548    633    367    313   1904
"""


def test_free_huge_blocks_are_counted_from_buddyinfo():
    # Orders 9 and 10 (2 MB and 4 MB blocks of 4 KB pages): (1 + 2 + 313) x 2 MB + (3 + 752 + 1904) x 4 MB.
    assert memory.free_huge_blocks_mb(BUDDYINFO) == (1 + 2 + 313) * 2 + (3 + 752 + 1904) * 4
    # 64 KB pages (2^5 of them in a 2 MB huge page): orders 5 and up count.
    assert memory.free_huge_blocks_mb("Node 0, zone Normal 9 9 9 9 9 1 0", 65536) == 2.0
    assert memory.free_huge_blocks_mb("") == 0.0


def test_huge_pages_are_ready_by_defrag_mode_or_free_blocks(monkeypatch):
    monkeypatch.undo()
    files = {"/sys/kernel/mm/transparent_hugepage/defrag": "always defer defer+madvise [madvise] never\n",
             "/proc/buddyinfo": BUDDYINFO, "/sys/kernel/mm/transparent_hugepage/hpage_pmd_size": "2097152\n"}
    monkeypatch.setattr(memory, "_read", files.get)
    monkeypatch.setattr(memory.os, "sysconf", lambda name: 4096)
    assert memory.huge_pages_ready()                      # 11 GB free in big blocks
    monkeypatch.setattr(memory, "HUGE_PAGES_FREE_MB", 20000)
    assert not memory.huge_pages_ready()                  # not enough: the advice would compact
    files["/sys/kernel/mm/transparent_hugepage/defrag"] = "always defer defer+madvise madvise [never]\n"
    assert memory.huge_pages_ready()                      # never compacts on a fault
    files["/sys/kernel/mm/transparent_hugepage/defrag"] = "always defer [defer+madvise] madvise never\n"
    assert not memory.huge_pages_ready()
    del files["/proc/buddyinfo"]
    assert not memory.huge_pages_ready()                  # nothing known: small pages


def test_small_pages_turns_the_advice_off_and_restores_it():
    get, put = memory._SWITCH
    for before in (True, False):
        put(before)
        try:
            with memory.small_pages():
                assert not advice()
                with memory.small_pages():   # nested: still off, and the outer exit restores
                    assert not advice()
                assert not advice()
            assert advice() == before
        finally:
            put(True)


def test_concurrent_uses_restore_once_the_last_leaves():
    memory._SWITCH[1](True)
    inside, release = threading.Event(), threading.Event()

    def other():
        with memory.small_pages():
            inside.set()
            release.wait(10)

    thread = threading.Thread(target=other)
    thread.start()
    inside.wait(10)
    with memory.small_pages():
        assert not advice()
    assert not advice()      # the other thread is still building
    release.set()
    thread.join()
    assert advice()


def test_an_exception_inside_restores_the_advice():
    memory._SWITCH[1](True)
    with pytest.raises(ZeroDivisionError):
        with memory.small_pages():
            1 / 0
    assert advice()


def test_export_and_renderer_build_without_advice_and_restore_it(monkeypatch):
    """Through Blender: export_scene and Renderer() allocate with the advice off, and leave it as it was."""
    import bpy
    from bpy_helpers import export_current, new_scene
    from ember.kernels import Renderer
    seen = []
    original = np.empty

    def spy(*args, **kwargs):
        seen.append(advice())
        return original(*args, **kwargs)

    memory._SWITCH[1](True)
    new_scene(16, 16)
    bpy.ops.mesh.primitive_cube_add()
    monkeypatch.setattr(np, "empty", spy)
    exported = export_current()
    exported_calls = len(seen)
    assert advice()
    renderer = Renderer(exported.scene, threads=1, processes=False)
    monkeypatch.undo()
    renderer.close()
    assert 0 < exported_calls < len(seen) and not any(seen), seen
    assert advice()


_KEPT_HEAP_PROBE = r"""
import importlib.util, json, resource, sys
import numpy as np
spec = importlib.util.spec_from_file_location("memory", sys.argv[1])
memory = importlib.util.module_from_spec(spec)
spec.loader.exec_module(memory)

def faults_of_the_second():
    first = np.ones(8 << 20)       # 64 MB: over glibc's settled mmap threshold
    del first
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    second = np.ones(8 << 20)
    del second
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before

out = {"glibc": memory.keep_freed_memory(False), "settled": faults_of_the_second()}
with memory.kept_heap():
    with memory.kept_heap():       # nested (a viewport and an F12 render)
        out["kept"] = faults_of_the_second()
    out["kept_outer"] = faults_of_the_second()
out["after"] = faults_of_the_second()
print(json.dumps(out))
"""


def test_a_render_keeps_freed_memory_for_its_next_arrays():
    """Inside kept_heap (a render), an array freed and made again reuses its pages instead of faulting fresh
    ones from the system; once the last render is over, glibc gives big blocks back again. Measured in a
    process of its own: glibc's thresholds are the process's, which other tests' renders on other threads
    would move."""
    import json
    import subprocess
    import sys
    path = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "kernels", "memory.py")
    run = subprocess.run([sys.executable, "-c", _KEPT_HEAP_PROBE, path], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    out = json.loads(run.stdout.strip().splitlines()[-1])
    if not out["glibc"]:
        pytest.skip("not glibc")
    settled = out["settled"]
    assert settled >= 16 and out["after"] >= 16
    assert out["kept"] < settled / 4 and out["kept_outer"] < settled / 4
