"""One engine's renders of one .blend as its author saved it, for bench/corpus.py (run in a fresh process
per file and engine, so that a crash or a hang stops only this file).

    .venv/bin/python bench/corpus_render.py FILE.blend OUT.npz --engine CYCLES|EMBER --seeds 0 1
                                            [--samples 16] [--long-side 160] [--threads 2]
                                            [--set PATH=VALUE ...]

Opens the file (never saves it), keeps its camera (or, saved without one, adds one framing what renders:
frame_camera), scene, lights, materials and film, and changes only
what an equal comparison needs: the resolution (long side scaled to --long-side, aspect kept), samples,
seed, threads, denoising and adaptive sampling off, compositing and the sequencer off (the render
layer itself is compared), and a sampling pattern that gives every pixel its own sequence (the noise
estimate of bench/corpus.py treats pixels as independent; blue-noise layouts are not). Ember takes the
file's Cycles settings where it has them (map_cycles_settings); the Cycles settings it lacks are listed.

OUT.npz holds `images` (seeds, H, W, 4) float32 linear RGBA, row 0 at the top, `seconds` (one per seed:
bpy.ops.render.render's wall time) and `meta`, a JSON string (settings, lacking, missing images).
A failure writes `error` (one line) instead of images.
"""
from __future__ import annotations

import argparse
import ast
import json
import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench.common import import_ember  # noqa: E402

import_ember()
import bpy  # noqa: E402

from tests.bpy_helpers import ensure_registered, load_exr  # noqa: E402

# scene.cycles -> scene.ember, same meaning and units.
SHARED_SETTINGS = ("max_bounces", "diffuse_bounces", "glossy_bounces", "transmission_bounces",
                   "transparent_max_bounces", "sample_clamp_direct", "sample_clamp_indirect",
                   "blur_glossy", "caustics_reflective", "caustics_refractive", "pixel_filter_type", "filter_width",
                   "volume_bounces", "volume_biased", "volume_step_rate", "volume_max_steps")


def lacking_settings(scene) -> list[str]:
    """Cycles settings of this file that change the image and that Ember has no counterpart for, each as
    'name=value' (only those not at the value that makes them inert)."""
    c = scene.cycles
    simplify = scene.render.use_simplify
    lacking = []
    checks = (("min_light_bounces", c.min_light_bounces > 0),
              ("min_transparent_bounces", c.min_transparent_bounces > 0),
              # Simplify's (Cycles reads it only with Simplify on; Blender 5.3)
              ("texture_resolution_render", simplify and getattr(c, "texture_resolution_render", 1.0) != 1.0),
              ("shading_system (OSL)", c.shading_system))
    for name, active in checks:
        if active:
            value = getattr(c, name.split(" ")[0], None)
            lacking.append(f"{name}={round(value, 4) if isinstance(value, float) else value}")
    return lacking


def map_cycles_settings(scene) -> dict:
    """Copy the file's Cycles settings that Ember has onto scene.ember; returns them by name."""
    mapped = {}
    for name in SHARED_SETTINGS:
        value = getattr(scene.cycles, name)
        setattr(scene.ember, name, value)
        mapped[name] = round(value, 4) if isinstance(value, float) else value
    return mapped


def missing_images() -> list[str]:
    """Image files the .blend names that are neither packed nor on disk (both engines render them as a
    missing texture)."""
    missing = []
    for image in bpy.data.images:
        if image.source in ("FILE", "SEQUENCE", "TILED") and image.packed_file is None and image.filepath:
            if not os.path.exists(bpy.path.abspath(image.filepath, library=image.library)):
                missing.append(image.filepath)
    return missing


def scale_resolution(render, long_side: int) -> tuple[int, int]:
    """Scale the output so that its long side is `long_side` pixels, keeping the aspect ratio."""
    width = render.resolution_x * render.resolution_percentage / 100
    height = render.resolution_y * render.resolution_percentage / 100
    factor = long_side / max(width, height)
    render.resolution_x, render.resolution_y = (max(4, round(width * factor)), max(4, round(height * factor)))
    render.resolution_percentage = 100
    return render.resolution_x, render.resolution_y


def configure(scene, engine: str, samples: int, long_side: int, threads: int) -> dict:
    render = scene.render
    size = scale_resolution(render, long_side)
    render.threads_mode, render.threads = "FIXED", threads
    render.use_compositing = render.use_sequencer = False
    render.use_single_layer = True
    settings = render.image_settings
    if getattr(settings, "media_type", "IMAGE") != "IMAGE":
        settings.media_type = "IMAGE"
    settings.file_format, settings.color_mode, settings.color_depth = "OPEN_EXR", "RGBA", "32"
    for layer in scene.view_layers:
        layer.samples = 0   # a view layer's own sample count would override the scene's in Cycles
    c = scene.cycles
    c.device, c.samples, c.use_animated_seed, c.time_limit, c.sample_offset = "CPU", samples, False, 0.0, 0
    c.use_adaptive_sampling = c.use_denoising = False
    c.sampling_pattern = "TABULATED_SOBOL"
    c.auto_scrambling_distance, c.scrambling_distance = False, 1.0
    meta = {"size": size, "saved_by": ".".join(map(str, bpy.data.version)), "file_engine": render.engine,
            "missing_images": missing_images()}
    if engine == "EMBER":
        e = scene.ember
        meta["mapped"] = map_cycles_settings(scene)
        meta["lacking"] = lacking_settings(scene)
        e.samples, e.use_animated_seed, e.time_limit, e.sample_offset = samples, False, 0.0, 0
        e.use_adaptive_sampling = e.use_denoising = False
        e.sampling_pattern = "SOBOL_BURLEY"
    render.engine = engine
    return meta


def frame_camera(scene) -> bool:
    """A file saved without a camera (an asset, a model) is seen by one added to the scene (never saved): a 50 mm
    lens looking down at the bounding sphere of what renders, from the front right, as Blender's View All frames it
    (in both engines' processes alike). False when nothing renders."""
    from mathutils import Vector
    depsgraph = bpy.context.evaluated_depsgraph_get()
    corners = [inst.matrix_world @ Vector(c) for inst in depsgraph.object_instances
               if inst.object.type in {"MESH", "CURVE", "CURVES", "POINTCLOUD", "VOLUME", "SURFACE", "META", "FONT"}
               and not inst.object.original.hide_render for c in inst.object.bound_box]
    if not corners:
        return False
    low = Vector([min(c[k] for c in corners) for k in range(3)])
    high = Vector([max(c[k] for c in corners) for k in range(3)])
    centre, radius = (low + high) / 2, max((high - low).length / 2, 1e-3)
    data = bpy.data.cameras.new("Corpus camera")
    data.lens, data.clip_start, data.clip_end = 50.0, radius * 1e-3, radius * 100.0
    camera = bpy.data.objects.new("Corpus camera", data)
    scene.collection.objects.link(camera)
    direction = Vector((1.0, -1.4, 0.9)).normalized()
    half_angle = min(data.angle_x, data.angle_y) / 2
    camera.location = centre + direction * (radius / np.sin(half_angle) * 1.05)
    camera.rotation_euler = (-direction).to_track_quat("-Z", "Y").to_euler()
    scene.camera = camera
    return True


def set_seed(scene, engine: str, seed: int) -> None:
    (scene.ember if engine == "EMBER" else scene.cycles).seed = seed


def render_seeds(scene, engine: str, seeds: list[int]) -> tuple[np.ndarray, list[float]]:
    images, seconds = [], []
    with tempfile.TemporaryDirectory() as tmp:
        scene.render.filepath = os.path.join(tmp, "frame.exr")
        for seed in seeds:
            set_seed(scene, engine, seed)
            start = time.perf_counter()
            bpy.ops.render.render(write_still=True, scene=scene.name)
            seconds.append(time.perf_counter() - start)
            if not os.path.exists(scene.render.filepath):
                raise RuntimeError("the render wrote no image")
            images.append(load_exr(scene.render.filepath))
            os.remove(scene.render.filepath)
    return np.stack(images), seconds


def apply_overrides(scene, overrides: list[str]) -> None:
    """--set PATH=VALUE: a setting of the scene (e.g. cycles.diffuse_bounces=1024) changed before anything
    else, in both engines' processes; VALUE is a Python literal."""
    for item in overrides:
        path, _, text = item.partition("=")
        *owners, name = path.strip().split(".")
        target = scene
        for owner in owners:
            target = getattr(target, owner)
        if not hasattr(target, name):
            raise RuntimeError(f"--set {item}: the scene has no setting {path.strip()!r}")
        setattr(target, name, ast.literal_eval(text.strip()))


def run(args) -> dict:
    ensure_registered()
    bpy.ops.wm.open_mainfile(filepath=os.path.abspath(args.file), load_ui=False)
    ensure_registered()
    scene = bpy.context.scene
    scene.frame_set(scene.frame_current)
    added = scene.camera is None and frame_camera(scene)
    if scene.camera is None:
        raise RuntimeError(f"scene {scene.name!r} has no camera and nothing to frame")
    apply_overrides(scene, args.set)
    meta = configure(scene, args.engine, args.samples, args.long_side, args.threads)
    meta["camera_added"] = bool(added)
    images, seconds = render_seeds(scene, args.engine, args.seeds)
    return dict(images=images, seconds=np.asarray(seconds), meta=json.dumps(meta))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file")
    parser.add_argument("out")
    parser.add_argument("--engine", choices=("CYCLES", "EMBER"), required=True)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--samples", type=int, default=16)
    parser.add_argument("--long-side", type=int, default=160)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--set", action="append", default=[], metavar="PATH=VALUE")
    args = parser.parse_args(argv)
    try:
        result = run(args)
    except Exception as err:  # one line for the parent's table: the file, not the tool, failed
        message = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        np.savez(args.out, error=f"{type(err).__name__}: {message}")
        return 1
    np.savez(args.out, **result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
