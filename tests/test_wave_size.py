"""The automatic wave size (RenderSettings.wave_size None): WAVE_SIZE paths traced at once, twice as many when
the materials mix lobes, and waves WAVE_SPAN times that, whose paths start as others end; the image is the
same whatever the wave size and the paths traced at once, to float rounding (where a path falls in its
batch can change a value by one float32 step: 8 of 6,144 values at 48x32, 4 samples, waves of 512 against
4,096 paths)."""
from __future__ import annotations

import os
import sys

import numpy as np

from bpy_helpers import export_current

from ember.kernels import Renderer, RenderSettings, integrator, schedule
from ember.kernels.schedule import LAYERED_WAVE_SIZE, WAVE_SIZE, WAVE_SPAN, plan_pass

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench import scenes  # noqa: E402


def _renderer(build) -> Renderer:
    build()
    return Renderer(export_current().scene, threads=2)


def test_layered_materials_get_larger_waves_and_the_same_image():
    with _renderer(lambda: scenes.materials_scene(64, 48)) as renderer:
        assert renderer.layered
        assert renderer.wave_size(RenderSettings()) == WAVE_SPAN * LAYERED_WAVE_SIZE
        assert renderer.live_paths(RenderSettings()) == LAYERED_WAVE_SIZE
        assert renderer.wave_size(RenderSettings(wave_size=1000)) == 1000
        assert renderer.live_paths(RenderSettings(wave_size=1000)) == 1000
        # 64 x 48 pixels x 256 samples: after the first pass the two sizes take other samples per pass
        # (at 96 samples both took all 95 left in one pass, and the test could not fail).
        assert plan_pass(64, 48, 1, 256, LAYERED_WAVE_SIZE) != plan_pass(64, 48, 1, 256, WAVE_SIZE)
        automatic = renderer.render(RenderSettings(samples=256, seed=4)).image
        fixed = renderer.render(RenderSettings(samples=256, seed=4, wave_size=WAVE_SIZE)).image
    np.testing.assert_allclose(automatic, fixed, rtol=1e-6, atol=1e-7)


def test_diffuse_scenes_keep_the_default_waves():
    with _renderer(lambda: scenes.cornell_scene(32, 32)) as renderer:
        # Its unused default material row is a Principled BSDF: only the materials triangles use count.
        assert renderer.shading.mixes_lobes and not renderer.layered
        assert renderer.wave_size(RenderSettings()) == WAVE_SPAN * WAVE_SIZE
        assert renderer.live_paths(RenderSettings()) == WAVE_SIZE


def test_background_renders_start_with_full_passes():
    """quick_first_pass False (background mode): the first pass is a full one, every wave at once; the image
    is the same sum of the same samples, in another order (float rounding)."""
    assert plan_pass(256, 256, 0, 32, LAYERED_WAVE_SIZE)[0] == 1
    spp, bands = plan_pass(256, 256, 0, 32, LAYERED_WAVE_SIZE, quick_first=False)
    assert spp == 16 and len(bands) == 4
    # The renders' first passes (32 x 24 pixels, 40 samples, waves of 4096 paths): 1 sample, or 21 in 4 waves.
    assert plan_pass(32, 24, 0, 40, 4096)[0] == 1
    spp, bands = plan_pass(32, 24, 0, 40, 4096, quick_first=False)
    assert spp == 21 and len(bands) == 4
    with _renderer(lambda: scenes.materials_scene(32, 24)) as renderer:
        quick = renderer.render(RenderSettings(samples=40, seed=2, wave_size=4096))
        full = renderer.render(RenderSettings(samples=40, seed=2, wave_size=4096, quick_first_pass=False))
    assert quick.progress.paths == full.progress.paths == 32 * 24 * 40
    np.testing.assert_allclose(full.image, quick.image, rtol=1e-6, atol=1e-7)


def test_the_bands_of_a_pass_interleave_and_the_image_stays(monkeypatch):
    """A pass's bands interleave (band j of n: rows j, j + n, ...) so that its waves cost alike: every row is
    in one band, no band is over the wave size; the image, its passes, Cryptomatte and adaptive sampling's
    counts are those of one band of every row, to float rounding."""
    for width, height, done, total, size in ((256, 256, 0, 32, LAYERED_WAVE_SIZE), (160, 120, 1, 128, 1 << 18),
                                             (64, 48, 0, 40, 4096), (300, 7, 0, 64, 1024)):
        spp, bands = plan_pass(width, height, done, total, size, quick_first=False)
        n = len(bands)
        assert sorted(r for band in bands for r in band) == list(range(height))
        assert all(band == range(j, height, n) for j, band in enumerate(bands))
        assert all(len(band) * width * spp <= max(size, width * spp) for band in bands)
    assert len(plan_pass(32, 24, 0, 40, 4096, quick_first=False)[1]) > 1
    settings = dict(samples=40, seed=2, passes=("normal", "diffuse_direct", "depth"), cryptomatte=("object",),
                    adaptive_threshold=0.05, adaptive_min_samples=8)
    plan, planned = schedule.plan_pass, []
    monkeypatch.setattr(schedule, "plan_pass", lambda *a: planned.append(plan(*a)) or planned[-1])
    with _renderer(lambda: scenes.materials_scene(32, 24)) as renderer:
        many = renderer.render(RenderSettings(wave_size=4096, **settings))
        assert sum(len(bands) > 1 for _, bands in planned) > len(planned) // 2   # the 1-sample pass is one band
        planned.clear()
        monkeypatch.setattr(schedule, "MIN_WAVE_PATHS", 1 << 30)   # no pass cut into waves for two cores
        one = renderer.render(RenderSettings(wave_size=1 << 22, **settings))
        assert all(bands == [range(24)] for _, bands in planned)
    np.testing.assert_allclose(many.image, one.image, rtol=1e-6, atol=1e-7)
    np.testing.assert_array_equal(many.film.pixel_samples, one.film.pixel_samples)
    assert 0 < np.count_nonzero(many.film.pixel_samples < 40) < 32 * 24   # adaptive sampling stopped some
    for name in settings["passes"]:
        np.testing.assert_allclose(many.film.aux[name], one.film.aux[name], rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(many.film.crypto["object"].ids, one.film.crypto["object"].ids)


def test_paths_start_as_others_end_and_the_image_stays(monkeypatch):
    """A wave of more paths than are traced at once starts them batch by batch, beside the long paths of
    the batches before (the glass of the materials scene keeps paths bouncing): no bounce traces more than
    the live paths, more than one batch starts, and the image is the one of tracing the wave at once, to
    float rounding, and the same for one and two threads."""
    sizes, starts = [], []
    original_step, original_start = integrator.step, integrator.start_paths

    def step(tables, wave, state, rays, **kwargs):
        sizes.append(len(state))
        return original_step(tables, wave, state, rays, **kwargs)

    def start(tables, wave, paths, begin, end):
        starts.append((begin, end, len(paths)))
        return original_start(tables, wave, paths, begin, end)

    paths = 48 * 32 * 16
    settings = RenderSettings(samples=16, seed=5, wave_size=paths // 4, max_bounces=12)
    scenes.materials_scene(48, 32)
    scene = export_current().scene
    with Renderer(scene, threads=1) as renderer:   # (worker processes would not see the patches)
        at_once = renderer.render(settings).image
        monkeypatch.setattr(schedule, "LAYERED_WAVE_SIZE", 1500)
        monkeypatch.setattr(integrator, "step", step)
        monkeypatch.setattr(integrator, "start_paths", start)
        batched = renderer.render(settings).image
    sizes_started = [end - begin for begin, end, _ in starts]
    assert sum(sizes_started) == paths and max(sizes) <= 1500 and len(starts) > paths // 1500
    # A batch inside a wave (neither its first nor its remainder) that starts while paths are going fills
    # only what they leave.
    inside = [end - begin for begin, end, n in starts if 0 < begin and end < n]
    assert inside and min(inside) < max(sizes_started)
    np.testing.assert_allclose(batched, at_once, rtol=1e-6, atol=1e-7)
    # The batched render above is the one-thread image (one thread has no worker processes).
    with Renderer(scene, threads=2, processes=False) as two:
        assert np.array_equal(batched, two.render(settings).image)


def test_a_batch_starts_from_what_the_whole_wave_would():
    """WavePaths makes what each path starts from (pixel, sample, random numbers, strata) as its batch
    starts: the same values as made for the whole wave, for batches of whole pixels and of parts of one.
    The wave's band is every third row from row 12 (interleaved bands): its pixels are on those rows."""
    from ember.kernels.paths import WavePaths
    scenes.cornell_scene(48, 32)
    camera = export_current().scene.camera
    pixels = np.flatnonzero(np.random.default_rng(3).random(48 * 5) < 0.7)  # an adaptive wave's pixels
    for pattern in ("AUTOMATIC", "SOBOL_BURLEY"):
        settings = RenderSettings(samples=40, seed=9, sampling_pattern=pattern)
        paths = WavePaths(settings, camera, 0, range(12, 27, 3), 48, pixels, 8, 6)
        rng, row, col, strata = paths.batch(0, len(paths))
        assert len(row) == len(paths) == 6 * len(pixels)
        assert np.array_equal(row, 12 + 3 * (np.repeat(pixels, 6) // 48))
        assert np.array_equal(col, np.repeat(pixels, 6) % 48)
        for lo, hi in ((0, 12), (12, 19), (19, 300), (300, len(paths))):
            b_rng, b_row, b_col, b_strata = paths.batch(lo, hi)
            assert np.array_equal(b_row, row[lo:hi]) and np.array_equal(b_col, col[lo:hi])
            assert np.array_equal(b_rng.x, rng.x[lo:hi]) and np.array_equal(b_rng.y, rng.y[lo:hi])
            for mine, whole in zip(b_strata, strata):
                assert np.array_equal(mine, whole if np.size(whole) == 1 else whole[lo:hi])
