"""bench/corpus.py: its statistics on synthetic renders with known noise, and the whole tool on .blend files
built here (one Ember matches, one with a setting and a node Ember lacks, one that is not a .blend)."""
from __future__ import annotations

import os
import subprocess
import sys

import bpy
import numpy as np
import pytest

from bench import corpus
from tests.bpy_helpers import diffuse_material, mesh_object, new_scene

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


# ---------------------------------------------------------------- statistics on synthetic renders
def synthetic_renders(rng, image, sigma, count=2):
    """count renders of `image` (H, W) with independent Gaussian pixel noise sigma, as (count, H, W, 4)."""
    noisy = image[None] + rng.normal(0.0, sigma, (count, *image.shape))
    return np.repeat(noisy[..., None], 4, axis=-1).astype(np.float32)


def test_same_image_reads_as_noise():
    rng = np.random.default_rng(7)
    image = np.linspace(0.2, 1.0, 320 * 320).reshape(320, 320)
    result = corpus.compare(synthetic_renders(rng, image, 0.05), synthetic_renders(rng, image, 0.05))
    # 1600 blocks: the sample 90th percentile of |N(0, 1)| (1.645) has a standard error of about 0.04.
    assert abs(result.p90_z - 1.645) < 0.2
    assert abs(result.p90_over_cycles_noise - 1.645) < 0.2
    assert abs(result.noise_ratio - 1.0) < 0.05   # 320 * 320 pixel variances
    assert not result.beyond_noise


def test_noisier_ember_is_not_a_difference():
    rng = np.random.default_rng(8)
    image = np.full((160, 160), 0.5)
    result = corpus.compare(synthetic_renders(rng, image, 0.05), synthetic_renders(rng, image, 0.15))
    assert abs(result.noise_ratio - 3.0) < 0.15
    assert result.p90_over_cycles_noise > 3.0    # against Cycles' noise alone the difference looks large
    assert not result.beyond_noise               # against the difference's own noise it is noise


def test_a_bias_in_part_of_the_frame_is_beyond_noise():
    rng = np.random.default_rng(9)
    image = np.full((160, 160), 0.5)
    biased = image.copy()
    biased[:, :40] *= 1.05   # a quarter of the frame 5% brighter; a block's mean has noise 0.05 / 8 = 0.6%
    result = corpus.compare(synthetic_renders(rng, image, 0.05), synthetic_renders(rng, biased, 0.05))
    assert result.beyond_noise
    assert result.block_z[:, :5].mean() > 3.0 and abs(result.block_z[:, 5:].mean()) < 0.2


def test_plain_background_blocks_are_left_out():
    rng = np.random.default_rng(10)
    image = np.full((80, 80), 0.3)
    cycles, ember = synthetic_renders(rng, image, 0.02), synthetic_renders(rng, image, 0.02)
    cycles[:, :, 40:], ember[:, :, 40:] = 0.7, 0.7   # noise-free and equal in both: half the blocks
    result = corpus.compare(cycles, ember)
    assert (result.blocks_counted, result.blocks_equal) == (50, 50)
    assert abs(result.p90_z - 1.645) < 0.6       # 50 blocks


def test_noise_free_images_that_differ_by_rounding_agree():
    """A plain grey world in both engines (hinhesh/Blender seaproject.blend): no noise at all, and a float32 rounding
    apart. The whole image's standard error is floored as the blocks' noise is (NOISE_FLOOR_RELATIVE); before, a
    1e-7 difference over a zero standard error read beyond noise. A 1% difference still does."""
    grey = np.full((2, 16, 16, 4), 0.25, np.float32)
    assert not corpus.compare(grey, grey * np.float32(1 + 2e-7)).beyond_noise
    assert corpus.compare(grey, grey * np.float32(1.01)).beyond_noise


def test_black_images_compare_without_nan():
    black = np.zeros((2, 16, 16, 4), np.float32)
    result = corpus.compare(black, black)
    assert (result.mean_relative, result.noise_ratio, result.beyond_noise) == (0.0, 1.0, False)
    lit = black.copy()
    lit[:, :8] = 0.5
    assert corpus.compare(black, lit).beyond_noise


def test_a_collection_of_repositories_is_searched_with_recursive(tmp_path):
    """-r: the .blend files in the subfolders too (each repository's files beside its images), named by their path so
    that two main.blend stay apart, and --only matching the file's own name; without it, the folder's own files."""
    from bench.corpus import blend_files, build_parser, file_label
    for rel in ("top.blend", "owner+repo/main.blend", "owner+repo/blend/main.blend", "other+repo/scene.BLEND",
                "other+repo/notes.txt"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_bytes(b"")
    folder = str(tmp_path)
    assert [file_label(f, folder) for f in blend_files(folder)] == ["top.blend"]
    found = [file_label(f, folder) for f in blend_files(folder, recursive=True)]
    assert found == ["other+repo/scene.BLEND", "owner+repo/blend/main.blend", "owner+repo/main.blend", "top.blend"]
    assert [file_label(f, folder) for f in blend_files(folder, "main", True)] == ["owner+repo/blend/main.blend",
                                                                                 "owner+repo/main.blend"]
    assert build_parser().parse_args([folder, "-r"]).recursive


def test_reports_are_read_from_a_renders_output():
    stdout = ("Fra:1 Mem:10M | Sample 1/4\n"
              "Ember | Frame 1 | Warning: Material 'A': Wireframe node 'W' is not supported\n"
              "Ember | Frame 1 | Warning: Material 'A': Wireframe node 'W' is not supported\n"
              "Ember | Frame 1 | Warning: Light 'L' of type X is not supported\n"
              "Error: Ember: invalid scene data: no triangles\n")
    warnings, errors = corpus.parse_reports(stdout)
    assert warnings == ["Material 'A': Wireframe node 'W' is not supported",
                        "Light 'L' of type X is not supported"]
    assert errors == ["Ember: invalid scene data: no triangles"]


# ---------------------------------------------------------------- settings
def test_cycles_settings_are_mapped_or_listed_as_lacking():
    from bench import corpus_render
    scene = new_scene(16, 16)
    mesh_object("Smooth", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1, 2)], smooth=True)
    mesh_object("Flat", [(0, 0, 1), (1, 0, 1), (0, 1, 1)], [(0, 1, 2)])
    scene.cycles.sample_clamp_indirect, scene.cycles.blur_glossy = 3.0, 0.25
    scene.cycles.use_light_tree, scene.cycles.min_light_bounces = False, 2
    mapped = corpus_render.map_cycles_settings(scene)
    assert (scene.ember.sample_clamp_indirect, scene.ember.blur_glossy) == (3.0, 0.25)
    assert mapped["sample_clamp_indirect"] == 3.0 and mapped["max_bounces"] == scene.cycles.max_bounces
    lacking = corpus_render.lacking_settings(scene)
    assert mapped["diffuse_bounces"] == scene.cycles.diffuse_bounces == scene.ember.diffuse_bounces
    assert "min_light_bounces=2" in lacking and not any(
        item.split("=")[0] in corpus_render.SHARED_SETTINGS or key in item for item in lacking
        for key in ("exposure", "fast_gi", "cull", "use_light_tree", "light_sampling_threshold"))
    bpy.data.objects["Smooth"].shadow_terminator_shading_offset = 0.2   # rendered now: not lacking
    assert not any("shadow_terminator" in item for item in corpus_render.lacking_settings(scene))


# ---------------------------------------------------------------- the tool on .blend files
def build_scene(different: bool):
    """A floor and a box under an area lamp, with Cycles settings Ember takes over; where different, one it lacks
    (Min Light Bounces, which only changes the noise) and a second lamp of negative power over the box (Cycles
    subtracts its light; Ember leaves it out, warning); and a material Ember warns about
    (a UV Along Stroke node, which only Freestyle line styles read, on a value multiplied by 0: nothing changes in
    Cycles)."""
    scene = new_scene(48, 32)
    floor = diffuse_material("Floor", (0.7, 0.7, 0.7))
    mesh_object("Floor", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], [(0, 1, 2, 3)], floor)
    box = diffuse_material("Box", (0.8, 0.3, 0.2))
    stroke, times = box.node_tree.nodes.new("ShaderNodeUVAlongStroke"), box.node_tree.nodes.new("ShaderNodeMath")
    times.operation, times.inputs[1].default_value = "MULTIPLY", 0.0
    box.node_tree.links.new(stroke.outputs["UV"], times.inputs[0])
    box.node_tree.links.new(times.outputs[0], next(n for n in box.node_tree.nodes if n.type.startswith("BSDF")).inputs["Roughness"])
    verts = [(x, y, z) for z in (0, 1.5) for y in (-0.7, 0.7) for x in (-0.7, 0.7)]
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    mesh_object("Box", verts, faces, box)
    lamp = bpy.data.lights.new("Lamp", "AREA")
    lamp.energy, lamp.size = 400.0, 2.0
    lamp_ob = bpy.data.objects.new("Lamp", lamp)
    lamp_ob.location = (1.0, -1.5, 4.0)
    scene.collection.objects.link(lamp_ob)
    scene.cycles.sample_clamp_indirect = 5.0
    scene.cycles.pixel_filter_type = "GAUSSIAN"
    if different:
        dark = bpy.data.lights.new("Dark", "AREA")
        dark.energy, dark.size = -200.0, 1.0
        dark_ob = bpy.data.objects.new("Dark", dark)
        dark_ob.location = (0.0, 0.0, 2.5)
        scene.collection.objects.link(dark_ob)
        scene.cycles.min_light_bounces = 2
    return scene


@pytest.fixture(scope="module")
def corpus_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("corpus")
    for name, different in (("same.blend", False), ("lacking.blend", True), ("nocamera.blend", False)):
        scene = build_scene(different)
        if name == "nocamera.blend":   # an asset saved without a camera: the tool adds one framing it
            bpy.data.objects.remove(scene.camera)
        bpy.ops.wm.save_as_mainfile(filepath=str(folder / name), copy=True)
    (folder / "broken.blend").write_bytes(b"not a blend file")
    out = folder / "out"
    run = subprocess.run([sys.executable, os.path.join(ROOT, "bench", "corpus.py"), str(folder), "-o", str(out),
                          "--samples", "8", "--long-side", "48", "--threads", "1", "--timeout", "120"],
                         capture_output=True, text=True, timeout=600)
    return run, out


def table_row(stdout: str, name: str) -> list[str]:
    line = next(line for line in stdout.splitlines() if line.startswith(f"| {name} |"))
    return [cell.strip() for cell in line.strip("|").split("|")]


def test_the_tool_runs_every_file_and_tables_them(corpus_run):
    run, out = corpus_run
    assert run.returncode == 0, run.stderr
    same, lacking, broken = (table_row(run.stdout, n) for n in ("same.blend", "lacking.blend", "broken.blend"))
    assert same[-1] == "within noise", run.stdout
    assert same[7] == "1"                                    # the UV Along Stroke warning, once for both renders
    assert lacking[-1] == "beyond noise" and "min_light_bounces=2" in lacking[8], run.stdout
    assert float(lacking[4]) > 5 and "has negative power" in run.stdout   # the box and floor under it: far off
    assert broken[-1].startswith("failed: Cycles:") and "Ember:" in broken[-1]
    assert "sample_clamp_indirect=5.0" in run.stdout and "pixel_filter_type=GAUSSIAN" in run.stdout
    assert "UV Along Stroke node" in run.stdout and "is not supported" in run.stdout
    assert (out / "summary.md").read_text().count("| same.blend |") == 1
    assert table_row(run.stdout, "nocamera.blend")[-1] == "within noise", run.stdout
    assert run.stdout.count("saved without a camera") == 1


def test_side_by_side_pngs(corpus_run):
    run, out = corpus_run
    assert sorted(os.listdir(out)) == ["lacking.png", "nocamera.png", "same.png", "summary.md"]
    image = bpy.data.images.load(str(out / "same.png"))
    try:
        width, height = image.size
        pixels = np.empty(width * height * 4, np.float32)
        image.pixels.foreach_get(pixels)
    finally:
        bpy.data.images.remove(image)
    assert (width, height) == (3 * 48 + 2 * 2, 32)
    panels = pixels.reshape(height, width, 4)[..., :3]
    cycles, ember = panels[:, :48], panels[:, 50:98]
    assert cycles.mean() > 0.05 and abs(ember.mean() / cycles.mean() - 1) < 0.1
