"""The sampling pattern (Render Properties > Sampling > Advanced > Pattern, as Cycles' Sampling Pattern):
AUTOMATIC lays the first bounce's numbers out as Cycles' final renders do, so that neighbouring pixels'
errors are blue noise; SOBOL_BURLEY gives each pixel a sequence of its own. Checked through Blender on soft
shadows lit directly (the first bounce's numbers decide all of the noise there), with the variance over
eight seeds of each aligned 2x2 block's mean against a quarter of its pixels' variance: 1 for pixels whose
errors are independent, below 1 where neighbours' errors cancel."""
from __future__ import annotations

import bpy
import numpy as np
import pytest

from bpy_helpers import add_camera, mesh_object, new_scene, render_to_array

SEEDS = range(10, 18)


def _shadow_scene():
    scene = new_scene(64, 64)
    mesh_object("Floor", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], [(0, 1, 2, 3)])
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0, 0, 0.8))
    light = bpy.data.lights.new("Area", "AREA")
    light.size, light.energy = 3.0, 300.0
    lamp = bpy.data.objects.new("Area", light)
    lamp.location = (0.5, 0.3, 3.0)
    scene.collection.objects.link(lamp)
    add_camera(scene, (0, -5, 4), (0, 0, 0))
    return scene


def _block_ratio(images) -> tuple[float, float, float, float]:
    """(ratio, its standard error from the blocks' scatter (delta method), the pixels' mean variance, its
    standard error)."""
    a = np.asarray(images, np.float64)
    pixel_var = a.var(axis=0, ddof=1)
    h, w = pixel_var.shape
    num = a.reshape(len(a), h // 2, 2, w // 2, 2).mean(axis=(2, 4)).var(axis=0, ddof=1).ravel()
    den = pixel_var.reshape(h // 2, 2, w // 2, 2).mean(axis=(1, 3)).ravel() / 4
    ratio = num.sum() / den.sum()
    spread = num - ratio * den
    se = float(np.sqrt((spread ** 2).sum() / (len(num) - 1) / len(num)) / den.mean())
    return float(ratio), se, float(pixel_var.mean()), float(pixel_var.std() / np.sqrt(pixel_var.size))


@pytest.fixture(scope="module")
def ratios():
    scene = _shadow_scene()
    out = {}
    for pattern in ("AUTOMATIC", "SOBOL_BURLEY"):
        scene.ember.sampling_pattern = pattern
        out[pattern] = _block_ratio([render_to_array(scene, "EMBER", 4, seed=s, max_bounces=0)[..., :3].mean(-1)
                                     for s in SEEDS])
    return out


def test_automatic_pattern_makes_neighbouring_errors_cancel(ratios):
    """Measured: 0.47 +- 0.04 (AUTOMATIC) against 0.96 +- 0.05 (SOBOL_BURLEY): a 2x2 block's mean is
    twice as exact as independent pixels' would be, and each pixel is as noisy as before."""
    ratio, se, variance, variance_se = ratios["AUTOMATIC"]
    own_ratio, own_se, own_variance, own_variance_se = ratios["SOBOL_BURLEY"]
    assert abs(own_ratio - 1.0) < 4 * own_se, (own_ratio, own_se)     # independent pixels
    assert ratio < 1.0 - 4 * se and ratio < own_ratio - 4 * np.hypot(se, own_se), (ratio, se, own_ratio)
    # Each pixel is as noisy either way (measured 0.01362 and 0.01352, standard errors 0.0008).
    assert abs(variance - own_variance) < 4 * np.hypot(variance_se, own_variance_se), (variance, own_variance)


def test_the_pattern_is_a_scene_setting_cycles_names():
    scene = new_scene(8, 8)
    assert scene.ember.sampling_pattern == "AUTOMATIC"
    items = [i.identifier for i in scene.ember.bl_rna.properties["sampling_pattern"].enum_items]
    assert items == ["AUTOMATIC", "SOBOL_BURLEY"]
