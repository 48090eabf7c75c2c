"""Motion blur of hair (issue 37): the kernel's seconds for a furry ball that slides and turns a quarter
circle in the shutter, against the same exported scene with its shutter taken away (everything where it is
at the frame), one thread, medians of a few runs.

    .venv313/bin/python bench/shape_motion.py [--strands 3000] [--samples 16] [--runs 3]

The ball: a UV sphere with a hair particle system (3D Curves, 9 keys a strand), 96x96, up to 3 bounces. Its
hair is an Embree instance with motion steps; every query of the scene goes through the 16-ray packets,
which carry the rays' times.
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


def build(strands: int):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.resolution_x = scene.render.resolution_y = 96
    scene.render.use_motion_blur = True
    scene.cycles_curves.shape = "THICK"
    cam = bpy.data.objects.new("Camera", bpy.data.cameras.new("Camera"))
    scene.collection.objects.link(cam)
    cam.location, cam.rotation_euler = (0, -6, 1.5), (math.radians(80), 0, 0)
    scene.camera = cam
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    scene.collection.objects.link(sun)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.8, location=(0, 0, 1))
    ball = bpy.context.active_object
    ball.modifiers.new("Fur", "PARTICLE_SYSTEM")
    part = ball.particle_systems[0].settings
    part.type, part.count, part.hair_length, part.radius_scale = "HAIR", strands, 0.3, 0.03
    for frame, location, turn in ((1, (0, 0, 1), 0.0), (2, (0.4, 0, 1.2), math.pi / 2)):
        ball.location, ball.rotation_euler = location, (0, 0, turn)
        ball.keyframe_insert("location", frame=frame)
        ball.keyframe_insert("rotation_euler", frame=frame)
    scene.frame_set(1)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    return export_scene(depsgraph, motion=sample_motion(_Frames(scene), depsgraph, cam)).scene


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--strands", type=int, default=3000)
    parser.add_argument("--samples", type=int, default=16)
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    moving = build(args.strands)
    still = dataclasses.replace(moving, shutter_table=None)
    settings = RenderSettings(samples=args.samples, max_bounces=3)
    for label, scene in (("moving", moving), ("still", still)):
        render(scene, settings, threads=1)   # warm up
        seconds = []
        for _ in range(args.runs):
            start = time.perf_counter()
            render(scene, settings, threads=1)
            seconds.append(time.perf_counter() - start)
        print(f"{label}: {median(seconds):.2f} s ({args.strands} strands, {args.samples} samples, one thread)")


if __name__ == "__main__":
    main()
