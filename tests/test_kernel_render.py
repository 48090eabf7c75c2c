"""The path tracer against closed-form answers, itself (modes, threads) and its contracts."""
import dataclasses
import time

import numpy as np
import pytest

from ember.kernels import Renderer, RenderSettings, integrator, render
from ember.kernels.accel import Accel
from ember.kernels.shapes import box, cornell_box
from kernel_helpers import inside_emitting_sphere, sphere_in_furnace, trace_samples
from stats import mean_and_stderr

MODES = ("COSINE", "LECTURE", "NEE_MIS")


# ---------------------------------------------------------------- closed forms
def test_white_furnace_cosine_is_exact():
    """Albedo 1 in a uniform world of radiance L: every sample of every pixel is L."""
    result = render(sphere_in_furnace(albedo=1.0, world=2.0), RenderSettings(samples=4, mode="COSINE"))
    assert np.allclose(result.image[..., :3], 2.0, rtol=1e-5)
    assert np.all(result.image[..., 3] == 1.0)


@pytest.mark.parametrize("mode", MODES)
def test_white_furnace_every_pixel_is_l(mode):
    samples = trace_samples(sphere_in_furnace(albedo=1.0, world=2.0), RenderSettings(mode=mode), 64)
    mean, se = mean_and_stderr(samples, axis=0)  # per pixel and channel
    # COSINE: every sample is L up to float32 rounding (f / pdf of a Lambert lobe, each computed in its
    # own frame), so the mean must be too.
    noiseless = se < 1e-6
    assert np.allclose(mean[noiseless], 2.0, rtol=1e-5)
    z = np.abs(mean - 2.0)[~noiseless] / se[~noiseless]
    assert np.all(z < 5.0), z.max()  # 5 sigma over ~3000 pixel-channels


@pytest.mark.parametrize("mode", MODES)
def test_convex_sphere_of_albedo_half_renders_half_l(mode):
    """A convex surface sees only the world: it reflects albedo x L = 0.5 L."""
    samples = trace_samples(sphere_in_furnace(albedo=0.5, world=2.0), RenderSettings(mode=mode), 64)
    # Pixels well inside the sphere's outline (radius about 12 px around the centre of 32x32).
    yy, xx = np.mgrid[0:32, 0:32] + 0.5
    inside = ((yy - 16) ** 2 + (xx - 16) ** 2 < 9 ** 2).ravel()
    if mode in ("COSINE", "NEE_MIS"):
        # Exact up to float32 rounding at grazing angles: NEE_MIS samples no world of one colour as a light
        # (as Cycles), so its BSDF rays alone find it.
        assert np.allclose(samples[:, :, inside], 1.0, rtol=1e-4)
    else:
        m, se = mean_and_stderr(samples[:, 0, inside].mean(axis=1))
        assert abs(m - 1.0) < 4 * se, (m, se)
        assert se < 0.01
    assert np.allclose(samples[:, :, 0], 2.0)  # the corner pixel sees the world itself


@pytest.mark.parametrize("max_bounces", [0, 1, 4])
def test_inside_an_emitting_sphere_cosine_is_the_geometric_series(max_bounces):
    """Every path hits the sphere at every vertex: L = Le * sum_{k=0}^{S} albedo^k, S = max_bounces + 1."""
    rho, le = 0.5, 3.0
    expected = le * sum(rho ** k for k in range(max_bounces + 2))
    result = render(inside_emitting_sphere(rho, le), RenderSettings(samples=2, max_bounces=max_bounces, mode="COSINE"))
    assert np.allclose(result.image[..., :3], expected, rtol=1e-5)


@pytest.mark.parametrize("mode", ["LECTURE", "NEE_MIS"])
def test_inside_an_emitting_sphere_converges_to_the_series(mode):
    """LECTURE samples directions badly; NEE_MIS splits each bounce between light and BSDF sampling
    and plays Russian roulette: both must still average to the series."""
    rho, le, bounces = 0.5, 3.0, 5
    expected = le * sum(rho ** k for k in range(bounces + 2))
    samples = trace_samples(inside_emitting_sphere(rho, le), RenderSettings(mode=mode, max_bounces=bounces), 256)
    m, se = mean_and_stderr(samples[:, 0].ravel())
    assert abs(m - expected) < 4 * se, (m, se, expected)
    assert se < 0.01 * expected


# ---------------------------------------------------------------- the two estimators
def test_all_modes_agree_and_variance_falls_from_lecture_to_cosine_to_nee():
    scene = cornell_box(16, 16, light_size=1.0, light_radiance=6.0, wall_subdivisions=2, sphere_segments=8)
    stats = {}
    for mode in MODES:
        s = trace_samples(scene, RenderSettings(mode=mode, max_bounces=4), 256)
        lum = s.mean(axis=1)  # (samples, pixels)
        blocks = lum.reshape(len(lum), 4, 4, 4, 4).mean(axis=(2, 4)).reshape(len(lum), 16)
        stats[mode] = (*mean_and_stderr(blocks, axis=0), lum.var(axis=0).mean())
    m_c, se_c, var_c = stats["COSINE"]
    for mode in ("LECTURE", "NEE_MIS"):
        m, se, _ = stats[mode]
        z = np.abs(m_c - m) / np.sqrt(se_c ** 2 + se ** 2)
        assert np.all(z < 4.5), (mode, z)  # 16 blocks, 4.5 sigma each
    assert stats["NEE_MIS"][2] < var_c < stats["LECTURE"][2], {k: v[2] for k, v in stats.items()}
    assert m_c.mean() > 0.05  # the box is lit: the comparison is not between two black images


# ---------------------------------------------------------------- determinism and threads
def test_same_image_for_one_and_two_threads():
    scene = cornell_box(96, 64, wall_subdivisions=2, sphere_segments=8)
    settings = RenderSettings(samples=5, wave_size=2048, seed=3)
    a = render(scene, settings, threads=1).image
    b = render(scene, settings, threads=2).image
    assert np.array_equal(a, b)
    c = render(scene, RenderSettings(samples=5, wave_size=2048, seed=4), threads=2).image
    assert not np.array_equal(a, c)  # the user seed matters


def test_same_image_for_one_and_two_threads_with_layered_materials():
    """The closure mixture (lobe choice, delta glass, transparency) keeps images independent of threads."""
    from ember.kernels.scene import Closure, Materials, Param, Shader
    scene = cornell_box(64, 48, wall_subdivisions=2, sphere_segments=8)

    def principled(**inputs):
        return Shader((Closure("PRINCIPLED", tuple((k.replace("_", " "), Param.of(v)) for k, v in inputs.items())),))
    shaders = list(scene.materials.shaders)
    shaders[0] = principled(Base_Color=(0.7, 0.7, 0.7), Roughness=0.3, Coat_Weight=0.5, Alpha=0.8)
    shaders[4] = principled(Base_Color=(1, 1, 1), Transmission_Weight=1.0, Roughness=0.0)
    scene = dataclasses.replace(scene, materials=Materials(tuple(shaders)))
    settings = RenderSettings(samples=4, wave_size=2048, seed=5)
    a = render(scene, settings, threads=1).image
    assert np.array_equal(a, render(scene, settings, threads=2).image)
    assert np.isfinite(a).all() and a[..., :3].mean() > 0


def test_accel_chunked_queries_match_one_call():
    positions, _ = box((-1, -1, 0), (1, 1, 2), inward=True, subdivisions=4)
    rng = np.random.default_rng(0)
    n = 50_000
    o = rng.uniform(-0.9, 0.9, (n, 3)).astype(np.float32) + np.float32([0, 0, 1])
    d = rng.normal(size=(n, 3)).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = np.full(n, np.inf, np.float32)
    with Accel(positions, 1) as one, Accel(positions, 2) as two:
        h1, h2 = one.intersect(o, d, t), two.intersect(o, d, t)
        assert np.array_equal(h1.prim, h2.prim) and np.array_equal(h1.t, h2.t)
        assert np.all(h1.prim >= 0)  # inside a closed box every ray hits
        short = np.full(n, 0.05, np.float32)
        assert np.array_equal(one.occluded(o, d, short), two.occluded(o, d, short))
        assert np.array_equal(two.occluded(o, d, h1.t * 1.01), np.ones(n, bool))
        assert not two.occluded(o, d, h1.t * 0.99).any()


# ---------------------------------------------------------------- the progressive API
def test_tiles_progress_and_memory_bound(monkeypatch):
    scene = cornell_box(64, 48, wall_subdivisions=2, sphere_segments=8)
    largest = []
    original = integrator.trace

    def spy(tables, paths, *args, **kwargs):
        largest.append(len(paths))
        return original(tables, paths, *args, **kwargs)

    monkeypatch.setattr(integrator, "trace", spy)
    tiles, reports = [], []
    result = render(scene, RenderSettings(samples=6, wave_size=1000), threads=2,
                    on_tile=lambda film, r0, r1: tiles.append((r0, r1, film.samples_done)),
                    on_progress=lambda p: reports.append((p.samples_done, p.fraction)))
    assert max(largest) <= 1000  # no wave ever holds more paths than wave_size
    assert tiles[0][2] == 0 and tiles[-1][2] == 6
    assert reports[-1] == (6, 1.0)
    assert all(a[1] <= b[1] for a, b in zip(reports, reports[1:]))
    assert result.progress.paths == 64 * 48 * 6 and result.progress.rays_per_s > 0
    assert not result.stopped_early


def test_should_stop_keeps_a_finite_partial_image():
    scene = cornell_box(64, 64, wall_subdivisions=2, sphere_segments=8)
    tiles = []   # should_stop() is also polled between bounces: stop once two waves are in the film
    with Renderer(scene, threads=1) as renderer:
        result = renderer.render(RenderSettings(samples=50, wave_size=1024), should_stop=lambda: len(tiles) >= 2,
                                 on_tile=lambda film, r0, r1: tiles.append((r0, r1)))
    assert result.stopped_early and len(tiles) == 2
    assert np.isfinite(result.image).all()
    assert result.progress.samples_done == 0  # stopped inside the first pass
    assert result.image[..., 3].max() == 1.0  # but the rows it reached are there


def test_time_limit_stops_the_render():
    scene = cornell_box(32, 32, wall_subdivisions=2, sphere_segments=8)
    result = render(scene, RenderSettings(samples=10_000, time_limit_s=1e-6, wave_size=256), threads=1)
    assert result.stopped_early and result.progress.samples_done < 10_000


def test_a_wave_costs_a_fixed_part_and_its_paths_at_a_rate():
    """schedule.wave_cost: waves of 0.5 s tails and 100k paths/s besides give back those two, the first wave
    (which also pays the render's one-time costs) left out where there are others; the fixed part is the
    median tail, so one odd wave does not move it; the rate is the slowest recent wave's (the render waits
    for its slowest thread)."""
    from ember.kernels import schedule
    assert schedule.wave_cost([]) is None
    timed = [(n, 0.5 + n / 1e5, 0.5) for n in (50_000, 200_000, 400_000)]
    cost = schedule.wave_cost([(20_000, 3.0, 2.5)] + timed)
    assert cost.fixed == pytest.approx(0.5) and cost.rate == pytest.approx(1e5)
    assert cost.paths(1.5) == pytest.approx(100_000)
    assert cost.paths(0.2) == 0.0
    assert schedule.wave_cost([(20_000, 3.0, 2.5)]).fixed == pytest.approx(2.5)    # the first alone
    assert schedule.wave_cost(timed + [(100_000, 3.0, 2.0)]).fixed == pytest.approx(0.5)
    slow = [(100_000, 1.5, 0.5), (100_000, 2.5, 0.5), (100_000, 1.5, 0.5)]
    assert schedule.wave_cost([(1, 1.0, 0.5)] + slow).rate == pytest.approx(5e4)
    assert schedule.wave_cost([(1, 1.0, 0.5)] + slow + timed * 2).rate == pytest.approx(1e5)   # the last 4
    # Embree's share of a wave split over threads can make its tail most of it: the rate stays finite.
    assert np.isfinite(schedule.wave_cost([(1, 1.0, 0.5), (100, 1.0, 1.0)]).rate)


def test_passes_near_the_time_limit_take_the_samples_that_fit():
    """schedule.paced at 0.1 s + paths / 1M paths/s per wave, two threads, a 10k-pixel image: with 1.8 s left a
    pass takes two thirds of it; 1.1M paths a thread are over a wave_size of 2^20, so two waves a thread, each
    paying its 0.1 s: 1M paths a thread, 200 samples in four waves. Within six waves' fixed cost of the end the
    last pass takes 95% of the time left, one wave a thread; less than half a sample's paths gives 0."""
    from ember.kernels import schedule
    cost = schedule.WaveCost(0.1, 1e6)
    assert schedule.paced(cost, 1.8, 10_000, 2, 1 << 20) == (200, 500_000, 4)
    assert schedule.paced(cost, 1.8, 10_000, 2, 1 << 21) == (220, 1_100_000, 2)
    assert schedule.paced(cost, 0.5, 10_000, 2, 1 << 20) == (75, 375_000, 2)
    assert schedule.paced(cost, 0.2, 10_000, 2, 1 << 20) == (18, 90_000, 2)
    assert schedule.paced(cost, 0.102, 10_000, 2, 1 << 20)[0] == 0


def test_paced_waves_are_bounded_by_the_bytes_they_keep_per_path():
    """A paced pass's waves hold PACED_WAVE_BYTES of per-path buffers at most: radiance and alpha are 16 bytes a
    path, each pass's channels and Cryptomatte's ids and weight 4 more each; never fewer paths than the wave
    size, and the wave size itself where the settings set one (tests and tools that pin their waves)."""
    from ember.kernels import passes, schedule
    plain = RenderSettings()
    with_passes = RenderSettings(passes=("normal", "diffuse_direct", "mist"), cryptomatte=("object", "material"))
    assert passes.path_bytes(plain) == 16
    assert passes.path_bytes(with_passes) == 16 + 4 * (3 + 3 + 1) + 4 * 3
    assert schedule.paced_wave_size(plain, 1 << 20) == schedule.PACED_WAVE_BYTES // 16 > 1 << 20
    assert schedule.paced_wave_size(with_passes, 1 << 20) == schedule.PACED_WAVE_BYTES // 56
    assert schedule.paced_wave_size(plain, 1 << 24) == 1 << 24
    assert schedule.paced_wave_size(RenderSettings(wave_size=5000), 5000) == 5000


def test_a_pass_paced_to_a_time_limit_has_the_waves_it_is_given():
    """plan_pass with `waves`: all the samples asked in that many interleaved bands, more where a band would
    hold more pixels than band_pixels; the quick first pass is left as it is; an image of fewer rows than
    waves takes fewer samples, so that a wave stays within wave_size."""
    from ember.kernels.schedule import plan_pass
    assert plan_pass(160, 120, 1, 41, 1 << 20, True, 1 << 17, 2) == (40, [range(0, 120, 2), range(1, 120, 2)])
    spp, bands = plan_pass(160, 120, 1, 2, 1 << 20, True, 4800, 2)
    assert spp == 1 and len(bands) == 4 and sorted(r for b in bands for r in b) == list(range(120))
    assert plan_pass(160, 120, 0, 41, 1 << 20, True, 1 << 17, 2)[0] == 1
    spp, bands = plan_pass(32, 8, 1, 10_001, 4096, True, None, 40)     # 8 rows for 40 waves of 4,096 paths
    assert len(bands) == 8 and spp == 4096 // 32


def test_a_time_limited_render_starts_with_one_sample_and_paces_by_its_waves(monkeypatch):
    """Whatever quick_first_pass says, a time-limited render's first pass is one sample (its waves give
    the rate); later passes are cut to what the rate says fits; a render that runs out of time before
    its samples is stopped early."""
    from ember.kernels import schedule
    scene = cornell_box(32, 32, wall_subdivisions=2, sphere_segments=8)
    planned, paced = [], []
    plan, pace = schedule.plan_pass, schedule.paced
    monkeypatch.setattr(schedule, "plan_pass", lambda *a: planned.append(a) or plan(*a))
    monkeypatch.setattr(schedule, "paced", lambda *a: paced.append(a) or pace(*a))
    with Renderer(scene, threads=2) as renderer:
        result = renderer.render(RenderSettings(samples=10_000, time_limit_s=0.5, quick_first_pass=False))
        assert planned[0][5] is True and result.progress.samples_done >= 1
        assert result.stopped_early and result.progress.samples_done < 10_000
        assert paced and all(cost.rate > 0 and cost.fixed >= 0 for cost, *_ in paced)
        # The cost comes from the waves' own times; a paced pass has a wave a thread (or more, by wave_size).
        assert sum(paths for paths, *_ in renderer.crew.waves) == result.progress.paths
        assert all(0 <= tail <= seconds for _, seconds, tail, _ in renderer.crew.waves)
        assert renderer.crew.rate() > 0
        assert all(a[7] is not None and a[7] % 2 == 0 for a in planned[1:])
        # Its passes may take waves of more paths than the render's wave size (schedule.paced_wave_size).
        assert all(a[4] == schedule.paced_wave_size(RenderSettings(), renderer.wave_size(RenderSettings()))
                   > renderer.wave_size(RenderSettings()) for a in paced)
        planned.clear()
        renderer.render(RenderSettings(samples=4, quick_first_pass=False))
        assert planned[0][5] is False            # no limit: the plan as asked


def test_region_renders_the_same_pixels_as_the_full_frame():
    scene = cornell_box(40, 30, wall_subdivisions=2, sphere_segments=8)
    full = render(scene, RenderSettings(samples=3)).image
    part = render(scene, RenderSettings(samples=3, region=(5, 7, 25, 20))).image
    assert part.shape == (13, 20, 4)
    assert np.allclose(part, full[7:20, 5:25], rtol=1e-6, atol=1e-7)


def test_transparent_background_gives_alpha_zero_where_the_world_is_seen():
    scene = sphere_in_furnace(albedo=0.5, world=1.0)
    img = render(scene, RenderSettings(samples=2, transparent_background=True)).image
    assert img[0, 0, 3] == 0.0 and np.all(img[0, 0, :3] == 0.0)  # corner: world only
    assert img[16, 16, 3] == 1.0 and img[16, 16, 0] > 0          # centre: the sphere


def test_nonfinite_radiance_never_reaches_the_film(monkeypatch):
    scene = sphere_in_furnace(albedo=0.5, world=1.0)
    with Renderer(scene, 1) as renderer:
        def poisoned(dx, dy, dz, ray=None):
            out = np.ones((3, len(dx)), np.float32)
            out[:, dz > 0] = np.nan
            out[:, dz < -0.5] = np.inf
            return out
        monkeypatch.setattr(renderer.environment, "radiance", poisoned)
        result = renderer.render(RenderSettings(samples=4))
    assert np.isfinite(result.image).all()
    assert result.progress.nonfinite_paths > 0


def test_settings_are_checked():
    scene = sphere_in_furnace(0.5, 1.0)
    for bad, field in [(dict(mode="FAST"), "mode"), (dict(samples=0), "samples"),
                       (dict(max_bounces=-1), "max_bounces"), (dict(region=(0, 0, 99, 5)), "region"),
                       (dict(time_limit_s=float("nan")), "time_limit_s")]:
        with pytest.raises(ValueError, match=field):
            render(scene, RenderSettings(**bad))


def test_a_closed_renderer_is_freed_without_the_cycle_collector():
    import gc
    import weakref
    gc.disable()
    try:
        with Renderer(cornell_box(8, 8), 1) as renderer:
            renderer.render(RenderSettings(samples=1))
        ref = weakref.ref(renderer)
        del renderer
        assert ref() is None  # big scenes must not wait for gc to give their memory back
    finally:
        gc.enable()


def test_sample_clamping_limits_contributions_as_cycles_does():
    """Clamp Direct / Clamp Indirect (Cycles' film_clamp_light): every contribution's |R| + |G| + |B| is
    scaled to 3 x the limit. A white furnace sphere (world 1, albedo 0.5): direct light at the first hit
    sums to about 1.5 per sample. Clamping direct at 0.3 caps it, so the image falls; a clamp above every
    contribution changes nothing."""
    scene = sphere_in_furnace(albedo=0.5, world=1.0)
    with Renderer(scene, 1) as renderer:
        plain = renderer.render(RenderSettings(samples=4, max_bounces=4)).image
        same = renderer.render(RenderSettings(samples=4, max_bounces=4, clamp_direct=1e6, clamp_indirect=1e6)).image
        clamped = renderer.render(RenderSettings(samples=4, max_bounces=4, clamp_direct=0.3)).image
    np.testing.assert_array_equal(plain, same)
    sphere = plain[..., 0] < 0.99   # pixels on the sphere (the world reads exactly 1)
    assert clamped[..., 0][sphere].mean() < plain[..., 0][sphere].mean() - 0.05
    # The world seen by the camera is a direct contribution of 3 (1 per channel): clamped to 3 x 0.3.
    np.testing.assert_allclose(clamped[..., :3][~sphere].sum(axis=-1), 0.9, rtol=1e-5)
    # Indirect light is what reaches the first hit through two or more scatterings. Inside an emitting
    # sphere of albedo 0.5 (every path bounces on the wall): none with max_bounces 0, some with 2. (A clamp
    # above every contribution still makes the render a clamped one, which chooses lights as Cycles' tree does:
    # the same choices as the clamped render's.)
    inside = inside_emitting_sphere(albedo=0.5, radiance=1.0)
    with Renderer(inside, 1) as renderer:
        direct = renderer.render(RenderSettings(samples=4, max_bounces=0, clamp_indirect=1e30)).image
        still = renderer.render(RenderSettings(samples=4, max_bounces=0, clamp_indirect=1e-3)).image
        bounced = renderer.render(RenderSettings(samples=4, max_bounces=2, clamp_indirect=1e-3)).image
        free = renderer.render(RenderSettings(samples=4, max_bounces=2)).image
    np.testing.assert_array_equal(direct, still)
    assert bounced[..., 0].mean() < free[..., 0].mean() - 0.1
    with pytest.raises(ValueError, match="clamp_direct"):
        RenderSettings(clamp_direct=-1.0).validate(8, 8)


def test_adaptive_sampling_stops_converged_pixels_and_stays_unbiased():
    """A diffuse sphere in a white furnace (world 1) with its sky: the sky pixels are exact from the first
    sample and converge at the first check; the sphere's keep sampling until their noise is low. The
    adaptive image matches a non-adaptive one within the noise of their difference."""
    scene = sphere_in_furnace(albedo=0.5, world=1.0)
    settings = RenderSettings(samples=256, max_bounces=4, adaptive_threshold=0.01, adaptive_min_samples=16)
    with Renderer(scene, 1) as renderer:
        adaptive = renderer.render(settings)
        fixed = renderer.render(RenderSettings(samples=256, max_bounces=4, seed=1))
    counts = adaptive.film.pixel_samples
    sky = fixed.image[..., 0] > 0.999
    # Sky pixels away from the sphere stop at the first check; those beside it go on while it does (a
    # converged pixel next to an unconverged one keeps sampling, as Cycles' filter has it).
    open_sky = sky.copy()
    open_sky[1:] &= sky[:-1]
    open_sky[:-1] &= sky[1:]
    open_sky[:, 1:] &= sky[:, :-1]
    open_sky[:, :-1] &= sky[:, 1:]
    assert counts[open_sky].max() == 16 and counts[~sky].max() > 16
    assert adaptive.progress.paths == counts.sum() < 256 * counts.size
    assert not adaptive.stopped_early
    # Unbiased: the sphere's mean against the fixed render's, within 4 standard errors of the difference
    # (per-pixel noise from the adaptive film's odd/even halves, and the fixed film's own).
    diff = adaptive.image[..., :3][~sky].mean() - fixed.image[..., :3][~sky].mean()
    n = adaptive.film.pixel_samples[~sky].astype(float)[:, None]
    half_gap = np.abs(adaptive.film.sums[..., :3][~sky] / n - 2 * adaptive.film.half[~sky] / n)
    se = np.sqrt((half_gap ** 2).mean() / (~sky).sum() * 2)
    assert abs(diff) < 4 * se + 1e-4, (diff, se)
    with pytest.raises(ValueError, match="adaptive_min_samples"):
        RenderSettings(adaptive_min_samples=-1).validate(8, 8)
