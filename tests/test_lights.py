"""Light sampling: every routine against the pdf that MIS uses for it (chi-square), closed-form
irradiance from disk, sized point and sun lights, and the value of NEE + MIS on a small light."""
import math

import numpy as np
import pytest

from ember.kernels import Camera, Lights, Materials, Renderer, RenderSettings, World, render
from ember.kernels.lights import selection as light_selection
from ember.kernels.lights import triangles as light_triangles
from ember.kernels import sampling
from ember.kernels.environment import Environment
from ember.kernels.lights import LightSampler
from ember.kernels.shapes import cornell_box, look_at, quad, subdivided_quad
from kernel_helpers import make_scene, trace_samples
from stats import assert_chi2, mean_and_stderr

N = 200_000


def one_light(kind, position=(0, 0, 2), frame=np.eye(3), radiance=(5, 5, 5), radius=0.0, size=(0, 0),
              spot=(1.0, 0.0), sun_half=0.0):
    return Lights(kind=np.int32([kind]), position=np.float32([position]), frame=np.float32([frame]),
                  radiance=np.float32([radiance]), radius=np.float32([radius]), size=np.float32([size]),
                  spot_cos=np.float32([spot]), sun_half_angle=np.float32([sun_half]))


def sampler_for(lights=None, positions=None, emission=None, world=None):
    positions = np.zeros((0, 3, 3), np.float32) if positions is None else positions
    t = len(positions)
    m = 1 if emission is None else 2
    scene = make_scene(positions, np.zeros_like(positions), material_ids=np.full(t, m - 1, np.int32),
                       albedo=[(0.5,) * 3] * m, emission=None if emission is None else [(0,) * 3, emission],
                       world=world or World(color=np.zeros(3, np.float32)), lights=lights or Lights())
    env = Environment(scene.world)
    table_emission = np.zeros((m, 3), np.float32) if emission is None else np.float32([(0,) * 3, emission])

    class Emitters:
        emissive = table_emission.max(axis=1) > 0
        varies = np.zeros(m, bool)

        def __call__(self, tri, b1=None, b2=None, toward=None, dist=None):
            return table_emission[scene.material_ids[tri]].T.copy()

    return LightSampler(scene, env, Emitters())


def uniforms(n=N, seed=0):
    rng = np.random.default_rng(seed)
    return (rng.random(n, dtype=np.float32) for _ in range(3))


def chi2_directions(samples_w, pdf_of, axis, theta_max, bins=(12, 24), sub=24):
    """Bin directions around `axis` in (theta, phi) and compare with the integral of pdf_of over each bin."""
    ax = np.float32(axis) / np.linalg.norm(axis)
    tx, ty, tz, bx, by, bz = (np.float32(c) for c in sampling.orthonormal_basis(*[np.float32([a]) for a in ax]))
    w = np.stack(samples_w)
    cos_t = np.clip(ax @ w, -1, 1)
    theta = np.arccos(cos_t)
    phi = np.arctan2(np.float32([bx, by, bz]).ravel() @ w, np.float32([tx, ty, tz]).ravel() @ w)
    counts, t_edges, p_edges = np.histogram2d(theta, phi, bins=bins, range=[[0, theta_max], [-np.pi, np.pi]])
    # Midpoint quadrature of pdf * sin(theta) over every bin.
    ts = (t_edges[:-1, None] + (np.arange(sub) + 0.5)[None, :] / sub * np.diff(t_edges)[:, None]).ravel()
    ps = (p_edges[:-1, None] + (np.arange(sub) + 0.5)[None, :] / sub * np.diff(p_edges)[:, None]).ravel()
    tt, pp = np.meshgrid(ts, ps, indexing="ij")
    st, ct = np.sin(tt), np.cos(tt)
    dirs = [ct * a + st * (np.cos(pp) * t + np.sin(pp) * b) for a, t, b in
            zip(ax, np.float32([tx, ty, tz]).ravel(), np.float32([bx, by, bz]).ravel())]
    pdf = pdf_of(*(d.ravel().astype(np.float32) for d in dirs)).reshape(tt.shape)
    cell = np.diff(t_edges)[0] / sub * np.diff(p_edges)[0] / sub
    expected = (pdf * st * cell).reshape(bins[0], sub, bins[1], sub).sum(axis=(1, 3)) * len(theta)
    assert_chi2(counts, expected)
    return counts.sum() / len(theta)


def nee_pdf_via_intersection(sampler, p):
    """The pdf MIS uses when a BSDF ray from p finds the light."""
    def pdf_of(dx, dy, dz):
        n = len(dx)
        o = [np.full(n, np.float32(c)) for c in p]
        found = sampler.intersect(*o, dx, dy, dz, np.full(n, np.inf, np.float32))
        return np.where(found.hit, found.pdf, 0)
    return pdf_of


P = (0.3, -0.2, 0.0)
TILTED = np.array([[1, 0, 0], [0, math.cos(0.5), -math.sin(0.5)], [0, math.sin(0.5), math.cos(0.5)]])


@pytest.mark.parametrize("kind, extra", [
    (3, dict(size=(1.5, 0.7), frame=TILTED)),     # rectangle
    (4, dict(size=(1.2, 0.6), frame=TILTED)),     # ellipse
    (0, dict(radius=0.6)),                        # sized point light (a disk facing the point)
    (1, dict(radius=0.4, spot=(math.cos(0.6), 0.2))),  # sized spot
])
def test_surface_light_sampling_matches_its_mis_pdf(kind, extra):
    sampler = sampler_for(one_light(kind, **extra))
    u = uniforms()
    s = sampler.sample(*(np.full(N, np.float32(c)) for c in P), *u)
    ok = s.pdf > 0
    assert ok.mean() > 0.99
    axis = np.float32([0, 0, 2]) - np.float32(P)
    pdf_of = nee_pdf_via_intersection(sampler, P)
    chi2_directions((s.wx[ok], s.wy[ok], s.wz[ok]), pdf_of, axis, theta_max=0.6)
    # The returned pdf equals the MIS pdf of the same direction.
    pdf_again = pdf_of(s.wx[:2000], s.wy[:2000], s.wz[:2000])
    assert np.allclose(pdf_again, s.pdf[:2000], rtol=2e-3)


def test_sun_with_an_angle_samples_its_cone():
    half = math.radians(8)
    sampler = sampler_for(one_light(2, sun_half=half, radiance=(2, 2, 2), frame=TILTED))
    s = sampler.sample(*(np.zeros(N, np.float32) for _ in range(3)), *uniforms())
    z_axis = TILTED[:, 2]
    cone = np.float32(sampling.uniform_cone_pdf(np.float32(math.cos(half))))
    chi2_directions((s.wx, s.wy, s.wz), lambda x, y, z: np.full(len(x), cone), z_axis, theta_max=half)
    assert np.allclose(s.pdf, cone, rtol=1e-5)


@pytest.mark.parametrize("size", [1.0, 0.02])  # near: sampled by solid angle; small and far: by area
def test_emissive_triangle_sampling_matches_its_mis_pdf(size):
    positions, _ = quad((-0.5, -0.4, 1.5), (1.2 * size, 0.1 * size, 0.0), (0.2 * size, 0.9 * size, 0.3 * size))
    sampler = sampler_for(positions=positions, emission=(4, 4, 4))
    s = sampler.sample(*(np.full(N, np.float32(c)) for c in P), *uniforms(seed=2))
    assert np.all(s.pdf > 0)
    # Where would a BSDF ray in that direction hit? Intersect the two triangles by hand.
    from ember.kernels.accel import Accel
    with Accel(positions, 1) as accel:
        def pdf_of(dx, dy, dz):
            n = len(dx)
            o = np.tile(np.float32(P), (n, 1))
            h = accel.intersect(o, np.stack([dx, dy, dz], 1), np.full(n, np.inf, np.float32))
            e1 = positions[:, 1] - positions[:, 0]
            e2 = positions[:, 2] - positions[:, 0]
            ng = np.cross(e1, e2)
            ng /= np.linalg.norm(ng, axis=1, keepdims=True)
            prim = np.maximum(h.prim, 0)
            cos_l = (ng[prim] * np.stack([dx, dy, dz], 1)).sum(1)
            ox, oy, oz = (np.full(n, np.float32(c)) for c in P)
            return np.where(h.prim >= 0, sampler.pdf_triangle_hit(prim, h.t, cos_l, ox, oy, oz), 0)
        centre = positions.reshape(-1, 3).mean(axis=0)
        theta_max = 1.2 if size == 1.0 else 0.03
        chi2_directions((s.wx, s.wy, s.wz), pdf_of, centre - np.float32(P), theta_max=theta_max)
        spherical = light_triangles.spherical_choice(sampler, np.take(sampler.tri_table, [0], axis=0).T,
                                                     np.int32([0]), *(np.float32([c]) for c in P))[0][0]
        assert spherical == (size == 1.0)


def test_emissive_triangles_are_sampled_by_solid_angle_within_their_longest_edge_of_their_plane():
    """Solid angle from points nearer the triangle's plane than its longest edge, area beyond (the comparison
    Cycles' kernel/light/triangle.h describes). Either way the irradiance under the triangle is its closed form."""
    positions, _ = quad((-0.5, -0.5, 2.0), (0.0, 1.0, 0.0), (1.0, 0.0, 0.0))   # faces down; diagonal sqrt 2
    sampler = sampler_for(positions=positions, emission=(3, 3, 3))
    table = np.take(sampler.tri_table, [0, 0, 0, 0], axis=0).T
    heights = np.float32([1.3, 1.4, 1.43, 1.5])   # below the plane by these; the longest edge is 1.414
    spherical = light_triangles.spherical_choice(sampler, table, np.int32([0, 0, 0, 0]), np.zeros(4, np.float32),
                                                 np.zeros(4, np.float32), np.float32(2.0) - heights)[0]
    assert spherical.tolist() == [True, True, False, False]
    for h in (0.5, 3.0):   # both ways of sampling give the irradiance of a uniformly emitting square
        a = 0.5 / h        # half side over height: E = L * 4 * a / sqrt(1 + a^2) * atan(a / sqrt(1 + a^2))
        closed = 3.0 * 4 * a / math.sqrt(1 + a * a) * math.atan(a / math.sqrt(1 + a * a))
        e, se = nee_irradiance(sampler, (0.0, 0.0, 2.0 - h))
        assert abs(e - closed) < 4 * se + 1e-4 * closed, (h, e, se, closed)


@pytest.mark.parametrize("compensated", [True, False])
def test_hdri_sampling_matches_its_pdf(compensated):
    """Light samples of an HDRI, with MIS compensation (the default) or without: the pdf they come with is
    the one escaped rays' MIS weights read (direction_pdf), their directions follow it, and it integrates
    to one over the sphere."""
    rng = np.random.default_rng(4)
    hdri = (rng.random((32, 64, 3)) ** 8 * 50).astype(np.float32)   # spiky, like a sun in a sky
    hdri[20, 10] = 3000.0
    rot = np.float32([[0, -1, 0], [1, 0, 0], [0, 0, 1]]) @ TILTED.astype(np.float32)
    env = Environment(World(hdri=hdri, strength=1.0, env_from_world=rot.astype(np.float32),
                            mis_compensation=compensated))
    u1, u2, _ = uniforms()
    wx, wy, wz, pdf = env.sample_direction(u1, u2)
    # Equal up to float32 round trips that land a sample on the neighbouring cell (a few in 10^4).
    assert np.mean(~np.isclose(pdf, env.direction_pdf(wx, wy, wz), rtol=1e-3)) < 1e-3
    # Over the whole sphere (theta from the world z axis up to pi).
    chi2_directions((wx, wy, wz), env.direction_pdf, (0, 0, 1), theta_max=np.pi, bins=(16, 32))
    # And the distribution integrates to one.
    v1, v2, _ = uniforms(400_000, seed=9)
    x, y, z = sampling.sample_uniform_sphere(v1, v2)
    m, se = mean_and_stderr(env.direction_pdf(x, y, z) * 4 * np.pi)
    assert abs(m - 1.0) < 5 * se


# ---------------------------------------------------------------- closed forms
def nee_irradiance(sampler, p, normal=(0, 0, 1), n=N):
    """Monte Carlo irradiance at p from light sampling alone (no occluders): E = mean(L cos / pdf)."""
    s = sampler.sample(*(np.full(n, np.float32(c)) for c in p), *uniforms(n, seed=7))
    cos = np.maximum(s.wx * normal[0] + s.wy * normal[1] + s.wz * normal[2], 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        e = np.where(s.pdf > 0, s.radiance[0] * cos / s.pdf, 0)
    return mean_and_stderr(e)


@pytest.mark.parametrize("h, radius", [(2.0, 0.5), (1.0, 1.0)])
def test_irradiance_under_a_uniform_disk_light(h, radius):
    """E = L pi R^2 / (h^2 + R^2) on the axis of a disk of radiance L facing the point."""
    L = 3.0
    disk = one_light(4, position=(0, 0, h), radiance=(L,) * 3, size=(2 * radius, 2 * radius))
    m, se = nee_irradiance(sampler_for(disk), (0, 0, 0))
    expected = L * np.pi * radius ** 2 / (h ** 2 + radius ** 2)
    assert abs(m - expected) < 4 * se + 1e-6, (m, se, expected)


def test_irradiance_from_a_sized_point_light_is_cycles_facing_disk():
    """Cycles 5.0 lights a point with a sized point light as a disk facing it: E = I / (d^2 + r^2)
    on axis (measured in Cycles: 6.3665 for I = 100 / 4 pi, d = 1, r = 0.5)."""
    intensity = 100 / (4 * np.pi)
    r = 0.5
    light = one_light(0, position=(0, 0, 1.0), radiance=(intensity / (np.pi * r * r),) * 3, radius=r)
    m, se = nee_irradiance(sampler_for(light), (0, 0, 0))
    assert abs(m - intensity / (1.0 + r * r)) < 4 * se + 1e-6, (m, se)
    assert abs(m - 6.3665) < 4 * se + 2e-3


@pytest.mark.parametrize("angle_deg, sun_half", [(0.0, 0.0), (35.0, 0.0), (35.0, math.radians(6)),
                                                 (35.0, math.radians(0.526 / 2))])
def test_sun_at_a_known_angle_on_a_diffuse_plane(angle_deg, sun_half):
    """A diffuse plane of albedo rho under a sun of irradiance E at angle a: radiance rho / pi * E cos a.
    Blender's default sun (0.526 degrees) is a cone narrow enough that float32 rounds its cosine by 0.14%
    of 1 - cos: its radiance must follow the cone actually sampled."""
    rho, e = 0.6, 3.0
    a = math.radians(angle_deg)
    frame = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    positions, normals = quad((-5, -5, 0), (10, 0, 0), (0, 10, 0))
    cam = Camera(world_from_camera=look_at((0, 0, 3), (0, 0.001, 0), up=(0, 1, 0)), width=8, height=8,
                 fov_rad=np.radians(20))
    scene = make_scene(positions, normals, albedo=(rho,) * 3, camera=cam,
                       lights=one_light(2, radiance=(e,) * 3, frame=frame, sun_half=sun_half))
    img = render(scene, RenderSettings(samples=64, max_bounces=0, mode="NEE_MIS")).image[..., 0]
    expected = rho / np.pi * e * math.cos(a)
    if sun_half == 0:
        assert np.allclose(img, expected, rtol=1e-4)  # a delta light: exact, sample by sample
    elif sun_half < 0.01:
        assert abs(img.mean() - expected) < 3e-4 * expected, img.mean() / expected - 1   # noise: 3e-5
    else:
        assert abs(img.mean() - expected) < 0.01 * expected


# ---------------------------------------------------------------- why NEE + MIS
def test_nee_mis_has_far_lower_error_than_cosine_on_a_small_light():
    # The lamp hangs 0.2 below the ceiling: right under it, its back would light the ceiling at
    # 1/r^2 from a centimetre away, a singularity that is noisy for any strategy.
    scene = cornell_box(24, 24, light_size=0.25, light_radiance=60.0, wall_subdivisions=2, sphere_segments=8,
                        light_height=1.8)
    reference = trace_samples(scene, RenderSettings(mode="NEE_MIS", max_bounces=3, seed=99), 512).mean(axis=0)
    # Pixels that see the lamp itself are equally noisy in both modes (the pixel filter's edge): the
    # comparison is about the light the lamp casts on the room.
    room = np.all(reference < 5.0, axis=0)
    errors = {}
    for mode in ("NEE_MIS", "COSINE"):
        img = trace_samples(scene, RenderSettings(mode=mode, max_bounces=3, seed=1), 16).mean(axis=0)
        errors[mode] = float(np.sqrt(np.mean((img - reference)[:, room] ** 2)))
    factor = errors["COSINE"] / errors["NEE_MIS"]
    print(f"equal-sample RMSE, small light: COSINE/NEE_MIS = {factor:.1f}x ({errors})")
    assert factor > 3.0, errors


def test_grazing_light_beside_a_lamp_hung_just_under_a_ceiling():
    """The ceiling beside a lamp 1 cm below it sees the lamp's back at grazing angles. Shadow rays
    must aim from their offset origin at the sampled point: aimed from the surface point, the eps
    offset made them cross the lamp's plane early, and NEE lost 99.9% of this light."""
    rho, le, h, gap = 0.7, 15.0, 0.25, 0.01
    ceiling, ceiling_n = quad((-2, -2, 2.0), (4, 0, 0), (0, 4, 0))       # faces up; both sides shade
    lamp, lamp_n = quad((-h, -h, 2.0 - gap), (0, 2 * h, 0), (2 * h, 0, 0))
    positions = np.concatenate([ceiling, lamp])
    normals = np.concatenate([ceiling_n, lamp_n])
    x0 = 0.3  # a ceiling point 5 cm beside the lamp's edge, seen from below
    cam = Camera(world_from_camera=look_at((x0, 0.0, 1.5), (x0, 0.0001, 2.0), up=(0, 1, 0)), kind="ORTHO",
                 ortho_scale=1e-3, width=2, height=2, clip_start=0.0, clip_end=10.0)
    scene = make_scene(positions, normals, material_ids=np.int32([0, 0, 1, 1]), albedo=[(rho,) * 3, (0,) * 3],
                       emission=[(0,) * 3, (le,) * 3], camera=cam)
    # Irradiance at the point from the lamp's top face, by a midpoint rule over the lamp.
    k = 800
    g = (np.arange(k) + 0.5) / k * 2 * h - h
    qx, qy = np.meshgrid(g, g)
    dx, dy, dz = qx - x0, qy, -gap
    r2 = dx * dx + dy * dy + dz * dz
    irradiance = np.sum(le * (gap / np.sqrt(r2)) ** 2 / r2) * (2 * h / k) ** 2
    samples = trace_samples(scene, RenderSettings(mode="NEE_MIS", max_bounces=0, seed=2), 2000)[:, 0]
    m, se = mean_and_stderr(samples.mean(axis=1))
    assert abs(m - rho / np.pi * irradiance) < 4 * se, (m, se, rho / np.pi * irradiance)


def test_light_choice_frequencies_match_the_selection_pmf():
    """Chi-square of the emitter chosen by LightSampler.choose against select_pmf, over point, spot, sun
    and area lights of spread-out powers, emissive triangles and an HDRI world (the fallback selection:
    by power within local and distant emitters, distant ones sharing a fixed part)."""
    rng = np.random.default_rng(7)
    k = 12
    kinds = np.int32([0, 1, 3, 4] * 3)
    lights = Lights(kind=kinds, position=rng.uniform(-3, 3, (k, 3)).astype(np.float32),
                    frame=np.repeat(np.eye(3, dtype=np.float32)[None], k, axis=0),
                    radiance=np.float32(rng.exponential(5.0, (k, 1)) * np.ones((1, 3))),
                    radius=np.float32(rng.uniform(0.05, 0.5, k)), size=np.float32(rng.uniform(0.1, 1.0, (k, 2))),
                    spot_cos=np.float32([(0.5, 0.1)] * k), sun_half_angle=np.zeros(k, np.float32))
    tri = np.float32(rng.uniform(-2, 2, (20, 3, 3)))
    hdri = np.float32(rng.exponential(1.0, (8, 16, 3)))
    sampler = sampler_for(lights=lights, positions=tri, emission=(2.0, 1.5, 1.0), world=World(hdri=hdri))
    pmf = sampler.select_pmf
    assert len(pmf) == k + 20 + 1 and abs(pmf.sum() - 1) < 1e-9 and (pmf > 0).all()
    n = 400_000
    chosen = sampler.choose(np.random.default_rng(8).random(n, dtype=np.float32))
    counts = np.bincount(chosen, minlength=len(pmf))
    assert_chi2(counts, pmf * n)


def test_a_world_of_one_colour_is_no_light():
    """As in Cycles, a world of one colour in every direction is not sampled by next-event estimation (BSDF
    rays find it, with MIS weight 1): the lamps get every light sample. A world that varies (an HDRI) is."""
    lamp = Lights(kind=np.int32([0]), position=np.float32([(0, 0, 2)]), frame=np.eye(3, dtype=np.float32)[None],
                  radiance=np.float32([(5.0,) * 3]), radius=np.zeros(1, np.float32), size=np.zeros((1, 2), np.float32),
                  spot_cos=np.float32([(1.0, 0.0)]), sun_half_angle=np.zeros(1, np.float32))
    grey = sampler_for(lights=lamp, world=World(color=np.float32([0.3, 0.3, 0.3])))
    assert grey.select_pmf[grey.world_index] == 0 and grey.select_pmf[0] == 1 and not grey.samples_world()
    d = np.float32([[0, 0, 1], [1, 0, 0]])
    np.testing.assert_array_equal(grey.pdf_world(*d.T), 0.0)
    sky = np.float32(np.random.default_rng(14).uniform(0.1, 1.0, (8, 16, 3)))
    lit = sampler_for(lights=lamp, world=World(hdri=sky))
    assert lit.samples_world() and 0 < lit.select_pmf[lit.world_index] < 1
    flat = sampler_for(lights=lamp, world=World(hdri=np.full((8, 16, 3), 0.3, np.float32)))
    assert not flat.samples_world()


def _half_glowing_panel():
    """A 2 x 2 m ceiling panel of 128 triangles at z = 2 over a floor, UVs spanning it, its 8 x 8 emission
    texture white in the middle half (columns 2 to 5) and black outside; the camera looks down at the floor."""
    panel, panel_n = subdivided_quad((-1, -1, 2), (2, 0, 0), (0, 2, 0), 8)
    floor, floor_n = quad((-3, -3, 0), (6, 0, 0), (0, 6, 0))
    uv = np.zeros((len(panel) + 2, 3, 2), np.float32)
    uv[:len(panel)] = (panel[..., :2] + 1) / 2
    texture = np.zeros((8, 8, 3), np.float32)
    texture[:, 2:6] = 1.0
    materials = Materials.diffuse([(0.5,) * 3, (0.7,) * 3], emission=[(4.0,) * 3, (0,) * 3],
                                  emission_texture=[0, -1])
    cam = Camera(world_from_camera=look_at((0, -3, 1.5), (0, 0, 0)), width=16, height=16, fov_rad=np.radians(60))
    return make_scene(np.concatenate([panel, floor]), np.concatenate([panel_n, floor_n]),
                      material_ids=np.r_[np.zeros(len(panel), np.int32), np.ones(2, np.int32)], uvs=uv,
                      materials=materials, textures=(texture,), camera=cam)


def test_light_samples_go_to_the_glowing_part_of_an_emission_map(monkeypatch):
    """Triangles of a textured emitter are weighed by their own emission, estimated at a few points of each:
    those that show none are not light-sampled (BSDF rays find them, with MIS weight 1), the rest in
    proportion to what they show. The floor's mean is COSINE's (no bias) with less variance than when
    every triangle was sampled at the map's mean (an emission map is mostly black: Damaged Helmet's 98%)."""
    scene = _half_glowing_panel()
    with Renderer(scene, 1) as renderer:
        sampler = renderer.lights
        centre_u = (scene.positions[sampler.tri_ids, :, 0].mean(axis=1) + 1) / 2
    # The outer columns of triangles (u below 1/8 or above 7/8) see only black texels (the lookup wraps to
    # the other black edge); the next ones in reach the white ones' filter.
    assert len(sampler.tri_ids) == 96 and ((centre_u > 0.125) & (centre_u < 0.875)).all(), centre_u
    nee = trace_samples(scene, RenderSettings(mode="NEE_MIS", max_bounces=1, seed=3), 256)
    cosine = trace_samples(scene, RenderSettings(mode="COSINE", max_bounces=1, seed=3), 256)
    (m_n, se_n), (m_c, se_c) = (mean_and_stderr(run.mean(axis=(1, 2))) for run in (nee, cosine))
    assert abs(m_n - m_c) < 4 * np.hypot(se_n, se_c), (m_n, se_n, m_c, se_c)
    # Every triangle at the map's mean, as before: half the light samples land on black.
    monkeypatch.setattr(light_selection, "emission_estimates",
                        lambda emission, tri, materials, varies: emission(tri).T.astype(np.float32))
    flat = trace_samples(scene, RenderSettings(mode="NEE_MIS", max_bounces=1, seed=3), 256)
    ratio = nee.var(axis=0).mean() / flat.var(axis=0).mean()
    print(f"per-sample variance, own estimates / the map's mean: {ratio:.3f}")
    assert ratio < 0.8
