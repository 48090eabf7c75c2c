"""Subsurface scattering (kernels/subsurface.py, kernels/bsdf/bssrdf.py): the random walk's distance sampling and
energy in a homogeneous slab against closed forms, the white furnace through Blender, parity with Cycles for every
method (Christensen-Burley's kernel tests: test_subsurface_disk.py)."""
from __future__ import annotations

import math

import bpy
import numpy as np
import pytest

from ember.kernels import subsurface
from ember.kernels import subsurface_medium as medium
from ember.kernels.accel import Hits
from ember.kernels.bsdf import bssrdf

import bpy_helpers as H


class _Slab:
    """An accel stand-in: the slab -depth < z < 0, its top face prim 0 and its bottom face prim 1."""

    def __init__(self, depth):
        self.depth = depth

    def intersect(self, origins, dirs, t_max, split=True, time=None):
        oz, dz = origins[:, 2].astype(np.float64), dirs[:, 2].astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(dz > 0, -oz / dz, np.where(dz < 0, (-self.depth - oz) / dz, np.inf))
        prim = np.where(dz > 0, 0, 1).astype(np.int32)
        miss = ~(t <= t_max) | ~(t >= 0)
        prim[miss] = -1
        t = np.where(miss, np.inf, t).astype(np.float32)
        z = np.zeros(len(t), np.float32)
        return Hits(prim, t, z, z.copy())


def _walks(n, depth, albedo, radius, g=0.0, seed=1):
    rng = np.random.default_rng(seed)
    keys = (rng.integers(0, 2 ** 32, n, dtype=np.uint32), rng.integers(0, 2 ** 32, n, dtype=np.uint32))
    up = np.zeros((3, n))
    up[2] = 1.0
    color = np.full((3, n), albedo, np.float32)
    return subsurface.walk(_Slab(depth), None, np.zeros((3, n)), -up.astype(np.float32), up.astype(np.float32), up,
                           None, color, np.full((3, n), radius, np.float32), np.full(n, g), np.ones(n, bool), color,
                           keys)


def test_first_flight_crosses_a_slab_with_the_probability_of_its_optical_depth():
    """Walks entering a slab of optical depth tau along its normal: the first flight crosses it (leaves at the
    bottom along the entry direction, weight 1 for a grey medium) with probability exp(-tau)."""
    n, radius = 40000, 0.5
    for tau in (0.5, 1.5):
        rows, prim, u, v, t, direction, thr = _walks(n, tau * radius, 0.8, radius)
        first = (prim == 1) & (direction[2] == -1.0)
        estimate = thr[0, first].sum() / n
        expected = math.exp(-tau)
        sigma = math.sqrt(expected * (1 - expected) / n)
        assert abs(estimate - expected) < 4 * sigma, (tau, estimate, expected)
        assert np.allclose(thr[:, first], 1.0, atol=1e-5)


@pytest.mark.parametrize("g", [0.0, 0.6])
def test_white_slab_loses_no_energy(g):
    """Albedo 1 (single-scattering albedo 0.999999): every walk comes out of a slab of optical depth 2, top or
    bottom, and the weights of the exits average 1 (the estimator's MIS over guided, classic and channels)."""
    n = 8000
    rows, prim, u, v, t, direction, thr = _walks(n, 1.0, 1.0, 0.5, g=g)
    total = thr.sum(axis=1) / n
    err = thr.std(axis=1) / math.sqrt(n) + 1e-3
    assert np.all(np.abs(total - 1.0) < 4 * err + 0.005), (total, err)
    assert len(rows) > 0.99 * n


def _mixed_walks(n, seed):
    """Walks into a slab of depth 1 whose parameters vary per walk: albedo per channel (0 and 1 among them), radius
    (a few flights to the far side or many), anisotropy of either sign, both models, entry directions and
    throughputs."""
    rng = np.random.default_rng(seed)
    keys = (rng.integers(0, 2 ** 32, n, dtype=np.uint32), rng.integers(0, 2 ** 32, n, dtype=np.uint32))
    albedo = rng.uniform(0.0, 1.0, (3, n))
    albedo[:, ::7] = 1.0
    albedo[1, 3::11] = 0.0
    radius = rng.uniform(0.02, 0.4, (3, n))
    g = np.where(rng.random(n) < 0.3, 0.0, rng.uniform(-0.9, 0.9, n))
    van = rng.random(n) < 0.7
    d0 = np.stack([rng.uniform(-0.5, 0.5, n), rng.uniform(-0.5, 0.5, n), -np.ones(n)])
    d0 /= np.linalg.norm(d0, axis=0)
    up = np.zeros((3, n))
    up[2] = 1.0
    thr = rng.uniform(0.2, 2.0, (3, n))
    return (_Slab(1.0), None, np.zeros((3, n)), d0.astype(np.float32), up.astype(np.float32), up, None,
            albedo.astype(np.float32), radius.astype(np.float32), g, van, thr.astype(np.float32), keys)


def _libm_like_numpy():
    """Whether NumPy's float64 exp is the C library's here (it is but with AVX-512, where NumPy has its own): the
    walks' Python tail then gives the NumPy steps' numbers bit for bit."""
    x = np.random.default_rng(0).uniform(-40.0, 5.0, 4000)
    return np.array_equal(np.exp(x), [math.exp(t) for t in x])


def _assert_same_exits(a, b, exact, label):
    assert all(x.dtype == y.dtype and x.shape == y.shape for x, y in zip(a, b)), label
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1]), label
    for x, y in zip(a[2:], b[2:]):
        if exact:
            assert np.array_equal(x, y, equal_nan=True), label
        else:
            np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-7, err_msg=label)


def test_python_tail_walks_as_the_numpy_steps_do(monkeypatch):
    """kernels/subsurface_tail.py steps the last few walks in Python floats, TAIL_CHUNK steps ahead with one query,
    keeping each walk's steps up to its first flight that met the surface: the exits, their order, lengths,
    directions and throughputs are those of stepping every walk in NumPy to the end, whatever the chunk (3: the
    last chunk before MAX_BOUNCES is shorter) and where the hand-over falls."""
    from ember.kernels import subsurface_tail
    args = _mixed_walks(300, 5)
    monkeypatch.setattr(subsurface, "TAIL_WALKS", 0)
    batch = subsurface.walk(*args)
    assert len(batch[0]) > 200 and len(np.unique(batch[0])) == len(batch[0])
    exact = _libm_like_numpy()
    for tail_walks, chunk in ((10 ** 9, 16), (10 ** 9, 3), (40, 16)):
        monkeypatch.setattr(subsurface, "TAIL_WALKS", tail_walks)
        monkeypatch.setattr(subsurface_tail, "TAIL_CHUNK", chunk)
        _assert_same_exits(batch, subsurface.walk(*args), exact, (tail_walks, chunk))


def test_python_tail_takes_numpys_infinities_where_python_raises(monkeypatch):
    """Where a walk's step divides by zero (here a channel of sigma_t 0 with throughput left in it, which a walk from
    the entry never reaches) Python raises where NumPy gives inf: the tail steps that walk with NumPy's scalars, and
    its exits are the NumPy steps' still."""
    from ember.kernels import subsurface_tail
    (accel, _, p0, d0, n0, _, _, albedo, radius, g, van, thr, keys) = _mixed_walks(60, 8)
    table = medium.WalkTable(p0, d0, n0.astype(np.float64), albedo, radius, g, van, thr)
    c, s = table.constants, table.state
    rng = np.random.default_rng(9)
    s[medium.POSITION][2] = rng.uniform(-0.9, -0.1, 60)
    c[medium.HAVE_OPPOSITE], c[medium.OPPOSITE] = rng.random(60) < 0.5, 1.0
    for rows in (medium.SIGMA_T, medium.SIGMA_S, medium.SIGMA_T_STAR, medium.SIGMA_S_STAR):
        c[rows][2, ::3] = 0.0
    s[medium.THROUGHPUT][2, ::3] = 5.0

    def trace(origin, d, t_max, rows):
        return medium.local_hits(accel, None, origin, d, t_max, None, None, rows)

    numpy_scalars = []
    ahead = subsurface_tail._ahead

    def spy(*args):
        numpy_scalars.append(args[-2] is np.exp)
        return ahead(*args)
    monkeypatch.setattr(subsurface_tail, "_ahead", spy)
    found = []
    for tail_walks in (0, 10 ** 9):
        monkeypatch.setattr(subsurface, "TAIL_WALKS", tail_walks)
        exits = medium.Exits()
        with np.errstate(all="ignore"):
            subsurface._steps(c.copy(), s.copy(), np.arange(60), keys, 1, trace, exits)
        found.append(exits.gather())
    assert any(numpy_scalars) and not all(numpy_scalars)
    assert len(found[0][0]) > 40
    _assert_same_exits(found[0], found[1], _libm_like_numpy(), "inf")


class _Paths:
    """A PathState stand-in for WalkPool: the walks' numbers in the test's batch."""

    def __init__(self, ids, throughput=None):
        self.ids, self.time, self.throughput = ids, None, throughput

    def rows(self, idx):
        return _Paths(self.ids[idx], None if self.throughput is None else self.throughput[:, idx])

    @staticmethod
    def concat(a, b):
        return _Paths(np.concatenate([a.ids, b.ids]), None if a.throughput is None else
                      np.concatenate([a.throughput, b.throughput], axis=1))


def test_parked_walks_leave_where_walks_taken_to_the_end_do(monkeypatch):
    """WalkPool: walks added in three batches between rounds that step them while more than PARK_WALKS go on and
    park the rest (so walks at different steps, some past the similarity level and some not, step together), then
    drained: each walk leaves where, when and with the throughput it does when walked to its end at once."""
    args = _mixed_walks(300, 5)
    whole = subsurface.walk(*args)
    monkeypatch.setattr(subsurface.WalkPool, "PARK_WALKS", 40)
    mixed = []
    step = subsurface._step

    def spy(c, s, live, numbers, bounce, trace, exits):
        mixed.append(bounce.min() <= medium.SIMILARITY_LEVEL < bounce.max())
        return step(c, s, live, numbers, bounce, trace, exits)
    monkeypatch.setattr(subsurface, "_step", spy)
    accel, object_rows = args[0], args[1]
    pool = subsurface.WalkPool(accel, object_rows)
    found = []
    for part in np.array_split(np.arange(300), 3):
        sub = [None if a is None else a[..., part] for a in args[2:12]] + [(args[12][0][part], args[12][1][part])]
        pool.add(_Paths(part), None, *subsurface.walk(accel, object_rows, *sub, park=True))
        found.append(pool.advance(drain=False))
        assert 0 < len(pool)
    found.append(pool.advance(drain=True))
    assert len(pool) == 0 and any(mixed) and not all(mixed)
    found = [f for f in found if f is not None]
    ids = np.concatenate([f[0].ids for f in found])
    order = np.argsort(ids)
    pooled = (ids[order], np.concatenate([f[1] for f in found])[order]) + tuple(
        np.concatenate([f[i] for f in found], axis=-1)[..., order] for i in (2, 3, 4, 5)) + (
        np.concatenate([f[0].throughput for f in found], axis=1)[:, order],)
    assert len(whole[0]) > 200
    back = np.argsort(whole[0])
    _assert_same_exits(tuple(x[..., back] for x in whole), pooled, _libm_like_numpy(), "pooled")


def test_step_numbers_are_each_steps_own_draws():
    """step_numbers draws a chunk of steps at once: each row is the keyed draw of that step alone (rng.keyed_uniforms
    with the walk's salt), and the directions' local frames follow from them as each step would compute them."""
    from ember.kernels import subsurface_medium as medium
    from ember.kernels.rng import keyed_uniforms
    rng = np.random.default_rng(2)
    n = 50
    keys = (rng.integers(0, 2 ** 32, n, dtype=np.uint32), rng.integers(0, 2 ** 32, n, dtype=np.uint32))
    g, dl = rng.uniform(-0.9, 0.9, n), rng.uniform(1.01, 30.0, n)
    phase_log = np.log((dl + 1.0) / (dl - 1.0))
    numbers = medium.step_numbers(keys, 7, 5, g, dl, phase_log)
    for j, step in enumerate(range(7, 12)):
        u_ch, u_t = keyed_uniforms(keys, 3 * step, medium.SALT)
        u_gs, u_gd = keyed_uniforms(keys, 3 * step + 1, medium.SALT)
        r1, r2 = (x.astype(np.float64) for x in keyed_uniforms(keys, 3 * step + 2, medium.SALT))
        row = numbers[j]
        assert np.array_equal(row[medium.U_CHANNEL], u_ch) and np.array_equal(row[medium.U_GUIDED], u_gs)
        assert np.array_equal(row[medium.U_BACKWARD], u_gd)
        assert np.array_equal(row[medium.FLIGHT], -np.log(1.0 - u_t.astype(np.float64)))
        cos_g = row[medium.GUIDED_COS]
        np.testing.assert_allclose(cos_g, dl - (dl + 1) * ((dl - 1) / (dl + 1)) ** r1, rtol=1e-9, atol=1e-12)
        sin_g = np.sqrt(1 - cos_g ** 2)
        np.testing.assert_allclose(row[medium.GUIDED_X], sin_g * np.cos(2 * np.pi * r2), atol=1e-12)
        gl = g if step <= medium.SIMILARITY_LEVEL else 0.0
        cos_c = row[medium.CLASSIC_COS]
        # Henyey-Greenstein's inverse cdf, isotropic past the similarity level.
        expected = np.where(np.abs(gl) >= 1e-3, (1 + gl * gl - ((1 - gl * gl) / (1 - gl + 2 * gl * r1)) ** 2) /
                            (2 * np.where(gl != 0, gl, 1.0)), 1 - 2 * r1)
        np.testing.assert_allclose(cos_c, expected, atol=1e-9)
        np.testing.assert_allclose(row[medium.CLASSIC_Y], np.sqrt(1 - cos_c ** 2) * np.sin(2 * np.pi * r2), atol=1e-12)


def test_coefficients_invert_the_albedo():
    """van de Hulst's inversion: albedo 1 is (almost) no absorption, albedo 0 all absorption; sigma_t is
    1 / radius; the legacy fit (Skin) gives sigma_t / (1 - g)."""
    sigma_t, alpha = medium.coefficients(np.array([[1.0], [0.5], [0.0]]), np.full((3, 1), 0.25),
                                         np.array([0.0]), np.array([True]))
    assert np.allclose(sigma_t, 4.0) and alpha[0, 0] > 0.9999 and alpha[2, 0] < 1e-3 and 0 < alpha[1, 0] < 1
    sigma_t, _ = medium.coefficients(np.full((3, 1), 0.5), np.full((3, 1), 0.25), np.array([0.5]),
                                     np.array([False]))
    assert np.allclose(sigma_t, 8.0)


# ---------------------------------------------------------------- through Blender
def _sss_scene(method, node=False, furnace=False):
    scene = H.new_scene(48, 48)
    white = (1.0, 1.0, 1.0, 1.0)
    if node:
        mat = H.node_material("sss", "ShaderNodeSubsurfaceScattering", Color=white if furnace else (0.9, 0.6, 0.5, 1),
                              Scale=0.2, Radius=(1.0, 0.4, 0.2), IOR=1.4, Roughness=1.0, Anisotropy=0.0)
        mat.node_tree.nodes["Subsurface Scattering"].falloff = method
    else:
        mat = H.node_material("sss", "ShaderNodeBsdfPrincipled", **{
            "Base Color": white if furnace else (0.8, 0.5, 0.4, 1), "Subsurface Weight": 1.0,
            "Subsurface Scale": 0.2, "Subsurface Radius": (1.0, 0.4, 0.2),
            "Subsurface Anisotropy": 0.0, "Roughness": 0.5})
        mat.node_tree.nodes["Principled BSDF"].subsurface_method = method
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=(0, 0, 0), segments=32, ring_count=16)
    obj = bpy.context.active_object
    obj.data.materials.append(mat)
    obj.data.shade_smooth()
    if furnace:
        H.set_world(scene, color=(1.0, 1.0, 1.0))
    else:   # backlit: an area light behind the sphere, a dim world
        H.set_world(scene, color=(0.05, 0.05, 0.05))
        light = bpy.data.lights.new("back", "AREA")
        light.energy, light.size = 300.0, 1.0
        lamp = bpy.data.objects.new("back", light)
        scene.collection.objects.link(lamp)
        lamp.location, lamp.rotation_euler = (0.0, 2.5, 0.3), (-1.57, 0.0, 0.0)
    H.add_camera(scene, (0, -3, 0), (0, 0, 0), lens=50)
    return scene


@pytest.mark.parametrize("node", [False, True])
def test_white_subsurface_sphere_in_a_white_world_is_the_world(node):
    """A furnace: albedo 1, no absorption, the sphere vanishes into the world (within noise, fixed seed). Up to
    Blender 5.1 Cycles' Random Walk is the legacy model (radius / (4 pi), short walks that the 256-step bound
    cuts): there the furnace must lose what Cycles' loses."""
    scene = _sss_scene("RANDOM_WALK", node=node, furnace=True)
    if bpy.app.version < (5, 2, 0):
        H.compare_to_cycles(scene, samples=32)
        return
    img = H.render_to_array(scene, "EMBER", 32, seed=3)[..., :3]
    sphere = img[14:34, 14:34]
    assert abs(sphere.mean() - 1.0) < 0.02, sphere.mean(axis=(0, 1))
    assert np.all(np.abs(sphere.mean(axis=(0, 1)) - 1.0) < 0.04), sphere.mean(axis=(0, 1))


def test_white_skin_sphere_loses_what_cycles_loses():
    """Random Walk (Skin) at albedo 1 shrinks the radius by sqrt(3 (1 - 0.999999)) (bssrdf_setup_radius), and
    walks of at most 256 steps that long do not all come out: Cycles' furnace reads about 0.93, and so must ours."""
    H.compare_to_cycles(_sss_scene("RANDOM_WALK_SKIN", furnace=True), samples=32)


@pytest.mark.parametrize("node", [False, True])
def test_white_burley_sphere_in_a_white_world_is_the_world(node):
    """Christensen-Burley's furnace: the profile is normalised and the disk estimator gives exactly 1 on a plane
    (tests/test_subsurface_disk.py); on this sphere (16 d, the profile's support, is half its radius for red) the
    probes' chords and the MIS over the axes leave Cycles' reading a little above 1 (1.006, 1.001, 0.999 by
    channel over 8 seeds of 32 samples, standard errors 0.001). Ours matches Cycles' image within noise, and its
    sphere is 1 within 1% per channel."""
    scene = _sss_scene("BURLEY", node=node, furnace=True)
    H.compare_to_cycles(scene, samples=32)
    sphere = H.render_to_array(scene, "EMBER", 32, seed=3)[14:34, 14:34, :3].mean(axis=(0, 1))
    assert np.all(np.abs(sphere - 1.0) < 0.01), sphere


@pytest.mark.parametrize("method,node", [("RANDOM_WALK", False), ("RANDOM_WALK_SKIN", False), ("RANDOM_WALK", True),
                                         ("BURLEY", False), ("BURLEY", True)])
def test_backlit_subsurface_sphere_matches_cycles(method, node):
    """The glow of a backlit subsurface sphere (Principled Random Walk, Skin and Christensen-Burley, the Subsurface
    Scattering node). Burley's image is far from the random walk's (mean 0.047 against 0.079 here): the fallback
    it had before would fail."""
    H.compare_to_cycles(_sss_scene(method, node), samples=64)


def test_subsurface_with_a_black_checker_base_colour_matches_cycles():
    """A backlit subsurface sphere whose Base Color is a checker of black and skin: the black squares' subsurface
    weight falls under the closure cutoff, the others' does not, in one batch of hits. Ember's BSSRDF setup took
    the IOR of all the batch's hits for the kept ones and stopped the render with an internal error (a public
    character model, Blender 2.80)."""
    scene = _sss_scene("RANDOM_WALK")
    tree = bpy.data.materials["sss"].node_tree
    checker = tree.nodes.new("ShaderNodeTexChecker")
    checker.inputs["Color1"].default_value = (0.0, 0.0, 0.0, 1.0)
    checker.inputs["Color2"].default_value = (0.8, 0.5, 0.4, 1.0)
    checker.inputs["Scale"].default_value = 4.0
    tree.links.new(checker.outputs["Color"], tree.nodes["Principled BSDF"].inputs["Base Color"])
    H.compare_to_cycles(scene, samples=64)


def _burley_on_a_floor():
    """A Christensen-Burley sphere sunk into a white floor, lit from above: the floor is within the reach of the
    probes (16 d = 0.64 for red) near the sphere's foot, and the floor's bounce lights the sphere's underside."""
    scene = H.new_scene(48, 48)
    mat = H.node_material("sss", "ShaderNodeBsdfPrincipled", **{
        "Base Color": (0.8, 0.5, 0.4, 1), "Subsurface Weight": 1.0, "Subsurface Scale": 0.5,
        "Subsurface Radius": (1.0, 0.4, 0.2), "Roughness": 0.5})
    mat.node_tree.nodes["Principled BSDF"].subsurface_method = "BURLEY"
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=(0, 0, 0), segments=32, ring_count=16)
    obj = bpy.context.active_object
    obj.data.materials.append(mat)
    obj.data.shade_smooth()
    H.quad_object("floor", (-3, -3, -0.4), (6, 0, 0), (0, 6, 0), H.diffuse_material("white", (0.9, 0.9, 0.9)))
    H.set_world(scene, color=(0.02, 0.02, 0.02))
    light = bpy.data.lights.new("key", "AREA")
    light.energy, light.size = 200.0, 1.0
    lamp = bpy.data.objects.new("key", light)
    scene.collection.objects.link(lamp)
    lamp.location, lamp.rotation_euler = (1.5, -1.0, 2.5), (0.5, 0.4, 0.0)
    H.add_camera(scene, (0, -3, 0.3), (0, 0, -0.1), lens=50)
    return scene


def test_burley_sphere_on_a_floor_matches_cycles(monkeypatch):
    """Probes see only the object entered (Cycles' scene_intersect_local): were the floor's hits kept, the blocks
    at the sphere's foot would be 29% too bright (z 6.4). After a diffuse bounce (the floor's) the sphere's
    closure is set up as diffuse (bssrdf_setup's PATH_RAY_DIFFUSE_ANCESTOR): the path state reaches it."""
    told = []

    def recording(*args, ancestor=None, **kwargs):
        told.append(None if ancestor is None else np.asarray(ancestor).copy())
        return add_bssrdf(*args, ancestor=ancestor, **kwargs)
    add_bssrdf = bssrdf.add_bssrdf
    monkeypatch.setattr(bssrdf, "add_bssrdf", recording)
    H.compare_to_cycles(_burley_on_a_floor(), samples=64)
    assert told and all(a is not None for a in told)
    after_diffuse = np.concatenate(told)
    assert 0 < after_diffuse.mean() < 0.5, after_diffuse.mean()


def test_walks_parked_between_steps_change_no_pixel(monkeypatch):
    """A wave parks its walks between the integrator's steps (subsurface.WalkPool) and their paths go on from their
    exits steps later, also where a wave starts its paths a few hundred at a time (parked paths count as in
    flight): each path's numbers are its own, so the image is the one of walks taken to their end at once, bit for
    bit (where NumPy's exp is the C library's, see _libm_like_numpy)."""
    from ember.kernels.renderer import Renderer
    scene = _sss_scene("RANDOM_WALK")
    scene.render.resolution_x = scene.render.resolution_y = 24
    rounds = []
    advance = subsurface.WalkPool.advance

    def spy(pool, drain):
        rounds.append((drain, pool._walking()))
        return advance(pool, drain)
    monkeypatch.setattr(subsurface.WalkPool, "advance", spy)
    monkeypatch.setattr(subsurface.WalkPool, "PARK_WALKS", 40)
    pooled = H.render_to_array(scene, "EMBER", 8, seed=2, threads=1)
    assert any(not drain and walking > 40 for drain, walking in rounds)
    assert any(drain and walking for drain, walking in rounds)
    live_paths = Renderer.live_paths
    monkeypatch.setattr(Renderer, "live_paths", lambda renderer, settings: 300)
    batched = H.render_to_array(scene, "EMBER", 8, seed=2, threads=1)
    monkeypatch.setattr(Renderer, "live_paths", live_paths)
    monkeypatch.setattr(subsurface.WalkPool, "of", classmethod(lambda cls, tables: None))
    whole = H.render_to_array(scene, "EMBER", 8, seed=2, threads=1)
    for image in (pooled, batched):
        if _libm_like_numpy():
            assert np.array_equal(image, whole)
        else:
            np.testing.assert_allclose(image, whole, rtol=1e-4, atol=1e-6)


@pytest.mark.parametrize("method", ["RANDOM_WALK", "RANDOM_WALK_SKIN", "BURLEY"])
def test_no_subsurface_method_is_warned(method):
    """Every method renders as Cycles does, without a warning."""
    _sss_scene(method, node=method == "BURLEY")
    assert not any("subsurface" in w.lower() for w in H.export_current().warnings)
