"""Waves rendered in other processes: the same renderer, rebuilt from the same SceneArrays in a child process.

Why: a wave is thousands of NumPy calls on arrays of ten to a hundred thousand paths. NumPy releases the GIL
inside each call, but the Python between the calls holds it, so two threads of one process reach about 1.4x
one thread's rate on the eight Principled spheres (0.54 against 0.39M paths/s) while two processes reach 2x
(0.70M). Cycles' threads share nothing in Python; these processes share nothing either.

How: a child is a plain Python (sys.executable, the parent's sys.path) that imports this package, nothing of
Blender. It receives the parent's validated scene once, builds its own Renderer (its own Embree BVH: Embree
scenes cannot be shared between processes), and then renders waves: it gets the arguments of
Renderer._render_rows and sends back its result, the same arrays bit for bit, since the child runs the same
code on the same data. Between renders the parent forwards its incremental updates (camera, instances,
materials, lights, the next frame's scene) in order, so a child stays the parent's twin.

The protocol is pickles over the child's stdin and stdout (the child points its own stdout at stderr, so
stray prints cannot break it); NumPy arrays travel as out-of-band buffers, written from and read into their
memory without a copy in the pickle. A child that dies or fails is dropped: its wave runs again in the
parent, so no wave is ever lost, and the image is the same.
"""
from __future__ import annotations

import io
import json
import os
import pickle
import queue
import struct
import subprocess
import sys
import threading
import traceback
import weakref

_HEADER = struct.Struct("<QI")   # pickle length, buffer count
_LENGTH = struct.Struct("<Q")

# Started in the child with `python -c`: register the package under its name in the parent (ember,
# bl_ext.user_default.ember, ...), with empty namespace modules for the prefixes Blender makes up at run
# time, then serve.
_BOOT = r"""
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


class WorkerLost(Exception):
    """The child process exited, failed or could not be reached; its wave runs in the parent."""


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
    """One child process and its pipes. render_rows() is called by one thread at a time (the wave slots);
    forward() may be called between renders, from another thread."""

    def __init__(self, scene_payload, on_ready, on_failed):
        exe = python_executable()
        if exe is None:
            raise WorkerLost("no Python interpreter to start a worker with")
        package, root, kernels = _package()
        cfg = json.dumps({"path": [p for p in sys.path if isinstance(p, str)], "package": package,
                          "init": os.path.join(root, "__init__.py"), "root": root, "kernels": kernels})
        self.process = subprocess.Popen([exe, "-c", _BOOT, cfg], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                        bufsize=0)
        self._in = io.BufferedWriter(self.process.stdin, 1 << 16)
        self._out = io.BufferedReader(self.process.stdout, 1 << 16)
        self._write = threading.Lock()
        self._write.acquire()   # the scene goes first: forwarded updates wait for it
        self.ready = False
        self.closed = False
        self.error = None
        threading.Thread(target=self._start, args=(scene_payload, on_ready, on_failed), daemon=True,
                         name="ember-worker-start").start()

    def _start(self, payload, on_ready, on_failed) -> None:
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
            on_failed(self)
            self.close()
            return
        self.ready = True
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

    def render_rows(self, args: tuple):
        """Renderer._render_rows(*args) in the child: (its result, rays traced, seconds in Embree)."""
        if self.closed:
            raise WorkerLost("the worker is closed")
        try:
            with self._write:
                send(self._in, ("rows", args))
            reply = receive(self._out)
        except (OSError, EOFError, ValueError, pickle.UnpicklingError) as err:
            self.close()
            raise WorkerLost(f"{type(err).__name__}: {err}") from err
        if reply[0] != "ok":
            self.close()
            raise WorkerLost(f"the worker failed: {reply[1]}")
        return reply[1], reply[2], reply[3]

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
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


class WaveSlots:
    """Where the next wave may run: None (a thread of this process) or a ready Worker. There are always as
    many slots as wave threads; a worker that becomes ready takes the place of a local slot, and a worker
    that is lost gives it back."""

    def __init__(self, local: int):
        self._queue = queue.Queue()
        self._lock = threading.Lock()
        self._retire = 0
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

    def add_worker(self, worker: Worker) -> None:
        with self._lock:
            self._retire += 1
        self._queue.put(worker)



class WorkerSet:
    """The child processes of one Renderer, started at most once until closed."""

    def __init__(self, slots: WaveSlots):
        self.slots = slots
        self.workers: list[Worker] = []
        self.failures: list[str] = []
        self.skipped = ""     # why no worker was started, when that was a choice (a big scene)
        self._lock = threading.Lock()
        self._finalizer = weakref.finalize(self, _close_all, self.workers)

    def start(self, count: int, scene, max_bytes: int) -> bool:
        """Start count children with the scene, unless its pickle is over max_bytes (each child holds a
        copy, and its own BVH). They join the slots as they become ready."""
        payload = pickled(scene)
        if pickled_size(payload) > max_bytes:
            self.skipped = f"the scene's {pickled_size(payload) >> 20} MB are over {max_bytes >> 20} MB"
            return False
        for _ in range(count):
            try:
                worker = Worker(payload, self.slots.add_worker, self._failed)
            except (OSError, WorkerLost) as err:
                self.failures.append(str(err))
                return
            with self._lock:
                self.workers.append(worker)
        return True

    def _failed(self, worker: Worker) -> None:
        self.failures.append(str(worker.error))

    def lost(self, worker: Worker, err: Exception) -> None:
        worker.error = err
        self.failures.append(str(err))
        worker.close()

    def forward(self, method: str, args: tuple, kwargs: dict) -> None:
        for worker in list(self.workers):
            worker.forward(method, args, kwargs)

    @property
    def ready(self) -> int:
        return sum(1 for w in self.workers if w.ready and not w.closed)

    def close(self) -> None:
        """Stop the children. Their slots, when taken, turn back into local ones (the wave threads see a
        closed worker as a lost one)."""
        _close_all(self.workers)


def _close_all(workers: list) -> None:
    for worker in workers:
        worker.close()


# ---------------------------------------------------------------------------------------------- the child
def serve() -> None:
    """The child's loop: build the Renderer from the scene, then apply updates and render waves until the
    parent closes the pipe."""
    import numpy as np

    from .integrator import Renderer

    incoming = os.fdopen(0, "rb", buffering=1 << 16)
    outgoing = os.fdopen(os.dup(1), "wb", buffering=1 << 16)
    os.dup2(2, 1)            # prints (NumPy, Embree, a stray debug line) go to stderr, not into the protocol
    sys.stdout = sys.stderr
    try:
        scene = receive(incoming)
        renderer = Renderer(scene, threads=1, processes=False)
        del scene
    except BaseException:  # noqa: BLE001 - tell the parent, which renders locally
        send(outgoing, ("error", traceback.format_exc(limit=4)))
        return
    send(outgoing, ("ready",))
    broken = None
    while True:
        try:
            message = receive(incoming)
        except EOFError:
            return
        if message[0] == "call":
            try:
                with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                    getattr(renderer, message[1])(*message[2], **message[3])
            except BaseException:  # noqa: BLE001 - the twin is no longer the parent's: say so at the next wave
                broken = traceback.format_exc(limit=4)
            continue
        if broken is not None:
            send(outgoing, ("error", broken))
            return
        rays, seconds = renderer.accel.rays_traced, renderer.accel.seconds_in_embree
        try:
            result = renderer._render_rows(*message[1])
        except BaseException:  # noqa: BLE001
            send(outgoing, ("error", traceback.format_exc(limit=4)))
            return
        send(outgoing, ("ok", result, renderer.accel.rays_traced - rays, renderer.accel.seconds_in_embree - seconds))
