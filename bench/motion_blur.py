"""Motion blur's cost: the kernel's seconds for a scene that moves in the shutter against the same exported scene
with its shutter taken away (everything where it is at the frame), one thread, medians of a few runs.

    .venv313/bin/python bench/motion_blur.py hair [--strands 3000] [--samples 16] [--runs 3]
    .venv313/bin/python bench/motion_blur.py deform [--cuts 220] [--samples 16] [--runs 3]
    .venv313/bin/python bench/motion_blur.py objects [--objects 800] [--samples 16] [--runs 3]

hair (issue 37): a UV sphere with a hair particle system (3D Curves, 9 keys a strand) that slides and turns a
quarter circle; its hair is an Embree instance with motion steps. deform: a cuts x cuts grid (about 2 cuts^2
triangles, smooth) rippled by a Wave modifier; its triangles are Embree triangles with time steps in a scene of
their own (kernels/moving.py); the export's seconds with the motion steps read are printed too. objects: a cloud of
small cubes (a donut's sprinkles, a particle system's instances), each sliding and turning in the shutter; they are
Embree instances whose transforms move, all in one scene (kernels/moving.py MovingObjects). All at 96x96, up to 3
bounces, a sun; every query of a moving scene goes through the 16-ray packets, which carry the rays' times.
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
import numpy as np  # noqa: E402
from mathutils import Vector  # noqa: E402

from ember.engine.export import export_scene  # noqa: E402
from ember.engine.export.motion import sample_motion  # noqa: E402
from ember.kernels import RenderSettings, render  # noqa: E402


class _Frames:
    """What sample_motion needs of a RenderEngine: frame_set."""

    def __init__(self, scene):
        self.scene = scene

    def frame_set(self, frame, subframe):
        self.scene.frame_set(frame, subframe=subframe)


def _stage():
    """An empty 96x96 scene with motion blur on, a camera and a sun; returns (scene, camera)."""
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
    return scene, cam


def _export(scene, cam):
    """(SceneArrays with the motion steps, the export's seconds) at frame 1."""
    scene.frame_set(1)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    start = time.perf_counter()
    arrays = export_scene(depsgraph, motion=sample_motion(_Frames(scene), depsgraph, cam)).scene
    return arrays, time.perf_counter() - start


def hair(strands: int):
    scene, cam = _stage()
    scene.cycles_curves.shape = "THICK"
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.8, location=(0, 0, 1))
    ball = bpy.context.active_object
    ball.modifiers.new("Fur", "PARTICLE_SYSTEM")
    part = ball.particle_systems[0].settings
    part.type, part.count, part.hair_length, part.radius_scale = "HAIR", strands, 0.3, 0.03
    for frame, location, turn in ((1, (0, 0, 1), 0.0), (2, (0.4, 0, 1.2), math.pi / 2)):
        ball.location, ball.rotation_euler = location, (0, 0, turn)
        ball.keyframe_insert("location", frame=frame)
        ball.keyframe_insert("rotation_euler", frame=frame)
    moving, seconds = _export(scene, cam)
    return moving, dataclasses.replace(moving, shutter_table=None), seconds, f"{strands} strands"


def deform(cuts: int):
    scene, cam = _stage()
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=cuts, y_subdivisions=cuts, size=3.0, location=(0, 0, 0.6),
                                    rotation=(1.1, 0, 0))
    grid = bpy.context.active_object
    wave = grid.modifiers.new("Wave", "WAVE")
    wave.height, wave.width, wave.narrowness, wave.speed = 0.5, 0.8, 1.0, 1.5
    bpy.ops.object.shade_smooth()
    moving, seconds = _export(scene, cam)
    still = dataclasses.replace(moving, shutter_table=None, deform_ids=None, deform_positions=None,
                                deform_normals=None)
    return moving, still, seconds, f"{len(moving.positions)} triangles"


def objects(count: int):
    scene, cam = _stage()
    rng = np.random.default_rng(3)
    bpy.ops.mesh.primitive_plane_add(size=8, location=(0, 0, 0))
    for k in range(count):
        bpy.ops.mesh.primitive_cube_add(size=0.08, location=tuple(rng.uniform((-1.5, -1.5, 0.3), (1.5, 1.5, 2.5))))
        cube = bpy.context.active_object
        start, shift = cube.location.copy(), rng.normal(scale=0.05, size=3)
        for frame, offset, turn in ((1, (0, 0, 0), 0.0), (2, tuple(shift), float(rng.uniform(0, math.pi)))):
            cube.location = start + Vector(offset)
            cube.rotation_euler = (turn, 0.5 * turn, 0)
            cube.keyframe_insert("location", frame=frame)
            cube.keyframe_insert("rotation_euler", frame=frame)
    moving, seconds = _export(scene, cam)
    return moving, dataclasses.replace(moving, shutter_table=None), seconds, f"{count} moving cubes"


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("scene", choices=("hair", "deform", "objects"))
    parser.add_argument("--objects", type=int, default=800)
    parser.add_argument("--strands", type=int, default=3000)
    parser.add_argument("--cuts", type=int, default=220)
    parser.add_argument("--samples", type=int, default=16)
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    build = {"hair": lambda: hair(args.strands), "deform": lambda: deform(args.cuts),
             "objects": lambda: objects(args.objects)}[args.scene]
    moving, still, export_seconds, size = build()
    print(f"export with the motion steps: {export_seconds:.2f} s ({size})")
    settings = RenderSettings(samples=args.samples, max_bounces=3)
    for label, scene in (("moving", moving), ("still", still)):
        render(scene, settings, threads=1)   # warm up
        seconds = []
        for _ in range(args.runs):
            start = time.perf_counter()
            render(scene, settings, threads=1)
            seconds.append(time.perf_counter() - start)
        print(f"{label}: {median(seconds):.2f} s ({size}, {args.samples} samples, one thread)")


if __name__ == "__main__":
    main()
