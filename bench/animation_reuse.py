"""Frames of an animation with Persistent Data (issue 14): seconds per frame when each frame builds its
scene anew, and when it reuses the scene built for the frame before (Blender's Persistent Data, honoured
by Ember and Cycles alike), both engines in one run.

    .venv/bin/python bench/animation_reuse.py [--triangles 1000000] [--frames 5] [--samples 4]

The scene: a still mesh of N triangles (bench/big_scenes.py's bumpy sphere) and a small cube that moves
every frame, 128x128, 2 threads. The first frame builds everything either way: the figures are the mean of
the frames after it.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench.common import import_ember  # noqa: E402

import_ember()
import bpy  # noqa: E402

from bench.big_scenes import build  # noqa: E402


def scene_with_mover(triangles: int, frames: int):
    scene = build("mesh", triangles, 0)
    bpy.ops.mesh.primitive_cube_add(size=0.3, location=(0.0, -1.4, 0.0))
    cube = bpy.context.object
    for f in range(1, frames + 1):
        cube.location.x = -0.8 + 1.6 * (f - 1) / max(frames - 1, 1)
        cube.keyframe_insert("location", frame=f)
    scene.render.threads_mode, scene.render.threads = "FIXED", 2
    return scene


def frame_seconds(scene, engine: str, persistent: bool, frames: int, samples: int) -> list[float]:
    scene.render.engine = engine
    scene.render.use_persistent_data = persistent
    if engine == "EMBER":
        scene.ember.samples, scene.ember.use_adaptive_sampling, scene.ember.use_denoising = samples, False, False
    else:
        scene.cycles.device, scene.cycles.samples = "CPU", samples
        scene.cycles.use_adaptive_sampling, scene.cycles.use_denoising = False, False
    times = []
    for f in range(1, frames + 1):
        scene.frame_set(f)
        start = time.perf_counter()
        bpy.ops.render.render()
        times.append(time.perf_counter() - start)
    scene.render.use_persistent_data = False
    bpy.ops.render.render()      # lets the kept scene go
    return times


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--triangles", type=int, default=1_000_000)
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--samples", type=int, default=4)
    args = ap.parse_args()
    scene = scene_with_mover(args.triangles, args.frames)
    print(f"{args.triangles:,}-triangle still mesh + a moving cube, 128x128, {args.samples} spp, 2 threads; "
          f"seconds per frame after the first (mean of {args.frames - 1})", flush=True)
    rows = {}
    for engine in ("EMBER", "CYCLES"):
        for persistent in (False, True):
            t = frame_seconds(scene, engine, persistent, args.frames, args.samples)
            rows[engine, persistent] = sum(t[1:]) / len(t[1:])
            print(f"{engine:6s} persistent data {'on ' if persistent else 'off'}: first {t[0]:.2f} s, then "
                  f"{rows[engine, persistent]:.3f} s/frame", flush=True)
    for engine in ("EMBER", "CYCLES"):
        print(f"{engine}: persistent data makes a frame {rows[engine, False] / rows[engine, True]:.1f}x faster")
    print(f"Ember / Cycles, persistent data on: {rows['EMBER', True] / rows['CYCLES', True]:.2f}; "
          f"off: {rows['EMBER', False] / rows['CYCLES', False]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
