"""The Shader > BSDF menu's less common nodes against Cycles (CPU, no clamping, box filter): Toon BSDF.

Same method as test_parity_materials: four seed replicates per engine; the whole-image mean within 2% and
every block of an 8x8 grid within 4.5 standard errors of the difference.
"""
import bpy

from bpy_helpers import add_camera, compare_to_cycles, new_scene, set_world
from test_parity_materials import grid_of_spheres, node_material

TOON = "ShaderNodeBsdfToon"


def add_light(scene, kind, location, energy, size=0.0, rotation=(0.0, 0.0, 0.0)):
    data = bpy.data.lights.new(kind, kind)
    data.energy = energy
    if kind == "SUN":
        data.angle = size
    else:
        data.shadow_soft_size = size
    light = bpy.data.objects.new(kind, data)
    scene.collection.objects.link(light)
    light.location, light.rotation_euler = location, rotation
    return light


def no_terminator_offset():
    """Cycles moves shadow rays of smooth triangles near the light's terminator to a smoothed surface
    (Object > Shadow Terminator > Geometry Offset, 0.1 by default), which Ember does not: a toon lobe, with
    no cosine to darken the terminator, shows it. Off here, on every object."""
    for ob in bpy.data.objects:
        ob.shadow_terminator_geometry_offset = 0.0


def test_toon_diffuse_and_glossy_under_a_sun_and_a_lamp():
    """Both components, hard and smooth edges, Size 0 (a mirror-like cone) and Size 1 with Smooth 1 (the
    whole hemisphere), lit as toon shaders are: a sun, a lamp and a dim world."""
    scene = new_scene(96, 48)
    materials = [
        node_material("Toon hard", TOON, Color=(0.8, 0.5, 0.3), Size=0.5, Smooth=0.0),
        node_material("Toon soft", TOON, Color=(0.3, 0.6, 0.8), Size=0.3, Smooth=0.4),
        node_material("Toon glossy", TOON, Color=(0.9, 0.9, 0.9), Size=0.2, Smooth=0.1, opt_component="GLOSSY"),
        node_material("Toon mirror", TOON, Color=(0.9, 0.8, 0.6), Size=0.0, Smooth=0.0, opt_component="GLOSSY"),
        node_material("Toon wide", TOON, Color=(0.7, 0.7, 0.7), Size=1.0, Smooth=1.0),
        node_material("Toon glossy wide", TOON, Color=(0.6, 0.9, 0.6), Size=0.6, Smooth=0.3,
                      opt_component="GLOSSY"),
    ]
    grid_of_spheres(materials, 3)
    no_terminator_offset()
    add_camera(scene, (0, -5.2, 1.0), (0, 0, 1.0), lens=45)
    set_world(scene, color=(0.05, 0.05, 0.08))
    add_light(scene, "POINT", (2, -3, 4), 800, size=0.3)
    # A sun without an angle: Ember's BSDF rays do not meet suns, which a mirror-like toon would show.
    add_light(scene, "SUN", (0, 0, 1), 2.0, size=0.0, rotation=(0.6, 0.3, 0.0))
    compare_to_cycles(scene, samples=128, max_bounces=4)


def _material(name):
    mat = bpy.data.materials.new(name)
    tree = mat.node_tree
    tree.nodes.clear()
    return mat, tree, tree.nodes.new("ShaderNodeOutputMaterial")


def _toon(tree, component="DIFFUSE", color=(0.8, 0.8, 0.8), size=0.5, smooth=0.0):
    node = tree.nodes.new(TOON)
    node.component = component
    node.inputs["Color"].default_value = (*color, 1.0)
    node.inputs["Size"].default_value = size
    node.inputs["Smooth"].default_value = smooth
    return node


def toon_shaders():
    """Toon materials as artists build them: a cel shader (diffuse plus glossy toon), a toon with a Fresnel
    rim of metal, a mirror-like toon mixed with diffuse, a bumped toon and a toon whose Size a texture
    drives."""
    cel, tree, out = _material("Cel")
    add = tree.nodes.new("ShaderNodeAddShader")
    tree.links.new(_toon(tree, color=(0.8, 0.4, 0.2), size=0.45, smooth=0.05).outputs[0], add.inputs[0])
    tree.links.new(_toon(tree, "GLOSSY", (0.6, 0.6, 0.6), size=0.1, smooth=0.05).outputs[0], add.inputs[1])
    tree.links.new(add.outputs[0], out.inputs["Surface"])

    rim, tree, out = _material("Rim")
    mix = tree.nodes.new("ShaderNodeMixShader")
    weight = tree.nodes.new("ShaderNodeLayerWeight")
    weight.inputs["Blend"].default_value = 0.3
    metal = tree.nodes.new("ShaderNodeBsdfPrincipled")
    metal.inputs["Metallic"].default_value = 1.0
    metal.inputs["Roughness"].default_value = 0.3
    tree.links.new(weight.outputs["Facing"], mix.inputs[0])
    tree.links.new(_toon(tree, color=(0.2, 0.5, 0.8), size=0.6, smooth=0.1).outputs[0], mix.inputs[1])
    tree.links.new(metal.outputs[0], mix.inputs[2])
    tree.links.new(mix.outputs[0], out.inputs["Surface"])

    mirror, tree, out = _material("Mirror toon")
    mix = tree.nodes.new("ShaderNodeMixShader")
    mix.inputs[0].default_value = 0.5
    diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
    tree.links.new(_toon(tree, "GLOSSY", (0.9, 0.9, 0.7), size=0.0).outputs[0], mix.inputs[1])
    tree.links.new(diffuse.outputs[0], mix.inputs[2])
    tree.links.new(mix.outputs[0], out.inputs["Surface"])

    bumped, tree, out = _material("Bumped toon")
    toon = _toon(tree, color=(0.7, 0.8, 0.5), size=0.7, smooth=0.2)
    bump = tree.nodes.new("ShaderNodeBump")
    bump.inputs["Strength"].default_value = 0.6
    noise = tree.nodes.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = 6.0
    tree.links.new(noise.outputs["Fac"], bump.inputs["Height"])
    tree.links.new(bump.outputs["Normal"], toon.inputs["Normal"])
    tree.links.new(toon.outputs[0], out.inputs["Surface"])

    driven, tree, out = _material("Textured size")
    toon = _toon(tree, "GLOSSY", (0.8, 0.7, 0.9), smooth=0.2)
    checker = tree.nodes.new("ShaderNodeTexChecker")
    checker.inputs["Color1"].default_value = (0.6, 0.6, 0.6, 1.0)
    checker.inputs["Color2"].default_value = (0.1, 0.1, 0.1, 1.0)
    checker.inputs["Scale"].default_value = 3.0
    tree.links.new(checker.outputs["Fac"], toon.inputs["Size"])
    tree.links.new(toon.outputs[0], out.inputs["Surface"])
    return [cel, rim, mirror, bumped, driven]


def test_toon_mixed_with_other_closures_bumped_and_textured():
    scene = new_scene(96, 48)
    grid_of_spheres(toon_shaders(), 5)
    no_terminator_offset()
    add_camera(scene, (0, -5.5, 1.2), (0, 0, 0.5), lens=40)
    set_world(scene, color=(0.1, 0.1, 0.12))
    add_light(scene, "SUN", (0, 0, 1), 1.2, size=0.0, rotation=(0.5, -0.4, 0.0))
    add_light(scene, "AREA", (-2, -2, 3), 80, size=1.0, rotation=(0.6, -0.5, 0.0))
    compare_to_cycles(scene, samples=128, max_bounces=4)


def test_toon_exports_its_component_and_inputs_without_a_warning():
    from bpy_helpers import camera_only_scene, export_current
    from test_export import add_cube
    camera_only_scene()
    mat, tree, out = _material("Toon")
    toon = _toon(tree, "GLOSSY", (0.1, 0.2, 0.3), size=0.25, smooth=0.75)
    tree.links.new(toon.outputs[0], out.inputs["Surface"])
    add_cube().data.materials.append(mat)
    result = export_current()
    (closure,) = result.scene.materials.shaders[1].closures
    assert closure.kind == "TOON" and closure.option("component") == "GLOSSY"
    assert closure.input("Size").value == (0.25,) and closure.input("Smooth").value == (0.75,)
    assert not [w for w in result.warnings if "Toon" in w]
