"""Denoising the demo scene at 16 samples against a converged image: as close to it as Cycles' denoised
image, in the same run.

The reference (tests/data/denoise_demo_reference_640x360.npz) is Ember's own render of the built-in demo
scene at 640x360: the mean of two 512-sample renders with different seeds, colours clipped to [0, 1] (what
a viewer sees; a few highlights would otherwise decide the figure), stored as float16, with the variance
of that mean (from the two halves), which is taken out of every squared error. Regenerate it with the
recipe in bench/denoise_vs_cycles.py after a change that is meant to alter the demo's image.
"""
from __future__ import annotations

import os

import bpy
import numpy as np
import pytest

from bpy_helpers import configure_engine, ensure_registered
from exr import render_multilayer
from ember.engine.demo import build_demo_scene

REFERENCE = os.path.join(os.path.dirname(__file__), "data", "denoise_demo_reference_640x360.npz")


@pytest.mark.skipif(not os.path.exists(REFERENCE), reason="the reference image is not there")
@pytest.mark.skipif(bpy.app.version < (5, 3, 0), reason=(
    "a comparison of the denoised images' quality, run on the newest Blender only (eight 640x360 renders, the "
    "suite's longest test: the oldest Blender's suite has no room for it); Ember's denoiser on every Blender's "
    "OpenImageDenoise is tested by test_denoise.py"))
def test_denoised_demo_is_as_close_to_the_reference_as_cycles():
    """Issue 13 set "at least 5x" on the demo as it was; since sun discs are met by BSDF rays (as in Cycles) the
    demo has sharp sun highlights, and both engines' denoised errors sit on the same floor (mostly the
    denoiser's smoothing of detail). Cycles, the oracle, rendered in the same run, is the bar: at 16 samples
    Ember's noisy image is no worse than Cycles' and its denoised image no worse than Cycles' denoised one,
    within three standard errors of the seeds' scatter. Ember's less noisy input gives it the smaller ratio of
    the two errors (docs/performance.md). The denoiser must still do its work: at least 4x."""
    data = np.load(REFERENCE)
    reference, variance = data["reference"].astype(np.float64), float(data["variance"])

    def errors(engine: str) -> tuple[tuple[float, float], tuple[float, float]]:
        """(RMS error, its standard error) of the noisy and of the denoised image, over four seeds (one seed's
        figure is itself noisy; the scatter gives the standard error). One render per seed gives both: the
        denoised Combined and the Noisy Image pass beside it."""
        ensure_registered()
        scene = build_demo_scene()
        scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 640, 360, 100
        layer = scene.view_layers[0]
        (layer.ember if engine == "EMBER" else layer.cycles).denoising_store_passes = True
        mse = {"Noisy Image": [], "Combined": []}
        for seed in range(4):
            configure_engine(scene, engine, 16, seed=seed, max_bounces=6, denoise=True)
            parts, _ = render_multilayer(scene)
            for name, values in mse.items():
                planes = {c.upper(): v for c, v in parts[f"{layer.name}.{name}"].items()}
                image = np.clip(np.stack([planes[c] for c in "RGB"], axis=-1).astype(np.float64), 0, 1)
                values.append(max(((image - reference) ** 2).mean() - variance, 0.0))

        def rmse(values):
            value = float(np.sqrt(np.mean(values)))
            return value, float(np.std(values, ddof=1) / 2 / (2 * value))
        return rmse(mse["Noisy Image"]), rmse(mse["Combined"])

    (noisy, noisy_se), (clean, clean_se) = errors("EMBER")
    (cycles_noisy, cycles_noisy_se), (cycles_clean, cycles_clean_se) = errors("CYCLES")
    assert noisy > 0.05  # 16 samples are noisy: the test can tell
    assert noisy < cycles_noisy + 3 * np.hypot(noisy_se, cycles_noisy_se), (noisy, cycles_noisy)
    assert clean < cycles_clean + 3 * np.hypot(clean_se, cycles_clean_se), (clean, cycles_clean)
    assert noisy / clean >= 4.0, (noisy, clean, noisy / clean)
