"""Light samples of the world focused on glossy lobes (issue 11): at a shading point whose sampling weight is
mostly one rough microfacet lobe, part of the world's light samples are drawn from the map's block around
that lobe's direction (environment.Environment.focus, focus.glossy_axes); the MIS weights use the
mixture's pdf, so the image is the same and the noise lower."""
import math

import numpy as np
import pytest

import bpy_helpers
from bench import scenes
from bpy_helpers import replicate_render
from stats import assert_chi2

from ember.kernels import sampling
from ember.kernels.bsdf import closures, focus, lobes
from ember.kernels.environment import Environment, WorldFocus, _BilinearDistribution
from ember.kernels.scene import World


def _map(h=16, w=32, seed=3):
    rng = np.random.default_rng(seed)
    image = rng.exponential(1.0, (h, w, 3)).astype(np.float32)
    image[4:6, 30:32] *= 80.0   # a hot spot against the seam
    image[0, 3] *= 200.0        # and one on the bottom row
    return image


def _patch_masses(dist):
    h, w = dist.height, dist.width
    r, c = np.meshgrid(np.arange(h + 1), np.arange(w), indexing="ij")
    r, c = r.ravel(), c.ravel()
    return dist.block_mass(r, r + 1, c, np.ones_like(c)).reshape(h + 1, w)


@pytest.mark.parametrize("compensate", [False, True])
@pytest.mark.parametrize("block", [(3, 9, 27, 10), (0, 17, 0, 32), (5, 12, 2, 9), (14, 17, 30, 4), (5, 6, 30, 1)])
def test_block_samples_follow_the_distribution_inside_the_block(compensate, block):
    """sample_block: every point lands in the block (rows [r0, r1), columns c0 .. c0 + nc - 1, wrapping past
    the seam), the patches are chosen in proportion to their mass (chi-square), the masses of single patches
    add up to block_mass, and the pdf returned is the map's pdf() at the point."""
    dist = _BilinearDistribution(_map(), compensate)
    h, w = dist.height, dist.width
    r0, r1, c0, nc = block
    n = 200_000
    rng = np.random.default_rng(sum(block))
    full = [np.full(n, x, np.int64) for x in block]
    mass = dist.block_mass(*full)
    assert mass[0] > 0
    masses = _patch_masses(dist)
    assert abs(masses.sum() - 1.0) < 1e-9
    cols = (c0 + np.arange(nc)) % w
    inside = np.zeros((h + 1, w), bool)
    inside[r0:r1][:, cols] = True
    assert mass[0] == pytest.approx(masses[inside].sum(), rel=1e-9)
    u, v, pdf = dist.sample_block(*full, rng.random(n, dtype=np.float32), rng.random(n, dtype=np.float32))
    r, c = dist.patch_of(u, v)
    # A point on a patch row's edge may be read as the next row's (float32); both are in the block here or not.
    assert np.mean(inside[r, c]) > 1 - 1e-4
    # The same float32 edge points: sin(theta) steps between patch rows, so the two rows' pdfs differ there.
    assert np.mean(np.abs(pdf / dist.pdf(u, v) - 1) > 2e-3) < 1e-4
    observed = np.bincount(r * w + c, minlength=(h + 1) * w).reshape(h + 1, w)
    expected = np.where(inside, masses, 0.0) / mass[0] * n
    assert observed[expected == 0].sum() <= 2
    live = expected > 0
    if live.sum() > 1:
        assert_chi2(observed[live], expected[live])


def _environment(**kwargs):
    angle = 0.7
    rot = np.array([[math.cos(angle), -math.sin(angle), 0], [math.sin(angle), math.cos(angle), 0], [0, 0, 1]],
                   np.float32)
    return Environment(World(hdri=_map(32, 64), env_from_world=rot, **kwargs))


def _focus(env, n, seed):
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(3, n)).astype(np.float32)
    d /= np.linalg.norm(d, axis=0)
    radius = rng.uniform(0.02, 1.0, n).astype(np.float32)
    share = rng.uniform(0.0, 0.9, n).astype(np.float32)
    return env.focus(*d, radius, share)


def test_focused_pdf_is_the_mixture_sampled_and_integrates_to_one():
    """With a focus per sample (random axes, radii and shares): the pdf that sample_direction returns is
    direction_pdf's with the same focus; over uniform directions the mixture's pdf averages to 1 / (4 pi);
    the blocks hold the cones they stand for; and where the share is 0 the samples are the unfocused ones
    bit for bit."""
    env = _environment()
    n = 300_000
    focus = _focus(env, n, 5)
    rng = np.random.default_rng(7)
    u1, u2 = rng.random(n, dtype=np.float32), rng.random(n, dtype=np.float32)
    wx, wy, wz, pdf = env.sample_direction(u1, u2, focus)
    # Away from the poles, where float32 directions lose sin(theta) (the map's own sampling does too).
    away = np.abs(wz) < 0.999
    assert np.mean(np.abs(pdf[away] / env.direction_pdf(wx, wy, wz, focus)[away] - 1) > 2e-3) < 1e-4
    assert np.mean(focus.p > 0) > 0.9
    # E[pdf(d) / uniform pdf] over uniform d is the pdf's integral.
    dx, dy, dz = sampling.sample_uniform_sphere(rng.random(n, dtype=np.float32), rng.random(n, dtype=np.float32))
    ratio = env.direction_pdf(dx, dy, dz, focus).astype(np.float64) / sampling.UNIFORM_SPHERE_PDF
    assert abs(ratio.mean() - 1.0) < 4 * ratio.std() / math.sqrt(n)
    # The block holds its cone: directions within the radius of the axis are inside it.
    rng = np.random.default_rng(9)
    axis = rng.normal(size=(3, 2000)).astype(np.float32)
    axis /= np.linalg.norm(axis, axis=0)
    radius = rng.uniform(0.05, 0.9, 2000).astype(np.float32)
    cone = env.focus(*axis, radius, np.full(2000, 0.5, np.float32))
    t = rng.normal(size=(3, 2000)).astype(np.float32)
    t -= axis * (t * axis).sum(axis=0)
    t /= np.linalg.norm(t, axis=0)
    angle = radius * rng.uniform(0, 0.98, 2000).astype(np.float32)
    d = axis * np.cos(angle) + t * np.sin(angle)
    ex, ey, ez = env.to_env(*d)
    from ember.kernels.environment import direction_to_equirect
    r, c = env._distribution.patch_of(*direction_to_equirect(ex, ey, ez))
    r0, r1, c0, nc = cone.block()
    assert np.all((r >= r0) & (r < r1) & (np.mod(c - c0, env._distribution.width) < nc))
    # No focus where the share is 0: the plain samples, bit for bit.
    zero = WorldFocus(focus.data.copy())
    zero.data[4] = 0.0
    np.testing.assert_array_equal(np.stack(env.sample_direction(u1, u2, zero)), np.stack(env.sample_direction(u1, u2)))
    assert Environment(World(color=np.ones(3, np.float32))).focuses is False
    assert _environment(focus=False).focuses is False


def _closures(specs):
    """A ClosureSet with one hit per spec: (lobe, alpha, eta, sample weight, wo), normal +z, plus a Lambert
    of sample weight 1 - weight when weight < 1."""
    n = len(specs)
    wo = np.array([s[4] for s in specs], np.float32).T
    wo /= np.linalg.norm(wo, axis=0)
    ns = (np.zeros(n, np.float32), np.zeros(n, np.float32), np.ones(n, np.float32))
    b = closures.ClosureBuilder(n, ns, tuple(wo))
    for i, (lobe, alpha, eta, weight, _) in enumerate(specs):
        hit = np.array([i])
        b.add(lobe, hit, np.full((3, 1), weight, np.float32), ax=alpha, ay=alpha, eta=eta)
        if weight < 1:
            b.add(lobes.LAMBERT, hit, np.full((3, 1), 1 - weight, np.float32))
    return b.finish(), wo


def test_glossy_axes_are_the_mirror_and_refracted_directions():
    """focus.glossy_axes: a reflection lobe gathers about the mirror direction, a refraction lobe about
    Snell's direction; glass about the branch that Fresnel favours (refraction at normal incidence, with a
    share of 1 - F; reflection under total internal reflection); the share is the lobe's part of the
    sampling weight; the radius grows with alpha and is twice the microfacet tilt for reflection. Singular
    lobes, lobes wider than MAX_AXIS_RADIUS and lobes with less than MIN_AXIS_SHARE of the weight are left
    out."""
    oblique = (0.6, 0.0, 0.8)
    specs = [(lobes.REFLECTION, 0.1, 1.0, 1.0, oblique),          # 0 mirror direction
             (lobes.REFRACTION, 0.1, 1.5, 1.0, oblique),          # 1 into glass
             (lobes.GLASS, 0.1, 1.5, 1.0, (0.0, 0.0, 1.0)),       # 2 glass, normal incidence: refract
             (lobes.GLASS, 0.1, 1 / 1.5, 1.0, (0.9, 0.0, 0.3)),   # 3 glass from inside past the critical angle
             (lobes.REFLECTION, 0.2, 1.0, 0.5, oblique),          # 4 half of the weight
             (lobes.REFLECTION, 0.0, 1.0, 1.0, oblique),          # 5 singular
             (lobes.REFLECTION, 0.9, 1.0, 1.0, oblique),          # 6 too wide
             (lobes.REFLECTION, 0.1, 1.0, 0.1, oblique),          # 7 too small a share
             (lobes.REFLECTION, 0.25, 1.0, 1.0, oblique)]         # 8 rougher than 0
    cs, wo = _closures(specs)
    hits, (dx, dy, dz), radius, share = focus.glossy_axes(cs)
    np.testing.assert_array_equal(hits, [0, 1, 2, 3, 4, 8])
    d = np.stack([dx, dy, dz])
    np.testing.assert_allclose(d[:, 0], [-0.6, 0.0, 0.8], atol=1e-6)               # mirror of wo about +z
    sin_t = 0.6 / 1.5
    np.testing.assert_allclose(d[:, 1], [-sin_t, 0.0, -math.sqrt(1 - sin_t ** 2)], atol=1e-6)
    np.testing.assert_allclose(d[:, 2], [0.0, 0.0, -1.0], atol=1e-6)
    f0 = ((1.5 - 1) / (1.5 + 1)) ** 2
    np.testing.assert_allclose(share[[0, 1, 2]], [1.0, 1.0, 1 - f0], rtol=1e-5)
    np.testing.assert_allclose(d[:, 3], wo[:, 3] * [-1, -1, 1], atol=1e-6)          # reflected, not refracted
    assert share[3] == pytest.approx(1.0)
    assert share[4] == pytest.approx(0.5, rel=1e-5)
    np.testing.assert_allclose(radius[0], 2 * math.atan(float(focus.AXIS_TILT) * 0.1), rtol=1e-5)
    assert radius[5] > radius[0]
    assert radius[1] < radius[0]   # entering glass bends the lobe less than a mirror does


def _frosted_scene(size):
    """A frosted glass sphere and a rough metal one on a floor under forest.exr, with a half-transparent
    canopy above them that the light and the BSDF rays toward the sky pass through."""
    import bpy
    scene = bpy_helpers.new_scene(size, size)
    for name, inputs, x in (("Frosted", {"Transmission Weight": 1.0, "Roughness": 0.3, "IOR": 1.45}, -0.55),
                            ("Metal", {"Base Color": (0.9, 0.7, 0.5, 1.0), "Metallic": 1.0, "Roughness": 0.3}, 0.55)):
        mat = bpy.data.materials.new(name)
        bsdf = mat.node_tree.nodes["Principled BSDF"]
        for key, value in inputs.items():
            bsdf.inputs[key].default_value = value
        scenes.add_mesh(name, *scenes.uv_sphere(32, 16, 0.5, (x, 0.0, 0.6)), mat, smooth=True)
    canopy = bpy.data.materials.new("Canopy")
    canopy.node_tree.nodes["Principled BSDF"].inputs["Alpha"].default_value = 0.5
    scenes.add_mesh("Canopy", *scenes.grid((-30, -30, 3), (60, 0, 0), (0, 60, 0), 1), canopy)
    scenes.add_mesh("Floor", *scenes.grid((-6, -6, 0), (12, 0, 0), (0, 12, 0), 1),
                    bpy_helpers.diffuse_material("Floor", (0.4, 0.4, 0.4)))
    bpy_helpers.add_camera(scene, (0.0, -2.6, 1.0), (0.0, 0.0, 0.55)).data.lens = 50
    bpy_helpers.set_world(scene, hdri=scenes.HDRI, strength=1.0, rotation=(0.0, 0.0, 0.6))
    return scene


def test_focus_changes_the_noise_not_the_image(monkeypatch):
    """Frosted glass and rough metal under forest.exr's sun, below a half-transparent canopy, rendered with
    and without focused world samples: the same image within noise (8 x 8 pixel blocks and the whole image,
    against standard errors from both sets' scatter; a focus lost by the rays that pass through the canopy,
    or by the escaped rays' MIS, makes them differ), and less noise with focus: the mean per-pixel variance was
    0.36-0.83x the plain one's over eight sets of eight seeds (0.16-0.22 against 0.22-0.49: the plain renders'
    fireflies decide). Bound 0.9."""
    monkeypatch.setattr(bpy_helpers, "REPLICATE_SEEDS", tuple(range(1, 9)))
    scene = _frosted_scene(32)
    focused, var_f = replicate_render(scene, "EMBER", 128, max_bounces=6)
    bpy_helpers.replace_world(monkeypatch, focus=False)
    plain, var_p = replicate_render(scene, "EMBER", 128, max_bounces=6)
    bpy_helpers.assert_same_image(focused, var_f, plain, var_p)
    assert var_f.mean() < 0.9 * var_p.mean(), (var_f.mean(), var_p.mean())
