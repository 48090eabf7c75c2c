"""The progressive render: how a render's samples become passes of waves, where each wave runs, and when the
render ends (Cycles' render_scheduler.cpp holds the same decisions).

A render takes its samples in passes (plan_pass): one sample per pixel first, for a quick image, then as many
as fill _WAVES_PER_PASS waves. A pass's waves are interleaved bands of rows, each described by a WaveJob and
run by the renderer's WaveCrew on a thread of this process or in a worker process (kernels/workers.py), ahead
of the film: the results are added in plan order, so the image does not depend on where or when a wave ran.
Between passes the loop checks adaptive sampling's convergence (every ADAPTIVE_STEP samples after the
minimum), paces the passes to a time limit (paced), refines the BVH once the render is known to be long, and
honours stop requests (polled every STOP_POLL_S while it waits; the waves in flight leave at their next
bounce).
"""
from __future__ import annotations

import collections
import itertools
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass, field

import numpy as np

from .film import Film
from .passes import path_bytes
from .settings import RenderSettings
from .workers import WaveSlots, WaveStopped, WorkerLost, WorkerSet, prestart, python_executable

# The measurements behind these numbers are in docs/architecture.md (The wavefront; Threads and worker
# processes).
# A pass is cut into at least this many waves when the image allows, so that two cores have
# independent work; wave_size then bounds each wave.
_WAVES_PER_PASS = 4
# ... but no wave is cut below this many paths: a wave pays a fixed cost in Python per bounce whatever its
# size, and small waves on two threads only contend for the GIL.
MIN_WAVE_PATHS = 1 << 16

# Paths traced at once (automatic): every bounce runs Python once per material and lobe of the batch, so
# scenes whose materials mix lobes (Principled layers, Mix Shaders) get twice the paths to spread it over;
# diffuse scenes are faster with the smaller batches.
WAVE_SIZE = 1 << 17
LAYERED_WAVE_SIZE = 1 << 18
# Paths per wave when RenderSettings.wave_size is None: this many times the paths traced at once. New paths
# start as others end (trace_paths), so a wave's long paths (glass) pay the stages' fixed cost per bounce
# once per wave, not once per batch.
WAVE_SPAN = 4

# Worker processes (kernels/workers.py): a renderer with several threads starts threads - 1 children once
# a render has this many seconds left by its rate so far, enough to repay a child's start. Each child holds
# a copy of the scene's arrays (textures included) and builds its own BVH: scenes over WORKER_MAX_TRIANGLES
# stay in one process, with threads (there a child costs more than it brings, and Embree's share of the
# work, which releases the GIL, is larger), and the children's copies of the arrays stay within
# WORKER_MAX_BYTES together (many cores, a big texture: fewer children).
WORKER_START_S = 1.5
# ... or at once when a render has this many paths (about a second's work): a child from the pool is ready
# in a fraction of that (prestart_workers has the pool's children start while the scene is exported), and
# until then the render runs on one thread (WaveSlots.reserve), so a child costs a short render little.
WORKER_START_PATHS = 1 << 19
WORKER_MAX_BYTES = 512 << 20
WORKER_MAX_TRIANGLES = 1 << 18

# A stop request (should_stop(): Esc, Ctrl-C) is polled at least this often while the render waits for its
# waves; the waves in flight, here and in the worker processes, are then told at once and leave at their next
# bounce, so a stop takes about this plus one bounce, whatever the size of the waves.
STOP_POLL_S = 0.05
# Every render of this process has its own number: a worker process (which may serve renderers one after
# another) stops the waves of the render it is told, and of none after it.
GENERATIONS = itertools.count(1)

ADAPTIVE_STEP = 16  # samples between convergence checks, as Cycles' adaptive_step

# Pacing to a time limit (paced): a pass takes this share of the time left while more than FINAL_PASS_TAILS
# waves' fixed costs are left, and the last pass the rest. Each pass has one wave per thread
# (more where wave_size says so): a wave pays a fixed cost (its tail: the last few long paths, bounce after
# bounce, each bounce paying the stages' cost in Python whatever the paths) that small waves cannot repay.
PASS_SHARE = 2.0 / 3.0
FINAL_PASS_TAILS = 6.0
# ... and its waves may hold up to this many bytes of per-path buffers (passes.path_bytes: 16 a path for the image,
# more with passes), more paths than the wave size, which also sets how far a fixed-sample render's progress
# moves at a time: a time-limited pass that the wave size would cut into rounds of waves on each thread pays
# every round's tail (on the Random Walk head a paced wave of 600,000-900,000 paths spent 0.7-1.1 s of its
# 1.6-2.7 s in its tail), and its progress is shown pass by pass anyway.
PACED_WAVE_BYTES = 128 << 20
# The last pass plans for this share of the time left: its waves' cost is an estimate, and the render's
# end waits for its slowest wave.
FINAL_PASS_SHARE = 0.95


@dataclass(frozen=True)
class WaveCost:
    """The seconds a wave of n paths takes on one thread: fixed + n / rate. The fixed part is the wave's
    tail and set-up, about the same whatever its size (tenths of a second in scenes of many materials)."""
    fixed: float
    rate: float

    def paths(self, seconds: float) -> float:
        """Paths of one wave that ends in `seconds` (0 when its fixed cost alone is more)."""
        return max(0.0, seconds - self.fixed) * self.rate


def wave_cost(waves: list, recent: int = 4) -> WaveCost | None:
    """The WaveCost of waves measured as (paths, seconds, tail seconds), None without any: the fixed part is
    the waves' median tail (integrator.trace's timing); the rate that of the slowest of the `recent` last
    waves without its tail, as the render ends with its slowest thread (on a loaded machine the threads
    and worker processes do not keep pace). The render's first wave is left out where others are: it also
    pays the render's one-time costs (the first gathers of textures, tables built on first use)."""
    waves = [w for w in waves if w[0] > 0 and w[1] > 0]
    if not waves:
        return None
    if len(waves) > 1:
        waves = waves[1:]
    fixed = float(np.median([min(tail, seconds) for _, seconds, tail in waves]))
    rate = min(paths / max(seconds - min(tail, seconds), 0.1 * seconds) for paths, seconds, tail in waves[-recent:])
    return WaveCost(fixed, float(rate))



@dataclass
class Progress:
    """What a render has done so far, passed to on_progress after every wave."""
    samples_done: int          # samples every pixel of the region has
    samples_total: int
    fraction: float            # of all paths of the render, 0..1
    elapsed_s: float
    paths: int = 0
    rays: int = 0
    seconds_in_embree: float = 0.0
    nonfinite_paths: int = 0   # paths whose radiance came out NaN or inf and were dropped
    workers: int = 0           # worker processes that rendered waves (kernels/workers.py), the most at once

    @property
    def paths_per_s(self) -> float:
        return self.paths / self.elapsed_s if self.elapsed_s > 0 else 0.0

    @property
    def rays_per_s(self) -> float:
        return self.rays / self.elapsed_s if self.elapsed_s > 0 else 0.0


@dataclass
class RenderResult:
    """What a render made. The image is resolved from the film when asked for (a full-frame float32
    copy): a caller that streams the result can read it in bands with film.resolve(row0, row1)."""
    film: Film = field(repr=False)
    progress: Progress
    stopped_early: bool
    dropped_triangles: int = 0

    @property
    def image(self) -> np.ndarray:
        """(H, W, 4) float32 linear RGBA of the region, row 0 at the top."""
        return self.film.resolve()


@dataclass(frozen=True)
class WaveJob:
    """One wave's work: samples first_sample .. first_sample + spp - 1 of the pixels of region rows `rows` (a
    band: every rows.step-th row, plan_pass), `width` pixels wide from (x0, y0) of the full frame; `active`
    (rows, width) bool, the pixels that still take samples (adaptive sampling; None: all); at most `live`
    paths traced at once (the render's own, so that a worker process traces the wave in the same batches);
    split: the pass has fewer waves than threads (its waves' rate is not one thread's)."""
    x0: int
    y0: int
    width: int
    rows: range
    first_sample: int
    spp: int
    split: bool = False
    active: np.ndarray | None = None
    live: int | None = None


class WaveCrew:
    """Where a renderer's waves run: `threads` slots, each a thread of this process or, once one is ready, a
    worker process (processes: None starts them when a render is long enough, True at once, False never).
    It also holds what the waves of the render in progress share: its generation, its stop flag and the
    record of its waves' times (rate, cost)."""

    def __init__(self, threads: int, processes: bool | None):
        self.threads = threads
        self.pool = ThreadPoolExecutor(threads, "ember-wave") if threads > 1 else None
        self.processes = processes if threads > 1 and python_executable() is not None else False
        self.slots = WaveSlots(threads)
        self.workers: WorkerSet | None = None
        self.remote_waves = 0    # waves rendered by worker processes (all renders)
        self.generation = 0      # the render in progress, or the last (GENERATIONS)
        # Set: the waves of the render in progress leave at their next bounce (a worker process's reader thread
        # sets its renderer's when the parent stops the render).
        self.stop_waves = threading.Event()
        self._poll = None        # the render's should_stop, polled by its own thread (check_stop)
        self._thread = None
        self._lock = threading.Lock()
        # (paths, seconds, tail seconds, split) of the render's waves in the order they ended, each timed on its
        # own thread; split: a wave of a pass split over the threads (fewer waves than threads).
        self.waves = []

    # ---------------------------------------------------------------- worker processes
    def start_workers(self, scene, triangles: int, runner: str) -> bool:
        """Start threads - 1 worker processes for `scene` (its `triangles`), each building `runner`
        ("module:class", kernels/workers.py) from it; False when this crew does not use them."""
        if self.processes is False:
            return False
        if self.workers is None:
            self.workers = WorkerSet(self.slots)
            if triangles > WORKER_MAX_TRIANGLES:
                self.workers.skipped = f"{triangles} primitives (triangles, curve segments, points) are over " \
                    f"{WORKER_MAX_TRIANGLES}"
                self.processes = False
                return False
            if not self.workers.start(self.threads - 1, scene, WORKER_MAX_BYTES, runner):
                self.processes = False   # not again for this renderer
                return False
        return True

    def workers_undecided(self) -> bool:
        """Automatic worker processes (processes=None) not started yet."""
        return self.processes is None and self.workers is None

    def wait_for_workers(self, timeout_s: float = 60.0) -> int:
        """Block until every started worker is ready or failed; the number ready."""
        deadline = time.perf_counter() + timeout_s
        workers = self.workers.workers if self.workers is not None else []
        while time.perf_counter() < deadline and any(not w.ready and not w.closed for w in workers):
            time.sleep(0.01)
        return self.workers.ready if self.workers is not None else 0

    @property
    def worker_count(self) -> int:
        """Worker processes ready to render waves."""
        return self.workers.ready if self.workers is not None else 0

    @property
    def worker_failures(self) -> list[str]:
        """Why worker processes were not started, failed or were dropped (their waves ran here)."""
        return list(self.workers.failures) if self.workers is not None else []

    def forward(self, method: str, args: tuple, kwargs: dict) -> None:
        """An update of the renderer, for the worker processes' twins."""
        if self.workers is not None:
            self.workers.forward(method, args, kwargs)

    # ---------------------------------------------------------------- a render's waves
    def begin(self, should_stop) -> None:
        """A render starts: a new generation, its stop flag down, should_stop polled by its thread, a clock of
        its own waves."""
        self.generation = next(GENERATIONS)
        self.stop_waves.clear()
        self._poll, self._thread = should_stop, threading.get_ident()
        self.waves = []   # this render's waves only (rate, cost)

    def end(self) -> None:
        """Every wave of the render is back."""
        self._poll = self._thread = None
        self.stop_waves.clear()

    def submit(self, tracer, settings: RenderSettings, job: WaveJob) -> Future:
        """Run tracer.render_wave(settings, job) in a free slot (now, on one thread), as a Future."""
        if self.pool is None:   # one thread: the wave runs now, its outcome kept as a pool's would be
            future = Future()
            try:
                future.set_result(self._wave(tracer, settings, job))
            except Exception as err:  # noqa: BLE001 - raised again by future.result(), as from a pool
                future.set_exception(err)
            return future
        return self.pool.submit(self._wave, tracer, settings, job)

    def _wave(self, tracer, settings: RenderSettings, job: WaveJob):
        """The wave in a free slot: this process or a ready worker process (timed, for rate and cost). A worker
        that is lost (closed, exited, failed) gives its slot back to this process, and the wave runs here."""
        began = time.perf_counter()
        result = self._in_slot(tracer, settings, job)
        seconds = time.perf_counter() - began
        with self._lock:
            self.waves.append((int(result[2].sum()), seconds, result[5], bool(job.split)))
        return result

    def cost(self) -> WaveCost | None:
        """What a wave costs on one thread, from the render's waves so far (wave_cost); None before the first."""
        with self._lock:
            return wave_cost([w[:3] for w in self.waves])

    def _in_slot(self, tracer, settings: RenderSettings, job: WaveJob):
        slot = self.slots.take()
        try:
            if self.stop_waves.is_set():   # it waited for its slot past a stop request
                raise WaveStopped()
            if slot is not None:
                try:
                    result, rays, seconds = slot.render_wave(settings, job, self.generation)
                except WorkerLost as err:
                    self.workers.lost(slot, err)
                    slot = None
                else:
                    tracer.accel.count(rays, seconds)
                    with self._lock:
                        self.remote_waves += 1
                    return result
            return tracer.render_wave(settings, job)
        finally:
            self.slots.give(slot)

    def result(self, future, should_stop):
        """future.result(), polling should_stop() every STOP_POLL_S meanwhile (a wave can take seconds)."""
        while True:
            try:
                return future.result(timeout=STOP_POLL_S)
            except FutureTimeout:
                self.stop_requested(should_stop)

    def stop_requested(self, should_stop) -> bool:
        """Whether the render in progress is to stop: once should_stop() says so, the waves in flight are told
        (here and in the worker processes), and leave at their next bounce."""
        if not self.stop_waves.is_set() and should_stop is not None and should_stop():
            self.stop_waves.set()
            if self.workers is not None:
                self.workers.stop(self.generation)
        return self.stop_waves.is_set()

    def check_stop(self) -> None:
        """Between the bounces of a wave: WaveStopped at a stop request. A wave on the render's own thread (one
        thread: the waves run there) polls should_stop itself, as nothing else does meanwhile."""
        if threading.get_ident() == self._thread:
            self.stop_requested(self._poll)
        if self.stop_waves.is_set():
            raise WaveStopped()

    def rate(self) -> float | None:
        """Paths per second of the render so far on all its threads, from its waves' own times (the
        render's wall time would also count the first waves' start-up, and miss the work of the waves still
        running): the rate of the waves that run side by side, one per thread, times the threads; until
        there are such waves, that of the waves split over the threads. None before the first wave."""
        with self._lock:
            waves = list(self.waves)
        for split in (False, True):
            paths = sum(w[0] for w in waves if w[3] == split)
            seconds = sum(w[1] for w in waves if w[3] == split)
            if paths and seconds > 0:
                return paths / seconds * (1 if split else self.threads)
        return None

    def close(self) -> None:
        """Stop the threads and the worker processes (these go back to the pool)."""
        if self.pool is not None:
            self.pool.shutdown(wait=True)
            self.pool = None
        if self.workers is not None:
            self.workers.close()


def worth_workers(progress: Progress) -> bool:
    """Whether the render has WORKER_START_S left at its rate so far."""
    if progress.paths <= 0 or progress.fraction >= 1.0:
        return False
    return progress.elapsed_s * (1.0 - progress.fraction) / progress.fraction > WORKER_START_S


def out_of_time(settings: RenderSettings, start: float) -> bool:
    return settings.time_limit_s > 0 and time.perf_counter() - start >= settings.time_limit_s


def render_passes(tracer, crew: "WaveCrew", settings: RenderSettings, on_tile=None, should_stop=None,
                  on_progress=None) -> RenderResult:
    """The progressive loop of one render of `tracer` (kernels.renderer.Renderer: render_wave, wave_size,
    live_paths, prepare_pass, start_workers, accel, scene) with its waves run by `crew`. See
    Renderer.render for the callbacks."""
    cam = tracer.scene.camera
    x0, y0, x1, y1 = settings.validate(cam.width, cam.height)
    width, height = x1 - x0, y1 - y0
    film = Film(width, height, adaptive=settings.adaptive_threshold > 0, passes=settings.passes,
                cryptomatte=settings.cryptomatte, cryptomatte_depth=settings.cryptomatte_depth,
                transparent=settings.transparent_background, exposure=settings.exposure)
    total = int(settings.samples)
    start = time.perf_counter()
    crew.begin(should_stop)
    embree_start = tracer.accel.seconds_in_embree
    rays_start = tracer.accel.rays_traced
    progress = Progress(0, total, 0.0, 0.0)
    stopped = False
    done = 0
    adaptive = settings.adaptive_threshold > 0
    min_samples = adaptive_min_samples(settings) if adaptive else total
    if crew.workers_undecided() and width * height * total >= WORKER_START_PATHS:
        tracer.start_workers()
    # Waves run concurrently (NumPy and Embree release the GIL, and worker processes share nothing);
    # their results are added to the film in the order they were planned, so the image does not depend
    # on the thread count. Waves of the next pass are queued while the last ones of a pass finish (a
    # pass's bands differ in cost: rows of sky and rows of glass), except before a convergence check,
    # which reads the whole film.
    in_flight = collections.deque()   # (rows, spp, future), in plan order
    pending = []                      # bands of the planned pass not yet submitted
    pass_spp = pass_first = 0
    pass_split = False
    depth = 1 if tracer.accel.threads == 1 else 2 * tracer.accel.threads   # waves submitted ahead
    while True:
        if not pending and not stopped and done < total:
            check = adaptive and done >= min_samples and (done - min_samples) % ADAPTIVE_STEP == 0
            if check and in_flight:
                pass  # add every wave in flight first
            elif done and settings.time_limit_s > 0 and in_flight:
                pass  # a paced pass is planned once every wave is back (below)
            elif done and out_of_time(settings, start):
                stopped = True  # a pass never starts after the limit
            else:
                if check:
                    film.update_convergence(settings.adaptive_threshold)
                    if film.converged.all():
                        break
                wave, last, waves = tracer.wave_size(settings), total, None
                rate = crew.rate()
                queued = sum(len(rows) * width * s for rows, s, _ in in_flight)   # paths planned, not in
                cost = crew.cost() if done and settings.time_limit_s > 0 else None
                if cost is not None:
                    # A time-limited render's passes take the samples that fit in a share of the time
                    # left by what its waves have cost so far, and the last pass the rest: the render ends
                    # close to its limit, not up to a wave or a pass after it (as Cycles' scheduler fits
                    # its samples to the time left), in few large waves. Such a pass is planned once every
                    # wave is back: on a loaded machine one thread can lag another by a second, and a
                    # wave's paths cannot be counted until it ends.
                    active = int(np.count_nonzero(~film.converged)) if adaptive else width * height
                    fit, wave, waves = paced(cost, settings.time_limit_s - (time.perf_counter() - start),
                                             active, tracer.accel.threads, paced_wave_size(settings, wave))
                    last = min(total, done + fit)
                if last == done:
                    stopped = True  # not even one more sample fits before the limit
                    continue
                # A time-limited render starts with a 1-sample pass too: its waves give the rate that
                # fits the next passes to the limit, whatever the limit.
                quick = settings.quick_first_pass or settings.time_limit_s > 0
                spp, bands = plan_pass(width, height, done, last, wave, quick, tracer.live_paths(settings), waves)
                if adaptive:  # passes end where the next convergence check falls
                    next_check = min_samples if done < min_samples else \
                        done + ADAPTIVE_STEP - (done - min_samples) % ADAPTIVE_STEP
                    spp = max(1, min(spp, next_check - done))
                if done or (spp < total and not quick):
                    # More than a quick first pass to come: a big scene's deferred triangle table is
                    # built (until then, gathers compute the rows they need), and its quick BVH is
                    # replaced by the medium one once the rate so far says the render has long enough
                    # to go (accel.QUICK_BVH_TRIANGLES), both on threads.
                    tracer.prepare_pass()
                    if rate:
                        time_left = ((total - done) * width * height + queued) / rate
                        if settings.time_limit_s > 0:
                            time_left = min(time_left, settings.time_limit_s - progress.elapsed_s)
                        tracer.accel.refine(time_left)
                pending = list(bands)
                pass_spp, pass_first = spp, int(settings.sample_offset) + done
                pass_split = len(bands) < tracer.accel.threads
                done += spp
        while pending and len(in_flight) < depth:
            rows = pending.pop(0)
            active = ~film.converged[rows] if adaptive else None      # (a range indexes as a list)
            job = WaveJob(x0, y0, width, rows, pass_first, pass_spp, pass_split, active, tracer.live_paths(settings))
            in_flight.append((rows, pass_spp, crew.submit(tracer, settings, job)))
        if not in_flight:
            break
        rows, spp, future = in_flight.popleft()
        if future.cancelled():
            continue
        try:
            sums, half, counts, bad, aux, _ = crew.result(future, should_stop)
        except WaveStopped:   # left at a stop request: its paths are incomplete, none is added
            stopped, pending = True, []
            for *_, queued in in_flight:
                queued.cancel()
            continue
        film.add_rows(rows, sums, counts if adaptive else spp, half, aux)
        progress.paths += int(counts.sum())
        progress.nonfinite_paths += bad
        progress.elapsed_s = time.perf_counter() - start
        progress.rays = tracer.accel.rays_traced - rays_start
        progress.seconds_in_embree = tracer.accel.seconds_in_embree - embree_start
        progress.samples_done = film.samples_done
        progress.fraction = progress.paths / (width * height * total)
        progress.workers = max(progress.workers, crew.worker_count)
        if on_tile is not None:
            on_tile(film, rows.start, rows[-1] + 1)
        if on_progress is not None:
            on_progress(progress)
        if crew.workers_undecided() and worth_workers(progress):
            tracer.start_workers()
        # A time limit always lets the first full pass finish, as Cycles' does; its waves in flight finish
        # too (a stop request has them leave at their next bounce).
        if not stopped and (crew.stop_requested(should_stop) or (
                film.samples_done > 0 and out_of_time(settings, start))):
            stopped = True
            pending = []  # start no more waves
            for *_, queued in in_flight:
                queued.cancel()
    if stopped and film.samples_done >= total:
        stopped = False  # the stop came with the last wave: the render is complete
    crew.end()   # every wave is back: trace_paths is free to run again
    return RenderResult(film, progress, stopped, tracer.dropped_triangles)


def prestart_workers(threads: int, paths: int) -> None:
    """Before a render of `paths` paths on `threads` threads exports its scene: start the worker processes
    its Renderer will take (kernels/workers.py prestart), when it will start them at once."""
    if threads > 1 and paths >= WORKER_START_PATHS and python_executable() is not None:
        prestart(threads - 1)



def adaptive_min_samples(settings: RenderSettings) -> int:
    """Samples before the first convergence check: the setting, or Cycles' automatic count (threshold
    0.1 -> 32, 0.01 -> 64, 0.001 -> 128), at least 4."""
    if settings.adaptive_min_samples > 0:
        return max(4, int(settings.adaptive_min_samples))
    return max(4, int(np.ceil(16.0 / settings.adaptive_threshold ** 0.3)))


def paced(cost: WaveCost, left_s: float, pixels: int, threads: int, wave_size: int):
    """(samples, paths per wave, waves) of a pass planned with left_s seconds of a time limit to go, at `cost`
    per wave on each of `threads` threads: the pass takes PASS_SHARE of the time left, or FINAL_PASS_SHARE
    once that is at most FINAL_PASS_TAILS waves' fixed cost; one wave per thread, or as many as keep waves
    within wave_size; the samples per pixel whose waves end nearest that (0 when not even half a sample's
    paths fit)."""
    span = FINAL_PASS_SHARE * left_s if left_s <= FINAL_PASS_TAILS * cost.fixed else PASS_SHARE * left_s
    per_thread = cost.paths(span)
    rounds = max(1, int(np.ceil(per_thread / max(wave_size, 1))))
    if rounds > 1:   # each further wave on a thread pays its fixed cost too
        per_thread = cost.rate * max(0.0, span - rounds * cost.fixed)
    fit = int(per_thread * threads / max(pixels, 1) + 0.5)
    waves = rounds * max(threads, 1)
    return max(fit, 0), max(1, min(wave_size, int(np.ceil(per_thread / rounds)))), waves


def paced_wave_size(settings: RenderSettings, wave_size: int) -> int:
    """The most paths a wave of a paced pass takes: PACED_WAVE_BYTES of per-path buffers, at least the render's
    wave size; the wave size itself where the settings give one."""
    if settings.wave_size is not None:
        return wave_size
    return max(wave_size, PACED_WAVE_BYTES // path_bytes(settings))


def plan_pass(width: int, height: int, done: int, total: int, wave_size: int, quick_first: bool = True,
               band_pixels: int | None = None, waves: int | None = None):
    """Samples per pixel of the next pass and its bands of rows (ranges of region rows), one wave each.

    The first pass takes one sample, for a quick first image (unless quick_first is False); later passes
    take enough samples to fill _WAVES_PER_PASS waves. A band holds at most band_pixels pixels where it can
    (a wave's sums per pixel are its own: at few samples per pixel, a wave of many paths would hold
    buffers for as many pixels). The bands interleave: of n bands, band j holds rows j, j + n, j + 2n...,
    so that the waves of a pass cost about the same wherever the image's costly rows are (rows of glass
    and rows of sky), and the last waves of a pass on two cores end together. The plan depends only on
    the image and the settings, never on the thread count, so every thread count sums the same numbers
    in the same order; except that of a time-limited render's later passes (paced), which give their
    count of `waves` and take all their samples (total - done) in as many bands as band_pixels allows
    (fewer samples where the image has fewer rows than waves, so that a wave stays within wave_size).
    """
    if waves is not None and not (done == 0 and quick_first):
        spp = max(1, total - done)
        count = max(1, int(waves))
        if band_pixels is not None:
            count = max(count, -(-height // max(1, band_pixels // width)))
        count = min(count, height)
        spp = max(1, min(spp, wave_size // max(1, -(-height // count) * width)))   # more waves than rows
        return spp, [range(j, height, count) for j in range(count)]
    if done == 0 and quick_first:
        spp = 1
    else:
        spp = int(np.clip(wave_size * _WAVES_PER_PASS // (width * height), 1, total - done))
    rows_per_wave = max(1, min(wave_size // (width * spp),
                               max(-(-height // _WAVES_PER_PASS), MIN_WAVE_PATHS // (width * spp))))
    if band_pixels is not None:
        rows_per_wave = max(1, min(rows_per_wave, band_pixels // width))
    count = -(-height // rows_per_wave)
    return spp, [range(j, height, count) for j in range(count)]
