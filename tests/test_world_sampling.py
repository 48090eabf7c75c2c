"""Sampling the world as a light (issue 11): the importance map follows what the lookups read, and an
HDRI with small bright windows is about as noisy per sample in Ember as in Cycles."""
import numpy as np

import bpy_helpers
from bench import scenes
from bpy_helpers import replicate_render

from ember.kernels.textures import Texture


def test_interior_hdri_per_sample_variance_near_cycles(monkeypatch):
    """A sphere, a floor and a wall lit by Blender's interior.exr (a few small windows up to 35,000 times
    the map's mean): Ember's per-sample variance was 16x Cycles' (fireflies from cells read half-bright
    from a window next door but sampled as dark); with cells sampled by their bilinear mean it was 1.5x
    (5x on the floor); on Cycles' automatic 4096 x 2048 map it is 1.03-1.04 (two sets of 8 seeds).
    Bound: issue 11's 1.2, well above that and the spread of the estimate over seeds."""
    monkeypatch.setattr(bpy_helpers, "REPLICATE_SEEDS", tuple(range(1, 9)))
    scene = scenes.interior_scene(48, 48)
    cycles, var_cycles = replicate_render(scene, "CYCLES", 64, max_bounces=4)
    ember, var_ember = replicate_render(scene, "EMBER", 64, max_bounces=4)
    assert abs(ember.mean() / cycles.mean() - 1) < 0.01
    ratio = var_ember.mean() / var_cycles.mean()
    assert ratio < 1.2, ratio


def test_hdri_distribution_samples_its_pdf_which_follows_the_bilinear_lookup():
    """The HDRI's distribution (environment._BilinearDistribution): its pdf is the bilinear lookup's level
    x sin(theta) of the patch row, normalised; it integrates to 1 over (u, v); and its samples land where
    the pdf says (chi-square over a grid finer than the texels, a bright texel at a pole and at the seam)."""
    from stats import assert_chi2

    from ember.kernels.environment import _BilinearDistribution
    rng = np.random.default_rng(6)
    h, w = 6, 9
    values = rng.exponential(1.0, (h, w)).astype(np.float32)
    values[0, 8] = 200.0
    values[3, 4] = 0.0
    image = np.repeat(values[:, :, None], 3, axis=2)
    dist = _BilinearDistribution(image)
    # pdf / lookup is constant along each patch row (v between texel centres, or a pole's half row).
    m = 126  # even: the patches' edges (texel centres) fall between midpoints
    frac = (np.arange(m) + 0.5) / m
    uu, vv = np.meshgrid((np.arange(w)[:, None] + frac[None, :]).ravel() / w,
                         (np.arange(h)[:, None] + frac[None, :]).ravel() / h)
    u, v = uu.ravel().astype(np.float32), vv.ravel().astype(np.float32)
    pdf = dist.pdf(u, v).astype(np.float64)
    looked = Texture(image).lookup(u, v, wrap_v=False)[0].astype(np.float64)
    assert abs(pdf.mean() - 1.0) < 1e-4  # the grid's midpoints integrate it over the unit square
    r = np.clip(np.floor(v.astype(np.float64) * h + 0.5), 0, h).astype(int)
    ratio = pdf / np.maximum(looked, 1e-12)
    for row in range(h + 1):
        sel = (r == row) & (looked > 1e-3)
        np.testing.assert_allclose(ratio[sel], ratio[sel].mean(), rtol=1e-4)
    n = 400_000
    su, sv, spdf = dist.sample(rng.random(n).astype(np.float32), rng.random(n).astype(np.float32))
    np.testing.assert_allclose(spdf, dist.pdf(su, sv), rtol=1e-4, atol=1e-6)
    bins_u, bins_v = 3 * w, 3 * h
    observed = np.bincount(np.minimum((sv * bins_v).astype(int), bins_v - 1) * bins_u +
                           np.minimum((su * bins_u).astype(int), bins_u - 1), minlength=bins_u * bins_v)
    cell = pdf.reshape(bins_v, m * h // bins_v, bins_u, m * w // bins_u).mean(axis=(1, 3)).ravel()
    assert_chi2(observed, cell / cell.sum() * n)
