"""Kernel benchmark: a Cornell-like box (about 1k triangles), 256x256, 8 bounces, all cores.

Prints paths/s per sampling mode, the Embree-only rate on the very rays the render traced (the
ceiling for this scene), and the share of the worker threads' time spent inside Embree.

    .venv/bin/python bench/kernel_cornell.py [--samples 32] [--threads 0] [--repeats 3]
"""
from __future__ import annotations

import argparse
import os
import sys
import time


sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench.common import import_ember, median  # noqa: E402

ember = import_ember()
from ember.kernels import Renderer, RenderSettings  # noqa: E402
from ember.kernels.accel import Accel  # noqa: E402
from ember.kernels.shapes import cornell_box  # noqa: E402


class RecordingAccel(Accel):
    """An Accel that keeps a copy of every closest-hit batch it is asked to trace."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.batches = []

    def intersect(self, origins, directions, t_max, split=True, time=None):
        self.batches.append((origins.copy(), directions.copy(), t_max.copy()))
        return super().intersect(origins, directions, t_max, split, time)


def embree_only(scene, batches, threads: int) -> float:
    """Rays/s of Embree alone on the recorded batches, same thread count, chunked over the pool."""
    with Accel(scene.positions, threads) as accel:
        for o, d, t in batches[:3]:
            accel.intersect(o, d, t)  # warm up
        start = time.perf_counter()
        for o, d, t in batches:
            accel.intersect(o, d, t)
        elapsed = time.perf_counter() - start
    return sum(len(o) for o, _, _ in batches) / elapsed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=32)
    ap.add_argument("--threads", type=int, default=0, help="0 = all cores")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="a smoke run: 8 samples, one repeat")
    args, _ = ap.parse_known_args()  # dev.py bench passes vs_cycles.py's flags to every benchmark
    if args.quick:
        args.samples, args.repeats = 8, 1

    scene = cornell_box(256, 256, wall_subdivisions=7, sphere_segments=12)
    print(f"Cornell box: {scene.triangle_count} triangles, 256x256, {args.samples} spp, max_bounces 8")
    for mode in ("NEE_MIS", "COSINE", "LECTURE"):
        settings = RenderSettings(samples=args.samples, max_bounces=8, mode=mode)
        with Renderer(scene, args.threads) as renderer:
            threads = renderer.accel.threads
            renderer.render(RenderSettings(samples=2, mode=mode))  # warm up
            runs = [renderer.render(settings).progress for _ in range(args.repeats)]
        paths_s = median([p.paths_per_s for p in runs])
        share = median([p.seconds_in_embree / (p.elapsed_s * threads) for p in runs])
        rays_per_path = runs[0].rays / runs[0].paths
        # The same rays again, Embree alone.
        with Renderer(scene, args.threads) as renderer:
            recorder = RecordingAccel(scene.positions, renderer.accel.threads)
            renderer.accel.close()
            renderer.accel = recorder
            renderer.render(settings)
            ceiling = embree_only(scene, recorder.batches, threads)
            recorder.close()
        print(f"{mode:8s} {paths_s / 1e6:6.3f} M paths/s | {rays_per_path:4.2f} rays/path | "
              f"Embree alone {ceiling / 1e6:6.2f} M rays/s = {ceiling / rays_per_path / 1e6:5.2f} M paths/s ceiling | "
              f"Ember at {paths_s * rays_per_path / ceiling:5.1%} of it | "
              f"time in Embree {share:5.1%} ({threads} threads)")


if __name__ == "__main__":
    main()
