"""Denoised Ember against denoised Cycles on the demo scene, at equal time (issue 13).

    .venv/bin/python bench/denoise_vs_cycles.py [--width 320] [--height 180] [--seconds 4 8] [--threads 2]

Both engines render the demo scene (engine/demo.py) through bpy.ops.render.render with a time limit, their
default denoiser on (OpenImageDenoise, albedo and normal, Accurate prefilter; Cycles' clamping and Ember's
off on both, box filter), and each image's RMSE against a converged reference is printed with their ratio.
The reference is Ember's, 2 x 512 samples with two seeds, cached in bench/results/ (its own noise, estimated
from the two halves, is taken out of every RMSE: RMSE^2 - var(reference)). Colours are clipped to [0, 1]
first (what a viewer sees; a few bright highlights would otherwise decide the whole figure).
Also printed: the denoiser's gain on Ember at 16 samples (issue 13's "at least 5x" on the demo).
--write-test-reference renders the reference tests/test_denoise_demo.py reads (640x360, about 15 minutes).
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench.common import ROOT, import_ember  # noqa: E402

import_ember()
import bpy  # noqa: E402

from ember.engine.demo import build_demo_scene  # noqa: E402
from tests import bpy_helpers as H  # noqa: E402

REFERENCE_SPP = 512


def scene_at(width, height):
    H.ensure_registered()
    scene = build_demo_scene()
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = width, height, 100
    return scene


def reference(width, height):
    path = os.path.join(ROOT, "bench", "results", f"denoise_reference_{width}x{height}.npz")
    if os.path.exists(path):
        data = np.load(path)
        return data["a"], data["b"]
    print(f"rendering the reference (2 x {REFERENCE_SPP} spp, cached in {path}) ...", file=sys.stderr, flush=True)
    a = H.render_to_array(scene_at(width, height), "EMBER", REFERENCE_SPP, seed=101, max_bounces=6)[..., :3]
    b = H.render_to_array(scene_at(width, height), "EMBER", REFERENCE_SPP, seed=202, max_bounces=6)[..., :3]
    os.makedirs(os.path.dirname(path), exist_ok=True)
    np.savez_compressed(path, a=a, b=b)
    return a, b


def timed(engine, width, height, seconds, threads):
    scene = scene_at(width, height)
    render = scene.render
    render.engine = engine
    render.threads_mode, render.threads = "FIXED", threads
    if engine == "CYCLES":
        H.configure_cycles(scene, 1 << 16, 0, 6)
        scene.cycles.use_denoising, scene.cycles.denoiser = True, "OPENIMAGEDENOISE"
        scene.cycles.time_limit = seconds
    else:
        e = scene.ember
        e.samples, e.max_bounces, e.time_limit = 1 << 16, 6, seconds
        e.diffuse_bounces = e.glossy_bounces = e.transmission_bounces = 6   # as configure_cycles
        e.use_adaptive_sampling, e.sample_clamp_direct, e.sample_clamp_indirect, e.blur_glossy = False, 0, 0, 0
        e.pixel_filter_type, e.use_denoising = "BOX", True
    import tempfile
    with tempfile.TemporaryDirectory() as tmp:
        render.image_settings.file_format, render.image_settings.color_depth = "OPEN_EXR", "32"
        render.filepath = os.path.join(tmp, "frame.exr")
        bpy.ops.render.render(write_still=True)
        return H.load_exr(render.filepath)[..., :3]


def rmse(image, ref_a, ref_b):
    clip = lambda x: np.clip(x, 0, 1)  # noqa: E731
    ref = (clip(ref_a) + clip(ref_b)) / 2
    var_ref = ((clip(ref_a) - clip(ref_b)) ** 2).mean() / 4
    return float(np.sqrt(max(((clip(image) - ref) ** 2).mean() - var_ref, 0.0)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=180)
    ap.add_argument("--seconds", type=float, nargs="+", default=[4.0, 8.0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--write-test-reference", action="store_true",
                    help="render tests/data/denoise_demo_reference_640x360.npz (2 x 512 spp at 640x360) and stop")
    args, _ = ap.parse_known_args()
    if args.write_test_reference:
        a, b = reference(640, 360)
        clip = lambda x: np.clip(x, 0, 1)  # noqa: E731
        path = os.path.join(ROOT, "tests", "data", "denoise_demo_reference_640x360.npz")
        np.savez_compressed(path, reference=((clip(a) + clip(b)) / 2).astype(np.float16),
                            variance=np.float64(((clip(a) - clip(b)) ** 2).mean() / 4))
        print(f"wrote {path}")
        return
    a, b = reference(args.width, args.height)
    print(f"demo scene {args.width}x{args.height}, reference 2 x {REFERENCE_SPP} spp (its noise taken out)")
    noisy = H.render_to_array(scene_at(args.width, args.height), "EMBER", 16, max_bounces=6)[..., :3]
    clean = H.render_to_array(scene_at(args.width, args.height), "EMBER", 16, max_bounces=6, denoise=True)[..., :3]
    gain = rmse(noisy, a, b) / rmse(clean, a, b)
    print(f"  Ember 16 spp: RMSE {rmse(noisy, a, b):.4f} noisy, {rmse(clean, a, b):.4f} denoised: "
          f"{gain:.1f}x (issue 13's target: 5x)")
    for seconds in args.seconds:
        ember = rmse(timed("EMBER", args.width, args.height, seconds, args.threads), a, b)
        cycles = rmse(timed("CYCLES", args.width, args.height, seconds, args.threads), a, b)
        print(f"  {seconds:.0f} s each, denoised: RMSE Ember {ember:.4f}, Cycles {cycles:.4f}: "
              f"ratio {ember / cycles:.2f}x")


if __name__ == "__main__":
    main()
