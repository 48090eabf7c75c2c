"""Node programs (issue 9): their share of a wave's time, and Ember against Cycles on the parity scenes.

    .venv/bin/python bench/node_programs.py [--size 128] [--samples 16]

For each scene of bench/scenes.py that node programs drive (the procedural marble: Noise -> Color Ramp,
Noise -> Bump, Voronoi -> Map Range roughness; the tinted image in a Layer Weight mix):
  share   the time spent running the material programs (every op, the Bump's offset evaluations
          included) against the whole render, one thread, the kernel called directly;
  ratio   paths/s of Ember and Cycles through bpy.ops.render.render, 2 threads, same samples and bounces.
Target: programs at most 25% of wave time on the marble scene.
"""
from __future__ import annotations

import argparse
import os
import sys
import threading
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench.common import import_ember  # noqa: E402

import_ember()
import bpy  # noqa: E402

from bench import scenes  # noqa: E402
from ember.engine.export import export_scene  # noqa: E402
from ember.kernels import Renderer, RenderSettings  # noqa: E402
from ember.kernels.shading import program  # noqa: E402
from tests.bpy_helpers import configure_cycles  # noqa: E402

SCENES = {"marble": scenes.marble_material, "tinted image, Layer Weight mix": scenes.tinted_material}
TARGET_SHARE = 0.25
MAX_BOUNCES = 8


class ProgramTimer:
    """Wall time inside ProgramRun._run at its outermost level, per thread (nested ops not counted twice)."""

    def __init__(self):
        self.seconds = 0.0
        self._local = threading.local()
        self._original = program.ProgramRun._run

    def __enter__(self):
        timer, original = self, self._original

        def timed(run, i):
            if getattr(timer._local, "inside", False):
                return original(run, i)
            timer._local.inside = True
            start = time.perf_counter()
            try:
                return original(run, i)
            finally:
                timer.seconds += time.perf_counter() - start
                timer._local.inside = False
        program.ProgramRun._run = timed
        return self

    def __exit__(self, *exc):
        program.ProgramRun._run = self._original


def share(size: int, samples: int) -> tuple[float, float, float]:
    """(program seconds, render seconds, paths/s) of one single-threaded kernel render of the open scene."""
    exported = export_scene(bpy.context.evaluated_depsgraph_get(), width=size, height=size)
    settings = RenderSettings(samples=samples, max_bounces=MAX_BOUNCES)
    with Renderer(exported.scene, threads=1) as renderer:
        renderer.render(RenderSettings(samples=1, max_bounces=MAX_BOUNCES))  # warm-up
        with ProgramTimer() as timer:
            start = time.perf_counter()
            renderer.render(settings)
            seconds = time.perf_counter() - start
    return timer.seconds, seconds, size * size * samples / seconds


def engine_rate(scene, engine: str, samples: int) -> float:
    """Paths/s of a whole render call (export and start-up included), 2 threads."""
    scene.render.engine = engine
    scene.render.threads_mode, scene.render.threads = "FIXED", 2
    if engine == "CYCLES":
        configure_cycles(scene, samples, 0, MAX_BOUNCES)
    else:
        scene.ember.samples, scene.ember.max_bounces, scene.ember.seed = samples, MAX_BOUNCES, 0
        scene.ember.diffuse_bounces = scene.ember.glossy_bounces = scene.ember.transmission_bounces = MAX_BOUNCES
        scene.ember.sample_clamp_direct = scene.ember.sample_clamp_indirect = scene.ember.blur_glossy = 0.0
        scene.ember.use_adaptive_sampling = False
        scene.ember.pixel_filter_type = "BOX"
        scene.ember.use_denoising = False
    bpy.ops.render.render()  # warm-up (kernels, imports)
    start = time.perf_counter()
    bpy.ops.render.render()
    return scene.render.resolution_x * scene.render.resolution_y * samples / (time.perf_counter() - start)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=128)
    parser.add_argument("--samples", type=int, default=16)
    args = parser.parse_args()
    for name, material in SCENES.items():
        scene = scenes.lit_sphere_scene(material, size=(args.size, args.size))
        programs_s, render_s, rate_1 = share(args.size, args.samples)
        cycles = engine_rate(scene, "CYCLES", args.samples)
        ember = engine_rate(scene, "EMBER", args.samples)
        fraction = programs_s / render_s
        print(f"== {name}: {args.size}x{args.size}, {args.samples} spp, max_bounces {MAX_BOUNCES}")
        print(f"  node programs: {programs_s:.2f} s of {render_s:.2f} s = {fraction:.0%} of wave time "
              f"(1 thread, {rate_1 / 1e6:.3f} M paths/s)")
        print(f"  2 threads, whole render call: Cycles {cycles / 1e6:.3f}, Ember {ember / 1e6:.3f} M paths/s, "
              f"ratio {ember / cycles:.2f}x")
        if name == "marble":
            print(f"target: node programs <= {TARGET_SHARE:.0%} of wave time on the marble scene: "
                  f"{fraction:.0%} {'met' if fraction <= TARGET_SHARE else 'NOT met'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
