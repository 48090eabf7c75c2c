"""A stop request (Esc, the command line's Ctrl-C or SIGTERM: should_stop()) reaches the waves in flight at
once: they leave at their next bounce, in this process and in the worker processes, instead of running to
their end. The scene is the inside of a closed white sphere (albedo 1, no Russian roulette in COSINE mode):
every path of a wave bounces max_bounces + 1 times, so a wave that ran to its end would show. Nothing here
depends on wall time: the bounces are counted (bench/cancel_latency.py measures the seconds)."""
import dataclasses
import threading

import numpy as np
import pytest

from kernel_helpers import inside_emitting_sphere

from ember.kernels import Renderer, RenderSettings
from ember.kernels import schedule
from ember.kernels.workers import WaveStopped

BOUNCES = 300
SETTINGS = RenderSettings(samples=8, seed=1, max_bounces=BOUNCES, mode="COSINE", wave_size=1 << 16)


@pytest.fixture(scope="module")
def sphere():
    return inside_emitting_sphere(albedo=1.0, radiance=0.1, width=128, height=128)


class Bounces:
    """Counts the renderer's ray batches (one per bounce of a wave, in this process), and those begun once
    its stop flag was set; asks for the stop at the `stop_at`-th."""

    def __init__(self, renderer, stop_at):
        self.renderer, self.stop_at = renderer, stop_at
        self.count = self.after_stop = 0
        self.requested = threading.Event()
        self._lock = threading.Lock()
        intersect = renderer.accel.intersect

        def counting(*args, **kwargs):
            with self._lock:
                self.count += 1
                self.after_stop += renderer.stop_waves.is_set()
                if self.count == stop_at:
                    self.requested.set()
            return intersect(*args, **kwargs)
        renderer.accel.intersect = counting


def test_waves_in_flight_leave_at_their_next_bounce(sphere):
    """Two threads, two waves of 65,536 paths in flight, each of 301 bounces. Before, should_stop() was
    polled only between waves: both ran their 301 bounces (and the next ones queued) before the render
    returned."""
    with Renderer(sphere, threads=2, processes=False) as renderer:
        bounces = Bounces(renderer, stop_at=4)
        result = renderer.render(SETTINGS, should_stop=bounces.requested.is_set)
    assert result.stopped_early and result.progress.paths == 0 and result.film.samples_done == 0
    assert bounces.count < BOUNCES   # no wave ran to its end
    # Each wave checks the flag just before it traces: at most one batch per wave can slip in between.
    assert bounces.after_stop <= 2, bounces.after_stop


def test_one_thread_polls_the_request_between_bounces(sphere):
    """One thread: the wave runs on the render's own thread, which nothing else polls meanwhile."""
    with Renderer(sphere, threads=1, processes=False) as renderer:
        bounces = Bounces(renderer, stop_at=3)
        result = renderer.render(SETTINGS, should_stop=bounces.requested.is_set)
    assert result.stopped_early and result.progress.paths == 0
    assert bounces.count == 3 and bounces.after_stop == 0


def test_worker_processes_are_told_at_once_and_serve_the_next_render(sphere):
    """A wave in a worker process leaves at its next bounce too (the stop travels on its pipe, read by a
    thread of the child while the wave runs); the stopped wave is not a failure, and the next render on the
    same workers is whole and the same image as one without them."""
    settings = RenderSettings(samples=2, seed=1, max_bounces=BOUNCES, mode="COSINE", wave_size=1 << 13)
    # The next render needs no long waves: a stop that outlived its render, or a reply of the stopped wave left on
    # the pipe, spoils the next render's waves whatever their length.
    after = dataclasses.replace(settings, max_bounces=8)
    with Renderer(sphere, threads=2, processes=False) as renderer:
        reference = renderer.render(after).image
    with Renderer(sphere, threads=2, processes=True) as renderer:
        assert renderer.crew.wait_for_workers() == 1
        worker = renderer.crew.workers.workers[0]
        outcomes = []
        render_wave = worker.render_wave

        def recorded(*args):
            try:
                return render_wave(*args)
            except WaveStopped:
                outcomes.append("stopped")
                raise
        worker.render_wave = recorded
        bounces = Bounces(renderer, stop_at=4)
        result = renderer.render(settings, should_stop=bounces.requested.is_set)
        assert result.stopped_early and result.progress.paths == 0
        assert outcomes == ["stopped"] and renderer.crew.remote_waves == 0
        assert renderer.crew.worker_failures == [] and renderer.crew.worker_count == 1
        image = renderer.render(after).image
        assert renderer.crew.remote_waves > 0
    np.testing.assert_array_equal(image, reference)


def test_a_time_limit_still_lets_the_waves_in_flight_finish(sphere, monkeypatch):
    """The time limit stops planning new passes; it does not drop the work of the waves running."""
    monkeypatch.setattr(schedule, "out_of_time", lambda settings, start: True)
    with Renderer(sphere, threads=2, processes=False) as renderer:
        result = renderer.render(RenderSettings(samples=8, seed=1, max_bounces=4, mode="COSINE", time_limit_s=1.0))
    assert result.stopped_early and result.film.samples_done >= 1 and result.progress.paths > 0
