"""Deformation motion blur of meshes: the kernel's seconds for a grid rippled by a Wave modifier (its triangles
with three time steps), against the same exported scene with its shutter taken away (everything where it is at the
frame), one thread, medians of a few runs; and the export's seconds with the motion steps read.

    .venv313/bin/python bench/deform_motion.py [--cuts 220] [--samples 16] [--runs 3]

The grid: cuts x cuts quads (about 2 cuts^2 triangles), smooth, 96x96, up to 3 bounces, a sun. Its triangles are
Embree triangles with time steps in a scene of their own, traced by the 16-ray packets, which carry the rays'
times (kernels/moving.py).
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench.common import import_ember, median  # noqa: E402

ember = import_ember()
import bpy  # noqa: E402

from ember.engine.export import export_scene  # noqa: E402
from ember.engine.export.motion import sample_motion  # noqa: E402
from ember.kernels import RenderSettings, render  # noqa: E402


class _Frames:
    def __init__(self, scene):
        self.scene = scene

    def frame_set(self, frame, subframe):
        self.scene.frame_set(frame, subframe=subframe)


def build(cuts: int):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.resolution_x = scene.render.resolution_y = 96
    scene.render.use_motion_blur = True
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(cam)
    cam.location, cam.rotation_euler = (0, -6, 1.5), (math.radians(80), 0, 0)
    scene.camera = cam
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    scene.collection.objects.link(sun)
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=cuts, y_subdivisions=cuts, size=3.0, location=(0, 0, 0.6),
                                    rotation=(1.1, 0, 0))
    grid = bpy.context.active_object
    wave = grid.modifiers.new("Wave", "WAVE")
    wave.height, wave.width, wave.narrowness, wave.speed = 0.5, 0.8, 1.0, 1.5
    bpy.ops.object.shade_smooth()
    scene.frame_set(1)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    start = time.perf_counter()
    arrays = export_scene(depsgraph, motion=sample_motion(_Frames(scene), depsgraph, cam)).scene
    return arrays, time.perf_counter() - start


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--cuts", type=int, default=220)
    parser.add_argument("--samples", type=int, default=16)
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    deforming, export_seconds = build(args.cuts)
    print(f"export with the motion steps: {export_seconds:.2f} s ({len(deforming.positions)} triangles)")
    still = dataclasses.replace(deforming, shutter_table=None, deform_ids=None, deform_positions=None,
                                deform_normals=None)
    settings = RenderSettings(samples=args.samples, max_bounces=3)
    for label, scene in (("deforming", deforming), ("still", still)):
        render(scene, settings, threads=1)   # warm up
        seconds = []
        for _ in range(args.runs):
            start = time.perf_counter()
            render(scene, settings, threads=1)
            seconds.append(time.perf_counter() - start)
        print(f"{label}: {median(seconds):.2f} s ({args.samples} samples, one thread)")


if __name__ == "__main__":
    main()
