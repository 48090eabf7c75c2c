"""Issue 10, "Reliability": one test (or a few) per item, through the real entry points (the command
line in a subprocess, or bpy), each of which failed before the fix. bench/reliability.py runs the wider
catalog of unusual input as a table."""
import math
import os
import signal
import subprocess
import sys
import tracemalloc

import bpy
import numpy as np
import pytest

from bpy_helpers import (add_camera, compare_to_cycles, diffuse_material, load_exr, mesh_object, new_scene,
                         render_to_array, set_world)
from test_cli import ROOT, ember

CLI_CODE = ("import sys; sys.path.insert(0, %r); from bench.common import import_ember; import_ember(); "
            "import runpy; sys.argv = ['ember'] + sys.argv[1:]; runpy.run_module('ember', run_name='__main__')" % ROOT)


def save_copy(path) -> str:
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True)
    return str(path)


def small_scene(width=32, height=24):
    scene = new_scene(width, height)
    mesh_object("Floor", [(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)], [(0, 1, 2, 3)], diffuse_material("Floor"))
    set_world(scene, color=(0.3, 0.4, 0.5))
    scene.render.engine = "EMBER"
    scene.ember.samples = 2
    return scene


def no_traceback(run):
    assert "Traceback" not in run.stderr and "RuntimeWarning" not in run.stderr, run.stderr


# ---------------------------------------------------------------- 1. default output of the command line
def test_default_output_follows_blenders_path_rules(tmp_path):
    """No -o: the file's output path, '//' next to the .blend, the frame number appended (or in place of
    '#'), the extension and format of the file, directories created, every frame of --frames or -a."""
    scene = small_scene()
    scene.ember.use_denoising = False   # the paths are under test, not the pixels
    scene.render.filepath = "//renders/frame_"
    png = save_copy(tmp_path / "shot.blend")
    run = ember("render", png, "--frames", "1-2")
    assert run.returncode == 0, run.stderr
    no_traceback(run)
    assert sorted(os.listdir(tmp_path / "renders")) == ["frame_0001.png", "frame_0002.png"]

    scene.render.filepath = "//exr/f_###_x"
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.frame_start, scene.frame_end = 3, 4
    exr = save_copy(tmp_path / "anim.blend")
    run = ember("render", exr, "-a")
    assert run.returncode == 0, run.stderr
    assert sorted(os.listdir(tmp_path / "exr")) == ["f_003_x.exr", "f_004_x.exr"]
    assert load_exr(str(tmp_path / "exr" / "f_003_x.exr")).shape == (24, 32, 4)


def test_unwritable_default_output_fails_before_rendering(tmp_path):
    scene = small_scene()
    (tmp_path / "taken").write_text("a file where a directory should be")
    scene.render.filepath = str(tmp_path / "taken" / "frames" / "f_")
    path = save_copy(tmp_path / "shot.blend")
    run = ember("render", path)
    assert run.returncode == 1
    assert run.stderr.strip().splitlines() == [
        f"ember: error: cannot write to '{tmp_path / 'taken' / 'frames'}': '{tmp_path / 'taken'}' is a file, "
        f"not a directory"]
    assert "Sample" not in run.stdout  # nothing was rendered


# ---------------------------------------------------------------- 2. light selection and far geometry
def lamp_on_floor(floor_half_size: float):
    scene = new_scene(40, 40)
    h = floor_half_size
    mesh_object("Floor", [(-h, -h, 0), (h, -h, 0), (h, h, 0), (-h, h, 0)], [(0, 1, 2, 3)], diffuse_material("Floor"))
    bpy.ops.mesh.primitive_cube_add(size=0.6, location=(0.4, 0.3, 0.3))
    bpy.context.active_object.data.materials.append(diffuse_material("Box", (0.7, 0.3, 0.2)))
    add_camera(scene, (0, -4, 2.5), (0, 0, 0.2))
    set_world(scene, color=(0.05, 0.05, 0.05))  # a dim sky: its share of NEE grew with the floor
    data = bpy.data.lights.new("Lamp", "POINT")
    data.energy, data.shadow_soft_size = 100.0, 0.1
    lamp = bpy.data.objects.new("Lamp", data)
    lamp.location = (-0.5, -0.5, 1.5)
    scene.collection.objects.link(lamp)
    return scene


@pytest.mark.parametrize("half_size", [500.0, 50_000.0])
def test_point_lamp_over_a_one_kilometre_floor_matches_cycles(half_size):
    """Before, the world's share of light samples grew with the scene's bounding sphere: at 1 km the
    lamp got 1 sample in 10^5 and rendered as fireflies. At 100 km the rays' offset, then scaled with the
    scene, lifted rays 10 cm off every surface."""
    compare_to_cycles(lamp_on_floor(half_size), samples=64, max_bounces=2)


def test_light_choice_does_not_depend_on_far_geometry():
    from ember.engine.export import export_scene
    from ember.kernels import Renderer
    pmfs = []
    for half in (2.0, 50_000.0):
        scene = lamp_on_floor(half)
        set_world(scene, hdri="forest.exr", strength=0.05)  # a world of one colour is no light for NEE
        exported = export_scene(bpy.context.evaluated_depsgraph_get())
        with Renderer(exported.scene, threads=1) as renderer:
            pmfs.append(renderer.lights.select_pmf.copy())
    assert np.array_equal(pmfs[0], pmfs[1]) and pmfs[0][0] == 0.5


# ---------------------------------------------------------------- 3. overlapping lights
def test_overlapping_soft_point_lights_match_cycles():
    """36 point lights of radius 0.1 m, 0.08 m apart: their spheres overlap. A BSDF ray meets them one after
    the other, each a transparent bounce, and ends at the last one allowed, as in Cycles."""
    scene = new_scene(40, 40)
    mesh_object("Floor", [(-3, -3, 0), (3, -3, 0), (3, 3, 0), (-3, 3, 0)], [(0, 1, 2, 3)], diffuse_material("Floor"))
    add_camera(scene, (0, -2.0, 2.0), (0, 0, 0.2))
    set_world(scene, color=(0, 0, 0))
    data = bpy.data.lights.new("Lamp", "POINT")
    data.energy, data.shadow_soft_size = 20.0, 0.1
    for i in range(6):
        for j in range(6):
            ob = bpy.data.objects.new(f"Lamp{i}{j}", data)
            ob.location = (0.08 * i - 0.2, 0.08 * j - 0.2, 0.6)
            scene.collection.objects.link(ob)
    # A BSDF ray passes through several lights, each a transparent bounce, as in Cycles (both engines at the
    # oracle's limit of 2).
    compare_to_cycles(scene, samples=64, max_bounces=2)


def test_light_proxies_find_what_testing_every_light_finds():
    """The Embree proxies against the exhaustive test, with lights on a grid (coplanar proxy faces
    were skipped at first), overlapping spheres, and coplanar overlapping area lights."""
    from ember.kernels import Lights, LIGHT_KINDS
    from ember.kernels.lights import LightProxies
    from test_lights import sampler_for
    rng = np.random.default_rng(3)
    grid = [(0.08 * i, 0.08 * j, 0.6) for i in range(8) for j in range(8)]
    panels = [(rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), 1.0) for _ in range(12)]
    k = len(grid) + len(panels)
    kind = np.int32([LIGHT_KINDS["POINT"]] * len(grid) + [LIGHT_KINDS["RECT"], LIGHT_KINDS["DISK"]] * 6)
    lights = Lights(kind=kind, position=np.float32(grid + panels), frame=np.float32([np.eye(3)] * k),
                    radiance=np.ones((k, 3), np.float32), radius=np.float32([0.1] * len(grid) + [0] * 12),
                    size=np.float32([(0, 0)] * len(grid) + [(0.4, 0.3)] * 12), spot_cos=np.float32([(1, 0)] * k),
                    sun_half_angle=np.zeros(k, np.float32))
    sampler = sampler_for(lights)
    assert isinstance(sampler.proxy, LightProxies)
    n = 4000
    o = np.c_[rng.uniform(-1, 1, n), rng.uniform(-1, 1, n), np.zeros(n)].astype(np.float32)
    d = rng.normal(size=(n, 3))
    d[:, 2] = np.abs(d[:, 2])
    d = (d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    args = (*o.T, *d.T)
    t_max = np.full(n, np.inf, np.float32)

    def hits(ray, light):
        t, _, _ = sampler.hit_pairs(ray, light, *(a[ray] for a in args))
        keep = t > 0
        return set(zip(ray[keep].tolist(), light[keep].tolist()))
    found = hits(*sampler.proxy.candidates(*args, t_max))
    everything = hits(np.tile(np.arange(n), k), np.repeat(np.arange(k), n))
    assert found == everything
    assert {light for _, light in found} == set(range(k))  # every light, area lights too, is met


# ---------------------------------------------------------------- 4. interrupting
def test_ctrl_c_keeps_finished_frames_saves_nothing_else_and_exits_130(tmp_path):
    scene = small_scene(320, 240)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=(0, 0, 0.5))
    scene.ember.use_denoising = False
    scene.ember.samples = 1                          # keyframed: frame 1 has one sample, frames 2 and 3 have 400
    scene.ember.keyframe_insert("samples", frame=1)
    scene.ember.samples = 400
    scene.ember.keyframe_insert("samples", frame=2)
    path = save_copy(tmp_path / "slow.blend")
    out = tmp_path / "f_#.png"
    proc = subprocess.Popen([sys.executable, "-c", CLI_CODE, "render", path, "-o", str(out), "--frames", "1-3"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    lines = []
    for line in proc.stdout:
        lines.append(line)
        if "saved" in line:
            break
    # interrupt frame 2 while it is still exporting or rendering
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    stdout = "".join(lines) + stdout
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr
    assert len(stderr.strip().splitlines()) == 1 and stderr.startswith("ember: interrupted"), stderr
    assert (tmp_path / "f_1.png").exists() and not (tmp_path / "f_3.png").exists()
    saved = [f for f in os.listdir(tmp_path) if f.endswith(".png")]
    assert all(f"saved {tmp_path / f}" in stdout for f in saved)  # every file there was complete
    assert not [f for f in os.listdir(tmp_path) if f.endswith(".partial")]


def test_esc_is_heard_during_export_and_scene_build(monkeypatch):
    """FinalRender.should_stop is Esc (engine.test_break, always False headless) or Ctrl-C on the
    command line; it is made True here at two moments."""
    import ember.engine.export.geometry as geometry_export
    import ember.engine.session as session
    from ember.kernels import renderer as renderer_module
    scene = small_scene()
    for i in range(20):
        mesh_object(f"Tri{i}", [(i, 0, 0), (i + 1, 0, 0), (i, 0, 1)], [(0, 1, 2)])
    reads, builds = [], []
    read_mesh, accel = geometry_export.read_mesh, renderer_module.Accel
    monkeypatch.setattr(geometry_export, "read_mesh", lambda m: reads.append(1) or read_mesh(m))
    monkeypatch.setattr(renderer_module, "Accel", lambda *a, **k: builds.append(1) or accel(*a, **k))

    monkeypatch.setattr(session.FinalRender, "should_stop", lambda self: True)
    render_to_array(scene, "EMBER", 2)
    assert reads == [] and builds == []  # Esc before the first object was read

    # Esc pressed once the export is done: the build stops before Embree's BVH.
    export = session.export_scene
    pressed = []
    monkeypatch.setattr(session, "export_scene", lambda *a, **k: (export(*a, **k), pressed.append(1))[0])
    monkeypatch.setattr(session.FinalRender, "should_stop", lambda self: bool(pressed))
    image = render_to_array(scene, "EMBER", 2)
    assert len(reads) > 0 and builds == [] and np.all(image == 0)


def test_time_limit_always_completes_the_first_pass():
    scene = small_scene(200, 160)
    scene.ember.time_limit = 1e-4
    image = render_to_array(scene, "EMBER", 64)
    assert np.all(image[..., 3] == 1.0) and np.all(image[..., :3].sum(axis=2) > 0)  # no empty rows


# ---------------------------------------------------------------- 5. large frames
def test_memory_is_the_film_plus_a_bounded_working_set(monkeypatch):
    """NumPy memory traced during a render (Blender's own result is not counted): the film's bytes per
    pixel (49 with adaptive sampling, the default; 32 without) plus a working set that does not grow with
    the frame. Rows reach Blender only as they change; the display is forced on every wave here, as in
    the worst case of an interactive render."""
    from ember.kernels.film import ADAPTIVE_BYTES_PER_PIXEL
    import ember.engine.session as session
    monkeypatch.setattr(session, "_background", lambda: False)
    monkeypatch.setattr(session, "DISPLAY_INTERVAL_S", 0.0)
    scene = small_scene()
    scene.ember.samples, scene.ember.sampling_mode = 1, "COSINE"
    # The film and the waves: the denoiser's own passes and buffers are measured by bench/denoise.py.
    scene.ember.use_denoising = False
    # One thread: one wave in flight, so the peak does not depend on how two threads' waves interleave
    # (up to 20 MB run to run with waves of 131,072 paths, enough to fake a per-pixel buffer below).
    scene.render.threads_mode, scene.render.threads = "FIXED", 1
    extra = {}
    for size in (1024, 2048):
        scene.render.resolution_x = scene.render.resolution_y = size
        tracemalloc.start()
        try:
            bpy.ops.render.render()
            extra[size] = tracemalloc.get_traced_memory()[1] - ADAPTIVE_BYTES_PER_PIXEL * size * size
        finally:
            tracemalloc.stop()
    # The working set is the waves in flight, so: within docs/performance.md's bound at both sizes (192 MB for two
    # threads' waves of 131,072 paths, so half of it for one; 56 and 62 MB measured), and no buffer of 8 or
    # more bytes per pixel beyond the film (before: 64 bytes per pixel more).
    assert max(extra.values()) < 96e6, extra
    assert extra[2048] - extra[1024] < 8 * (2048 ** 2 - 1024 ** 2), extra


# ---------------------------------------------------------------- 6. smaller ones
@pytest.mark.parametrize("args, message", [
    (["--seed", str(2 ** 40)], "--seed must be from 0 to 2147483647"),
    (["--seed", "-7"], "--seed must be from 0 to 2147483647"),
    (["--resolution", "1x1"], "--resolution must be from 4x4"),
    (["--max-bounces", "-1"], "--max-bounces must be from 0"),
])
def test_out_of_range_options_are_rejected_with_the_range(args, message):
    run = ember("render", *args, timeout=120)
    assert run.returncode == 2
    assert len(run.stderr.strip().splitlines()) == 1 and message in run.stderr, run.stderr


@pytest.mark.parametrize("place, message", [
    ("/proc/ember/out.png", "cannot create the directory '/proc/ember' in '/proc': its file system does not allow"),
    ("{tmp}/file/out.png", "cannot write to '{tmp}/file': '{tmp}/file' is a file, not a directory"),
])
def test_unwritable_output_messages_name_the_real_obstacle(tmp_path, place, message):
    (tmp_path / "file").write_text("x")
    run = ember("render", "-o", place.format(tmp=tmp_path), timeout=120)
    assert run.returncode == 1
    assert run.stderr.strip() == "ember: error: " + message.format(tmp=tmp_path) or \
        message.format(tmp=tmp_path) in run.stderr, run.stderr


def test_odd_lights_and_materials_warn_in_order_and_render_finite(tmp_path):
    """A BSDF in a material's Volume output, a negative and a 1e38 W light, a missing image with a Blender-relative
    path and a 1e30-scaled object: a warning each, printed before 'saved', absolute paths, a finite
    image, no NumPy warnings."""
    scene = small_scene()
    fog = bpy.data.materials.new("Fog")
    tree = fog.node_tree
    tree.nodes.clear()
    volume = tree.nodes.new("ShaderNodeBsdfDiffuse")
    tree.links.new(volume.outputs[0], tree.nodes.new("ShaderNodeOutputMaterial").inputs["Volume"])
    mesh_object("Cloud", [(-0.5, 0, 0.2), (0.5, 0, 0.2), (0, 0, 1)], [(0, 1, 2)], fog)
    for name, energy in (("Negative", -100.0), ("Blinding", 1e38)):
        data = bpy.data.lights.new(name, "POINT")
        data.energy, data.shadow_soft_size = energy, 0.1
        ob = bpy.data.objects.new(name, data)
        ob.location = (0.5, -0.5, 1.5)
        scene.collection.objects.link(ob)
    image = bpy.data.images.new("Missing", 4, 4)
    image.source, image.filepath = "FILE", "//../nowhere/x.png"
    mesh_object("Poster", [(-1, 1, 0), (1, 1, 0), (0, 1, 1)], [(0, 1, 2)], diffuse_material("Poster", image=image))
    huge = mesh_object("Huge", [(-1, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1, 2)])
    huge.scale = (1e30, 1e30, 1e30)
    (tmp_path / "scenes").mkdir()
    path = save_copy(tmp_path / "scenes" / "odd.blend")
    run = ember("render", path, "-o", str(tmp_path / "odd.exr"))
    assert run.returncode == 0, run.stderr
    no_traceback(run)
    out = run.stdout
    for text in ("Material 'Fog': Diffuse BSDF 'Diffuse BSDF' is not a volume shader", "Light 'Negative' has negative power",
                 "Light 'Blinding' is too bright", f"({tmp_path / 'nowhere' / 'x.png'})"):
        assert text in out and out.index(text) < out.index("saved"), out
    assert "//" not in out
    assert np.isfinite(load_exr(str(tmp_path / "odd.exr"))).all()


# ---------------------------------------------------------------- 7. the benchmark's reference renders
def test_benchmark_reference_render_shows_progress(tmp_path, monkeypatch, capfd):
    from bench import vs_cycles
    monkeypatch.setattr(vs_cycles, "RESULTS_DIR", str(tmp_path))
    monkeypatch.setattr(vs_cycles, "PROGRESS_INTERVAL_S", 0.0)
    bpy.app.handlers.render_stats.append(vs_cycles.record_stats)
    try:
        cfg = vs_cycles.Config(threads=2, max_bounces=2)
        scene = vs_cycles.build_scene("cornell", 16, cfg)
        vs_cycles.reference(scene, "cornell", 8, cfg, refresh=True)
    finally:
        bpy.app.handlers.render_stats.remove(vs_cycles.record_stats)
    captured = capfd.readouterr()
    assert "rendering the Cycles reference for cornell" in captured.out
    assert "reference cornell, half 2/2: sample" in captured.err


# ---------------------------------------------------------------- 8. export paths no test guarded
def test_light_temperature_reaches_the_render():
    """A sun with use_temperature at 3000 K over a white plane: the pixel's colour is the blackbody
    colour Cycles renders (tests/test_lights_parity.py), within its 1%."""
    from test_lights_parity import CYCLES_BLACKBODY
    scene = new_scene(8, 8)
    add_camera(scene, (0, 0, 3), (0, 0, 0))
    mesh_object("Plane", [(-5, -5, 0), (5, -5, 0), (5, 5, 0), (-5, 5, 0)], [(0, 1, 2, 3)],
                diffuse_material("White", (1.0, 1.0, 1.0)))
    set_world(scene, color=(0, 0, 0))
    data = bpy.data.lights.new("Sun", "SUN")
    data.energy, data.angle, data.use_temperature, data.temperature = math.pi, 0.0, True, 3000.0
    scene.collection.objects.link(bpy.data.objects.new("Sun", data))
    rgb = render_to_array(scene, "EMBER", 1, max_bounces=0)[..., :3].reshape(-1, 3).mean(axis=0)
    expected = np.array(CYCLES_BLACKBODY[3000])
    assert np.allclose(rgb, expected, rtol=0.01), (rgb, expected)


def test_smooth_normals_under_non_uniform_scale_use_the_inverse_transpose():
    """A smooth sphere scaled (1, 1, 0.25): the exported shading normals are Blender's corner normals
    through the inverse transpose of the object's matrix (as Cycles transforms them), not the matrix."""
    from ember.engine.export import export_scene
    new_scene(8, 8)
    bpy.ops.mesh.primitive_uv_sphere_add(segments=8, ring_count=6, radius=1.0)
    ob = bpy.context.active_object
    bpy.ops.object.shade_smooth()
    ob.scale = (1.0, 1.0, 0.25)
    ob.rotation_euler = (0.3, 0.2, 0.1)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    mesh = ob.evaluated_get(depsgraph).data
    mesh.calc_loop_triangles()
    loops = np.array([t.loops[:] for t in mesh.loop_triangles])
    corner = np.array([n.vector[:] for n in mesh.corner_normals])[loops]           # (T, 3, 3) object space
    linear = np.array(ob.matrix_world)[:3, :3]
    expected = corner @ np.linalg.inv(linear)                                      # n^T M^-1 = (M^-T n)^T
    expected /= np.linalg.norm(expected, axis=2, keepdims=True)
    normals = export_scene(depsgraph).scene.normals.astype(np.float64)
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    assert normals.shape == expected.shape and np.allclose(normals, expected, atol=1e-5)


# ---------------------------------------------------------------- 9. a failed save
def ember_with_file_size_limit(limit_bytes, *args):
    """The command line with RLIMIT_FSIZE: every write past `limit_bytes` fails (EFBIG; Python ignores
    SIGXFSZ), a write error injected under Blender's own image writer, as a full disk gives it."""
    import resource

    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, resource.RLIM_INFINITY))
    return subprocess.run([sys.executable, "-c", CLI_CODE, *args], capture_output=True, text=True, cwd=ROOT,
                          timeout=300, preexec_fn=limit)


def one_error_line(run) -> str:
    no_traceback(run)
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ember: error: "), run.stderr
    return lines[0]


def no_partial_files(directory) -> None:
    assert not [f for f in os.listdir(directory) if f.endswith(".partial")], os.listdir(directory)


def test_a_failed_write_keeps_the_earlier_frame_and_names_the_lost_ones(tmp_path):
    """Blender's writer logs a failed write and carries on: the truncated file was renamed over the frame
    and reported saved (exit 0). Now the frame before it stays, the render stops there, exit 1."""
    scene = small_scene(320, 240)
    # Written uncompressed, every file is the size of its pixels whatever the image (1.2 MB as EXR, 300 KB as PNG),
    # far over the limits below; the denoiser would only add seconds.
    scene.render.image_settings.exr_codec = "NONE"
    scene.render.image_settings.compression = 0
    scene.ember.use_denoising = False
    path = save_copy(tmp_path / "scene.blend")
    out = tmp_path / "out"
    out.mkdir()
    good = b"an earlier render of frame 1"
    (out / "f_1.exr").write_bytes(good)
    run = ember_with_file_size_limit(60_000, "render", path, "-o", str(out / "f_#.exr"), "--frames", "1-3",
                                     "--samples", "2")
    assert run.returncode == 1, run.stderr
    line = one_error_line(run)
    assert f"frame 1: cannot save {out / 'f_1.exr'}: " in line and "File too large" in line, line
    assert line.endswith("the existing file is kept; no frame was saved; frames 1-3 were not"), line
    assert (out / "f_1.exr").read_bytes() == good and sorted(os.listdir(out)) == ["f_1.exr"]
    assert "saved" not in run.stdout

    run = ember_with_file_size_limit(20_000, "render", path, "-o", str(out / "p.png"), "--samples", "1")
    assert run.returncode == 1 and "cannot save" in one_error_line(run)
    assert sorted(os.listdir(out)) == ["f_1.exr"]


def test_a_full_disk_loses_no_frame_and_reports_the_lost_ones(tmp_path, small_disk):
    """Uncompressed 160x120 RGBA float frames (310 KB) onto 1 MB: three fit. Before, the next ones were
    truncated or empty, printed 'saved', exit 0; rendering frame 1 again replaced it with a broken file."""
    from ember.engine.image_files import written_file_problem
    scene = small_scene(160, 120)
    scene.render.image_settings.exr_codec = "NONE"   # every frame the same size
    scene.ember.use_denoising = False                 # it would only add time
    path = save_copy(tmp_path / "scene.blend")
    run = ember("render", path, "-o", str(small_disk / "f_#.exr"), "--frames", "1-6", "--samples", "1")
    assert run.returncode == 1, run.stderr
    line = one_error_line(run)
    assert f"frame 4: cannot save {small_disk / 'f_4.exr'}: no space left on device" in line, line
    assert line.endswith("frames 1-3 were saved; frames 4-6 were not"), line
    saved = sorted(os.listdir(small_disk))
    assert saved == ["f_1.exr", "f_2.exr", "f_3.exr"]
    assert all(written_file_problem(str(small_disk / f), "OPEN_EXR") is None for f in saved)
    assert load_exr(str(small_disk / "f_3.exr")).shape == (120, 160, 4)

    first = (small_disk / "f_1.exr").read_bytes()
    run = ember("render", path, "-o", str(small_disk / "f_#.exr"), "--frames", "1", "--samples", "2")
    assert run.returncode == 1
    assert one_error_line(run).endswith("the existing file is kept")
    assert (small_disk / "f_1.exr").read_bytes() == first
    no_partial_files(small_disk)


# ---------------------------------------------------------------- 10. more threads than cores
def test_threads_are_capped_at_the_usable_cores(monkeypatch):
    """A renderer asked for 1000 threads (Blender allows 1024) runs the cores' worth: its wave threads and
    slots, and the worker processes it starts (threads - 1; before, 999 for a small scene)."""
    from ember.engine.export import export_scene
    from ember.kernels import Renderer
    from ember.kernels import workers
    from ember.kernels.accel import usable_cores
    small_scene()
    started = []
    monkeypatch.setattr(workers.WorkerSet, "start", lambda self, count, *a: started.append(count) or False)
    exported = export_scene(bpy.context.evaluated_depsgraph_get())
    with Renderer(exported.scene, threads=1000, processes=True) as renderer:
        assert renderer.accel.threads == usable_cores()
        assert started == ([usable_cores() - 1] if usable_cores() > 1 else [])


def test_blender_thread_count_beyond_the_cores_warns_and_renders_with_the_cores(monkeypatch, capfd):
    """Render Properties > Performance > Threads: Fixed, 1000 (through F12's path, bpy.ops.render.render)."""
    import ember.engine.session as session
    from ember.kernels.accel import usable_cores
    asked = []
    build = session.Renderer
    monkeypatch.setattr(session, "Renderer", lambda scene, threads=0, **k: asked.append(threads) or build(
        scene, threads=threads, **k))
    image = render_to_array(small_scene(), "EMBER", 2, threads=1000)   # threads_mode FIXED
    assert asked == [usable_cores()] and np.all(image[..., 3] == 1.0)
    out = capfd.readouterr().out
    assert (f"Warning: 1000 render threads asked for (Performance > Threads), but {usable_cores()} core"
            in out), out


def test_cli_threads_beyond_the_cores_say_so_on_one_line(tmp_path):
    """--threads 1000 on a process allowed one core (taskset): one line says so, and the render runs with 1."""
    small_scene()
    path = save_copy(tmp_path / "scene.blend")
    run = subprocess.run([sys.executable, "-c", CLI_CODE, "render", path, "-o", str(tmp_path / "f.png"),
                          "--threads", "1000"], capture_output=True, text=True, cwd=ROOT, timeout=300,
                         preexec_fn=lambda: os.sched_setaffinity(0, {min(os.sched_getaffinity(0))}))
    assert run.returncode == 0, run.stderr
    no_traceback(run)
    notes = [line for line in run.stdout.splitlines() if "--threads" in line]
    assert notes == ["Ember | Warning: --threads 1000 is more than the 1 core usable here: rendering with 1 "
                     "threads"], run.stdout
    assert "worker process" not in run.stdout and (tmp_path / "f.png").exists()


# ---------------------------------------------------------------- 11. long output names
def test_output_names_up_to_the_file_systems_limit_are_written(tmp_path):
    """A 255-byte file name is valid; the hidden temporary name it is written through is shortened to fit
    (before, '.NAME.XXXXXXXX.partial' went past 255 bytes: the frame rendered, then a traceback)."""
    small_scene()
    path = save_copy(tmp_path / "scene.blend")
    name = "a" * (255 - len("_1.png")) + "_#.png"
    run = ember("render", path, "-o", str(tmp_path / name), "--samples", "1", "--frames", "1")
    assert run.returncode == 0, run.stderr
    no_traceback(run)
    assert (tmp_path / name.replace("#", "1")).exists() and len(name) == 255
    no_partial_files(tmp_path)


@pytest.mark.parametrize("make, message", [
    (lambda tmp: tmp / ("b" * 249 + "_#.png"), "is 256 bytes: the file system of "),  # frame 10 makes it 256
    (lambda tmp: tmp.joinpath(*["d" * 200] * 5) / "f_#.png", "bytes: Blender writes paths of up to 1023"),
])
def test_output_names_too_long_fail_before_rendering(tmp_path, make, message):
    small_scene()
    path = save_copy(tmp_path / "scene.blend")
    before = sorted(str(p) for p in tmp_path.rglob("*"))
    run = ember("render", path, "-o", str(make(tmp_path)), "--samples", "1", "--frames", "9-10")
    assert run.returncode == 1
    assert message in one_error_line(run)
    assert "Sample" not in run.stdout   # nothing rendered
    assert sorted(str(p) for p in tmp_path.rglob("*")) == before   # no file, no directory, no stray partial


# ---------------------------------------------------------------- 12. signals
# The command line in its own session (process group), with a hook that sends signals to that group from a
# known point of the render: deterministic, and the signals travel as a farm manager's or a terminal's do.
SIGNAL_HOOK = """
import os, signal
from ember.engine import frame_save, session
from ember.kernels.accel import usable_cores
SIGNALS, FRAME, POINT = {signals!r}, {frame!r}, {point!r}
sent = []

def send():
    if not sent:
        sent.append(1)
        for sig in SIGNALS:
            os.killpg(0, sig)   # each handled (in this, the main thread) before the next is sent

progress = session.FinalRender._on_progress
def on_progress(self, p, line):
    progress(self, p, line)
    if POINT == "render" and self.scene.frame_current == FRAME and p.workers >= min(1, usable_cores() - 1):
        send()   # while worker processes render this frame's waves
session.FinalRender._on_progress = on_progress

check = frame_save.written_file_problem
def written_file_problem(path, file_format):
    if POINT == "save" and f"_{{FRAME}}." in path:
        send()   # Blender has written the temporary file; it is not renamed yet
    return check(path, file_format)
frame_save.written_file_problem = written_file_problem
"""


def ember_signalled(tmp_path, signals, frame, point, frames="1-3", samples=64):
    """The command line on a scene whose samples are keyframed: 1 before `frame` (the earlier frames only need to
    be saved), `samples` from it on."""
    scene = small_scene(320, 240)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=(0, 0, 0.5))
    scene.ember.use_denoising = False
    scene.ember.samples = 1
    scene.ember.keyframe_insert("samples", frame=frame - 1)
    scene.ember.samples = samples
    scene.ember.keyframe_insert("samples", frame=frame)
    path = save_copy(tmp_path / "scene.blend")
    hook = SIGNAL_HOOK.format(signals=[int(s) for s in signals], frame=frame, point=point)
    code = CLI_CODE.replace("import_ember(); ", "import_ember()\n" + hook + "\n")
    out = tmp_path / "out"
    run = subprocess.run([sys.executable, "-c", code, "render", path, "-o", str(out / "f_#.png"), "--frames", frames],
                         capture_output=True, text=True, cwd=ROOT, timeout=300, start_new_session=True)
    return run, out


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_a_signal_to_the_process_group_mid_frame_stops_cleanly(tmp_path, sig):
    """SIGTERM and SIGHUP (a farm manager, a closed terminal) as Ctrl-C: the frame in progress is dropped, the
    earlier one kept, exit 128 + the signal, one line; the worker processes, which get it too, stay quiet
    (before: SIGTERM killed the command outright, a worker printed a BrokenPipeError or KeyboardInterrupt
    traceback)."""
    run, out = ember_signalled(tmp_path, [sig], frame=2, point="render")
    assert run.returncode == 128 + sig, run.stderr
    no_traceback(run)
    name = "" if sig == signal.SIGINT else f" by {signal.Signals(sig).name}"
    assert run.stderr.strip() == f"ember: interrupted{name} during frame 2: nothing saved for it; frame 1 was saved"
    assert sorted(os.listdir(out)) == ["f_1.png"]


def test_a_signal_during_a_save_saves_that_frame_and_stops(tmp_path):
    run, out = ember_signalled(tmp_path, [signal.SIGTERM], frame=2, point="save", samples=1)
    assert run.returncode == 143, run.stderr
    no_traceback(run)
    assert run.stderr.strip() == "ember: interrupted by SIGTERM after frame 2: frames 1-2 were saved"
    assert sorted(os.listdir(out)) == ["f_1.png", "f_2.png"]   # whole: renamed after the check, not before


@pytest.mark.parametrize("point", ["render", "save"])
def test_a_second_signal_quits_at_once_without_a_traceback_or_a_partial_file(tmp_path, point):
    """Two Ctrl-C in a row (before: Blender printed the engine's KeyboardInterrupt traceback)."""
    run, out = ember_signalled(tmp_path, [signal.SIGINT, signal.SIGINT], frame=2, point=point,
                               samples=64 if point == "render" else 1)
    assert run.returncode == 130, run.stderr
    no_traceback(run)
    assert run.stderr.strip() == "ember: SIGINT again: quit at once; the frame in progress is not saved"
    assert sorted(os.listdir(out)) == ["f_1.png"]   # no f_2.png, no .f_2.png.*.partial


def test_sigterm_from_outside_once_a_frame_is_saved(tmp_path):
    """As a farm manager sends it: to the process group, from another process, at no chosen point."""
    scene = small_scene(320, 240)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=(0, 0, 0.5))
    # The signal comes once frame 1 is saved, long before frame 2 would be denoised: the denoiser would only add time.
    scene.ember.use_denoising = False
    path = save_copy(tmp_path / "scene.blend")
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-c", CLI_CODE, "render", path, "-o", str(out / "f_#.png"), "--frames",
                             "1-40", "--samples", "8"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            cwd=ROOT, start_new_session=True)
    try:
        for line in proc.stdout:
            if "saved" in line:
                os.killpg(proc.pid, signal.SIGTERM)
                break
        _, stderr = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 143, stderr
    assert "Traceback" not in stderr and len(stderr.strip().splitlines()) == 1, stderr
    assert stderr.startswith("ember: interrupted by SIGTERM "), stderr
    files = sorted(os.listdir(out))
    assert "f_1.png" in files and len(files) < 40 and not [f for f in files if not f.endswith(".png")]
