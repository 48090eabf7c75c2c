"""Denoising (engine/denoise.py): what OpenImageDenoise costs next to the render it cleans.

    .venv/bin/python bench/denoise.py [--width 1920] [--height 1080] [--threads 2] [--repeats 3] [--quick]

Both measured in the same run, with the same number of threads:
  render   the kernel's Cornell box at a quarter of the frame's width and height, 16 spp with
           the albedo and normal passes the denoiser reads; its paths/s give the time of a 64-spp render
           of the full frame (paths/s barely depend on the resolution: the work is per path)
  denoise  colour + albedo + normal of the full frame (that render tiled 4x4), prefilter ACCURATE
           (Cycles' default), each quality: the median of --repeats calls after a first one, shown apart
           (the very first also makes the CPU device); every call builds and commits its filters
Target (the issue): denoising under 10% of a 64-spp render at 1920x1080.
"""
from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench.common import import_ember, median  # noqa: E402

import_ember()
from ember.engine import denoise as dn  # noqa: E402
from ember.kernels import Renderer, RenderSettings  # noqa: E402
from ember.kernels.shapes import cornell_box  # noqa: E402

TARGET = 0.10
FINAL_SPP = 64
PASSES = ("denoising_albedo", "denoising_normal")


def render_rate(width: int, height: int, samples: int, threads: int, repeats: int):
    """Paths/s of the Cornell box with the denoising passes (median over repeats), and the last render's
    (colour, albedo, normal)."""
    rates = []
    with Renderer(cornell_box(width, height), threads) as renderer:
        renderer.render(RenderSettings(samples=2, passes=PASSES))  # warm up
        for seed in range(repeats):
            result = renderer.render(RenderSettings(samples=samples, seed=seed, passes=PASSES))
            rates.append(result.progress.paths_per_s)
    film = result.film
    return median(rates), (result.image[..., :3], film.resolve_pass(PASSES[0]), film.resolve_pass(PASSES[1]))


def tiled(image: np.ndarray, width: int, height: int) -> np.ndarray:
    h, w, _ = image.shape
    return np.ascontiguousarray(np.tile(image, (-(-height // h), -(-width // w), 1))[:height, :width])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=1920)
    ap.add_argument("--height", type=int, default=1080)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--samples", type=int, default=16, help="samples of the small render that measures paths/s")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="a smoke run: 480x270, 4 spp, one repeat")
    args, _ = ap.parse_known_args()
    if args.quick:
        args.width, args.height, args.samples, args.repeats = 480, 270, 4, 1
    ok, why = dn.available()
    if not ok:
        sys.exit(f"OpenImageDenoise is not available: {why}")
    print(why)

    rate, small = render_rate(args.width // 4, args.height // 4, args.samples, args.threads, args.repeats)
    render_s = args.width * args.height * FINAL_SPP / rate
    print(f"render   Cornell box {args.width // 4}x{args.height // 4}, {args.samples} spp + albedo/normal passes, "
          f"{args.threads} threads: {rate / 1e6:.3f} M paths/s")
    print(f"         -> {FINAL_SPP} spp at {args.width}x{args.height}: {render_s:8.1f} s (estimated)")

    color, albedo, normal = (tiled(image, args.width, args.height) for image in small)
    print(f"denoise  {args.width}x{args.height} colour + albedo + normal, prefilter ACCURATE, {args.threads} threads")
    for quality in dn.QUALITIES:
        start = time.perf_counter()
        dn.denoise(color, albedo, normal, quality=quality, threads=args.threads)
        first = time.perf_counter() - start
        times = []
        for _ in range(args.repeats):
            start = time.perf_counter()
            dn.denoise(color, albedo, normal, quality=quality, threads=args.threads)
            times.append(time.perf_counter() - start)
        ratio = median(times) / render_s
        verdict = "met" if ratio < TARGET else "NOT met"
        print(f"  {quality:8s} {median(times) * 1e3:8.0f} ms (first call {first * 1e3:6.0f} ms)   "
              f"denoise / render {ratio:6.2%}  (target < {TARGET:.0%}: {verdict})")


if __name__ == "__main__":
    main()
