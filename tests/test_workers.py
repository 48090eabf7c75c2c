"""Waves in worker processes (kernels/workers.py): the image, its passes and its statistics are the same bit
for bit as with threads; the viewport's and animations' updates reach the workers; a worker that dies loses
no wave; short renders and big scenes start none."""
from __future__ import annotations

import os
import sys

import numpy as np
import pytest

from bpy_helpers import export_current

from ember.kernels import Renderer, RenderSettings
from ember.kernels import accel, schedule, workers
from ember.kernels.schedule import Progress

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench import scenes  # noqa: E402

# Small waves, so that a short render has many and the workers take some of them.
SETTINGS = RenderSettings(samples=8, seed=3, wave_size=1024, passes=("normal", "diffuse_direct", "depth"),
                          cryptomatte=("object",))
# Adaptive sampling: a convergence check at 8 samples (about a quarter of the pixels converge there), then 16 more
# samples in waves of the pixels still rendering.
ADAPTIVE = RenderSettings(samples=24, seed=5, wave_size=1024, adaptive_threshold=0.05, adaptive_min_samples=8)


def _materials_scene(width=40, height=24):
    scenes.materials_scene(width, height)
    return export_current().scene


def _render(renderer, settings=SETTINGS, **kwargs):
    result = renderer.render(settings, **kwargs)
    film = result.film
    images = {"image": result.image, **{k: np.asarray(v) for k, v in film.aux.items()}}
    for kind, crypto in film.crypto.items():
        images[f"crypto_{kind}_ids"], images[f"crypto_{kind}_weights"] = crypto.ids, crypto.weights
    return result, images


def _assert_same(a: dict, b: dict):
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


@pytest.fixture(scope="module")
def materials():
    return _materials_scene()


@pytest.fixture(scope="module")
def reference(materials):
    with Renderer(materials, threads=2, processes=False) as renderer:
        result, images = _render(renderer)
        adaptive = renderer.render(ADAPTIVE)
        assert 0.1 < adaptive.film.converged.mean() < 0.9   # some pixels left the later waves, not all
    return result, images, adaptive.image


def test_frames_round_trip_arrays_without_copies_in_the_pickle():
    import io
    rows = np.arange(4096, dtype=np.float32).reshape(64, 64)
    message = ("rows", (rows, rows[:, ::2], {"n": 3}, np.zeros(0, np.int64)))
    stream = io.BytesIO()
    workers.send(stream, message)
    data, views = workers.pickled(message)
    # The contiguous array travels beside the pickle; the strided view (a copy of half of it) inside it.
    assert len(data) < 0.6 * rows.nbytes and views[0].nbytes == rows.nbytes
    stream.seek(0)
    back = workers.receive(stream)
    np.testing.assert_array_equal(back[1][0], rows)
    np.testing.assert_array_equal(back[1][1], rows[:, ::2])
    assert back[1][2] == {"n": 3} and back[1][3].dtype == np.int64
    with pytest.raises(EOFError):
        workers.receive(io.BytesIO(b"\x01\x02"))


def test_worker_processes_render_the_same_image_passes_and_counts(materials, reference):
    result0, images0, adaptive0 = reference
    with Renderer(materials, threads=2, processes=True) as renderer:
        assert renderer.crew.wait_for_workers() == 1, renderer.crew.worker_failures
        result, images = _render(renderer)
        assert renderer.crew.remote_waves > 0 and result.progress.workers == 1
        _assert_same(images, images0)
        assert result.progress.rays == result0.progress.rays
        assert result.progress.paths == result0.progress.paths
        # Adaptive sampling sends each wave its pixels still rendering.
        before = renderer.crew.remote_waves
        adaptive = renderer.render(ADAPTIVE).image
        assert renderer.crew.remote_waves > before
        np.testing.assert_array_equal(adaptive, adaptive0)
        assert renderer.crew.worker_failures == []


def test_updates_reach_the_workers(materials):
    """The camera, a material edit and the next frame's scene are applied in the workers too."""
    import bpy
    with Renderer(materials, threads=2, processes=True) as renderer:
        assert renderer.crew.wait_for_workers() == 1
        bpy.context.scene.camera.location.x += 0.3
        for material in bpy.data.materials:
            if material.node_tree is not None:
                for node in material.node_tree.nodes:
                    if node.type == "BSDF_PRINCIPLED":
                        node.inputs["Base Color"].default_value = (0.9, 0.2, 0.1, 1.0)
                        node.inputs["Roughness"].default_value = 0.35
        edited = export_current().scene
        assert renderer.update_scene(edited)
        before = renderer.crew.remote_waves
        _, images = _render(renderer)
        assert renderer.crew.remote_waves > before
        assert renderer.crew.worker_failures == []
    with Renderer(edited, threads=2, processes=False) as fresh:
        _, expected = _render(fresh)
    _assert_same(images, expected)
    _materials_scene()  # the module's other tests read the scene as it was


def test_a_worker_that_dies_mid_render_loses_no_wave(materials, reference):
    _, images0, _ = reference
    with Renderer(materials, threads=2, processes=True) as renderer:
        assert renderer.crew.wait_for_workers() == 1
        child = renderer.crew.workers.workers[0].process
        waves = []

        def kill_after_a_remote_wave(progress):
            waves.append(renderer.crew.remote_waves)
            if renderer.crew.remote_waves and child.poll() is None:
                child.kill()
        _, images = _render(renderer, on_progress=kill_after_a_remote_wave)
        assert child.poll() is not None and max(waves) > 0
        _assert_same(images, images0)
        assert len(renderer.crew.worker_failures) == 1
        # The next render runs in this process alone, and is the same again.
        after = renderer.crew.remote_waves
        _, again = _render(renderer)
        assert renderer.crew.remote_waves == after
        _assert_same(again, images0)


def test_closed_renderers_leave_their_workers_to_the_next_one(materials, reference, monkeypatch):
    _, images0, _ = reference
    workers.close_pool()
    with Renderer(materials, threads=2, processes=True) as first:
        assert first.crew.wait_for_workers() == 1
        pid = first.crew.workers.workers[0].process.pid
    assert [w.process.pid for w in workers.pooled()] == [pid]
    with Renderer(materials, threads=2, processes=True) as second:
        assert second.crew.wait_for_workers() == 1 and second.crew.workers.reused == 1
        assert second.crew.workers.workers[0].process.pid == pid and workers.pooled() == []
        _, images = _render(second)
        assert second.crew.remote_waves > 0
    _assert_same(images, images0)
    # Idle workers exit after IDLE_S.
    monkeypatch.setattr(workers, "IDLE_S", 0.2)
    with Renderer(materials, threads=2, processes=True) as third:
        assert third.crew.wait_for_workers() == 1
        child = third.crew.workers.workers[0]
    assert workers.pooled() == [child]
    child.process.wait(timeout=10)
    assert workers.pooled() == [] and child.closed
    # A pooled worker that died meanwhile is not taken.
    with Renderer(materials, threads=2, processes=True) as fourth:
        assert fourth.crew.wait_for_workers() == 1
        child = fourth.crew.workers.workers[0]
    child.process.kill()
    child.process.wait()
    with Renderer(materials, threads=2, processes=True) as fifth:
        assert fifth.crew.wait_for_workers() == 1 and fifth.crew.workers.reused == 0


def test_a_worker_that_cannot_build_the_scene_is_not_used(materials, monkeypatch):
    # A child that cannot import the package (a broken path) reports and exits: no slot waits for it.
    workers.close_pool()
    monkeypatch.setattr(workers, "_BOOT", "import sys; sys.exit(3)")
    with Renderer(materials, threads=2, processes=True) as renderer:
        assert renderer.crew.wait_for_workers() == 0
        assert len(renderer.crew.worker_failures) == 1
        _, images = _render(renderer, RenderSettings(samples=2, seed=1, wave_size=1024))
        assert renderer.crew.remote_waves == 0


def test_short_renders_and_big_scenes_start_no_workers(materials, monkeypatch):
    with Renderer(materials, threads=2) as renderer:
        renderer.render(RenderSettings(samples=2, seed=1))
        assert renderer.crew.workers is None and renderer.crew.remote_waves == 0
        # A render of many paths starts them at once (stopped here at once).
        renderer.render(RenderSettings(samples=schedule.WORKER_START_PATHS // (40 * 24) + 1, seed=1),
                        should_stop=lambda: True)
        assert renderer.crew.workers is not None and len(renderer.crew.workers.workers) == 1
    with Renderer(materials, threads=1, processes=True) as renderer:   # one thread: nothing to share
        assert renderer.crew.workers is None
    monkeypatch.setattr(schedule, "WORKER_MAX_BYTES", 1 << 10)
    with Renderer(materials, threads=2, processes=True) as renderer:
        assert renderer.crew.workers is not None and renderer.crew.workers.workers == []
        assert "MB are over" in renderer.crew.workers.skipped and renderer.crew.worker_failures == []
        assert renderer.start_workers() is False
    # Many threads (on as many cores): as many children as their copies fit in the bound.
    size = workers.pickled_size(workers.pickled(("scene", materials, f"{Renderer.__module__}:{Renderer.__qualname__}")))
    monkeypatch.setattr(schedule, "WORKER_MAX_BYTES", 2 * size + 1)
    monkeypatch.setattr(accel, "usable_cores", lambda: 6)
    workers.close_pool()
    with Renderer(materials, threads=6, processes=True) as renderer:
        assert len(renderer.crew.workers.workers) == 2 and renderer.crew.wait_for_workers() == 2
        _, images = _render(renderer, RenderSettings(samples=2, seed=1, wave_size=1024))
    monkeypatch.setattr(schedule, "WORKER_MAX_TRIANGLES", 1000)
    with Renderer(materials, threads=2, processes=True) as renderer:
        assert "primitives (triangles, curve segments, points) are over 1000" in renderer.crew.workers.skipped and renderer.crew.workers.workers == []


def test_a_loading_worker_holds_a_local_slot_until_ready_failed_or_late():
    """WaveSlots.reserve: while a worker loads, waves wait for it rather than run on a second thread of this
    process; the slot comes back when the worker fails or its time is up, and a ready worker takes it."""
    import queue
    import threading

    def taken(slots):
        """What slots.take() gives on another thread (a queue to wait on)."""
        out = queue.Queue()
        threading.Thread(target=lambda: out.put(slots.take()), daemon=True).start()
        return out

    worker, late = object(), object()
    slots = workers.WaveSlots(2)
    slots.reserve(worker, 60.0)
    assert slots.take() is None                 # one local slot is left
    waiting = taken(slots)
    with pytest.raises(queue.Empty):
        waiting.get(timeout=0.2)                # the second waits for the worker...
    slots.add_worker(worker)
    assert waiting.get(timeout=10) is worker    # ...and gets it, without a local slot retired twice
    slots.give(None)
    slots.give(worker)
    assert {id(slots.take()), id(slots.take())} == {id(None), id(worker)}
    # A worker that fails gives its slot back; so does one that is not ready in time.
    slots = workers.WaveSlots(2)
    slots.reserve(worker, 60.0)
    assert slots.take() is None
    waiting = taken(slots)
    slots.unreserve(worker)
    assert waiting.get(timeout=10) is None
    slots = workers.WaveSlots(2)
    slots.reserve(late, 0.05)
    assert slots.take() is None and taken(slots).get(timeout=10) is None
    slots.add_worker(late)                      # ready after its time: it takes the place of a local slot
    slots.give(None)
    slots.give(None)
    assert slots.take() is late


def test_prestarted_workers_wait_in_the_pool_for_the_renderer(materials):
    """A render about to export starts the workers its Renderer will take (prestart_workers), only when the
    Renderer would start them at once."""
    workers.close_pool()
    schedule.prestart_workers(2, schedule.WORKER_START_PATHS - 1)
    schedule.prestart_workers(1, schedule.WORKER_START_PATHS)
    assert workers.pooled() == []
    schedule.prestart_workers(2, schedule.WORKER_START_PATHS)
    assert len(workers.pooled()) == 1
    schedule.prestart_workers(2, schedule.WORKER_START_PATHS)    # one is there already
    assert len(workers.pooled()) == 1
    pid = workers.pooled()[0].process.pid
    with Renderer(materials, threads=2, processes=True) as renderer:
        assert renderer.crew.wait_for_workers() == 1 and renderer.crew.workers.reused == 1
        assert renderer.crew.workers.workers[0].process.pid == pid


def test_children_run_their_blas_on_one_thread(monkeypatch):
    """A child's BLAS threads would spin on the cores the parent renders on after each matrix product."""
    started = []
    popen = workers.subprocess.Popen
    monkeypatch.setattr(workers.subprocess, "Popen", lambda *a, **k: started.append(k) or popen(*a, **k))
    workers.Worker().close()
    (kwargs,) = started
    assert all(kwargs["env"][name] == "1" for name in workers._BLAS_THREADS)
    assert kwargs["env"]["PATH"] == os.environ["PATH"]    # the rest of the environment goes on


def test_the_start_waits_for_a_render_with_time_left():
    # 10% done after 0.2 s: 1.8 s left, over WORKER_START_S; 90% done: 0.02 s left.
    assert schedule.worth_workers(Progress(1, 10, 0.1, 0.2, paths=100))
    assert not schedule.worth_workers(Progress(9, 10, 0.9, 0.2, paths=900))
    assert not schedule.worth_workers(Progress(0, 10, 0.0, 0.0))


def test_f12_renders_with_worker_processes_and_says_so(tmp_path, monkeypatch, capfd):
    """End to end through Blender: a render long enough for workers (the bound lowered so that a small
    one is) has them render waves, the image equals a render with threads alone, and the finish line says
    how many took part."""
    import bpy
    from bpy_helpers import render_to_array
    scenes.materials_scene(40, 24)
    scene = bpy.context.scene
    scene.ember.use_denoising = False
    scene.render.threads_mode, scene.render.threads = "FIXED", 2
    capfd.readouterr()
    monkeypatch.setattr(schedule, "WORKER_START_PATHS", 1)
    monkeypatch.setattr(schedule, "LAYERED_WAVE_SIZE", 1024)   # many waves, so that the worker gets some
    monkeypatch.setattr(schedule, "MIN_WAVE_PATHS", 1024)
    prestarted = []
    original = schedule.prestart
    monkeypatch.setattr(schedule, "prestart", lambda count: prestarted.append(count) or original(count))
    workers.close_pool()
    helped = render_to_array(scene, "EMBER", 24, seed=3)
    out = capfd.readouterr().out
    assert "1 worker process" in out, out[-500:]
    assert prestarted == [1]    # started before the export, taken by the renderer
    monkeypatch.setattr(schedule, "WORKER_START_PATHS", 1 << 60)
    monkeypatch.setattr(schedule, "WORKER_START_S", 1e9)
    threads_only = render_to_array(scene, "EMBER", 24, seed=3)
    np.testing.assert_array_equal(helped, threads_only)
    assert "worker process" not in capfd.readouterr().out
