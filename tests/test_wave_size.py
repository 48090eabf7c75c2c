"""The automatic wave size (RenderSettings.wave_size None): waves of WAVE_SIZE paths, twice as many when the
materials mix lobes; the image is the same whatever the wave size, to float rounding (where a path falls in
its wave can change a value by one float32 step: 8 of 6,144 values at 48x32, 4 samples, waves of 512 against
4,096 paths)."""
from __future__ import annotations

import os
import sys

import numpy as np

from bpy_helpers import export_current

from ember.kernels import Renderer, RenderSettings
from ember.kernels.integrator import LAYERED_WAVE_SIZE, WAVE_SIZE, _plan_pass

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench import scenes  # noqa: E402


def _renderer(build) -> Renderer:
    build()
    return Renderer(export_current().scene, threads=2)


def test_layered_materials_get_larger_waves_and_the_same_image():
    with _renderer(lambda: scenes.materials_scene(64, 48)) as renderer:
        assert renderer._layered
        assert renderer.wave_size(RenderSettings()) == LAYERED_WAVE_SIZE
        assert renderer.wave_size(RenderSettings(wave_size=1000)) == 1000
        # 64 x 48 pixels x 256 samples: after the first pass the two sizes take other samples per pass
        # (at 96 samples both took all 95 left in one pass, and the test could not fail).
        assert _plan_pass(64, 48, 1, 256, LAYERED_WAVE_SIZE) != _plan_pass(64, 48, 1, 256, WAVE_SIZE)
        automatic = renderer.render(RenderSettings(samples=256, seed=4)).image
        fixed = renderer.render(RenderSettings(samples=256, seed=4, wave_size=WAVE_SIZE)).image
    np.testing.assert_allclose(automatic, fixed, rtol=1e-6, atol=1e-7)


def test_diffuse_scenes_keep_the_default_waves():
    with _renderer(lambda: scenes.cornell_scene(32, 32)) as renderer:
        # Its unused default material row is a Principled BSDF: only the materials triangles use count.
        assert renderer.shading.mixes_lobes and not renderer._layered
        assert renderer.wave_size(RenderSettings()) == WAVE_SIZE


def test_background_renders_start_with_full_passes():
    """quick_first_pass False (background mode): the first pass is a full one, every wave at once; the image
    is the same sum of the same samples, in another order (float rounding)."""
    assert _plan_pass(256, 256, 0, 32, LAYERED_WAVE_SIZE)[0] == 1
    spp, bands = _plan_pass(256, 256, 0, 32, LAYERED_WAVE_SIZE, quick_first=False)
    assert spp == 16 and len(bands) == 4
    with _renderer(lambda: scenes.materials_scene(64, 48)) as renderer:
        quick = renderer.render(RenderSettings(samples=40, seed=2, wave_size=4096))
        full = renderer.render(RenderSettings(samples=40, seed=2, wave_size=4096, quick_first_pass=False))
    assert quick.progress.paths == full.progress.paths == 64 * 48 * 40
    np.testing.assert_allclose(full.image, quick.image, rtol=1e-6, atol=1e-7)
