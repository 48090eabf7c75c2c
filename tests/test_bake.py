"""Baking with Ember (engine/bake.py, kernels/bake.py) against Cycles' bake of the same object, texel by texel:
every bake type Blender's bake operator offers, pass filters, normal spaces and swizzles, Selected to Active
with a cage extrusion, View From Active Camera, margins, a colour attribute target; errors reported; and the
command line's bake.

Data bakes (Position, Normal, UV, Roughness, Emit, Environment, Diffuse Color) are compared at one sample,
where both engines look at each texel's centre: equal to float rounding. Light bakes are compared within their
noise: each engine bakes four times with different seeds; their spread estimates each texel's variance (of
their mean, 3 degrees of freedom), and every 8 x 8 block's summed difference must lie within 4.5 standard
errors, the whole image's within 4 (its variance also estimated from the bakes' whole sums: the errors of
neighbouring texels are not independent).
"""
import os
import subprocess
import sys

import bpy
import numpy as np
import pytest

from bpy_helpers import configure_engine, export_current, new_scene, set_world

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SIZE = 32
SEEDS = (5, 17, 29, 41)


# ---------------------------------------------------------------- scenes
def _image_node_material(name, image):
    """A material whose active node is an Image Texture holding `image`: where Blender's bake writes."""
    mat = bpy.data.materials.new(name)
    tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    mat.node_tree.nodes.active = tex
    return mat


def _object_with_image(ob, name):
    image = bpy.data.images.new(name, SIZE, SIZE, float_buffer=True)
    ob.data.materials.clear()
    ob.data.materials.append(_image_node_material(name, image))
    return image


def _textured_principled(mat):
    """Principled BSDF with UV-checkered base colour and roughness, bumps and some emission."""
    tree = mat.node_tree
    bsdf = tree.nodes["Principled BSDF"]
    coord = tree.nodes.new("ShaderNodeTexCoord")
    checker = tree.nodes.new("ShaderNodeTexChecker")
    checker.inputs["Scale"].default_value = 4.0
    checker.inputs["Color1"].default_value = (0.8, 0.3, 0.2, 1.0)
    checker.inputs["Color2"].default_value = (0.2, 0.6, 0.8, 1.0)
    tree.links.new(coord.outputs["UV"], checker.inputs["Vector"])
    tree.links.new(checker.outputs["Color"], bsdf.inputs["Base Color"])
    ramp = tree.nodes.new("ShaderNodeMapRange")
    ramp.inputs["To Min"].default_value, ramp.inputs["To Max"].default_value = 0.25, 0.7
    tree.links.new(checker.outputs["Fac"], ramp.inputs["Value"])
    tree.links.new(ramp.outputs["Result"], bsdf.inputs["Roughness"])
    bsdf.inputs["Emission Color"].default_value = (1.0, 0.6, 0.3, 1.0)
    bsdf.inputs["Emission Strength"].default_value = 0.3
    wave = tree.nodes.new("ShaderNodeTexWave")   # bumps: the Normal bake then averages the closures' normals
    wave.inputs["Scale"].default_value = 3.0
    bump = tree.nodes.new("ShaderNodeBump")
    bump.inputs["Strength"].default_value = 0.4
    bump.inputs["Distance"].default_value = 0.1
    tree.links.new(wave.outputs["Fac"], bump.inputs["Height"])
    tree.links.new(bump.outputs["Normal"], bsdf.inputs["Normal"])


@pytest.fixture(scope="module")
def plane_scene():
    """A checkered, slightly glossy, faintly emitting plane under a sun and a blue-grey sky, a cube over it (its
    shadow and occlusion), and a rough glass plane beside it (Transmission)."""
    scene = new_scene(SIZE, SIZE)
    set_world(scene, color=(0.3, 0.4, 0.5), strength=1.0)
    bpy.ops.mesh.primitive_plane_add(size=2.0, location=(0.2, 0.1, 0.0), rotation=(0.15, -0.1, 0.3))
    plane = bpy.context.active_object
    plane.name = "Plane"
    image = _object_with_image(plane, "plane bake")
    _textured_principled(plane.data.materials[0])
    bpy.ops.mesh.primitive_cube_add(size=0.6, location=(0.3, 0.2, 0.8))
    cube = bpy.context.active_object
    grey = bpy.data.materials.new("grey")
    grey.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.5, 0.5, 0.5, 1.0)
    cube.data.materials.append(grey)
    bpy.ops.mesh.primitive_plane_add(size=1.5, location=(3.0, 0.0, 0.5), rotation=(0.6, 0.0, 0.0))
    glass = bpy.context.active_object
    glass.name = "Glass"
    glass_image = _object_with_image(glass, "glass bake")
    b = glass.data.materials[0].node_tree.nodes["Principled BSDF"]
    b.inputs["Transmission Weight"].default_value = 1.0
    b.inputs["Roughness"].default_value = 0.3
    b.inputs["Base Color"].default_value = (0.9, 0.8, 0.6, 1.0)
    bpy.ops.object.light_add(type="SUN", location=(0, 0, 5))
    sun = bpy.context.active_object
    sun.data.energy = 3.0
    sun.rotation_euler = (0.4, 0.2, 0.0)
    return scene, {"Plane": (plane, image), "Glass": (glass, glass_image)}


def bake(scene, target, image, engine, kind, samples=1, seed=SEEDS[0], sources=(), **options):
    """Bake `kind` into target's image with CYCLES or EMBER: (H, W, 4) float32, row 0 at the bottom."""
    configure_engine(scene, engine, samples, seed=seed, max_bounces=3)
    view_layer = bpy.context.view_layer
    for ob in view_layer.objects:
        ob.select_set(False)
    for ob in (target, *sources):
        ob.select_set(True)
    view_layer.objects.active = target
    options.setdefault("margin", 0)
    bpy.ops.object.bake(type=kind, use_clear=True, use_selected_to_active=bool(sources), **options)
    pixels = np.empty(image.size[0] * image.size[1] * 4, np.float32)
    image.pixels.foreach_get(pixels)
    return pixels.reshape(image.size[1], image.size[0], 4)


def assert_within_noise(cycles, ember, channels=3, block=8, z_block=4.5, z_whole=4.0) -> dict:
    """Bakes of each engine with different seeds agree within their noise (module docstring)."""
    c, e = (np.stack(bakes)[..., :channels].astype(np.float64) for bakes in (cycles, ember))
    mean_c, mean_e = c.mean(axis=0), e.mean(axis=0)
    var = c.var(axis=0, ddof=1) / len(c) + e.var(axis=0, ddof=1) / len(e)
    h, w = mean_c.shape[:2]

    def blocks(x):
        return x.reshape(h // block, block, w // block, block, channels).sum(axis=(1, 3))
    diff, spread = blocks(mean_e - mean_c), np.sqrt(blocks(var))
    z = np.where(spread > 0, diff / np.where(spread > 0, spread, 1.0), np.where(np.abs(diff) < 1e-5, 0.0, np.inf))
    # Both engines' errors are blue noise: smaller than independent within a block, somewhat larger over the
    # whole image. The whole image's variance is the larger of the texels' sum and its own over the bakes.
    sums = [x.sum(axis=(1, 2, 3)) for x in (c, e)]
    whole_var = max(var.sum(), sum(x.var(ddof=1) / len(x) for x in sums))
    whole = (mean_e - mean_c).sum() / np.sqrt(whole_var)
    report = {"mean_cycles": mean_c.mean(), "mean_ember": mean_e.mean(), "max_block_z": float(np.abs(z).max()),
              "whole_z": float(whole)}
    assert mean_c.mean() > 1e-3, f"Cycles baked an almost black image: {report}"
    assert np.abs(z).max() < z_block, report
    assert abs(whole) < z_whole, report
    return report


def parity(scene, target, image, kind, samples, sources=(), channels=3, **options) -> dict:
    pairs = [[bake(scene, target, image, engine, kind, samples, seed, sources, **options) for seed in SEEDS]
             for engine in ("CYCLES", "EMBER")]
    return assert_within_noise(*pairs, channels=channels)


# ---------------------------------------------------------------- data bakes: equal at one sample
@pytest.mark.parametrize("kind, options", [
    ("POSITION", {}),
    ("NORMAL", {}),
    ("NORMAL", {"normal_space": "OBJECT", "normal_r": "NEG_Y", "normal_g": "POS_X", "normal_b": "NEG_Z"}),
    ("UV", {}),
    ("ROUGHNESS", {}),
    ("EMIT", {}),
    ("ENVIRONMENT", {}),
    ("DIFFUSE", {"pass_filter": {"COLOR"}}),
])
def test_data_bakes_equal_cycles(plane_scene, kind, options):
    scene, objects = plane_scene
    plane, image = objects["Plane"]
    cycles = bake(scene, plane, image, "CYCLES", kind, **options)
    ember = bake(scene, plane, image, "EMBER", kind, **options)
    assert np.abs(cycles).max() > 1e-3, f"Cycles baked nothing for {kind}"
    if kind == "NORMAL":
        assert cycles[..., :3].std(axis=(0, 1)).max() > 0.01   # the bumps show
    np.testing.assert_allclose(ember, cycles, atol=2e-4, rtol=1e-4)


# ---------------------------------------------------------------- light bakes: within noise
@pytest.mark.parametrize("kind, options", [
    ("COMBINED", {}),
    ("COMBINED", {"pass_filter": {"DIRECT", "DIFFUSE", "EMIT"}}),
    ("COMBINED", {"pass_filter": {"INDIRECT", "GLOSSY", "DIFFUSE"}}),
    ("DIFFUSE", {"pass_filter": {"DIRECT", "INDIRECT"}}),
    ("GLOSSY", {"pass_filter": {"DIRECT", "INDIRECT"}}),
    ("GLOSSY", {"view_from": "ACTIVE_CAMERA"}),
    ("AO", {}),
    ("SHADOW", {}),
])
def test_light_bakes_match_cycles(plane_scene, kind, options):
    scene, objects = plane_scene
    plane, image = objects["Plane"]
    view_from = options.pop("view_from", "ABOVE_SURFACE")
    scene.render.bake.view_from = view_from
    try:
        parity(scene, plane, image, kind, 16, channels=4 if kind == "COMBINED" else 3, **options)
    finally:
        scene.render.bake.view_from = "ABOVE_SURFACE"


def test_transmission_bake_matches_cycles(plane_scene):
    scene, objects = plane_scene
    glass, image = objects["Glass"]
    parity(scene, glass, image, "TRANSMISSION", 16)


# ---------------------------------------------------------------- Selected to Active, margins, colour attributes
@pytest.fixture
def high_to_low():
    """A low plane (the active object, with the image) under a smooth high sphere that pokes through it."""
    scene = new_scene(SIZE, SIZE)
    set_world(scene, color=(0.3, 0.4, 0.5), strength=1.0)
    bpy.ops.mesh.primitive_plane_add(size=2.0)
    low = bpy.context.active_object
    image = _object_with_image(low, "low bake")
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.7, location=(0.1, 0.0, -0.2), segments=24, ring_count=12)
    high = bpy.context.active_object
    bpy.ops.object.shade_smooth()
    mat = bpy.data.materials.new("green")
    mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.2, 0.7, 0.3, 1.0)
    high.data.materials.append(mat)
    bpy.ops.object.light_add(type="SUN", location=(0, 0, 5))
    bpy.context.active_object.data.energy = 3.0
    return scene, low, high, image


def test_selected_to_active_normals_equal_cycles(high_to_low):
    scene, low, high, image = high_to_low
    options = dict(cage_extrusion=0.6, max_ray_distance=1.0)
    cycles = bake(scene, low, image, "CYCLES", "NORMAL", sources=(high,), **options)
    ember = bake(scene, low, image, "EMBER", "NORMAL", sources=(high,), **options)
    hit = np.abs(cycles[..., :3] - (0.5, 0.5, 1.0)).sum(axis=2) > 0.01   # texels whose rays found the sphere
    assert 100 < hit.sum() < SIZE * SIZE
    np.testing.assert_allclose(ember, cycles, atol=2e-4)


def test_selected_to_active_combined_matches_cycles(high_to_low):
    scene, low, high, image = high_to_low
    parity(scene, low, image, "COMBINED", 16, sources=(high,), cage_extrusion=0.6, max_ray_distance=1.0)


def test_margin_filled_as_cycles():
    """A cube's UV islands leave texels outside them; Blender fills a margin around them after the engine's bake,
    the same for Ember as for Cycles."""
    scene = new_scene(SIZE, SIZE)
    bpy.ops.mesh.primitive_cube_add(size=1.0, rotation=(0.3, 0.2, 0.1))
    cube = bpy.context.active_object
    image = _object_with_image(cube, "cube bake")
    bare = bake(scene, cube, image, "EMBER", "NORMAL", normal_space="OBJECT", margin=0)
    cycles = bake(scene, cube, image, "CYCLES", "NORMAL", normal_space="OBJECT", margin=3)
    ember = bake(scene, cube, image, "EMBER", "NORMAL", normal_space="OBJECT", margin=3)
    outside = bare[..., :3].sum(axis=2) == 0
    filled = outside & (ember[..., :3].sum(axis=2) > 0)
    assert outside.sum() > 100 and filled.sum() > 50
    np.testing.assert_allclose(ember, cycles, atol=2e-4)


def test_colour_attribute_target_matches_cycles():
    """Bakes into a colour attribute (Blender hands each face corner over as a texel, with its vertex's seed, so
    that a vertex's corners see the same numbers; it averages them into the vertex's colour)."""
    scene = new_scene(SIZE, SIZE)
    set_world(scene, color=(0.3, 0.4, 0.5), strength=1.0)
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=15, y_subdivisions=15, size=2.0)
    grid = bpy.context.active_object
    grid.data.color_attributes.new("Col", "FLOAT_COLOR", "POINT")
    grid.data.attributes.active_color = grid.data.color_attributes["Col"]
    bpy.ops.mesh.primitive_cube_add(size=0.6, location=(0.3, 0.2, 0.6))
    bpy.ops.object.light_add(type="SUN")
    bpy.context.active_object.data.energy = 3.0

    def corners(engine, seed):
        configure_engine(scene, engine, 16, seed=seed, max_bounces=3)
        for ob in bpy.context.view_layer.objects:
            ob.select_set(ob == grid)
        bpy.context.view_layer.objects.active = grid
        bpy.ops.object.bake(type="COMBINED", target="VERTEX_COLORS", use_clear=True)
        values = np.empty(len(grid.data.vertices) * 4, np.float32)
        grid.data.color_attributes["Col"].data.foreach_get("color", values)
        return values.reshape(16, 16, 4)   # the grid's vertices, in blocks of 16 for the noise test

    assert_within_noise(*[[corners(engine, seed) for seed in SEEDS] for engine in ("CYCLES", "EMBER")], block=4)


def test_an_image_per_material_each_baked(monkeypatch):
    """Blender calls the engine once per image (a material each here, or a UDIM tile each); each gets its own
    texels, and Ember exports and builds the scene once for them all."""
    from ember.engine import bake as engine_bake
    exports = []
    export = engine_bake.export_scene
    monkeypatch.setattr(engine_bake, "export_scene", lambda *a, **k: exports.append(1) or export(*a, **k))
    scene = new_scene(SIZE, SIZE)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.8, segments=16, ring_count=8)
    ob = bpy.context.active_object
    images = [bpy.data.images.new(f"part {i}", SIZE, SIZE, float_buffer=True) for i in range(2)]
    for image in images:
        ob.data.materials.append(_image_node_material(image.name, image))
    for i, face in enumerate(ob.data.polygons):
        face.material_index = int(face.center.z > 0.2)

    def both(engine):
        bake(scene, ob, images[0], engine, "NORMAL", normal_space="OBJECT")
        out = []
        for image in images:
            pixels = np.empty(SIZE * SIZE * 4, np.float32)
            image.pixels.foreach_get(pixels)
            out.append(pixels.reshape(SIZE, SIZE, 4))
        return out
    cycles, ember = both("CYCLES"), both("EMBER")
    assert len(exports) == 1
    for c, e in zip(cycles, ember):
        assert (np.abs(c[..., :3]).sum(axis=2) > 0).sum() > 50
        np.testing.assert_allclose(e, c, atol=2e-4)


@pytest.mark.parametrize("case", ["mirrored", "instanced"])
def test_mirrored_and_instanced_objects_bake_as_cycles(case, monkeypatch):
    """A mirrored object's texels see its outside; an object whose mesh Ember stores once for many instances
    finds its triangles among the instances'."""
    scene = new_scene(SIZE, SIZE)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.8, segments=16, ring_count=8)
    ob = bpy.context.active_object
    bpy.ops.object.shade_smooth()
    image = _object_with_image(ob, "sphere bake")
    if case == "mirrored":
        ob.scale = (-1.0, 1.0, 1.3)
    else:
        from ember.engine.export import instances
        monkeypatch.setattr(instances, "INSTANCE_MIN_TRIANGLES", 1)
        for i in range(3):
            copy = bpy.data.objects.new(f"copy {i}", ob.data)
            scene.collection.objects.link(copy)
            copy.location = (3.0 + 2.0 * i, 0.0, 0.0)
        assert export_current().scene.instances is not None
    for kind, options in (("NORMAL", {"normal_space": "OBJECT"}), ("POSITION", {})):
        cycles = bake(scene, ob, image, "CYCLES", kind, **options)
        np.testing.assert_allclose(bake(scene, ob, image, "EMBER", kind, **options), cycles, atol=2e-4)


def test_degenerate_triangles_leave_the_others_in_place():
    """Ember drops a triangle without area; the texels of the triangles after it still find theirs."""
    scene = new_scene(SIZE, SIZE)
    verts = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0), (3, 0, 0), (4, 0, 0),
             (2, 0, 0.2), (3, 0, 0.2), (3, 1, 0.2), (2, 1, 0.2)]
    mesh = bpy.data.meshes.new("sliver")
    mesh.from_pydata(verts, [], [(0, 1, 2, 3), (4, 5, 6), (7, 8, 9, 10)])
    uv = mesh.uv_layers.new(name="UVMap")
    corners = [(0.05, 0.05), (0.45, 0.05), (0.45, 0.45), (0.05, 0.45), (0.55, 0.55), (0.95, 0.6), (0.6, 0.95),
               (0.05, 0.55), (0.45, 0.55), (0.45, 0.95), (0.05, 0.95)]
    for loop, coord in zip(mesh.loops, corners):
        uv.data[loop.index].uv = coord
    ob = bpy.data.objects.new("sliver", mesh)
    scene.collection.objects.link(ob)
    image = _object_with_image(ob, "sliver bake")
    cycles = bake(scene, ob, image, "CYCLES", "POSITION")
    ember = bake(scene, ob, image, "EMBER", "POSITION")
    baked = np.abs(ember[..., :3]).sum(axis=2) > 0
    upper = np.zeros_like(baked)
    upper[SIZE // 2:, :SIZE // 2] = True   # the last face's island
    assert (baked & upper).sum() > 100
    np.testing.assert_allclose(ember[baked], cycles[baked], atol=2e-4)


def test_render_properties_show_the_bake_panels():
    """Render Properties > Bake (Cycles' panels: Blender's bake settings and the bake type) shows with Ember."""
    from types import SimpleNamespace
    new_scene(SIZE, SIZE)
    scene = bpy.context.scene
    scene.render.engine = "EMBER"
    scene.cycles.bake_type = "COMBINED"
    context = SimpleNamespace(engine="EMBER", scene=scene)
    for name in ("CYCLES_RENDER_PT_bake", "CYCLES_RENDER_PT_bake_influence", "CYCLES_RENDER_PT_bake_selected_to_active",
                 "CYCLES_RENDER_PT_bake_output", "CYCLES_RENDER_PT_bake_output_margin"):
        assert getattr(bpy.types, name).poll(context), name


# ---------------------------------------------------------------- what Ember cannot bake: reported, never a crash
def test_object_no_ray_sees_is_reported(high_to_low):
    scene, low, high, image = high_to_low
    configure_engine(scene, "EMBER", 1)
    for attr in ("visible_camera", "visible_diffuse", "visible_glossy", "visible_transmission",
                 "visible_volume_scatter", "visible_shadow"):
        setattr(low, attr, False)
    try:
        with pytest.raises(RuntimeError, match="Ember: object 'Plane' has no triangles"):
            bake(scene, low, image, "EMBER", "DIFFUSE")
    finally:
        for attr in ("visible_camera", "visible_diffuse", "visible_glossy", "visible_transmission",
                     "visible_volume_scatter", "visible_shadow"):
            setattr(low, attr, True)


# ---------------------------------------------------------------- the command line
def _ember(*args, timeout=300):
    code = ("import sys; sys.path.insert(0, %r); from bench.common import import_ember; import_ember(); "
            "import runpy; sys.argv = ['ember'] + sys.argv[1:]; runpy.run_module('ember', run_name='__main__')" % ROOT)
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=timeout,
                          cwd=ROOT)


def test_command_line_bake(tmp_path, high_to_low, capsys):
    """python -m ember bake writes what the bake operator makes in Blender (a subprocess, as a pipeline runs it);
    Selected to Active and a pass filter from the line; bad input is one line and a non-zero exit (in this
    process: the line's main, as the subprocess runs it)."""
    from ember.engine.cli import main
    scene, low, high, image = high_to_low
    blend = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    expected = bake(scene, low, image, "EMBER", "NORMAL", margin=0, normal_space="OBJECT")
    out = tmp_path / "normal.exr"
    run = _ember("bake", str(blend), "--type", "normal", "--object", "Plane", "-o", str(out), "--margin", "0",
                 "--resolution", f"{SIZE}x{SIZE}", "--normal-space", "object", "--samples", "1")
    assert run.returncode == 0, run.stderr
    assert "saved" in run.stdout
    loaded = bpy.data.images.load(str(out), check_existing=False)
    pixels = np.empty(SIZE * SIZE * 4, np.float32)
    loaded.pixels.foreach_get(pixels)
    bpy.data.images.remove(loaded)
    np.testing.assert_allclose(pixels.reshape(SIZE, SIZE, 4), expected, atol=1e-5)

    png = tmp_path / "s2a.png"
    assert main(["bake", str(blend), "--type", "combined", "--object", "Plane", "--selected", high.name,
                 "--cage-extrusion", "0.6", "-o", str(png), "--resolution", "16x16", "--samples", "2",
                 "--filter", "direct,diffuse"]) == 0
    assert png.stat().st_size > 0
    capsys.readouterr()
    assert main(["bake", str(blend), "--type", "diffuse", "--object", "Nope", "-o", str(png)]) == 1
    err = capsys.readouterr().err
    assert err.strip().count("\n") == 0 and "no object named 'Nope'" in err
    assert main(["bake", str(blend), "--type", "diffuse", "--filter", "direct,sparkle", "-o", str(png)]) == 2
    assert "--filter" in capsys.readouterr().err
