"""kernels.memory: NumPy's huge-page advice is off while a scene is built, and comes back after."""
from __future__ import annotations

import threading

import numpy as np
import pytest

from ember.kernels import memory

pytestmark = pytest.mark.skipif(memory._SWITCH is None, reason="NumPy has no huge-page switch here (not Linux)")


def advice() -> bool:
    return bool(memory._SWITCH[0]())


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
