"""The Shader > BSDF menu's less common nodes against Cycles (CPU, no clamping, box filter): Toon BSDF.

Same method as test_parity_materials: four seed replicates per engine; the whole-image mean within 2% and
every block of an 8x8 grid within 4.5 standard errors of the difference.
"""
import bpy
import numpy as np

from bpy_helpers import add_camera, compare_to_cycles, diffuse_material, hdri_world, mesh_object, new_scene, \
    render_to_array, set_world
from test_parity_materials import grid_of_spheres, node_material

TOON = "ShaderNodeBsdfToon"


def add_light(scene, kind, location, energy, size=0.0, rotation=(0.0, 0.0, 0.0)):
    data = bpy.data.lights.new(kind, kind)
    data.energy = energy
    if kind == "SUN":
        data.angle = size
    elif kind == "AREA":
        data.size = size
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


# ---------------------------------------------------------------- Ray Portal BSDF
PORTAL = "ShaderNodeBsdfRayPortal"


def portal_material(name, offset=None, direction=None, mix_with=None, fac=0.5, color=(1.0, 1.0, 1.0)):
    """A Ray Portal: the ray goes on from its hit moved by offset (a Geometry Position plus a vector), along
    direction (a Combine XYZ), or straight on; mixed half (fac) with another BSDF node when given."""
    mat, tree, out = _material(name)
    portal = tree.nodes.new(PORTAL)
    portal.inputs["Color"].default_value = (*color, 1.0)
    if offset is not None:
        geometry = tree.nodes.new("ShaderNodeNewGeometry")
        add = tree.nodes.new("ShaderNodeVectorMath")
        add.operation = "ADD"
        add.inputs[1].default_value = offset
        tree.links.new(geometry.outputs["Position"], add.inputs[0])
        tree.links.new(add.outputs[0], portal.inputs["Position"])
    if direction is not None:
        combine = tree.nodes.new("ShaderNodeCombineXYZ")
        for axis, value in zip("XYZ", direction):
            combine.inputs[axis].default_value = value
        tree.links.new(combine.outputs[0], portal.inputs["Direction"])
    shader = portal
    if mix_with is not None:
        shader = tree.nodes.new("ShaderNodeMixShader")
        shader.inputs[0].default_value = fac
        tree.links.new(tree.nodes.new(mix_with).outputs[0], shader.inputs[1])
        tree.links.new(portal.outputs[0], shader.inputs[2])
    tree.links.new(shader.outputs[0], out.inputs["Surface"])
    return mat


def portal_depth_glow(name, color):
    """An emitter that glows only where a ray that passed a Ray Portal sees it (Light Path > Portal Depth)."""
    mat, tree, out = _material(name)
    emission = tree.nodes.new("ShaderNodeEmission")
    emission.inputs["Color"].default_value = (*color, 1.0)
    light_path = tree.nodes.new("ShaderNodeLightPath")
    tree.links.new(light_path.outputs["Portal Depth"], emission.inputs["Strength"])
    tree.links.new(emission.outputs[0], out.inputs["Surface"])
    return mat


def teleport_scene(width=64, height=48):
    """A portal standing on a floor shows a room 20 m above, where spheres stand under a large area lamp (seen
    and sampled through the portal: found by BSDF rays, no MIS) and one glows only through portals. A lamp
    in front of the portal: the portal stops its shadow rays, the floor behind sees the far room through it."""
    scene = new_scene(width, height)
    mesh_object("Floor", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], [(0, 1, 2, 3)],
                diffuse_material("Floor", (0.5, 0.5, 0.5)))
    mesh_object("Portal", [(-1, 0, 0.2), (1, 0, 0.2), (1, 0, 1.8), (-1, 0, 1.8)], [(0, 1, 2, 3)],
                portal_material("Portal", offset=(0, 0, 20)))
    mesh_object("Far floor", [(-4, -4, 20), (4, -4, 20), (4, 4, 20), (-4, 4, 20)], [(0, 1, 2, 3)],
                diffuse_material("Far floor", (0.2, 0.6, 0.3)))
    spheres = [diffuse_material("Red", (0.9, 0.2, 0.1)), portal_depth_glow("Glow", (0.2, 0.4, 1.0)),
               diffuse_material("Yellow", (0.9, 0.8, 0.2))]
    for i, mat in enumerate(spheres):
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.4, location=(-0.8 + 0.8 * i, 1.5, 20.5), segments=24,
                                             ring_count=12)
        bpy.context.active_object.data.materials.append(mat)
    add_light(scene, "AREA", (0, 0, 24), 500, size=6.0)
    add_light(scene, "POINT", (1.5, -2.5, 2.5), 200, size=0.2)
    add_camera(scene, (0, -4, 1.2), (0, 0, 1.0), lens=35)
    set_world(scene, color=(0.05, 0.05, 0.07))
    return scene


def test_ray_portal_shows_another_place():
    """The canonical use: a Ray Portal whose Position moves the ray into another room."""
    scene = teleport_scene()
    compare_to_cycles(scene, samples=256, max_bounces=4)


def portal_panels_scene(width=80, height=40):
    """Four panels standing on a floor under a sun and a lamp, in front of an HDRI: a portal mixed half with
    a diffuse (its shadow is whole), one mixed half with a Transparent BSDF (shadow rays pass the sum of
    both: no shadow), a tinted portal that looks up at the sky, and one whose Position moves the ray 3 m
    sideways."""
    scene = new_scene(width, height)
    mesh_object("Floor", [(-6, -6, 0), (6, -6, 0), (6, 6, 0), (-6, 6, 0)], [(0, 1, 2, 3)],
                diffuse_material("Floor", (0.5, 0.5, 0.5)))
    panels = [portal_material("Half diffuse", mix_with="ShaderNodeBsdfDiffuse"),
              portal_material("Half transparent", mix_with="ShaderNodeBsdfTransparent", fac=0.5),
              portal_material("Skyward", direction=(0.0, 0.6, 0.8), color=(0.9, 0.6, 0.4)),
              portal_material("Sideways", offset=(3.0, 0.0, 0.0))]
    for i, mat in enumerate(panels):
        x = -2.25 + 1.5 * i
        mesh_object(mat.name, [(x - 0.6, 0, 0.2), (x + 0.6, 0, 0.2), (x + 0.6, 0, 1.4), (x - 0.6, 0, 1.4)],
                    [(0, 1, 2, 3)], mat)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=(0.5, 2.0, 0.5), segments=24, ring_count=12)
    bpy.context.active_object.data.materials.append(diffuse_material("Ball", (0.8, 0.3, 0.2)))
    add_light(scene, "SUN", (0, 0, 1), 1.0, size=0.0, rotation=(0.5, 0.0, 0.3))
    add_light(scene, "POINT", (-2.0, -2.0, 2.5), 150, size=0.3)
    add_camera(scene, (0, -5, 1.6), (0, 0, 0.8), lens=30)
    hdri_world(scene, "courtyard.exr", strength=0.3)
    return scene


def test_ray_portals_mixed_turned_and_moved_under_a_sun_and_a_lamp():
    compare_to_cycles(portal_panels_scene(), samples=128, max_bounces=4)


def test_what_the_camera_sees_of_the_world_through_a_portal_is_a_hole_in_a_transparent_film():
    """Through a portal (and a transparent surface) the camera's path is still the camera's: the world it
    meets leaves the film transparent, as Cycles keeps PATH_RAY_TRANSPARENT_BACKGROUND across portals.
    Alpha per 8 x 8 block agrees within 6 standard errors of a pixel's 0/1 coverage over the samples."""
    scene = portal_panels_scene(48, 24)
    scene.render.film_transparent = True
    samples = 256
    alpha = {engine: render_to_array(scene, engine, samples, max_bounces=4)[..., 3] for engine in ("CYCLES", "EMBER")}
    blocks = {k: a.reshape(3, 8, 6, 8).mean(axis=(1, 3)) for k, a in alpha.items()}
    assert blocks["CYCLES"].min() < 0.2 and blocks["CYCLES"].max() == 1.0  # the skyward portal, the floor
    tolerance = 6 * 0.5 / np.sqrt(samples * 64)
    np.testing.assert_allclose(blocks["EMBER"], blocks["CYCLES"], atol=tolerance)


# ---------------------------------------------------------------- Hair BSDF on meshes
HAIR = "ShaderNodeBsdfHair"


def hair_card(name, component="Reflection", color=(0.8, 0.6, 0.4), roughness=(0.2, 0.6), offset=0.0,
              uv_tangent=True):
    """A Hair BSDF as on a hair card: its tangent from the UV map (a Tangent node), or unlinked (the
    triangle's p2 - p0, as Cycles takes it on a mesh)."""
    mat, tree, out = _material(name)
    node = tree.nodes.new(HAIR)
    node.component = component
    node.inputs["Color"].default_value = (*color, 1.0)
    node.inputs["RoughnessU"].default_value, node.inputs["RoughnessV"].default_value = roughness
    node.inputs["Offset"].default_value = offset
    if uv_tangent:
        tangent = tree.nodes.new("ShaderNodeTangent")
        tangent.direction_type = "UV_MAP"
        tree.links.new(tangent.outputs["Tangent"], node.inputs["Tangent"])
    tree.links.new(node.outputs[0], out.inputs["Surface"])
    return mat


def hair_scene(width=64, height=48):
    """An empty scene for hair, with Cycles' light tree off. Cycles' hair samplers reach directions its eval
    excludes (below the normal; reflection beyond 90 degrees round the hair) and its reflection sampler
    reports a pdf that is not its density, so what a hair closure reflects depends on how lights are
    chosen, not only on the closure: where Cycles' light tree gives a lamp behind the normal no probability,
    the BSDF's samples toward it count in full, where Ember weighs them by MIS. With one lamp and the tree
    off, both choose it always and agree."""
    scene = new_scene(width, height)
    scene.cycles.use_light_tree = False
    set_world(scene, color=(0.0, 0.0, 0.0))
    return scene


def test_hair_bsdf_on_hair_cards():
    """Cards with UV tangents at a few angles, some lit from behind: reflection (shifted by Offset),
    transmission, rough reflection, and both mixed."""
    from bpy_helpers import quad_object
    scene = hair_scene()
    cards = [hair_card("Reflection", offset=0.15), hair_card("Transmission", "Transmission", (0.9, 0.7, 0.5)),
             hair_card("Rough reflection", roughness=(0.5, 0.9), color=(0.5, 0.6, 0.9))]
    mixed, tree, out = _material("Both")
    mix = tree.nodes.new("ShaderNodeMixShader")
    mix.inputs[0].default_value = 0.4
    for i, component in enumerate(("Reflection", "Transmission")):
        node = tree.nodes.new(HAIR)
        node.component = component
        node.inputs["RoughnessU"].default_value = 0.3
        tree.links.new(node.outputs[0], mix.inputs[1 + i])
    tree.links.new(mix.outputs[0], out.inputs["Surface"])
    cards.append(mixed)
    for i, mat in enumerate(cards):
        card = quad_object(mat.name, (-0.4, 0, -0.6), (0.8, 0, 0), (0, 0, 1.2), mat)
        card.location = (-1.8 + 1.2 * i, 0, 1.0)
        card.rotation_euler = (0.3 * i - 0.4, 0.5 - 0.25 * i, 0.2 * i)
    add_light(scene, "AREA", (3.5, 0.5, 2.0), 300, size=1.5, rotation=(0.0, 1.2, 0.0))
    add_camera(scene, (0, -4.5, 1.2), (0, 0, 1.0), lens=35)
    compare_to_cycles(scene, samples=256, max_bounces=4)


def test_hair_bsdf_on_smooth_spheres_takes_each_triangles_edge_for_its_tangent():
    """Unlinked, the tangent is each triangle's p2 - p0 (in the order Blender lists the corners): a faceted,
    per-triangle look, the same in both."""
    scene = hair_scene()
    materials = [hair_card("Edges", uv_tangent=False, roughness=(0.1, 1.0)),
                 hair_card("Edges rough", uv_tangent=False, roughness=(0.4, 0.5), offset=0.1, color=(0.5, 0.7, 0.9)),
                 hair_card("Edges transmission", "Transmission", uv_tangent=False, roughness=(0.3, 0.3))]
    grid_of_spheres(materials, 3)
    no_terminator_offset()
    add_light(scene, "AREA", (2, -3, 4), 600, size=2.0, rotation=(0.6, 0.3, 0.0))
    add_camera(scene, (0, -4.2, 1.0), (0, 0, 0.6), lens=40)
    compare_to_cycles(scene, samples=256, max_bounces=4)
