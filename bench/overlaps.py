"""What looking for faces that overlap in part costs a scene's start-up (kernels/coincident.py overlapping_planes
and overlap_pairs, run by the renderer for scenes of at most OVERLAP_SCENE_LIMIT static opaque triangles).

    .venv313/bin/python bench/overlaps.py [--repeats 3]

Kernel level, one process, no Cycles (the search is Ember's own bookkeeping: Cycles' rays skip only the triangle
they leave and need none). Per layout, the median wall time of the candidates' filter and of the pair search,
and the candidates and partners found:
  - a bumpy sphere (bench/big_scenes.py's mesh) of 100,000 and 250,000 triangles: every triangle in a plane
    of its own, the common case;
  - one flat grid of 250,000 triangles: one plane past PLANE_GROUP_LIMIT, not searched within;
  - 25 randomly turned flat grids of 10,000 triangles each;
  - 1,000 cubes standing on a floor of 80,000 triangles: the cubes' bottoms lie on the floor;
  - a slab with rim strips and 2,000 layered copies of small faces, a hair apart: the partners the search is for.
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench.big_scenes import bumpy_sphere  # noqa: E402
from bench.common import import_ember  # noqa: E402

import_ember()
from ember.kernels.coincident import overlap_pairs, overlapping_planes  # noqa: E402
from ember.kernels.renderer import OVERLAP_SCENE_LIMIT, coincident_offset  # noqa: E402

RAY_EPSILON = 1e-5


def _grid(n: int, scale: float = 1.0, z: float = 0.0) -> np.ndarray:
    """(2 n^2, 3, 3) float32 triangles of an n x n grid of quads over [0, scale]^2 at height z."""
    x, y = np.meshgrid(np.linspace(0, scale, n + 1), np.linspace(0, scale, n + 1))
    v = np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], 1)
    i = np.arange(n * n)
    a = (i // n) * (n + 1) + i % n
    b, d = a + 1, a + n + 1
    faces = np.concatenate([np.stack([a, b, d + 1], 1), np.stack([a, d + 1, d], 1)])
    return v[faces].astype(np.float32)


def _sphere(triangles: int) -> np.ndarray:
    v, q = bumpy_sphere(triangles)
    return v[np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])].astype(np.float32)


def _cube(corner, size) -> np.ndarray:
    c = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float) * size + corner
    f = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1), (2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4),
         (1, 5, 7), (1, 7, 3)]
    return c[np.array(f)].astype(np.float32)


def layouts():
    """(name, positions (T, 3, 3), object rows (T,))."""
    rng = np.random.default_rng(1)
    for count in (100_000, 250_000):
        p = _sphere(count)
        yield f"bumpy sphere, {len(p):,} triangles", p, np.zeros(len(p), np.int32)
    p = _grid(354, 10.0)
    yield f"one flat grid, {len(p):,} triangles", p, np.zeros(len(p), np.int32)
    parts = []
    for k in range(25):
        q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        parts.append((_grid(70, 3.0).reshape(-1, 3) @ q.T.astype(np.float32) + rng.normal(size=3) * 5)
                     .reshape(-1, 3, 3).astype(np.float32))
    yield "25 turned flat grids, 245,000 triangles", np.concatenate(parts), np.repeat(np.arange(25), len(parts[0]))
    floor = _grid(200, 50.0) - np.float32([25, 25, 0])
    cubes = [_cube(np.r_[rng.uniform(-20, 20, 2), 0], 0.3) for _ in range(1000)]
    p = np.concatenate([floor] + cubes)
    yield "1,000 cubes on an 80,000-triangle floor", p, np.r_[np.zeros(len(floor)), np.repeat(np.arange(1, 1001), 12)]
    slab = _grid(4, 4.0)
    rims = [_grid(1, 0.2) + np.float32([0.2 * (k % 20), 0.2 * (k // 20 % 20), 1e-6 * (k // 400)]) for k in range(2000)]
    p = np.concatenate([slab] + rims)
    yield "a slab under 2,000 layered small faces", p, np.zeros(len(p), np.int32)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    offset = coincident_offset(np.float32(RAY_EPSILON))
    print(f"load average at the start: {os.getloadavg()[0]:.1f}; scenes past {OVERLAP_SCENE_LIMIT:,} static opaque "
          "triangles skip the search")
    print("| Layout | Filter | Search | Candidates (across / within) | Partners |")
    print("| --- | --- | --- | --- | --- |")
    for name, positions, objects in layouts():
        objects = np.asarray(objects, np.int32)
        mask = np.ones(len(positions), bool)
        filter_s, search_s = [], []
        for _ in range(args.repeats):
            start = time.perf_counter()
            across, asking, within = overlapping_planes(positions, mask, offset, objects)
            middle = time.perf_counter()
            keys = overlap_pairs(positions, offset, objects, across, asking, within)
            filter_s.append(middle - start)
            search_s.append(time.perf_counter() - middle)
        print(f"| {name} | {statistics.median(filter_s):.3f} s | {statistics.median(search_s):.3f} s | "
              f"{int(across.sum()):,} / {int(within.sum()):,} | {len(keys):,} |")
    print(f"load average at the end: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
