"""Waves rendered in other processes: the same renderer, rebuilt from the same SceneArrays in a child process.

Why: a wave is thousands of NumPy calls on arrays of ten to a hundred thousand paths. NumPy releases the GIL
inside each call, but the Python between the calls holds it, so two threads of one process reach about 1.4x
one thread's rate on the eight Principled spheres (0.54 against 0.39M paths/s) while two processes reach 2x
(0.70M). Cycles' threads share nothing in Python; these processes share nothing either.

How: a child is a plain Python (sys.executable, the parent's sys.path) that imports this package, nothing of
Blender. It receives the parent's validated scene once, with the name of the runner to build from it (the
parent's renderer class, "module:class": this module knows only what a runner does, below), builds its own
(its own Embree BVH: Embree scenes cannot be shared between processes), and then renders waves: it gets a
wave's settings and job (kernels.schedule.WaveJob) and sends back the runner's render_wave result, the same
arrays bit for bit, since the child runs the same code on the same data.

A runner is built as runner(scene, threads=1, processes=False) and provides render_wave(settings, job),
stop_waves (a threading.Event its waves poll between bounces), accel.rays_traced and
accel.seconds_in_embree (counters), close(), and the update methods the parent forwards by name: between
renders the parent forwards its incremental updates (camera, instances, materials, lights, the next frame's
scene) in order, so a child stays the parent's twin. When the renderer closes, its children drop their scene
and wait in a pool for the next renderer of this process (an F12 render again, the next frame without
Persistent Data), which then skips their start; idle ones exit after IDLE_S.

The protocol is pickles over the child's stdin and stdout (the child points its own stdout at stderr, so
stray prints cannot break it); NumPy arrays travel as out-of-band buffers, written from and read into their
memory without a copy in the pickle. A child that dies or fails is dropped: its wave runs again in the
parent, so no wave is ever lost, and the image is the same.
"""
from __future__ import annotations

import atexit
import io
import json
import os
import pickle
import queue
import struct
import subprocess
import sys
import threading
import time
import traceback
import weakref

_HEADER = struct.Struct("<QI")   # pickle length, buffer count
_LENGTH = struct.Struct("<Q")

# Started in the child with `python -c`: ignore the signals that stop a render (Ctrl-C and a farm's SIGTERM
# reach the whole process group; the parent decides, and the child leaves when its pipes close), register
# the package under its name in the parent (ember, bl_ext.user_default.ember, ...), with empty namespace
# modules for the prefixes Blender makes up at run time, then serve.
_BOOT = r"""
import signal
for name in ("SIGINT", "SIGTERM", "SIGHUP"):
    if hasattr(signal, name):
        signal.signal(getattr(signal, name), signal.SIG_IGN)
import importlib, importlib.util, json, sys, types
cfg = json.loads(sys.argv[1])
sys.path[:] = cfg["path"]
parts = cfg["package"].split(".") if cfg["package"] else []
for i in range(1, len(parts)):
    prefix = ".".join(parts[:i])
    if prefix not in sys.modules:
        stub = types.ModuleType(prefix)
        stub.__path__ = []
        sys.modules[prefix] = stub
if parts:
    spec = importlib.util.spec_from_file_location(cfg["package"], cfg["init"], submodule_search_locations=[cfg["root"]])
    root = importlib.util.module_from_spec(spec)
    sys.modules[cfg["package"]] = root
    spec.loader.exec_module(root)
importlib.import_module(cfg["kernels"] + ".workers").serve()
"""


# What OpenBLAS, MKL, OpenMP and Accelerate read for their thread counts, when the library loads.
_BLAS_THREADS = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS", "VECLIB_MAXIMUM_THREADS")


class WorkerLost(Exception):
    """The child process exited, failed or could not be reached; its wave runs in the parent."""


class WaveStopped(Exception):
    """A wave left between two bounces at a stop request (here or in a child): nothing of it is kept."""


# ---------------------------------------------------------------------------------------------- framing
def pickled(obj) -> tuple[bytes, list]:
    """obj's pickle and its out-of-band buffers (views of NumPy's arrays, not copies)."""
    buffers = []
    data = pickle.dumps(obj, protocol=5, buffer_callback=buffers.append)
    return data, [b.raw() for b in buffers]


def pickled_size(payload) -> int:
    data, views = payload
    return len(data) + sum(v.nbytes for v in views)


def send(stream, obj, payload=None) -> None:
    """Write obj (or its payload from pickled()) to a binary stream: a header, the pickle, then each
    out-of-band buffer."""
    data, views = pickled(obj) if payload is None else payload
    stream.write(_HEADER.pack(len(data), len(views)))
    for view in views:
        stream.write(_LENGTH.pack(view.nbytes))
    stream.write(data)
    for view in views:
        stream.write(view)
    stream.flush()


def _read_exact(stream, n: int) -> bytearray:
    out = bytearray(n)
    view = memoryview(out)
    got = 0
    while got < n:
        k = stream.readinto(view[got:])
        if not k:
            raise EOFError("the stream ended")
        got += k
    return out


def receive(stream):
    """Read one object written by send()."""
    size, count = _HEADER.unpack(_read_exact(stream, _HEADER.size))
    lengths = [_LENGTH.unpack(_read_exact(stream, _LENGTH.size))[0] for _ in range(count)]
    data = _read_exact(stream, size)
    buffers = [_read_exact(stream, n) for n in lengths]
    return pickle.loads(data, buffers=buffers)


# ---------------------------------------------------------------------------------------------- the parent
def _package() -> tuple[str, str, str]:
    """(the name of the package that holds kernels, "" when kernels is imported alone; its directory; the
    name kernels is imported under)."""
    kernels = __name__.rsplit(".", 1)[0]
    root = kernels.rsplit(".", 1)[0] if "." in kernels else ""
    return root, os.path.dirname(os.path.dirname(os.path.abspath(__file__))), kernels


def python_executable() -> str | None:
    """The Python interpreter to start children with, or None when there is none to use. In Blender,
    sys.executable is its bundled Python (since 2.91); a path to Blender itself would not run `-c`."""
    exe = sys.executable
    if not exe or not os.path.isfile(exe) or "blender" in os.path.basename(exe).lower():
        return None
    return exe


class Worker:
    """One child process and its pipes. load() gives it a scene (in the background); render_wave() is called by
    one thread at a time (the wave slots); forward() may be called between renders, from another thread;
    release() drops the scene and puts the child in this process's pool of idle workers, for the next
    renderer (a fresh render then skips the child's start, about 0.3 s)."""

    def __init__(self):
        exe = python_executable()
        if exe is None:
            raise WorkerLost("no Python interpreter to start a worker with")
        package, root, kernels = _package()
        cfg = json.dumps({"path": [p for p in sys.path if isinstance(p, str)], "package": package,
                          "init": os.path.join(root, "__init__.py"), "root": root, "kernels": kernels})
        # (On Windows a console program started from Blender's window would open a console of its own.)
        # -I -S: no site-packages, .pth hooks or PYTHON* variables of this machine; the parent's sys.path
        # (Blender's, with the wheels' site-packages) is the child's whole path.
        # One thread for the BLAS NumPy may be linked with: a child is one core's worth of waves, and an
        # OpenBLAS pool spins its threads for a while after every matrix product, on the cores the parent
        # and the other children render on.
        env = dict(os.environ, **{name: "1" for name in _BLAS_THREADS})
        self.process = subprocess.Popen([exe, "-I", "-S", "-c", _BOOT, cfg], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, bufsize=0, env=env,
                                        creationflags=getattr(subprocess, "CREATE_NO_WINDOW", 0))
        self._in = io.BufferedWriter(self.process.stdin, 1 << 16)
        self._out = io.BufferedReader(self.process.stdout, 1 << 16)
        self._write = threading.Lock()
        self.ready = False      # holds a scene and renders waves
        self.loading = False
        self.closed = False
        self.error = None
        self.idle_since = None  # in the pool since (time.monotonic())

    def load(self, payload, on_ready, on_failed) -> None:
        """Send a scene (pickled(("scene", scene, runner))) and wait for the child's Renderer in the background;
        on_ready(self) or on_failed(self) then. Updates forwarded meanwhile follow the scene."""
        self._write.acquire()   # the scene goes first: forwarded updates wait for it
        self.ready, self.loading, self.error = False, True, None
        threading.Thread(target=self._load, args=(payload, on_ready, on_failed), daemon=True,
                         name="ember-worker-load").start()

    def _load(self, payload, on_ready, on_failed) -> None:
        try:
            try:
                send(self._in, None, payload)
            finally:
                self._write.release()
            del payload
            reply = receive(self._out)
            if reply[0] != "ready":
                raise WorkerLost(f"the worker could not build the scene: {reply[1]}")
        except BaseException as err:  # noqa: BLE001 - any failure: the worker is not used
            self.error = err if isinstance(err, WorkerLost) else WorkerLost(f"{type(err).__name__}: {err}")
            self.loading = False
            on_failed(self)
            self.close()
            return
        self.ready, self.loading = True, False
        on_ready(self)

    def forward(self, method: str, args: tuple, kwargs: dict) -> None:
        """Apply a Renderer update in the child too (after the scene, before the next wave)."""
        if self.closed:
            return
        try:
            with self._write:
                send(self._in, ("call", method, args, kwargs))
        except (OSError, ValueError) as err:
            self.error = WorkerLost(f"{type(err).__name__}: {err}")
            self.close()

    def render_wave(self, settings, job, generation: int):
        """The runner's render_wave(settings, job) in the child, for the render `generation` of the parent's
        renderer: (its result, rays traced, seconds in Embree); WaveStopped when stop() reached it first."""
        if self.closed or not self.ready:
            raise WorkerLost("the worker is closed")
        try:
            with self._write:
                send(self._in, ("wave", settings, job, generation))
            reply = receive(self._out)
        except (OSError, EOFError, ValueError, pickle.UnpicklingError) as err:
            self.close()
            raise WorkerLost(f"{type(err).__name__}: {err}") from err
        if reply[0] == "stopped":
            raise WaveStopped()
        if reply[0] != "ok":
            self.close()
            raise WorkerLost(f"the worker failed: {reply[1]}")
        return reply[1], reply[2], reply[3]

    def stop(self, generation: int) -> None:
        """Have the child leave, at its next bounce, a wave of the render `generation` or an earlier one (its
        reader thread takes this while the wave runs)."""
        if self.closed or not self.ready:
            return
        try:
            with self._write:
                send(self._in, ("stop", generation))
        except (OSError, ValueError):
            pass   # gone: its wave's reply says so

    def release(self) -> None:
        """Drop the child's scene and keep the child in the pool (closed instead when it is not healthy)."""
        if self.closed:
            return
        if not self.ready or self.process.poll() is not None:
            self.close()
            return
        self.ready = False
        try:
            with self._write:
                send(self._in, ("drop",))
        except (OSError, ValueError):
            self.close()
            return
        _pool_put(self)

    def close(self) -> None:
        if self.closed:
            return
        self.closed, self.ready = True, False
        for stream in (self._in, self._out):
            try:
                stream.close()
            except (OSError, ValueError):
                pass
        try:
            self.process.wait(timeout=1.0)
        except subprocess.TimeoutExpired:
            self.process.kill()
            self.process.wait()


# The idle workers of this process, newest last: a renderer takes them before starting new ones; each exits
# after IDLE_S in the pool (and with this process: its stdin closes).
IDLE_S = 120.0
_pool: list[Worker] = []
_pool_lock = threading.Lock()


def _pool_put(worker: Worker) -> None:
    worker.idle_since = time.monotonic()
    with _pool_lock:
        _pool.append(worker)
    timer = threading.Timer(IDLE_S, _expire, args=(worker, worker.idle_since))
    timer.daemon = True
    timer.start()


def _pool_take() -> Worker | None:
    with _pool_lock:
        while _pool:
            worker = _pool.pop()
            if not worker.closed and worker.process.poll() is None:
                worker.idle_since = None
                return worker
            worker.close()
    return None


def pooled() -> list:
    """The idle workers in this process's pool, oldest first (a copy)."""
    return list(_pool)


def prestart(count: int) -> None:
    """Have `count` idle workers in this process's pool, starting the missing ones now: a render about to
    export its scene calls this, so that the children's start (their imports, about 0.3 s) runs meanwhile
    on another core. Unused, they exit after IDLE_S like any idle worker."""
    with _pool_lock:
        idle = sum(1 for worker in _pool if not worker.closed)
    for _ in range(count - idle):
        try:
            worker = Worker()
        except (OSError, WorkerLost):
            return    # the render starts its own, or says why it cannot
        _pool_put(worker)


def _expire(worker: Worker, since: float) -> None:
    with _pool_lock:
        if worker not in _pool or worker.idle_since != since:
            return          # taken again meanwhile
        _pool.remove(worker)
    worker.close()


def close_pool() -> None:
    """Stop every idle worker now."""
    with _pool_lock:
        idle = list(_pool)
        _pool.clear()
    for worker in idle:
        worker.close()


atexit.register(close_pool)


# The longest a loading worker holds a local slot for itself (WaveSlots.reserve): longer than a child takes
# to load a real scene, new or from the pool, and short enough that a failing child costs little.
RESERVE_S = 1.0


class WaveSlots:
    """Where the next wave may run: None (a thread of this process) or a ready Worker. There are always as
    many slots as wave threads; a worker that becomes ready takes the place of a local slot, and a worker
    that is lost gives it back."""

    def __init__(self, local: int):
        self._queue = queue.Queue()
        self._lock = threading.Lock()
        self._retire = 0
        self._reserved = set()   # loading workers that hold a local slot (reserve)
        for _ in range(local):
            self._queue.put(None)

    def take(self):
        while True:
            slot = self._queue.get()
            if slot is None:
                with self._lock:
                    if self._retire:
                        self._retire -= 1
                        continue
            return slot

    def give(self, slot) -> None:
        self._queue.put(slot)

    def reserve(self, worker: Worker, seconds: float) -> None:
        """Hold a local slot for `worker` while it loads, for at most `seconds`: waves wait for it meanwhile
        rather than run on another thread of this process, where they would contend for the GIL with the
        waves already running (two threads of one process reach about 1.3x one thread on real scenes, a
        worker 2x) and keep the worker waiting for a slot once it is ready. The slot comes back when the
        worker fails or the time is up."""
        with self._lock:
            self._retire += 1
            self._reserved.add(worker)
        timer = threading.Timer(seconds, self.unreserve, args=(worker,))
        timer.daemon = True
        timer.start()

    def unreserve(self, worker: Worker) -> None:
        """Give back the local slot held for `worker` (nothing when it holds none)."""
        with self._lock:
            if worker not in self._reserved:
                return
            self._reserved.discard(worker)
            if self._retire:     # no local slot retired for it yet
                self._retire -= 1
                return
        self._queue.put(None)

    def add_worker(self, worker: Worker) -> None:
        with self._lock:
            if worker in self._reserved:    # it takes the local slot held for it
                self._reserved.discard(worker)
            else:
                self._retire += 1
        self._queue.put(worker)



class WorkerSet:
    """The worker processes of one Renderer: idle ones from the pool, or new ones."""

    def __init__(self, slots: WaveSlots):
        self.slots = slots
        self.workers: list[Worker] = []
        self.failures: list[str] = []
        self.skipped = ""     # why no worker was started, when that was a choice (a big scene)
        self.reused = 0       # workers taken from the pool
        self._lock = threading.Lock()
        self._closed = False
        self._finalizer = weakref.finalize(self, _close_all, self.workers)

    def start(self, count: int, scene, max_bytes: int, runner: str) -> bool:
        """Give up to count workers the scene and the runner to build from it ("module:class"), as many as
        their copies of it fit in max_bytes (each child holds a copy, and its own BVH); none when one copy
        does not. They join the slots as they become ready."""
        payload = pickled(("scene", scene, runner))
        size = pickled_size(payload)
        if size > max_bytes:
            self.skipped = f"the scene's {size >> 20} MB are over {max_bytes >> 20} MB"
            return False
        count = min(count, max_bytes // max(size, 1))
        for _ in range(count):
            worker = _pool_take()
            if worker is not None:
                self.reused += 1
            else:
                try:
                    worker = Worker()
                except (OSError, WorkerLost) as err:
                    self.failures.append(str(err))
                    return True
            with self._lock:
                self.workers.append(worker)
            self.slots.reserve(worker, RESERVE_S)
            worker.load(payload, self._ready, self._failed)
        return True

    def _ready(self, worker: Worker) -> None:
        with self._lock:
            closed = self._closed
        if closed:          # the renderer closed while the child was loading
            worker.release()
        else:
            self.slots.add_worker(worker)

    def _failed(self, worker: Worker) -> None:
        self.failures.append(str(worker.error))
        self.slots.unreserve(worker)

    def lost(self, worker: Worker, err: Exception) -> None:
        worker.error = err
        self.failures.append(str(err))
        worker.close()

    def forward(self, method: str, args: tuple, kwargs: dict) -> None:
        with self._lock:
            if self._closed:   # the workers may belong to another renderer now
                return
            workers = list(self.workers)
        for worker in workers:
            worker.forward(method, args, kwargs)

    def stop(self, generation: int) -> None:
        """Tell every worker at once to leave the waves of render `generation` (Worker.stop)."""
        with self._lock:
            workers = [] if self._closed else list(self.workers)
        for worker in workers:
            worker.stop(generation)

    @property
    def ready(self) -> int:
        return sum(1 for w in self.workers if w.ready and not w.closed)

    def close(self) -> None:
        """Give the healthy workers back to the pool (still loading ones follow when ready), close the
        others. Their slots, if taken again, turn back into local ones (a released worker renders no
        wave for this renderer: render_wave raises WorkerLost)."""
        with self._lock:
            self._closed = True
            workers = list(self.workers)
        for worker in workers:
            if not worker.loading:
                worker.release()
        self._finalizer.detach()


def _close_all(workers: list) -> None:
    for worker in workers:
        worker.close()


# ---------------------------------------------------------------------------------------------- the child
def serve() -> None:
    """The child's loop: build a runner from each scene it is sent, apply updates and render waves, until
    the parent closes the pipe, or goes (then quietly: the parent stopped, a farm ended it, it crashed)."""
    incoming = os.fdopen(0, "rb", buffering=1 << 16)
    outgoing = os.fdopen(os.dup(1), "wb", buffering=1 << 16)
    os.dup2(2, 1)            # prints (NumPy, Embree, a stray debug line) go to stderr, not into the protocol
    sys.stdout = sys.stderr
    try:
        _serve(incoming, outgoing)
    except (EOFError, OSError):  # the parent's end of a pipe is closed
        os._exit(0)          # nothing left to flush into a broken pipe at exit either


def _serve(incoming, outgoing) -> None:
    import importlib

    import numpy as np

    from .memory import keep_freed_memory, trim_heap

    keep_freed_memory()   # a child renders waves and nothing else (memory.keep_freed_memory); "drop" trims
    inbox = _Inbox(incoming)
    renderer = None
    broken = None
    while True:
        message = inbox.next()
        kind = message[0]
        if kind in ("scene", "drop") and renderer is not None:
            renderer.close()       # its BVH and tables go now (the light sampler's cycle would keep them)
        if kind == "scene":
            renderer = broken = None
            try:
                module, _, name = message[2].partition(":")
                renderer = getattr(importlib.import_module(module), name)(message[1], threads=1, processes=False)
            except BaseException:  # noqa: BLE001 - tell the parent, which renders without this child
                send(outgoing, ("error", traceback.format_exc(limit=4)))
                return
            del message
            inbox.renderer = renderer
            send(outgoing, ("ready",))
        elif kind == "drop":
            renderer = broken = inbox.renderer = None
            trim_heap()
        elif kind == "call":
            try:
                with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                    getattr(renderer, message[1])(*message[2], **message[3])
            except BaseException:  # noqa: BLE001 - the twin is no longer the parent's: say so at the next wave
                broken = traceback.format_exc(limit=4)
        elif kind == "wave":
            if broken is not None or renderer is None:
                send(outgoing, ("error", broken or "no scene"))
                return
            rays, seconds = renderer.accel.rays_traced, renderer.accel.seconds_in_embree
            inbox.start_wave(message[3])
            try:
                result = renderer.render_wave(message[1], message[2])
            except WaveStopped:
                send(outgoing, ("stopped",))
                continue
            except BaseException:  # noqa: BLE001
                send(outgoing, ("error", traceback.format_exc(limit=4)))
                return
            send(outgoing, ("ok", result, renderer.accel.rays_traced - rays,
                            renderer.accel.seconds_in_embree - seconds))


class _Inbox:
    """The child's messages, read by a thread of their own, so that a stop reaches the wave that runs (as its
    renderer's stop flag, seen at the next bounce) while the others wait their turn."""

    def __init__(self, incoming):
        self._incoming = incoming
        self._queue = queue.Queue()
        self._lock = threading.Lock()
        self._stopped = 0        # the latest render generation the parent stopped
        self._wave = None        # the generation of the wave running, None between waves
        self.renderer = None
        threading.Thread(target=self._read, daemon=True, name="ember-worker-inbox").start()

    def next(self):
        """The next message other than a stop; EOFError when the parent has closed the pipe."""
        message = self._queue.get()
        if message is None:
            raise EOFError("the parent closed the pipe")
        with self._lock:
            self._wave = None
        return message

    def start_wave(self, generation: int) -> None:
        with self._lock:
            self._wave = generation
            if self.renderer is not None:
                stop = self.renderer.stop_waves
                stop.set() if generation <= self._stopped else stop.clear()

    def _read(self) -> None:
        try:
            while True:
                message = receive(self._incoming)
                if message[0] != "stop":
                    self._queue.put(message)
                    continue
                with self._lock:
                    self._stopped = max(self._stopped, message[1])
                    if self._wave is not None and self._wave <= self._stopped and self.renderer is not None:
                        self.renderer.stop_waves.set()
        except (EOFError, OSError, ValueError, pickle.UnpicklingError):
            self._queue.put(None)
