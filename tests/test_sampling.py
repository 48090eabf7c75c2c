"""Every warp against its pdf (chi-square), and the lecture's hemisphere estimator."""
import numpy as np
import pytest

from ember.kernels import sampling
from stats import assert_chi2, mean_and_stderr

N = 400_000
THETA_BINS, PHI_BINS = 16, 32


def uniforms(n=N, seed=0):
    rng = np.random.default_rng(seed)
    return rng.random(n, dtype=np.float32), rng.random(n, dtype=np.float32)


def expected_counts(pdf_of_theta, theta_max, n=N, sub=12):
    """Expected counts per (theta, phi) bin: integrate pdf(theta) sin(theta) dtheta dphi by midpoints."""
    edges = np.linspace(0.0, theta_max, THETA_BINS + 1)
    probs = []
    for t0, t1 in zip(edges[:-1], edges[1:]):
        t = t0 + (np.arange(sub) + 0.5) * (t1 - t0) / sub
        probs.append(np.sum(pdf_of_theta(t) * np.sin(t)) * (t1 - t0) / sub * (2 * np.pi / PHI_BINS))
    return np.repeat(np.array(probs)[:, None], PHI_BINS, axis=1) * n


def histogram(x, y, z, theta_max):
    theta = np.arccos(np.clip(z.astype(np.float64), -1, 1))
    phi = np.arctan2(y, x).astype(np.float64)
    counts, _, _ = np.histogram2d(theta, phi, bins=[THETA_BINS, PHI_BINS],
                                  range=[[0, theta_max], [-np.pi, np.pi]])
    return counts


def test_cosine_hemisphere_matches_its_pdf():
    x, y, z = sampling.sample_cosine_hemisphere(*uniforms())
    assert np.allclose(x * x + y * y + z * z, 1, atol=1e-5) and np.all(z >= 0)
    expected = expected_counts(lambda t: sampling.cosine_hemisphere_pdf(np.cos(t)), np.pi / 2)
    assert_chi2(histogram(x, y, z, np.pi / 2), expected)


def test_lecture_hemisphere_matches_its_pdf():
    x, y, z, sin_t = sampling.sample_lecture_hemisphere(*uniforms())
    assert np.allclose(sin_t, np.sqrt(x * x + y * y), atol=1e-5)
    expected = expected_counts(lambda t: sampling.lecture_hemisphere_pdf(np.sin(t)), np.pi / 2)
    assert_chi2(histogram(x, y, z, np.pi / 2), expected)


def test_cosine_sampler_is_not_the_lecture_sampler():
    """The chi-square test has power: cosine samples fail against the lecture pdf."""
    from stats import chi2_statistic, chi2_upper_quantile
    x, y, z = sampling.sample_cosine_hemisphere(*uniforms())
    expected = expected_counts(lambda t: sampling.lecture_hemisphere_pdf(np.sin(t)), np.pi / 2)
    stat, dof = chi2_statistic(histogram(x, y, z, np.pi / 2), expected)
    assert stat > chi2_upper_quantile(dof)


@pytest.mark.parametrize("cos_max", [0.2, 0.9, 0.9999])
def test_uniform_cone_matches_its_pdf(cos_max):
    ux, uy = uniforms()
    x, y, z = sampling.sample_uniform_cone(ux, uy, np.float32(cos_max))
    theta_max = np.arccos(cos_max)
    expected = expected_counts(lambda t: np.full_like(t, sampling.uniform_cone_pdf(cos_max)), theta_max)
    assert_chi2(histogram(x, y, z, theta_max), expected)


def test_uniform_sphere_and_disk():
    x, y, z = sampling.sample_uniform_sphere(*uniforms())
    counts, _, _ = np.histogram2d(z, np.arctan2(y, x), bins=[16, 32], range=[[-1, 1], [-np.pi, np.pi]])
    assert_chi2(counts, np.full_like(counts, N / counts.size))  # Archimedes: z is uniform
    dx, dy = sampling.sample_uniform_disk(*uniforms(seed=3))
    r2 = dx * dx + dy * dy
    counts, _, _ = np.histogram2d(r2, np.arctan2(dy, dx), bins=[16, 32], range=[[0, 1], [-np.pi, np.pi]])
    assert_chi2(counts, np.full_like(counts, N / counts.size))  # uniform area: r^2 is uniform


def test_lecture_estimator_integrates_cosine_to_pi():
    """pi^2 sin(theta) f(omega) with f = cos(theta): the slide's estimator of the integral of cos."""
    x, y, z, sin_t = sampling.sample_lecture_hemisphere(*uniforms(200_000, seed=5))
    mean, se = mean_and_stderr(np.pi ** 2 * sin_t.astype(np.float64) * z)
    assert abs(mean - np.pi) < 4 * se, (mean, se)
    assert se < 0.01  # the test resolves errors of a third of a percent


def test_local_frame_is_orthonormal_and_maps_z_to_n():
    rng = np.random.default_rng(2)
    n = rng.normal(size=(3, 10_000)).astype(np.float32)
    n /= np.linalg.norm(n, axis=0)
    n[:, :3] = [[0, 0, 0], [0, 0, 0], [1, -1, -0.99999994]]  # the poles, where naive frames break
    n[:, :3] /= np.linalg.norm(n[:, :3], axis=0)
    tx, ty, tz, bx, by, bz = sampling.orthonormal_basis(*n)
    t, b = np.stack([tx, ty, tz]), np.stack([bx, by, bz])
    for a, c in ((t, b), (t, n), (b, n)):
        assert np.allclose((a * c).sum(0), 0, atol=1e-5)
    assert np.allclose((t * t).sum(0), 1, atol=1e-5) and np.allclose((b * b).sum(0), 1, atol=1e-5)
    w = sampling.local_to_world(np.zeros(10_000, np.float32), np.zeros(10_000, np.float32),
                                np.ones(10_000, np.float32), *n)
    assert np.allclose(np.stack(w), n, atol=1e-6)


def test_power_heuristic():
    w = sampling.power_heuristic(np.float32([1, 0, np.inf, 2]), np.float32([1, 1, 3, 0]))
    assert np.allclose(w, [0.5, 0.0, 1.0, 1.0])


@pytest.mark.parametrize("segments", [1, 7])
def test_guided_cdf_search_equals_searchsorted(segments):
    """The guide table gives searchsorted's answers exactly: spiky and flat rows, zero-width entries,
    queries on the entries themselves, at 0 and just below 1, and a few buckets (long walks)."""
    rng = np.random.default_rng(11)
    rows = []
    for s in range(segments):
        w = rng.random(300) ** 8
        w[rng.random(300) < 0.3] = 0.0          # empty cells: repeated cdf values
        w[s % 300] += 50.0                      # a spike
        cdf = np.cumsum(w)
        rows.append(cdf / cdf[-1] + s)
    cdf = np.concatenate(rows)
    for buckets in (0, 5):
        guided = sampling.GuidedCdf(cdf, segments=segments, buckets=buckets)
        seg = rng.integers(0, segments, 20000)
        u = np.concatenate([rng.random(15000), np.zeros(1000), np.full(1000, np.nextafter(1.0, 0.0)),
                            (cdf[rng.integers(0, len(cdf), 3000)] % 1.0)])
        u32 = u.astype(np.float32) % np.float32(1.0)
        for values in (u, u32):
            got = guided.search(seg if segments > 1 else 0, values)
            want = np.searchsorted(cdf, np.asarray(values, np.float64) + (seg if segments > 1 else 0), side="right")
            np.testing.assert_array_equal(got, want)


def test_guided_cdf_search_steps_back_when_rounding_starts_a_bucket_late():
    # u = nextafter(5/6, 0) is below the entry 5/6, yet u * 6 rounds to 5: the guide of bucket 5 starts
    # after that entry, and the search must step back to it.
    u = np.nextafter(5 / 6, 0.0)
    assert int(u * 6) == 5
    cdf = np.array([0.25, 5 / 6, 0.9, 1.0])
    got = sampling.GuidedCdf(cdf, buckets=6).search(0, np.array([u]))
    np.testing.assert_array_equal(got, np.searchsorted(cdf, [u], side="right"))


def test_channel_mean_is_numpys_mean_bit_for_bit():
    rng = np.random.default_rng(2)
    for dtype in (np.float32, np.float64):
        rgb = (rng.standard_normal((3, 5001)) * 10 ** rng.uniform(-3, 3, (3, 5001))).astype(dtype)
        got = sampling.channel_mean(rgb)
        assert got.dtype == dtype
        np.testing.assert_array_equal(got, rgb.mean(axis=0))
    broadcast = np.broadcast_to(np.float32([[0.1], [0.7], [0.3]]), (3, 9))
    np.testing.assert_array_equal(sampling.channel_mean(broadcast), broadcast.mean(axis=0))


def test_column_helpers_match_numpys_fancy_index():
    """put_columns and scale_columns write what a[:, idx] = v and a[:, idx] *= f write, row by row, for a
    (k, m) value, a (m,) factor and a scalar broadcast to every column."""
    rng = np.random.default_rng(4)
    a = rng.random((3, 50)).astype(np.float32)
    idx = np.array([3, 7, 20, 49, 0])
    for value in (rng.random((3, 5)).astype(np.float32), np.float32(0.0)):
        want, got = a.copy(), a.copy()
        want[:, idx] = value
        sampling.put_columns(got, idx, value)
        np.testing.assert_array_equal(got, want)
    unique = np.array([1, 4, 9, 30])
    for factor in (rng.random((3, 4)).astype(np.float32), rng.random(4).astype(np.float32)):
        want, got = a.copy(), a.copy()
        want[:, unique] *= factor
        sampling.scale_columns(got, unique, factor)
        np.testing.assert_array_equal(got, want)


def _corner_solid_angle(x, y, d):
    """Solid angle of the rectangle [0, x] x [0, y] in a plane at distance d, seen from the foot's normal
    (signed by x and y): atan(x y / (d sqrt(x^2 + y^2 + d^2)))."""
    return np.arctan(x * y / (d * np.sqrt(x * x + y * y + d * d)))


def _rect_solid_angle(x0, x1, y0, y1, d):
    return (_corner_solid_angle(x1, y1, d) - _corner_solid_angle(x0, y1, d)
            - _corner_solid_angle(x1, y0, d) + _corner_solid_angle(x0, y0, d))


def _tilted_rectangle(n):
    """A 1.5 x 0.7 rectangle turned about x, seen from points off its centre: (rect, frame) where the
    frame gives the rectangle's plane coordinates."""
    c = np.float32([0.3, -0.2, 2.0])
    a = 0.5
    ex = np.float32([1, 0, 0])
    ey = np.float32([0, np.cos(a), np.sin(a)])
    p = np.float32([0.1, 0.4, 0.2])
    rect = sampling.SphericalRectangle(
        tuple(np.full(n, v, np.float32) for v in p), tuple(np.full(n, v, np.float32) for v in c),
        tuple(np.full(n, v, np.float32) for v in ex), tuple(np.full(n, v, np.float32) for v in ey),
        np.full(n, 1.5, np.float32), np.full(n, 0.7, np.float32))
    return rect, (p, c, ex, ey)


def test_spherical_rectangle_samples_are_uniform_in_its_solid_angle():
    """The solid angle against the closed form (the rectangle split at the foot of the perpendicular), and
    the samples' landing places on a 6 x 6 grid of the rectangle against each cell's share of the solid
    angle (chi-square): the directions are uniform in the solid angle, as the pdf 1 / S says."""
    rect, (p, c, ex, ey) = _tilted_rectangle(N)
    ez = np.cross(ex, ey)
    d = abs(float(np.dot(c - p, ez)))
    xc, yc = float(np.dot(c - p, ex)), float(np.dot(c - p, ey))
    x_edges = xc + np.linspace(-0.75, 0.75, 7)
    y_edges = yc + np.linspace(-0.35, 0.35, 7)
    whole = _rect_solid_angle(x_edges[0], x_edges[-1], y_edges[0], y_edges[-1], d)
    assert abs(float(rect.solid_angle[0]) / whole - 1) < 1e-5 and rect.usable.all()
    q = np.stack(rect.sample(*uniforms()), axis=1).astype(np.float64) - p
    assert np.abs(q @ ez.astype(np.float64) - np.dot(c - p, ez)).max() < 1e-5      # on the rectangle's plane
    counts, _, _ = np.histogram2d(q @ ex, q @ ey, bins=[x_edges, y_edges])
    assert counts.sum() == N
    cells = np.array([[_rect_solid_angle(x0, x1, y0, y1, d) for y0, y1 in zip(y_edges[:-1], y_edges[1:])]
                      for x0, x1 in zip(x_edges[:-1], x_edges[1:])])
    assert_chi2(counts, N * cells / whole)
    dist = np.linalg.norm(q, axis=1).astype(np.float32)
    np.testing.assert_allclose(rect.pdf(dist, np.full(N, 0.5, np.float32)), 1 / whole, rtol=1e-5)


def test_tiny_spherical_rectangle_falls_back_to_area_sampling():
    """Below a solid angle float32 cannot resolve, sampling is uniform in the area and the pdf is the
    area's, dist^2 / (area cos): the estimator stays consistent where the spherical one would not be."""
    n = 20_000
    far = tuple(np.full(n, v, np.float32) for v in (0.0, 0.0, 0.0))
    centre = tuple(np.full(n, v, np.float32) for v in (0.0, 0.0, 400.0))
    ex = tuple(np.full(n, v, np.float32) for v in (1.0, 0.0, 0.0))
    ey = tuple(np.full(n, v, np.float32) for v in (0.0, 1.0, 0.0))
    rect = sampling.SphericalRectangle(far, centre, ex, ey, np.full(n, 0.5, np.float32), np.full(n, 0.5, np.float32))
    assert not rect.usable.any()
    x, y, z = rect.sample(*uniforms(n))
    assert np.allclose(z, 400.0) and abs(x.mean()) < 0.01 and abs(x.std() - 0.5 / np.sqrt(12)) < 0.01
    dist = np.sqrt(x * x + y * y + z * z)
    np.testing.assert_allclose(rect.pdf(dist, z / dist), dist ** 3 / (0.25 * z), rtol=1e-4)
