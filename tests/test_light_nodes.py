"""A light's node tree (Cycles' light shader) against Cycles: a constant emission (colour, strength, a Blackbody,
Add and Mix Shaders) scales the light; an emission that varies (Light Falloff, a texture over the light's normal or
object space, the normal of a sphere lamp) is evaluated where each ray meets the light. Each failed before: Ember
read no light tree, so a lamp whose Emission Strength was 2.5 rendered as bright as one of 1."""
import math

import bpy
import numpy as np
import pytest

from bpy_helpers import compare_to_cycles, export_current, quad_object, render_to_array
from test_lights_parity import add_light, stage


def light_tree(light):
    """The light's own tree (created on Blender 5.0, where lights start without one) and its Emission node."""
    if light.node_tree is None:   # Blender 5.3 gives every light a tree, and keeps Use Nodes on
        light.use_nodes = True
    tree = light.node_tree
    return tree, next(n for n in tree.nodes if n.bl_idname == "ShaderNodeEmission")


def constant(light):
    tree, emission = light_tree(light)
    emission.inputs["Color"].default_value = (1.0, 0.5, 0.25, 1.0)
    emission.inputs["Strength"].default_value = 2.5


def blackbody_mix(light):
    """Mix Shader (0.3) of the Emission, coloured by a Blackbody and made 1.5x by a Math node, and a green
    Emission: all constants, folded."""
    tree, emission = light_tree(light)
    body = tree.nodes.new("ShaderNodeBlackbody")
    body.inputs["Temperature"].default_value = 3000.0
    times = tree.nodes.new("ShaderNodeMath")
    times.operation = "MULTIPLY"
    times.inputs[0].default_value, times.inputs[1].default_value = 0.5, 3.0
    green = tree.nodes.new("ShaderNodeEmission")
    green.inputs["Color"].default_value = (0.1, 1.0, 0.2, 1.0)
    mix = tree.nodes.new("ShaderNodeMixShader")
    mix.inputs[0].default_value = 0.3
    output = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputLight")
    tree.links.new(body.outputs[0], emission.inputs["Color"])
    tree.links.new(times.outputs[0], emission.inputs["Strength"])
    tree.links.new(emission.outputs[0], mix.inputs[1])
    tree.links.new(green.outputs[0], mix.inputs[2])
    tree.links.new(mix.outputs[0], output.inputs["Surface"])


def falloff(output, strength=1.0, smooth=0.0):
    def build(light):
        tree, emission = light_tree(light)
        node = tree.nodes.new("ShaderNodeLightFalloff")
        node.inputs["Strength"].default_value = strength
        node.inputs["Smooth"].default_value = smooth
        tree.links.new(node.outputs[output], emission.inputs["Strength"])
    return build


def checker(coordinate):
    """A Checker texture over the Texture Coordinate `coordinate` colours the emission (a gobo)."""
    def build(light):
        tree, emission = light_tree(light)
        coords = tree.nodes.new("ShaderNodeTexCoord")
        texture = tree.nodes.new("ShaderNodeTexChecker")
        texture.inputs["Scale"].default_value = 6.0
        texture.inputs["Color1"].default_value = (1.0, 0.9, 0.6, 1.0)
        texture.inputs["Color2"].default_value = (0.05, 0.1, 0.3, 1.0)
        tree.links.new(coords.outputs[coordinate], texture.inputs["Vector"])
        tree.links.new(texture.outputs["Color"], emission.inputs["Color"])
    return build


def image_gobo(light):
    """An Image Texture (a generated colour grid, Clip) over the lamp's UV colours its emission: a gobo."""
    tree, emission = light_tree(light)
    coords, texture = tree.nodes.new("ShaderNodeTexCoord"), tree.nodes.new("ShaderNodeTexImage")
    texture.image = bpy.data.images.new("Gobo", 32, 32)
    texture.image.generated_type = "COLOR_GRID"
    texture.extension = "CLIP"
    tree.links.new(coords.outputs["UV"], texture.inputs["Vector"])
    tree.links.new(texture.outputs["Color"], emission.inputs["Color"])


def normal_colour(light):
    """The emission's colour is the light's normal there (|x|, 0, |z|): a sphere lamp's outward normal."""
    tree, emission = light_tree(light)
    geometry = tree.nodes.new("ShaderNodeNewGeometry")
    split = tree.nodes.new("ShaderNodeSeparateXYZ")
    join = tree.nodes.new("ShaderNodeCombineColor")
    tree.links.new(geometry.outputs["Normal"], split.inputs[0])
    for axis in (0, 2):
        absolute = tree.nodes.new("ShaderNodeMath")
        absolute.operation = "ABSOLUTE"
        tree.links.new(split.outputs[axis], absolute.inputs[0])
        tree.links.new(absolute.outputs[0], join.inputs[axis])
    tree.links.new(join.outputs[0], emission.inputs["Color"])


CASES = {
    "constant": ("POINT", dict(energy=200.0, shadow_soft_size=0.3), constant),
    "blackbody_mix": ("AREA", dict(energy=150.0, shape="RECTANGLE", size=1.0, size_y=0.5), blackbody_mix),
    "point_linear": ("POINT", dict(energy=80.0, shadow_soft_size=0.3), falloff("Linear")),
    "delta_constant_smooth": ("POINT", dict(energy=40.0, shadow_soft_size=0.0), falloff("Constant", 1.0, 2.0)),
    "area_quadratic_smooth": ("AREA", dict(energy=150.0, shape="RECTANGLE", size=1.0, size_y=0.5),
                              falloff("Quadratic", 1.0, 4.0)),
    "sun_linear": ("SUN", dict(energy=2.0, angle=math.radians(5)), falloff("Linear", 1.5)),
    "spot_gobo": ("SPOT", dict(energy=400.0, shadow_soft_size=0.1, spot_size=math.radians(60)), checker("Normal")),
    "disk_object": ("AREA", dict(energy=150.0, shape="DISK", size=1.2), checker("Object")),
    "sphere_normal": ("POINT", dict(energy=200.0, shadow_soft_size=0.5, use_soft_falloff=False), normal_colour),
    # The lamps' UV (Cycles' spot_light_uv, point_light_uv, area_light_uv, sun_light_uv) and Generated.
    "spot_uv": ("SPOT", dict(energy=400.0, shadow_soft_size=0.0, spot_size=1.2), checker("UV")),
    "spot_image_gobo": ("SPOT", dict(energy=400.0, spot_size=1.2), image_gobo),
    "sphere_uv": ("POINT", dict(energy=200.0, shadow_soft_size=0.5, use_soft_falloff=False), checker("UV")),
    "area_uv": ("AREA", dict(energy=150.0, shape="RECTANGLE", size=1.5, size_y=0.8), checker("UV")),
    "sun_uv": ("SUN", dict(energy=2.0, angle=math.radians(20)), checker("UV")),
    "point_generated": ("POINT", dict(energy=200.0, shadow_soft_size=0.3), checker("Generated")),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_light_node_tree_matches_cycles(name):
    kind, props, build = CASES[name]
    scene = stage()
    build(add_light(scene, kind, **props).data)
    compare_to_cycles(scene, samples=128, max_bounces=2)


def test_light_seen_through_a_mirror_takes_its_tree():
    """BSDF rays that meet a lamp (a sharp mirror facing a sized point light with a Linear falloff) read its
    program where they meet it, as its light samples do."""
    scene = stage()
    add_light(scene, "POINT", location=(0.2, -1.5, 1.2), energy=60.0, shadow_soft_size=0.25).data
    build = falloff("Linear", 1.0)
    build(bpy.data.objects["Point"].data)
    bpy.ops.mesh.primitive_plane_add(size=1.5, location=(0.0, 1.2, 0.8), rotation=(math.radians(80), 0, 0))
    mirror = bpy.data.materials.new("Mirror")
    mirror.use_nodes = True
    bsdf = mirror.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Metallic"].default_value, bsdf.inputs["Roughness"].default_value = 1.0, 0.05
    bpy.context.active_object.data.materials.append(mirror)
    compare_to_cycles(scene, samples=128, max_bounces=2)


def test_light_tree_without_emission_is_dark():
    """A light whose Light Output has nothing connected emits nothing (Cycles' estimate is zero); one whose tree
    holds a loop renders nothing, with a warning."""
    scene = stage(16, 16)
    ob = add_light(scene, "POINT", energy=200.0, shadow_soft_size=0.3)
    tree, _ = light_tree(ob.data)
    for link in list(tree.links):
        tree.links.remove(link)
    assert render_to_array(scene, "EMBER", 4, max_bounces=2)[..., :3].max() == 0.0
    assert export_current().scene.lights.count == 0


def test_light_tree_loop_is_named():
    scene = stage(16, 16)
    looped = add_light(scene, "POINT", energy=200.0, shadow_soft_size=0.3)
    tree, emission = light_tree(looped.data)
    a, b = tree.nodes.new("ShaderNodeMath"), tree.nodes.new("ShaderNodeMath")
    tree.links.new(a.outputs[0], b.inputs[0])
    tree.links.new(b.outputs[0], a.inputs[0])
    tree.links.new(b.outputs[0], emission.inputs["Strength"])
    warnings = export_current().warnings
    assert any("Light 'Point'" in w and "loop" in w for w in warnings), warnings


def principled_and_bsdf(light):
    """A Mix Shader of a Principled BSDF (its emission, under Alpha 0.8) and a Diffuse BSDF (nothing), by 0.3: Cycles
    evaluates a light's shader for its emission closures only. Ember read no emission from a Principled BSDF in a
    light (black, with a warning)."""
    tree, emission = light_tree(light)
    principled = tree.nodes.new("ShaderNodeBsdfPrincipled")
    principled.inputs["Emission Color"].default_value = (1.0, 0.5, 0.2, 1.0)
    principled.inputs["Emission Strength"].default_value = 3.0
    principled.inputs["Alpha"].default_value = 0.8
    mix = tree.nodes.new("ShaderNodeMixShader")
    mix.inputs[0].default_value = 0.3
    tree.links.new(principled.outputs[0], mix.inputs[1])
    tree.links.new(tree.nodes.new("ShaderNodeBsdfDiffuse").outputs[0], mix.inputs[2])
    output = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputLight")
    tree.links.new(mix.outputs[0], output.inputs["Surface"])


def test_principled_and_bsdfs_in_a_light_emit_as_in_cycles():
    scene = stage(24, 24)
    add_light(scene, "SPOT", energy=300.0, shadow_soft_size=0.2, spot_size=1.2)
    principled_and_bsdf(bpy.data.objects["Spot"].data)
    result = export_current()
    assert not any("Light 'Spot'" in w for w in result.warnings), result.warnings
    assert result.scene.lights.count == 1
    compare_to_cycles(scene, samples=128, max_bounces=2)


def test_varying_light_keeps_a_program_and_a_constant_one_folds():
    scene = stage(16, 16)
    constant(add_light(scene, "POINT", energy=200.0, shadow_soft_size=0.3).data)
    falloff("Linear")(add_light(scene, "SPOT", energy=100.0).data)
    lights = export_current().scene.lights
    by_kind = {int(k): i for i, k in enumerate(lights.kind)}
    point, spot = by_kind[0], by_kind[1]
    # The constant tree's (1, 0.5, 0.25) x 2.5 is in the radiance: 200 W / (4 pi) / (pi 0.3^2) x that.
    base = 200.0 / (4 * math.pi) / (math.pi * 0.09)
    assert np.allclose(lights.radiance[point], base * 2.5 * np.array([1.0, 0.5, 0.25]), rtol=1e-5)
    assert lights.shader[point] == -1 and lights.shader[spot] == 0 and len(lights.shaders) == 1


@pytest.mark.skipif(bpy.app.version >= (5, 3), reason="Blender 5.3 keeps Use Nodes on for every light")
def test_light_with_use_nodes_off_ignores_its_tree():
    """Cycles reads a light's tree only with Use Nodes on (blender/shader.cpp sync_lights)."""
    scene = stage(16, 16)
    ob = add_light(scene, "POINT", energy=200.0, shadow_soft_size=0.3)
    constant(ob.data)
    ob.data.use_nodes = False
    radiance = export_current().scene.lights.radiance[0]
    assert np.allclose(radiance, radiance[0]) and np.isclose(radiance[0], 200.0 / (4 * math.pi) / (math.pi * 0.09),
                                                             rtol=1e-5)


@pytest.mark.parametrize("output", ["Linear", "Constant"])
def test_light_falloff_on_an_emissive_mesh_matches_cycles(output):
    """Light Falloff in a material: the emission scales with the length of the ray that reaches the surface
    (Cycles' sd->ray_length), for camera rays and the rays bounced off the floor alike."""
    scene = stage()
    panel = bpy.data.materials.new("Panel")
    panel.use_nodes = True
    tree = panel.node_tree
    tree.nodes.clear()
    out, emission = tree.nodes.new("ShaderNodeOutputMaterial"), tree.nodes.new("ShaderNodeEmission")
    node = tree.nodes.new("ShaderNodeLightFalloff")
    node.inputs["Strength"].default_value = 3.0
    node.inputs["Smooth"].default_value = 0.5
    tree.links.new(node.outputs[output], emission.inputs["Strength"])
    tree.links.new(emission.outputs[0], out.inputs["Surface"])
    quad_object("Panel", (-1.0, -1.2, 1.8), (1.2, 0, 0), (0, 0.5, 0.3), panel)
    compare_to_cycles(scene, samples=128, max_bounces=2)


def test_light_falloff_in_a_world_passes_its_strength():
    """Cycles' background shading point has an infinite ray length (shader_setup_from_background): Light
    Falloff gives its Strength on every output there."""
    scene = stage()
    world = scene.world
    tree = world.node_tree
    node = tree.nodes.new("ShaderNodeLightFalloff")
    node.inputs["Strength"].default_value = 0.7
    tree.links.new(node.outputs["Constant"], tree.nodes["Background"].inputs["Strength"])
    tree.nodes["Background"].inputs["Color"].default_value = (0.3, 0.4, 0.5, 1.0)
    compare_to_cycles(scene, samples=64, max_bounces=2)


# IES profiles written for these tests (photometric types C, A and B): a round downlight and asymmetric ones.
DOWNLIGHT = """IESNA:LM-63-2002
[TEST] Ember test downlight
TILT=NONE
1 1000 1.0 7 1 1 2 0.1 0.1 0.0
1.0 1.0 12
0 15 30 45 60 75 90
0
900 850 700 420 150 30 0
"""
ASYMMETRIC = """IESNA:LM-63-2002
[TEST] Ember test asymmetric, type {kind}
TILT=NONE
1 1000 2.0 9 5 {kind} 2 0.1 0.1 0.0
1.0 0.8 12
{vertical}
{horizontal}
500 480 400 300 150 80 40 20 10
500 400 250 120 60 30 15 5 0
500 450 380 260 200 120 60 30 10
500 300 150 100 50 20 10 5 0
500 480 400 300 150 80 40 20 10
"""
PROFILES = {
    "type_c_round": DOWNLIGHT,
    "type_c": ASYMMETRIC.format(kind=1, vertical="0 22.5 45 67.5 90 112.5 135 157.5 180", horizontal="0 90 180 270 360"),
    "type_a": ASYMMETRIC.format(kind=3, vertical="-90 -67.5 -45 -22.5 0 22.5 45 67.5 90", horizontal="0 20 45 70 90"),
    "type_b": ASYMMETRIC.format(kind=2, vertical="0 10 20 30 45 60 70 80 90", horizontal="-90 -45 0 45 90"),
}


def ies_light(light, text, external_dir=None):
    """The lamp's Emission Strength from an IES Texture of `text`: a Text datablock, or a file in external_dir."""
    tree, emission = light_tree(light)
    node = tree.nodes.new("ShaderNodeTexIES")
    if external_dir is None:
        block = bpy.data.texts.new("profile.ies")
        block.from_string(text)
        node.mode, node.ies = "INTERNAL", block
    else:
        path = external_dir / "profile.ies"
        path.write_text(text)
        node.mode, node.filepath = "EXTERNAL", str(path)
    node.inputs["Strength"].default_value = 0.05
    tree.links.new(node.outputs["Fac"], emission.inputs["Strength"])
    return node


@pytest.mark.parametrize("name", sorted(PROFILES))
def test_ies_profile_matches_cycles(name, tmp_path):
    """A tilted point lamp with an IES Texture (Cycles' util/ies.cpp reading, kernel_ies_interp lookup) lights the
    floor and the objects as in Cycles; the round downlight from a file, the others from Text datablocks."""
    scene = stage()
    ob = add_light(scene, "POINT", location=(-0.5, -0.4, 1.6), rotation=(0.3, 0.2, 0.5), energy=200.0,
                   shadow_soft_size=0.1)
    ies_light(ob.data, PROFILES[name], tmp_path if name == "type_c_round" else None)
    compare_to_cycles(scene, samples=128, max_bounces=2)


def test_ies_on_a_wide_spot_matches_cycles():
    scene = stage()
    ob = add_light(scene, "SPOT", location=(-0.5, -0.4, 1.6), rotation=(0.4, -0.3, 0.0), energy=200.0,
                   shadow_soft_size=0.1, spot_size=2.0)
    ies_light(ob.data, PROFILES["type_c"])
    compare_to_cycles(scene, samples=128, max_bounces=2)


def test_ies_without_a_profile_gives_100_times_its_strength(tmp_path):
    """Cycles' kernel gives a slot without a profile 100 (kernel_ies_interp): a missing file and a text that is no
    IES file each light the lamp 100 x 0.05 = 5 times, named in a warning."""
    scene = stage(16, 16)
    missing = add_light(scene, "POINT", energy=200.0, shadow_soft_size=0.3)
    node = ies_light(missing.data, "", tmp_path)
    node.filepath = str(tmp_path / "nowhere.ies")
    broken = add_light(scene, "SPOT", energy=200.0)
    ies_light(broken.data, "not an IES file")
    exported = export_current()
    assert any("Light 'Point'" in w and "nowhere.ies could not be read" in w for w in exported.warnings), \
        exported.warnings
    assert any("Light 'Spot'" in w and "is not an IES file" in w for w in exported.warnings), exported.warnings
    lights = exported.scene.lights
    assert lights.shader is None   # both fold to constants
    base = 200.0 / (4 * math.pi) / (math.pi * 0.09)
    assert np.allclose(lights.radiance[list(lights.kind).index(0)], base * 5.0, rtol=1e-5)


def _type_c(horizontal, rows):
    head = f"1 1000 1.0 3 {len(horizontal.split())} 1 2 0 0 0\n1 1 0\n0 45 90\n{horizontal}\n"
    return "IESNA:LM-63-2002\nTILT=NONE\n" + head + "\n".join(rows) + "\n"


@pytest.mark.parametrize("horizontal,rows,angles,first_columns", [
    # One quadrant: mirrored to a half, then to the whole circle.
    ("0 45 90", ["3 2 1", "6 5 4", "9 8 7"], [0, 45, 90, 135, 180, 225, 270, 315, 360], [0, 1, 2, 1, 0, 1, 2, 1, 0]),
    # A half: mirrored to the whole circle.
    ("0 90 180", ["3 2 1", "6 5 4", "9 8 7"], [0, 90, 180, 270, 360], [0, 1, 2, 1, 0]),
    # Stored from 90 to 270 degrees: rotated to 0-180, then mirrored.
    ("90 180 270", ["3 2 1", "6 5 4", "9 8 7"], [0, 90, 180, 270, 360], [0, 1, 2, 1, 0]),
    # The 360-degree column left out (the spacing says where it goes): the 0-degree one repeated there.
    ("0 120 240", ["3 2 1", "6 5 4", "9 8 7"], [0, 120, 240, 360], [0, 1, 2, 0]),
])
def test_ies_type_c_symmetries_as_cycles_reads_them(horizontal, rows, angles, first_columns):
    """Cycles' IESFile::process_type_c: the horizontal angles a file gives, mirrored to [0, 360]; intensities in W/sr
    (candela x 4 pi / 177.83)."""
    from ember.engine.export.ies import CANDELA_TO_WATT, parse_ies
    table = parse_ies(_type_c(horizontal, rows))
    np.testing.assert_allclose(np.degrees(table.h_angles), angles, atol=1e-4)
    np.testing.assert_allclose(np.degrees(table.v_angles), [0, 45, 90], atol=1e-4)
    given = np.array([[float(x) for x in r.split()] for r in rows])
    np.testing.assert_allclose(table.intensity, given[first_columns] * CANDELA_TO_WATT, rtol=1e-6)


def test_emitter_hidden_from_the_camera_matches_cycles():
    """An emissive panel that shows Transparent to camera rays (Mix Shader by Light Path > Is Camera Ray): its light
    samples are no camera rays (Cycles' light_sample_shader_eval evaluates them with PATH_RAY_EMISSION), so they
    take its emission, as the rays bounced off the floor do; the camera sees through it."""
    scene = stage()
    panel = bpy.data.materials.new("Hidden")
    tree = panel.node_tree
    tree.nodes.clear()
    out, emission = tree.nodes.new("ShaderNodeOutputMaterial"), tree.nodes.new("ShaderNodeEmission")
    emission.inputs["Strength"].default_value = 6.0
    path, clear, mix = (tree.nodes.new(kind) for kind in ("ShaderNodeLightPath", "ShaderNodeBsdfTransparent",
                                                          "ShaderNodeMixShader"))
    tree.links.new(path.outputs["Is Camera Ray"], mix.inputs[0])
    tree.links.new(emission.outputs[0], mix.inputs[1])
    tree.links.new(clear.outputs[0], mix.inputs[2])
    tree.links.new(mix.outputs[0], out.inputs["Surface"])
    quad_object("Panel", (-1.0, -1.2, 1.8), (1.2, 0, 0), (0, 0.5, 0.3), panel)
    compare_to_cycles(scene, samples=128, max_bounces=2)


def test_several_varying_lamps_together_match_cycles():
    """Lamps of every kind whose emissions vary, in one scene: each light sample and each lamp a ray meets reads its
    own program, point and frame (a batch mixes them)."""
    scene = stage()
    ies_light(add_light(scene, "POINT", location=(-0.5, -0.4, 1.6), rotation=(0.3, 0.2, 0.5), energy=100.0,
                        shadow_soft_size=0.1).data, PROFILES["type_c"])
    checker("UV")(add_light(scene, "SPOT", location=(1.2, -1.0, 2.2), rotation=(0.5, 0.4, 0.0), energy=200.0,
                            spot_size=1.2).data)
    falloff("Linear", 0.5)(add_light(scene, "AREA", location=(0.5, 1.0, 2.0), energy=80.0, size=0.6).data)
    checker("UV")(add_light(scene, "SUN", energy=1.0, angle=math.radians(20)).data)
    compare_to_cycles(scene, samples=128, max_bounces=2)


def test_ray_length_of_the_world_is_cycles_flt_max():
    """Cycles gives the world's shading point an infinite ray, FLT_MAX (shader_setup_from_background): Light Path's
    Ray Length there is 3.4e38, so a Math node's Less Than 1000 on it is 0 (before: 0, and the test gave 1)."""
    scene = stage()
    tree = scene.world.node_tree
    path, less = tree.nodes.new("ShaderNodeLightPath"), tree.nodes.new("ShaderNodeMath")
    less.operation, less.inputs[1].default_value = "LESS_THAN", 1000.0
    tree.links.new(path.outputs["Ray Length"], less.inputs[0])
    mix = tree.nodes.new("ShaderNodeMix")
    mix.data_type = "RGBA"
    socket = {s.identifier: s for s in (*mix.inputs, *mix.outputs)}
    socket["A_Color"].default_value, socket["B_Color"].default_value = (0.4, 0.5, 0.6, 1.0), (2.0, 0.0, 0.0, 1.0)
    tree.links.new(less.outputs[0], socket["Factor_Float"])
    tree.links.new(socket["Result_Color"], tree.nodes["Background"].inputs["Color"])
    compare_to_cycles(scene, samples=32, max_bounces=2)
