"""The light tree (kernels.light_tree): its selection pmf against its sampling frequencies, the pmf MIS
uses against the probability the sampler used, and renders with it against the global power CDF (same
mean, lower variance) on a scene of many small lamps and one of many emissive triangles."""
import dataclasses

import numpy as np
import pytest

from ember.kernels import Camera, Lights, Renderer, RenderSettings, World
from ember.kernels.lights import selection as light_selection
from ember.kernels.light_tree import LightTree
from ember.kernels.light_tree_cycles import CyclesLightTree
from ember.kernels.shapes import cornell_box, look_at, quad, subdivided_quad, uv_sphere
from kernel_helpers import make_scene, trace_samples
from stats import assert_chi2, mean_and_stderr
from test_lights import sampler_for

RECT = 3


def many_lights(k=100, seed=1, kinds=(0, 1, 3, 4), radius=(0.0, 0.2), clamped=False):
    """k lamps of the given kinds; clamped: the render clamps, so the choice is Cycles' (Lights.clamped)."""
    rng = np.random.default_rng(seed)
    frames = np.stack([np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(k)]).astype(np.float32)
    return Lights(kind=np.int32(rng.choice(kinds, k)), position=rng.uniform(-5, 5, (k, 3)).astype(np.float32),
                  frame=frames, radiance=np.float32(rng.exponential(5.0, (k, 1)) * rng.uniform(0.3, 1, (k, 3))),
                  radius=np.float32(rng.uniform(*radius, k)), size=np.float32(rng.uniform(0.1, 0.5, (k, 2))),
                  spot_cos=np.float32([(0.5, 0.1)] * k), sun_half_angle=np.zeros(k, np.float32), clamped=clamped)


def sky():
    """A small HDRI world: it varies with direction, so next-event estimation samples it."""
    return World(hdri=np.float32(np.random.default_rng(6).uniform(0.1, 0.5, (8, 16, 3))))


def mixed_sampler(monkeypatch, world=True, clamped=False):
    """Lights of every local kind, emissive triangles and a world, with the tree forced on (clamped: Cycles')."""
    monkeypatch.setattr(light_selection, "TREE_MIN_DIVERGENCE", 0.0)
    tri = np.float32(np.random.default_rng(2).uniform(-3, 3, (40, 3, 3)))
    sampler = sampler_for(lights=many_lights(clamped=clamped), positions=tri, emission=(2.0, 1.5, 1.0),
                          world=sky() if world else None)
    assert sampler.tree is None or isinstance(sampler.tree, CyclesLightTree if clamped else LightTree)
    return sampler


def at(p, n):
    return tuple(np.full(n, c, np.float32) for c in p)


@pytest.mark.parametrize("clamped", [False, True])
@pytest.mark.parametrize("world", [True, False])
def test_tree_pmf_sums_to_one_and_matches_frequencies(world, clamped, monkeypatch):
    """At fixed points: the selection pmf over every emitter sums to 1 and the emitters chosen with
    choose_at follow it (chi-square), for the tree with and without distant emitters, Ember's and Cycles' (a clamped
    render's, kernels.light_tree_cycles: its walk, its leaves of several lamps, the emissive object's subtree)."""
    sampler = mixed_sampler(monkeypatch, world, clamped)
    assert sampler.uses_tree
    k = sampler.world_index + 1
    rng = np.random.default_rng(3)
    for p in rng.uniform(-5, 5, (4, 3)).astype(np.float32):
        pmf = sampler.selection_pmf(np.arange(k), *at(p, k)).astype(np.float64)
        if not sampler.weighs_distant:   # (clamped: the world's share is Cycles' root's at p, selection_pmf's)
            pmf[-1] = sampler.select_pmf[-1]
        n = 300_000
        chosen, select = sampler.choose_at(rng.random(n, dtype=np.float32), *at(p, n))
        assert_choices_follow(pmf, chosen, select, clamped)
        # The tree concentrates on what is near: it differs from the global pmf.
        assert np.abs(pmf - sampler.select_pmf).max() > 1e-3


def assert_choices_follow(pmf, chosen, select, clamped):
    """The choices (chosen, select) follow pmf (chi-square) and report it. Cycles' tree (clamped) chooses no light
    where its walk meets a leaf none of whose lamps can light the point (light_tree_sample returns false: a lamp
    facing away, a spot's cone): there pmf sums to less than 1, select is 0, and those draws are a bin of their own."""
    total = pmf.sum()
    if clamped:
        assert total <= 1 + 1e-5, total
    else:
        assert abs(total - 1) < 1e-5, total
    none = select == 0
    np.testing.assert_allclose(select[~none], pmf[chosen[~none]].astype(np.float32), rtol=1e-6)
    counts, expected = np.bincount(chosen[~none], minlength=len(pmf)), pmf * len(chosen)
    if clamped:
        counts, expected = np.append(counts, none.sum()), np.append(expected, max(1 - total, 0) * len(chosen))
    else:
        assert not none.any()
    assert_chi2(counts, expected)


def facing(n, normal, two_sided=False):
    return tuple(np.full(n, c, np.float32) for c in normal) + (np.full(n, two_sided),)


@pytest.mark.parametrize("clamped", [False, True])
@pytest.mark.parametrize("two_sided", [False, True])
def test_tree_pmf_with_a_normal_sums_to_one_and_matches_frequencies(two_sided, clamped, monkeypatch):
    """With the shading point's normal (Cycles' incidence factor): the pmf still sums to 1, choose_at follows it
    (chi-square) and reports it, the MIS pmf equals it, and it differs from the pmf without a normal; for Ember's
    tree and Cycles'."""
    sampler = mixed_sampler(monkeypatch, clamped=clamped)
    k = sampler.world_index + 1
    rng = np.random.default_rng(13)
    for p in rng.uniform(-5, 5, (3, 3)).astype(np.float32):
        normal = rng.normal(size=3)
        normal /= np.linalg.norm(normal)
        pmf = sampler.selection_pmf(np.arange(k), *at(p, k), facing=facing(k, normal, two_sided)).astype(np.float64)
        if not sampler.weighs_distant:
            pmf[-1] = sampler.select_pmf[-1]
        n = 300_000
        chosen, select = sampler.choose_at(rng.random(n, dtype=np.float32), *at(p, n), facing=facing(n, normal, two_sided))
        assert_choices_follow(pmf, chosen, select, clamped)
        plain = sampler.selection_pmf(np.arange(k), *at(p, k)).astype(np.float64)
        if not sampler.weighs_distant:
            plain[-1] = sampler.select_pmf[-1]
        assert np.abs(pmf - plain)[:-1].max() > 1e-3


@pytest.mark.parametrize("clamped", [False, True])
def test_a_lamp_behind_an_opaque_point_is_not_chosen(clamped):
    """Two lamps on either side of a wall: a point on one face chooses only the lamp in front of it (Cycles
    gives a node behind an opaque surface no importance), both where the surface transmits, and both without
    a normal; a zero normal (a point in a medium) is as no normal. In Ember's tree and in Cycles'."""
    lights = Lights(clamped=clamped, kind=np.zeros(2, np.int32), position=np.float32([(-1, 0, 0), (1, 0, 0)]),
                    frame=np.repeat(np.eye(3, dtype=np.float32)[None], 2, axis=0),
                    radiance=np.float32([(5,) * 3, (5,) * 3]), radius=np.float32([0.1, 0.1]),
                    size=np.zeros((2, 2), np.float32), spot_cos=np.float32([(1.0, 0.0)] * 2),
                    sun_half_angle=np.zeros(2, np.float32))
    sampler = sampler_for(lights=lights)
    assert sampler.uses_tree and sampler.reads_facing
    p = at((-0.01, 0.3, 0.2), 2)
    toward_first = sampler.selection_pmf(np.arange(2), *p, facing=facing(2, (-1, 0, 0)))
    np.testing.assert_allclose(toward_first, [1.0, 0.0])
    np.testing.assert_allclose(sampler.selection_pmf(np.arange(2), *p, facing=facing(2, (1, 0, 0))), [0.0, 1.0])
    both = sampler.selection_pmf(np.arange(2), *p, facing=facing(2, (-1, 0, 0), True))
    assert (both > 0.2).all()
    assert isinstance(sampler.tree, CyclesLightTree if clamped else LightTree)
    np.testing.assert_allclose(both.sum(), 1.0, rtol=1e-6)
    np.testing.assert_allclose(sampler.selection_pmf(np.arange(2), *p, facing=facing(2, (0, 0, 0))),
                               sampler.selection_pmf(np.arange(2), *p))


def test_global_pmf_below_threshold_is_unchanged(monkeypatch):
    """Without a tree (too few emitters) choose_at is choose() with select_pmf, whatever the point."""
    sampler = mixed_sampler(monkeypatch)
    assert sampler.uses_tree
    monkeypatch.setattr(light_selection, "TREE_MIN_EMITTERS", 10 ** 9)
    sampler = mixed_sampler(monkeypatch)
    assert not sampler.uses_tree
    n = 300_000
    u = np.random.default_rng(4).random(n, dtype=np.float32)
    chosen, select = sampler.choose_at(u, *at((1, 2, 3), n))
    np.testing.assert_array_equal(chosen, sampler.choose(u))
    np.testing.assert_array_equal(select, sampler.pmf32[chosen])
    assert_chi2(np.bincount(chosen, minlength=len(sampler.select_pmf)), sampler.select_pmf * n)


def test_mis_pmf_equals_the_sampling_probability(monkeypatch):
    """selection_pmf(e, p), which the MIS pdfs use, is the probability choose_at reported for e at p;
    and end to end: a BSDF ray toward the point NEE sampled on an area light finds the same pdf."""
    sampler = mixed_sampler(monkeypatch)
    assert sampler.uses_tree
    n = 50_000
    rng = np.random.default_rng(5)
    p = rng.uniform(-5, 5, (3, n)).astype(np.float32)
    chosen, select = sampler.choose_at(rng.random(n, dtype=np.float32), *p)
    local = chosen < sampler.world_index
    np.testing.assert_allclose(sampler.selection_pmf(chosen[local], *(c[local] for c in p)), select[local],
                               rtol=1e-5)
    # Area lights on a grid (no two overlap), points below them.
    k = 36
    g = np.stack(np.meshgrid(np.arange(6), np.arange(6)), -1).reshape(-1, 2) * 1.5 - 3.75
    lights = Lights(kind=np.full(k, RECT, np.int32), position=np.float32(np.c_[g, np.full(k, 2.0)]),
                    frame=np.repeat(np.eye(3, dtype=np.float32)[None], k, axis=0),
                    radiance=np.float32(rng.uniform(1, 10, (k, 1)) * np.ones((1, 3))),
                    radius=np.zeros(k, np.float32), size=np.full((k, 2), 0.5, np.float32),
                    spot_cos=np.float32([(1.0, 0.0)] * k), sun_half_angle=np.zeros(k, np.float32))
    sampler = sampler_for(lights=lights)
    assert sampler.uses_tree
    px, py = rng.uniform(-4, 4, (2, n)).astype(np.float32)
    pz = rng.uniform(-1, 1.5, n).astype(np.float32)
    ls = sampler.sample(px, py, pz, *(rng.random(n, dtype=np.float32) for _ in range(3)))
    ok = np.flatnonzero(ls.pdf > 0)
    found = sampler.intersect(px[ok], py[ok], pz[ok], ls.wx[ok], ls.wy[ok], ls.wz[ok], ls.dist[ok] * 1.01)
    hit, pdf = found.hit, found.pdf
    assert hit.mean() > 0.99
    np.testing.assert_allclose(pdf[hit], ls.pdf[ok][hit], rtol=2e-3)


def _floor_scene(lights=None, emitters=None, size=16, eye=(0, -9, 7), target=(0, 0, 0)):
    floor, floor_n = quad((-6, -6, 0), (12, 0, 0), (0, 12, 0))
    positions, normals, mats = [floor], [floor_n], [np.zeros(2, np.int32)]
    if emitters is not None:
        positions.append(emitters)
        normals.append(np.zeros_like(emitters))
        mats.append(np.ones(len(emitters), np.int32))
    cam = Camera(world_from_camera=look_at(eye, target), width=size, height=size,
                 fov_rad=np.radians(60))
    return make_scene(np.concatenate(positions), np.concatenate(normals), material_ids=np.concatenate(mats),
                      albedo=[(0.7,) * 3, (0.5,) * 3], emission=[(0,) * 3, (20.0,) * 3], camera=cam,
                      lights=lights or Lights())


def _tree_against_global(scene, monkeypatch, samples):
    settings = RenderSettings(mode="NEE_MIS", max_bounces=2, seed=7)
    tree = trace_samples(scene, settings, samples)
    monkeypatch.setattr(light_selection, "TREE_MIN_EMITTERS", 10 ** 9)
    flat = trace_samples(scene, settings, samples)
    means = []
    for run in (tree, flat):
        per_sample = run.mean(axis=(1, 2))          # the image's mean, per sample
        means.append(mean_and_stderr(per_sample))
    (m_t, se_t), (m_f, se_f) = means
    assert abs(m_t - m_f) < 4 * np.hypot(se_t, se_f), (m_t, se_t, m_f, se_f)
    ratio = tree.var(axis=0).mean() / flat.var(axis=0).mean()  # per-sample variance, mean over pixels
    print(f"tree / global CDF per-sample variance: {ratio:.3f} (means {m_t:.5f} +- {se_t:.5f}, "
          f"{m_f:.5f} +- {se_f:.5f})")
    return ratio


def test_many_lamps_same_mean_lower_variance(monkeypatch):
    """~100 small point, spot and area lamps over a floor: the tree's image has the global CDF's mean
    and less variance per sample."""
    lamps = many_lights(k=100, seed=9, radius=(0.02, 0.05))
    lamps.position[:, 2] = np.abs(lamps.position[:, 2]) * 0.4 + 0.3
    lamps.frame[:] = np.eye(3, dtype=np.float32)       # area lights face down, toward the floor
    ratio = _tree_against_global(_floor_scene(lights=lamps), monkeypatch, 256)
    assert ratio < 0.8


def test_many_emissive_triangles_same_mean_lower_variance(monkeypatch):
    """400 small emissive triangles scattered under a ceiling (two-sided mesh lights); the camera, below
    them, sees only the floor (a pixel seeing an emitter has a variance no light selection changes)."""
    rng = np.random.default_rng(11)
    centre = np.c_[rng.uniform(-5, 5, (400, 2)), rng.uniform(1.8, 2.6, 400)]
    tris = (centre[:, None, :] + rng.normal(0, 0.08, (400, 3, 3))).astype(np.float32)
    scene = _floor_scene(emitters=tris, eye=(0, -1, 1.5), target=(0, 0.5, 0))
    ratio = _tree_against_global(scene, monkeypatch, 256)
    assert ratio < 0.8


def test_two_lamps_get_the_tree_same_mean_lower_variance(monkeypatch):
    """Two point lamps low over a floor, apart: each point chooses the lamp near it more often (as Cycles'
    tree does from two lights on), the power pmf's mean with a fraction of its variance per sample
    (measured 0.14x)."""
    lamps = Lights(kind=np.int32([0, 0]), position=np.float32([(-2, 0, 1.0), (2.5, 1, 1.2)]),
                   frame=np.repeat(np.eye(3, dtype=np.float32)[None], 2, axis=0),
                   radiance=np.float32([(50,) * 3] * 2), radius=np.float32([0.05, 0.05]),
                   size=np.zeros((2, 2), np.float32), spot_cos=np.float32([(1.0, 0.0)] * 2),
                   sun_half_angle=np.zeros(2, np.float32))
    scene = _floor_scene(lights=lamps, eye=(0, -7, 4), target=(0, 0, 0))
    with Renderer(scene, 1) as renderer:
        assert renderer.lights.selection == "tree"
    assert _tree_against_global(scene, monkeypatch, 128) < 0.5


def test_tree_only_where_it_pays():
    """The automatic choice: a compact mesh light cut into 72 triangles (the tree would choose as the
    power pmf does, at a cost) keeps the global CDF; a hundred lamps spread over a floor get the tree;
    fewer than TREE_MIN_EMITTERS emitters never do."""
    cornell = cornell_box(16, 16)
    keep = cornell.material_ids != 3
    lamp, lamp_n = subdivided_quad((-0.25, -0.25, 1.99), (0, 0.5, 0), (0.5, 0, 0), 6)
    compact = dataclasses.replace(
        cornell, positions=np.concatenate([cornell.positions[keep], lamp]),
        normals=np.concatenate([cornell.normals[keep], lamp_n]), uvs=np.zeros((keep.sum() + 72, 3, 2), np.float32),
        material_ids=np.concatenate([cornell.material_ids[keep], np.full(72, 3, np.int32)]))
    lamps = many_lights(k=100, seed=9, radius=(0.02, 0.05))
    few = many_lights(k=light_selection.TREE_MIN_EMITTERS - 1, seed=9, radius=(0.02, 0.05))
    chosen = {}
    for name, scene in (("compact", compact), ("lamps", _floor_scene(lights=lamps)),
                        ("few", _floor_scene(lights=few)), ("cornell", cornell)):
        with Renderer(scene, 1) as renderer:
            chosen[name] = (renderer.lights.uses_tree, renderer.lights.tree_divergence)
    print(chosen)
    assert [chosen[k][0] for k in ("compact", "lamps", "few", "cornell")] == [False, True, False, False]


# ---------------------------------------------------------------- a few emissive triangles: solid angles
def test_solid_angle_choice_matches_its_pmf_and_favours_the_near_triangle():
    """Among a quad lamp's two triangles and two more, choose_at follows selection_pmf (chi-square), the
    MIS pmf is the probability reported, and a point under one triangle chooses it far more often than
    the power pmf's even split would."""
    lamp, _ = quad((-0.5, -0.5, 2.0), (1.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    extra, _ = quad((2.0, -0.2, 1.5), (0.0, 0.4, 0.0), (0.0, 0.0, 0.4))
    sampler = sampler_for(positions=np.concatenate([lamp, extra]), emission=(3.0, 2.0, 1.0))
    assert sampler.selection == "solid angle" and not sampler.uses_tree
    k = sampler.world_index
    centroid = lamp[0].mean(axis=0)
    rng = np.random.default_rng(8)
    for p in [centroid - (0, 0, 0.05), (0.0, 0.0, 0.5), (1.5, 0.0, 1.4), (-3.0, 4.0, -2.0)]:
        pmf = sampler.selection_pmf(np.arange(k), *at(p, k)).astype(np.float64)
        assert abs(pmf.sum() - 1) < 1e-5, pmf
        n = 300_000
        chosen, select = sampler.choose_at(rng.random(n, dtype=np.float32), *at(p, n))
        np.testing.assert_allclose(select, pmf[chosen].astype(np.float32), rtol=1e-6)
        assert_chi2(np.bincount(chosen, minlength=k), pmf * n)
    near = sampler.selection_pmf(np.arange(k), *at(centroid - (0, 0, 0.05), k))
    assert near[0] > 0.8, near   # measured 0.95; the power pmf gives each of the lamp's halves 0.43
    # With a world too: the triangles share the local half of the choices, the world keeps its own.
    lit = sampler_for(positions=np.concatenate([lamp, extra]), emission=(3.0, 2.0, 1.0), world=sky())
    assert lit.selection == "solid angle"
    kw = lit.world_index + 1
    for p in [centroid - (0, 0, 0.05), (1.5, 0.0, 1.4)]:
        pmf = lit.selection_pmf(np.arange(kw), *at(p, kw)).astype(np.float64)
        pmf[-1] = lit.select_pmf[-1]
        assert abs(pmf.sum() - 1) < 1e-5 and abs(pmf[:-1].sum() - (1 - light_selection.DISTANT_SHARE)) < 1e-5, pmf
        n = 300_000
        chosen, select = lit.choose_at(rng.random(n, dtype=np.float32), *at(p, n))
        np.testing.assert_allclose(select, pmf[chosen].astype(np.float32), rtol=1e-6)
        assert_chi2(np.bincount(chosen, minlength=kw), pmf * n)
    # Only for two to SOLID_ANGLE_MAX_EMITTERS triangles and nothing else local (the others may get a tree).
    five = np.concatenate([lamp, extra, lamp[:1] + np.float32(3.0)])
    assert sampler_for(positions=five, emission=(1, 1, 1)).selection != "solid angle"
    assert sampler_for(lights=many_lights(k=1), positions=lamp, emission=(1, 1, 1)).selection != "solid angle"
    assert sampler_for(positions=lamp[:1], emission=(1, 1, 1)).selection == "power"


def test_quad_lamp_solid_angle_choice_same_mean_lower_variance(monkeypatch):
    """A quad lamp (two triangles) just above a floor, the camera under it looking down at the floor:
    choosing the lamp's half by solid angle keeps the power pmf's mean, with less variance."""
    lamp, _ = quad((-1.0, -1.0, 0.6), (2.0, 0.0, 0.0), (0.0, 2.0, 0.0))
    scene = _floor_scene(emitters=lamp, eye=(0, -0.2, 0.5), target=(0, 0.3, 0))
    settings = RenderSettings(mode="NEE_MIS", max_bounces=1, seed=7)
    chosen = trace_samples(scene, settings, 256)
    monkeypatch.setattr(light_selection, "SOLID_ANGLE_MAX_EMITTERS", 0)
    flat = trace_samples(scene, settings, 256)
    (m_c, se_c), (m_f, se_f) = (mean_and_stderr(run.mean(axis=(1, 2))) for run in (chosen, flat))
    assert abs(m_c - m_f) < 4 * np.hypot(se_c, se_f), (m_c, se_c, m_f, se_f)
    ratio = chosen.var(axis=0).mean() / flat.var(axis=0).mean()
    print(f"solid-angle choice / power pmf per-sample variance: {ratio:.3f}")
    assert ratio < 0.8


def _lamp_set(seed):
    """Area lamps of 1 x 1 (facing +z, and some turned), a delta spot and a point lamp among them: the
    tree's nodes mix emitters whose cones point different ways."""
    rng = np.random.default_rng(seed)
    k = 12
    frames = np.tile(np.eye(3, dtype=np.float32), (k, 1, 1))
    frames[:, :, 2] *= -1          # the frame's z is the lamp's back: these face +z
    frames[:, :, 0] *= -1          # (a right-handed frame)
    turned = rng.random(k) < 0.4
    frames[turned] = np.stack([np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(int(turned.sum()))])
    kind = np.full(k, RECT, np.int32)
    kind[0], kind[1] = 1, 0         # a delta spot (pointing down its -z) and a point lamp
    frames[0] = np.diag(np.float32([1, 1, 1]))   # the spot shines down -z
    position = np.float32(np.stack([rng.integers(-2, 3, k) * 1.5, rng.integers(-2, 3, k) * 1.5,
                                    rng.uniform(-0.2, 0.2, k)], axis=1))
    position[0] = (0.3, 0.2, 2.0)
    return Lights(kind=kind, position=position, frame=np.float32(frames),
                  radiance=np.float32(rng.uniform(0.5, 5.0, (k, 3))), radius=np.zeros(k, np.float32),
                  size=np.ones((k, 2), np.float32), spot_cos=np.float32([(np.cos(0.5), 0.05)] * k),
                  sun_half_angle=np.zeros(k, np.float32))


def _can_light(lights, e, p):
    """Whether lamp e sends any light to point p: an area lamp to the side in front of it, a spot inside its
    cone, a point lamp everywhere."""
    c, z = lights.position[e].astype(np.float64), lights.frame[e, :, 2].astype(np.float64)
    d = np.asarray(p, np.float64) - c
    if lights.kind[e] == 0:
        return True
    if lights.kind[e] == 1:
        return -np.dot(d, z) / np.linalg.norm(d) > lights.spot_cos[e, 0]
    return -np.dot(d, z) > 1e-4


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_every_emitter_that_lights_a_point_can_be_chosen(seed, monkeypatch):
    """The tree may prefer emitters but never starves one that lights the point: at points one unit and a
    hair in front of each lamp, beside it, between lamps (inside the nodes' boxes) and scattered around,
    every lamp that can light the point has a non-zero selection probability, and the delta spot is chosen
    there (a delta light is found by no BSDF ray: only its light samples light the point)."""
    monkeypatch.setattr(light_selection, "TREE_MIN_DIVERGENCE", 0.0)
    lights = _lamp_set(seed)
    sampler = sampler_for(lights=lights)
    assert sampler.uses_tree
    k = lights.count
    rng = np.random.default_rng(seed + 10)
    normals = -lights.frame[:, :, 2].astype(np.float64)
    points = [lights.position + normals * d + side for d in (1.0, 1e-2)
              for side in ((0, 0, 0), (0.45, 0, 0), (0, -0.45, 0))]
    points.append(0.5 * (lights.position + np.roll(lights.position, 1, axis=0)) + (0, 0, 0.3))
    points.append(rng.uniform(-4, 4, (64, 3)))
    points = np.concatenate(points).astype(np.float32)
    pmf = np.stack([sampler.selection_pmf(np.arange(k), *at(p, k)) for p in points])
    lit = np.array([[_can_light(lights, e, p) for e in range(k)] for p in points])
    starved = lit & ~(pmf > 0)
    assert not starved.any(), [(points[i], e) for i, e in zip(*np.nonzero(starved))][:5]
    under_spot = np.float32([0.3, 0.2, 0.8])
    assert _can_light(lights, 0, under_spot)
    n = 4000
    chosen, _ = sampler.choose_at(rng.random(n, dtype=np.float32), *at(under_spot, n))
    assert np.count_nonzero(chosen == 0) > 0


# ---------------------------------------------------------------- a lamp beside an emissive mesh
def test_a_lamp_beside_an_emissive_mesh_keeps_its_share():
    """A 2 W point lamp 0.2 m off a sphere of 9024 glowing triangles (one object): at points on the sphere
    near the lamp the tree chooses the lamp often (the mesh competes as one emitter beside it, and the
    cluster the point stands in is weighed by a lower bound too), and choose_at follows selection_pmf there
    (chi-square).
    The lamp's light dominates there: a tree that let the triangles outbid it level after level gave it a
    quarter of the choices here, 0.2% beside the emissive glass shade of a real lamp, and its rare samples
    were fireflies."""
    lamp = Lights(kind=np.int32([0]), position=np.float32([(-0.45, -0.45, 0.3)]),
                  frame=np.eye(3, dtype=np.float32)[None], radiance=np.float32([(2 / (4 * np.pi),) * 3]),
                  radius=np.zeros(1, np.float32), size=np.zeros((1, 2), np.float32),
                  spot_cos=np.float32([(1.0, 0.0)]), sun_half_angle=np.zeros(1, np.float32))
    ball, _ = uv_sphere(48, radius=0.6)
    sampler = sampler_for(lights=lamp, positions=ball, emission=(0.15, 0.25, 0.5))
    assert sampler.uses_tree
    k = sampler.world_index
    rng = np.random.default_rng(12)
    direction = np.float32([-1, -1, 0.5]) / np.linalg.norm([-1, -1, 0.5])
    for p in [0.6 * direction, 0.6 * np.float32([-0.7, -0.7, 0.0]), 0.6 * np.float32([-1, 0, 0])]:
        pmf = sampler.selection_pmf(np.arange(k), *at(p, k)).astype(np.float64)
        assert abs(pmf.sum() - 1) < 1e-5, pmf.sum()
        assert pmf[0] > 0.5, pmf[0]   # measured 0.62-0.94; 0.23-0.26 before
        n = 200_000
        chosen, select = sampler.choose_at(rng.random(n, dtype=np.float32), *at(p, n))
        np.testing.assert_allclose(select, pmf[chosen].astype(np.float32), rtol=1e-6)
        assert_chi2(np.bincount(chosen, minlength=k), pmf * n)


def test_groups_stay_together_in_the_tree():
    """Each group's emitters fill a subtree of their own (no lone emitter or other group's emitter under
    the node where the group comes together), and the lone emitters stand beside the groups."""
    rng = np.random.default_rng(13)
    n = 300
    group = np.where(rng.random(n) < 0.1, -1, rng.integers(0, 6, n))
    lo = rng.uniform(-5, 5, (n, 3))
    tree = LightTree(lo, lo + 0.1, rng.uniform(0.5, 2, n), np.tile([0.0, 0.0, 1.0], (n, 1)), np.full(n, np.pi),
                     group)
    assert tree.units == (group < 0).sum() + len(np.unique(group[group >= 0]))
    for g in np.unique(group[group >= 0]):
        members = np.flatnonzero(group == g)
        ancestors = [set(_ancestors(tree, tree.leaf_of[e])) for e in members]
        common = set.intersection(*ancestors)
        lowest = max(common, key=lambda node: len(_ancestors(tree, node)))
        under = _leaves_under(tree, lowest)
        assert sorted(under) == sorted(members), g
    np.testing.assert_allclose(tree.pmf_all(*at((0.3, -0.2, 0.1), 1)).sum(), 1.0, rtol=1e-9)


def _ancestors(tree, node):
    out = [node]
    while tree.parent[out[-1]] >= 0:
        out.append(int(tree.parent[out[-1]]))
    return out


def _leaves_under(tree, node):
    if tree.left[node] < 0:
        return [int(tree.emitter_at[node])]
    return _leaves_under(tree, tree.left[node]) + _leaves_under(tree, tree.right[node])


def test_clamped_renders_share_light_samples_as_cycles_tree():
    """Under clamping the light tree is Cycles' (kernels.light_tree_cycles), in closed form for two point lamps of radii
    r (Soft Falloff: not spheres): Cycles weighs a lamp by the mean of R, G and B of its strength over 4 pi (here the
    radiance Ember keeps times pi r^2), bounds it above by E / d^2 and below by E d / (d^2 + r^2)^1.5 (at its rim's
    distance, times the cosine of the half angle its radius subtends), and chooses by the mean of the two shares
    (whether the two stand in one leaf or each in its own: light_tree_child_importance bounds a lone lamp as itself).
    Ember's own tree (unclamped) chooses otherwise."""
    centres, radii = np.float32([(-1, 0, 1), (2, 0, 1)]), np.float32([0.6, 0.2])
    radiance = np.float32([(4, 4, 4), (1, 2, 6)])

    def lamps(clamped):
        return Lights(kind=np.zeros(2, np.int32), position=centres,
                      frame=np.repeat(np.eye(3, dtype=np.float32)[None], 2, axis=0), radiance=radiance,
                      radius=radii, size=np.zeros((2, 2), np.float32), spot_cos=np.float32([(1.0, 0.0)] * 2),
                      sun_half_angle=np.zeros(2, np.float32), clamped=clamped)
    p = np.array([0.5, 0.0, 0.0])
    energy = radiance.mean(axis=1) * np.pi * radii.astype(np.float64) ** 2
    d2 = ((centres - p) ** 2).sum(axis=1)
    upper = energy / d2
    lower = energy * np.sqrt(d2) / (d2 + radii ** 2) ** 1.5
    expected = 0.5 * (upper / upper.sum() + lower / lower.sum())
    cycles = sampler_for(lights=lamps(True))
    assert isinstance(cycles.tree, CyclesLightTree)
    np.testing.assert_allclose(cycles.selection_pmf(np.arange(2), *at(p, 2)), expected, rtol=1e-5)
    ember = sampler_for(lights=lamps(False))
    assert np.abs(ember.selection_pmf(np.arange(2), *at(p, 2)) - expected).max() > 0.01


def test_cycles_tree_splits_as_cycles_builds():
    """Cycles' build (scene/light_tree.cpp should_split): up to 8 co-located lamps stay one leaf (no split can cost
    less), 9 are halved; lamps far apart along x split there, each side a leaf of its own."""
    from ember.kernels.light_tree_cycles import POINT, Units, build

    def units(centres):
        n = len(centres)
        c = np.float64(centres)
        return Units(np.full(n, POINT), np.ones(n), c - 0.1, c + 0.1, c, np.tile([0, 0, 1.0], (n, 1)),
                     np.full(n, np.pi), np.full(n, np.pi / 2), radius=np.full(n, 0.1))
    nodes, _ = build(units([(0, 0, 0)] * 8))
    assert len(nodes["left"]) == 1 and nodes["count"][0] == 8
    nodes, _ = build(units([(0, 0, 0)] * 9))
    assert nodes["left"][0] >= 0 and sorted(nodes["count"][1:3]) == [4, 5]
    nodes, order = build(units([(0, 0, 0), (0.1, 0, 0), (10, 0, 0), (10.1, 0, 0)]))
    leaves = np.flatnonzero(nodes["left"] < 0)
    groups = sorted(sorted(order[nodes["first"][i]:nodes["first"][i] + nodes["count"][i]].tolist()) for i in leaves)
    assert all(g in ([0, 1], [2, 3], [0], [1], [2], [3]) for g in groups), groups
    assert nodes["left"][0] >= 0
    left, right = nodes["left"][0], nodes["right"][0]
    sides = [sorted(order[nodes["first"][i]:nodes["first"][i] + nodes["count"][i]].tolist()) for i in (left, right)]
    assert sorted(sides) == [[0, 1], [2, 3]]


def test_cycles_importance_fast_paths_match_the_general_formula():
    """light_tree_cycles._importance's passes for cones that emit every way and for point lamps' cones (facing the
    point) give Cycles' general formula's bounds, with and without a normal (the point's: to rounding, where the
    general formula's cos theta of an axis built from the direction falls a hair short of 1; Cycles sets it to 1
    there, as the fast pass does)."""
    from ember.kernels.light_tree_cycles import _importance
    rng = np.random.default_rng(0)
    n = 20_000
    p2c = rng.normal(size=(3, n))
    p2c /= np.linalg.norm(p2c, axis=0)
    normal = rng.normal(size=(3, n))
    normal /= np.linalg.norm(normal, axis=0)
    cos_u, near = rng.uniform(-1, 1, n), rng.uniform(0.1, 3, n)
    far, energy = near * rng.uniform(1, 2, n), rng.uniform(0.1, 5, n)
    for fac in (None, (*normal, rng.random(n) < 0.3)):
        general = _importance(p2c, cos_u, rng.normal(size=(3, n)), np.full(n, np.pi), np.full(n, np.pi / 2), far, near,
                              energy, fac)
        for a, b in zip(general, _importance(p2c, cos_u, None, np.full(n, np.pi), None, far, near, energy, fac, "omni")):
            np.testing.assert_array_equal(a, b)
        general = _importance(p2c, cos_u, -p2c, np.zeros(n), np.full(n, np.pi / 2), far, near, energy, fac)
        for a, b in zip(general, _importance(p2c, cos_u, None, None, None, far, near, energy, fac, "point")):
            np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6 * a.max())
        assert (general[1] > 0).any() and (general[0] > general[1]).any()


def test_a_render_chooses_lights_by_its_own_clamping():
    """Renderer.render takes the tree its settings' clamping asks for (Lights.clamped), whatever the scene was built
    with: Cycles' for a clamped render, Ember's for an unclamped one, switching between renders."""
    scene = _floor_scene(lights=many_lights(k=12, radius=(0.05, 0.2)), size=8)
    with Renderer(scene, 1) as renderer:
        assert isinstance(renderer.lights.tree, LightTree)
        renderer.render(RenderSettings(samples=1, max_bounces=1, clamp_indirect=10.0))
        assert isinstance(renderer.lights.tree, CyclesLightTree) and renderer.scene.lights.clamped
        renderer.render(RenderSettings(samples=1, max_bounces=1))
        assert isinstance(renderer.lights.tree, LightTree) and not renderer.scene.lights.clamped


def test_clamped_renders_weigh_an_emissive_object_by_its_materials_estimate_dark_triangles_included():
    """Cycles measures an emissive object by its triangles' area times its material's estimate (a texture counts as
    white), all of them: an object of 8 triangles whose texture leaves 6 dark weighs 8 triangles' worth beside a lamp,
    while light samples still go to its 2 bright triangles only (the dark ones are left to BSDF rays)."""
    import dataclasses
    from ember.kernels.environment import Environment
    from ember.kernels.lights import LightSampler
    from ember.kernels.shapes import subdivided_quad
    tri, normals = subdivided_quad((-1, -1, 2), (2, 0, 0), (0, 2, 0), 2)
    lamp = Lights(kind=np.zeros(1, np.int32), position=np.float32([(3, 0, 1)]),
                  frame=np.eye(3, dtype=np.float32)[None], radiance=np.float32([(5, 5, 5)]),
                  radius=np.float32([0.1]), size=np.zeros((1, 2), np.float32), spot_cos=np.float32([(1.0, 0.0)]),
                  sun_half_angle=np.zeros(1, np.float32), clamped=True)
    scene = make_scene(tri, normals, material_ids=np.ones(len(tri), np.int32), albedo=[(0.5,) * 3] * 2,
                       emission=[(0,) * 3, (2.0,) * 3], lights=lamp)
    shaders = list(scene.materials.shaders)
    shaders[1] = dataclasses.replace(shaders[1], emission_estimate=(2.0, 2.0, 2.0))
    scene = dataclasses.replace(scene, materials=dataclasses.replace(scene.materials, shaders=tuple(shaders)))
    bright = np.arange(len(tri)) < 2

    class Emitters:
        emissive = np.array([False, True])
        varies = np.array([False, True])

        def __call__(self, t, b1=None, b2=None, toward=None, dist=None):
            return np.where(bright[t], np.float32(2.0), np.float32(0.0))[None, :].repeat(3, axis=0)
    sampler = LightSampler(scene, Environment(scene.world), Emitters())
    assert len(tri) == 8 and sorted(sampler.tri_ids.tolist()) == [0, 1]
    keys, energy, lo, hi = sampler.object_totals
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum()
    np.testing.assert_allclose(energy, [2.0 * area], rtol=1e-6)
    np.testing.assert_allclose(lo[0], tri.reshape(-1, 3).min(axis=0), atol=1e-6)
    tree = sampler.tree
    assert isinstance(tree, CyclesLightTree)
    np.testing.assert_allclose(tree.u.energy[tree.u.kind == 3], [2.0 * area], rtol=1e-5)
