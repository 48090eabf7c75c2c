"""How long a stop request (Esc in Blender, Ctrl-C or SIGTERM on the command line: session.request_cancel)
takes to end a final render, through bpy as F12 runs it, with the wave threads and worker processes of the
machine's cores; optionally with busy processes beside it, as on a shared render node.

    .venv/bin/python bench/cancel_latency.py [--scene materials] [--size 640] [--repeats 5] [--load 2]

For each repeat, the stop is requested a random 1-3 s into the render (seeded) and the time until
bpy.ops.render.render returns is printed, with the bounces local wave threads began after the request (the
worker processes' own bounces are not visible here). Prints the median and the maximum.
"""
from __future__ import annotations

import argparse
import multiprocessing
import os
import random
import sys
import threading
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench.common import import_ember, median  # noqa: E402

import_ember()
import bpy  # noqa: E402

from bench import scenes  # noqa: E402
from ember.engine import session  # noqa: E402
from ember.kernels import accel  # noqa: E402


def busy(stop) -> None:
    """A process that keeps a core busy until `stop` is set (load beside the render)."""
    while not stop.is_set():
        sum(i * i for i in range(10_000))


def one_stop(scene, delay_s: float) -> tuple[float, int]:
    """Seconds from the request to the render's return, and the bounces begun after the request."""
    requested = [None]
    late = [0]
    intersect = accel.Accel.intersect

    def counting(self, *args, **kwargs):
        if requested[0] is not None:
            late[0] += 1
        return intersect(self, *args, **kwargs)

    def request():
        requested[0] = time.perf_counter()
        session.request_cancel()

    timer = threading.Timer(delay_s, request)
    accel.Accel.intersect = counting
    session.clear_cancel()
    try:
        timer.start()
        bpy.ops.render.render(write_still=False)
        ended = time.perf_counter()
    finally:
        timer.cancel()
        accel.Accel.intersect = intersect
        session.clear_cancel()
    if requested[0] is None:
        raise SystemExit("the render ended before the stop: raise --samples or --size")
    return ended - requested[0], late[0]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="materials", choices=("materials", "cornell"))
    ap.add_argument("--size", type=int, default=640)
    ap.add_argument("--samples", type=int, default=4096)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--load", type=int, default=0, help="busy processes beside the render")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    from ember import register
    register()
    build = scenes.materials_scene if args.scene == "materials" else scenes.cornell_scene
    scene = build(args.size, args.size)
    scene.render.engine = "EMBER"
    scene.ember.samples, scene.ember.use_denoising = args.samples, False
    scene.render.threads_mode = "AUTO"
    stop = multiprocessing.Event()
    loaders = [multiprocessing.Process(target=busy, args=(stop,), daemon=True) for _ in range(args.load)]
    for p in loaders:
        p.start()
    rng = random.Random(args.seed)
    times = []
    try:
        for i in range(args.repeats):
            latency, late = one_stop(scene, rng.uniform(1.0, 3.0))
            times.append(latency)
            print(f"stop {i + 1}: {latency:.3f} s to return, {late} local bounces begun after the request", flush=True)
    finally:
        stop.set()
        for p in loaders:
            p.join()
    print(f"{args.scene} {args.size}x{args.size}, {accel.usable_cores()} cores, load {args.load}: median "
          f"{median(times):.3f} s, max {max(times):.3f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
