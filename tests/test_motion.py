"""Transform motion blur and the shutter (kernels.motion) against Cycles 5.0's formulas."""
import numpy as np
import pytest

from ember.kernels import motion
from stats import assert_chi2, chi2_statistic, chi2_upper_quantile

EPS32 = float(np.finfo(np.float32).eps)
EPS64 = float(np.finfo(np.float64).eps)


def rotation(axis, angle):
    """(3, 3) rotation by angle (radians) about axis (Rodrigues)."""
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def affine(linear, translation=(0.0, 0.0, 0.0)):
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = linear, translation
    return m


def random_steps(rng, count, mirrored=False, shear=True):
    """count world_from_object matrices R S + t with scale in [0.5, 2], optional shear and mirror."""
    steps = []
    for _ in range(count):
        s = np.diag(rng.uniform(0.5, 2.0, 3))
        if shear:
            s[0, 1], s[0, 2], s[1, 2] = rng.uniform(-0.5, 0.5, 3)
        if mirrored:
            s[2, 2] = -s[2, 2]
        steps.append(affine(rotation(rng.normal(size=3), rng.uniform(0, np.pi)) @ s, rng.normal(size=3)))
    return np.array(steps)


def z_angle(m):
    """Angle (radians) of the rotation about +Z in a (..., 3, 4) matrix with no scale."""
    return np.arctan2(m[..., 1, 0], m[..., 0, 0])


def key_times(count):
    return np.arange(count) / (count - 1)


# ---------------------------------------------------------------- interpolation

@pytest.mark.parametrize("count", [2, 3, 5])
@pytest.mark.parametrize("mirrored,shear", [(False, True), (True, False)])
def test_keys_return_the_keys(count, mirrored, shear):
    steps = random_steps(np.random.default_rng(count), count, mirrored, shear)
    out = motion.interpolate(motion.decompose(steps), key_times(count))
    # A handful of float64 roundings per entry, on entries up to ~4 in size.
    assert np.abs(out - steps[:, :3, :]).max() < 64 * EPS64 * 4


def test_many_decomposed_at_once_are_each_decomposed_alone():
    """decompose_many (a particle system's moving instances in one pass) gives each object's decomposition bit for
    bit, whatever its step count, mirror, shear, dtype, or a zero-scale step borrowing its neighbour's rotation."""
    rng = np.random.default_rng(11)
    keys = [random_steps(rng, count, mirrored, shear) for count, mirrored, shear in
            ((2, False, False), (3, True, False), (5, False, True), (2, True, True))]
    keys.append(random_steps(rng, 3).astype(np.float32))
    zero = random_steps(rng, 3)
    zero[1, :3, :3] = 0.0
    keys.append(zero)
    for alone, together in zip([motion.decompose(k) for k in keys], motion.decompose_many(keys)):
        for a, b in zip(alone, together):
            assert a.dtype == b.dtype
            np.testing.assert_array_equal(a, b)


def test_many_objects_interpolated_at_once_are_each_interpolated_alone():
    """interpolate_many (the hits on hundreds of moving objects at once) gives each row what interpolate gives its
    object alone at that time, bit for bit, objects of 2, 3 and 5 steps mixed (stack_by_steps groups them)."""
    rng = np.random.default_rng(5)
    decomposed = [motion.decompose(random_steps(rng, count)) for count in (2, 3, 5, 3, 2, 5, 5)]
    objects = rng.integers(0, len(decomposed), 400)
    times = rng.uniform(0.0, 1.0, 400)
    times[:3] = (0.0, 1.0, 0.5)
    out = np.full((400, 3, 4), np.nan)
    for members, stacked in motion.stack_by_steps(decomposed):
        place = np.full(len(decomposed), -1)
        place[members] = np.arange(len(members))
        rows = np.flatnonzero(place[objects] >= 0)
        out[rows] = motion.interpolate_many(stacked, place[objects[rows]], times[rows])
    for k in range(400):
        np.testing.assert_array_equal(out[k], motion.interpolate(decomposed[objects[k]], times[k:k + 1])[0])


def test_keys_return_the_keys_in_float32():
    steps = random_steps(np.random.default_rng(7), 3).astype(np.float32)
    decomposed = motion.decompose(steps)
    assert all(a.dtype == np.float32 for a in decomposed)
    out = motion.interpolate(decomposed, key_times(3).astype(np.float32))
    assert out.dtype == np.float32
    assert np.abs(out - steps[:, :3, :]).max() < 64 * EPS32 * 4


def test_mirrored_and_sheared_step_comes_back_as_cycles_rebuilds_it():
    """Cycles negates the rotation and the scale diagonal of a mirrored step but not its shear, so the
    rebuilt matrix is Q S' with S' = S with its shear negated (Q S: Gram-Schmidt of the columns)."""
    steps = random_steps(np.random.default_rng(3), 2, mirrored=True, shear=True)
    out = motion.interpolate(motion.decompose(steps), key_times(2))
    for m, got in zip(steps, out):
        q, r = np.linalg.qr(m[:3, :3])
        signs = np.sign(np.diag(r))  # Gram-Schmidt has a positive diagonal
        q, r = q * signs, signs[:, None] * r
        cycles = q @ (np.diag(np.diag(r)) - np.triu(r, 1))
        assert np.abs(got[:, :3] - cycles).max() < 1e-12
        assert np.abs(got[:, :3] - m[:3, :3]).max() > 0.05  # and it is not the key


def test_pure_translation_is_piecewise_linear():
    translations = np.array([[0.0, 0.0, 0.0], [2.0, -1.0, 0.5], [2.0, 3.0, -4.0]])
    steps = np.array([affine(np.eye(3), t) for t in translations])
    time = np.random.default_rng(0).random(1000)
    out = motion.interpolate(motion.decompose(steps), time)
    expected = np.stack([np.interp(time, key_times(3), translations[:, i]) for i in range(3)], -1)
    assert np.abs(out[:, :, 3] - expected).max() < 16 * EPS64 * 4
    assert np.abs(out[:, :, :3] - np.eye(3)).max() < 16 * EPS64


def test_rotation_about_z_by_90_degrees_is_45_at_half_time():
    steps = np.array([affine(np.eye(3)), affine(rotation([0, 0, 1], np.pi / 2))])
    time = np.linspace(0, 1, 101)
    out = motion.interpolate(motion.decompose(steps), time)
    assert abs(z_angle(out[50]) - np.pi / 4) < 1e-12
    # slerp: constant angular speed, and a pure rotation (no shrinking midway as a matrix lerp would)
    assert np.abs(z_angle(out) - time * np.pi / 2).max() < 1e-12
    assert np.abs(np.linalg.det(out[:, :, :3]) - 1).max() < 1e-12


def test_rotation_over_three_steps_is_piecewise():
    angles = np.radians([0.0, 90.0, 150.0])
    steps = np.array([affine(rotation([0, 0, 1], a)) for a in angles])
    time = np.random.default_rng(1).random(1000)
    out = motion.interpolate(motion.decompose(steps), time)
    assert np.abs(z_angle(out) - np.interp(time, key_times(3), angles)).max() < 1e-12


def test_small_rotations_use_normalised_lerp():
    """Below 2 acos(0.9995) = 3.6 degrees Cycles lerps the quaternions and normalises."""
    theta = np.radians(3.0)
    steps = np.array([affine(np.eye(3)), affine(rotation([0, 0, 1], theta))])
    time = np.linspace(0, 1, 11)
    out = motion.interpolate(motion.decompose(steps), time)
    half = theta / 2
    nlerp_angle = 2 * np.arctan2(time * np.sin(half), (1 - time) + time * np.cos(half))
    assert np.abs(z_angle(out) - nlerp_angle).max() < 1e-14
    assert np.abs(nlerp_angle - time * theta).max() > 1e-9  # and that is not slerp


def test_sign_flipped_quaternions_take_the_short_way():
    """170 and 190 degrees about Z: their quaternions point away from each other; the path must pass
    through 180 degrees (20 degrees of travel), not back through 0."""
    steps = np.array([affine(rotation([0, 0, 1], np.radians(a))) for a in (170.0, 190.0)])
    decomposed = motion.decompose(steps)
    assert np.dot(decomposed.rotation[0], decomposed.rotation[1]) > 0
    out = motion.interpolate(decomposed, np.array([0.25, 0.5, 0.75]))
    expected = np.radians([175.0, 180.0, 185.0])
    assert np.abs(np.cos(z_angle(out) - expected) - 1).max() < 1e-12


def test_scale_and_shear_interpolate_linearly_after_the_rotation():
    """Cycles lerps the scale/shear matrix S and rotates it: M(t) = R(t) lerp(S0, S1)."""
    s0 = np.array([[1.0, 0.0, 0.2], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    s1 = np.array([[3.0, 0.4, 0.2], [0.0, 2.0, -0.6], [0.0, 0.0, 0.5]])
    steps = np.array([affine(s0), affine(rotation([0, 0, 1], np.pi / 2) @ s1)])
    time = np.linspace(0, 1, 9)
    out = motion.interpolate(motion.decompose(steps), time)
    for t, m in zip(time, out):
        expected = rotation([0, 0, 1], t * np.pi / 2) @ ((1 - t) * s0 + t * s1)
        assert np.abs(m[:, :3] - expected).max() < 1e-12
    # uniform scale 1 -> 3 is 2 at half time (linear, not geometric)
    steps = np.array([affine(np.eye(3)), affine(3 * np.eye(3))])
    assert np.allclose(motion.interpolate(motion.decompose(steps), np.array([0.5]))[0, :, :3],
                       2 * np.eye(3), atol=1e-14)


def test_zero_scale_step_borrows_its_neighbours_rotation():
    steps = np.array([affine(rotation([0, 0, 1], np.radians(30))), np.zeros((4, 4)),
                      affine(rotation([0, 0, 1], np.radians(60)))])
    steps[1, 3, 3] = 1
    decomposed = motion.decompose(steps)
    assert np.array_equal(decomposed.rotation[1], decomposed.rotation[0])
    out = motion.interpolate(decomposed, np.array([0.25]))[0]
    assert np.abs(out[:, :3] - 0.5 * rotation([0, 0, 1], np.radians(30))).max() < 1e-12


def test_camera_matrix_with_flipped_z_matches_interpolating_the_rotation():
    """Cycles hands the camera over as R diag(1, 1, -1) (mirrored); interpolating that is the same as
    interpolating R and flipping after, so Ember may interpolate matrix_world directly."""
    r0, r1 = rotation([1, 2, 3], 0.4), rotation([-1, 0.5, 2], 1.9)
    flip = np.diag([1.0, 1.0, -1.0])
    time = np.linspace(0, 1, 7)
    cycles = motion.interpolate(motion.decompose(np.array([affine(r0 @ flip), affine(r1 @ flip)])), time)
    ember = motion.interpolate(motion.decompose(np.array([affine(r0), affine(r1)])), time)
    assert np.abs(cycles[:, :, :3] - ember[:, :, :3] @ flip).max() < 1e-12


def test_quaternion_round_trip_covers_every_branch():
    rng = np.random.default_rng(5)
    rots = [rotation(rng.normal(size=3), a) for a in rng.uniform(0, np.pi, 200)]
    rots += [rotation(axis, np.pi) for axis in np.eye(3)]  # trace -1: each diagonal branch
    rots = np.array(rots)
    q = motion.matrix_to_quaternion(rots)
    assert np.abs(np.linalg.norm(q, axis=-1) - 1).max() < 1e-12
    assert np.abs(motion.quaternion_to_matrix(q) - rots).max() < 1e-12


# ---------------------------------------------------------------- inverse

@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_inverse_times_matrix_is_identity(dtype):
    rng = np.random.default_rng(11)
    steps = random_steps(rng, 4, shear=True)
    m = motion.interpolate(motion.decompose(steps.astype(dtype)), rng.random(2000).astype(dtype))
    inv = motion.affine_inverse(m)
    assert inv.dtype == dtype
    lin, inv_lin = m[:, :, :3].astype(np.float64), inv[:, :, :3].astype(np.float64)
    cond = np.linalg.cond(lin)
    # inverse of a well-conditioned 3x3 in precision eps: error ~ cond * eps per entry
    tol = 32 * float(np.finfo(dtype).eps) * cond[:, None, None]
    assert np.all(np.abs(lin @ inv_lin - np.eye(3)) < tol)
    assert np.all(np.abs(inv_lin @ lin - np.eye(3)) < tol)
    # the translations cancel: inv maps the matrix's image of a point back to that point
    p = rng.normal(size=(len(m), 3))
    world = np.einsum("nij,nj->ni", lin, p) + m[:, :, 3]
    back = np.einsum("nij,nj->ni", inv_lin, world) + inv[:, :, 3]
    scale = 1 + np.abs(world).max(-1) + np.abs(p).max(-1)
    assert np.all(np.abs(back - p).max(-1) < 32 * float(np.finfo(dtype).eps) * cond * scale)


def test_inverse_of_a_singular_matrix_stays_finite():
    m = np.zeros((1, 3, 4), np.float32)
    assert np.all(np.isfinite(motion.affine_inverse(m)))


# ---------------------------------------------------------------- shutter

FLAT = np.ones(257)  # Blender's default curve, sampled as Cycles does (257 points)


def cycles_flat_time(u):
    """A flat curve's table maps level (i + 0.5) / 256 through a 255-interval CDF indexed over 256:
    time = 255 (255 u + 0.5) / 256^2."""
    return 255.0 * (255.0 * u + 0.5) / 65536.0


def test_flat_shutter_curve_is_the_identity_up_to_cycles_table_offset():
    u = np.linspace(0, 1, 4097, dtype=np.float32)
    for curve in (FLAT, np.ones(256), np.array([])):
        time = motion.sample_time(u, motion.shutter_table(curve))
        assert time.dtype == np.float32
        assert np.abs(time - u).max() <= 1.5 / 256 + 4 * EPS32
        assert np.abs(time - cycles_flat_time(u.astype(np.float64))).max() < 8 * EPS32
    assert np.all(np.diff(time) >= 0)


def curve_samples(f, count=257):
    return f(np.arange(count) / (count - 1))


def cycles_time_cdf(f, edges):
    """Distribution of sampled times for the curve f, from the Cycles recipe written out longhand:
    interval k of the time axis [k/256, (k+1)/256) carries weight |curve at index 257 k / 254 - 1|
    (k = 0 reads the curve's last sample), and the uniform number covers levels [0.5, 255.5] / 256."""
    c = curve_samples(f)
    k = np.arange(255)
    position = k / 254 * len(c) - 1
    weights = np.where(k == 0, c[-1], np.interp(position, np.arange(len(c)), c))
    cdf = np.concatenate([[0], np.cumsum(np.abs(weights))]) / np.abs(weights).sum()
    level = np.interp(edges, np.arange(256) / 256, cdf)
    return np.clip((level - 0.5 / 256) / (255 / 256), 0, 1)


def shaped(x):
    return 0.1 + x * x  # density ratio 11 across the shutter


def test_sampled_times_follow_the_shutter_curve():
    n, bins = 200_000, 32
    uc = np.random.default_rng(2024).random(n, dtype=np.float32)
    time = motion.sample_time(uc, motion.shutter_table(curve_samples(shaped)))
    edges = np.linspace(0, 1, bins + 1)
    observed, _ = np.histogram(time, edges)
    expected = np.diff(cycles_time_cdf(shaped, edges)) * n
    assert_chi2(observed, expected)
    # power: the same samples are far from a flat shutter's distribution
    flat_expected = np.diff(cycles_time_cdf(lambda x: np.ones_like(x), edges)) * n
    stat, dof = chi2_statistic(observed, flat_expected)
    assert stat > 10 * chi2_upper_quantile(dof)


def test_shutter_curve_first_sample_quirk():
    """A curve closed for its first half still opens the shutter at time 0: Cycles evaluates its first
    CDF point at index -1, which falls through to the curve's last (open) sample. Weights: 1 for
    [0, 1/256), 0.5 for the interval where the curve opens, 127 more open intervals: 128.5 in all."""
    half = curve_samples(lambda x: (x >= 0.5).astype(float))
    table = motion.shutter_table(half)
    first_mass = 1 / 128.5
    for i in (0, 1):  # levels (i + 0.5) / 256 fall in the first interval: time = level / mass / 256
        assert abs(table[i] - (i + 0.5) / 256 / first_mass / 256) < 4 * EPS32
    assert table[2] > 127 / 256  # the rest waits for the curve to open
    assert np.all(np.diff(table) >= 0) and table[-1] <= 1


def test_rolling_shutter_row_time_and_mix():
    height = 8
    row = np.arange(height)
    uc = np.full(height, 0.3, np.float32)
    table = motion.shutter_table(FLAT)
    shutter = motion.sample_time(uc, table)
    # duration 0: the row's own time, Cycles' 1 - y / height with y counted from the bottom row
    assert np.allclose(motion.sample_time(uc, table, row, height, 0.0), (row + 1) / height, atol=EPS32)
    # duration 1: the plain shutter time; in between, the documented mix
    assert np.allclose(motion.sample_time(uc, table, row, height, 1.0), shutter, atol=2 * EPS32)
    mixed = motion.sample_time(uc, table, row, height, 0.25)
    expected = (shutter - 0.5) * 0.25 + ((row + 1) / height - 0.5) * 0.75 + 0.5
    assert np.allclose(mixed, expected, atol=4 * EPS32)
    assert mixed.dtype == np.float32 and np.all((mixed >= 0) & (mixed <= 1))
