"""Node programs end to end: Blender node trees compiled at export (engine/export/nodes.py) and run by the
kernel (kernels/shading/program.py), against Cycles.

Point-wise nodes are probed pixel-exactly (tests/node_probe.py: a face attribute per pixel, so the value
does not depend on where the sample lands). Nodes that depend on where in the pixel the ray hits (texture
coordinates, view-dependent weights) are compared as images at equal samples with noise-derived
tolerances (bpy_helpers.compare_to_cycles).
"""
import bpy
import numpy as np
import pytest

from bpy_helpers import compare_to_cycles, emission_material, export_current, mesh_object, new_scene, set_world
from node_probe import probe_scene, render_probe, sweep

from bench import scenes


def probe_both(build, points: dict):
    scene, count = probe_scene(build, points)
    return render_probe(scene, count, "CYCLES"), render_probe(scene, count, "EMBER")


# ---------------------------------------------------------------- exact probes
def test_attribute_and_xyz_nodes_pass_values_exactly():
    points = sweep(-1e3, 1e3, 128)

    def build(tree, s):
        sep = tree.nodes.new("ShaderNodeSeparateXYZ")
        tree.links.new(s["probe"], sep.inputs[0])
        comb = tree.nodes.new("ShaderNodeCombineXYZ")
        for src, dst in ((2, 0), (0, 1), (1, 2)):
            tree.links.new(sep.outputs[src], comb.inputs[dst])
        return comb.outputs[0]

    cycles, ember = probe_both(build, {"probe": points})
    np.testing.assert_allclose(cycles, points[:, [2, 0, 1]], rtol=1e-6)
    np.testing.assert_allclose(ember, cycles, rtol=1e-6, atol=1e-6)


def test_implicit_conversions_match_blender():
    """A colour into a float input is its luminance, a vector's is its average; floats splat."""
    points = sweep(0.0, 2.0, 64)

    def build_color(tree, s):
        sep = tree.nodes.new("ShaderNodeSeparateXYZ")
        rgb = tree.nodes.new("ShaderNodeCombineColor")   # VECTOR -> RGBA -> VALUE (luminance)
        tree.links.new(s["probe"], rgb.inputs[0])
        tree.links.new(rgb.outputs[0], sep.inputs[0])    # colour into a vector input: the same numbers
        comb = tree.nodes.new("ShaderNodeCombineXYZ")
        tree.links.new(rgb.outputs[0], comb.inputs[0])   # colour into a float: luminance
        tree.links.new(s["probe"], comb.inputs[1])       # vector into a float: the average
        tree.links.new(sep.outputs[2], comb.inputs[2])
        return comb.outputs[0]

    cycles, ember = probe_both(build_color, {"probe": points})
    np.testing.assert_allclose(ember, cycles, rtol=2e-6, atol=2e-6)


def test_constant_subgraphs_fold_and_shared_ones_run_once():
    """Unlinked inputs fold away; a node read by two consumers is one op."""
    points = sweep(-2, 2, 64)

    def build(tree, s):
        const = tree.nodes.new("ShaderNodeCombineXYZ")
        const.inputs[0].default_value = 0.25
        sep_const = tree.nodes.new("ShaderNodeSeparateXYZ")
        tree.links.new(const.outputs[0], sep_const.inputs[0])
        sep = tree.nodes.new("ShaderNodeSeparateXYZ")
        tree.links.new(s["probe"], sep.inputs[0])
        comb = tree.nodes.new("ShaderNodeCombineXYZ")
        tree.links.new(sep_const.outputs[0], comb.inputs[0])   # folded: 0.25
        tree.links.new(sep.outputs[1], comb.inputs[1])
        tree.links.new(sep.outputs[1], comb.inputs[2])         # the same op read twice
        return comb.outputs[0]

    scene, count = probe_scene(build, {"probe": points})
    exported = export_current()
    program = next(s.program for s in exported.scene.materials.shaders if s.name == "Probe")
    kinds = [op.kind for op in program.ops]
    assert kinds == ["ATTRIBUTE", "ShaderNodeSeparateXYZ", "ShaderNodeCombineXYZ"], kinds
    ember = render_probe(scene, count, "EMBER")
    np.testing.assert_allclose(ember, np.stack([np.full(len(points), 0.25), points[:, 1], points[:, 1]], 1),
                               rtol=1e-6)


def test_node_groups_reroutes_and_muted_nodes_are_seen_through():
    points = sweep(-2, 2, 64)

    def build(tree, s):
        group = bpy.data.node_groups.new("Swap", "ShaderNodeTree")
        group.interface.new_socket("In", in_out="INPUT", socket_type="NodeSocketVector")
        group.interface.new_socket("Out", in_out="OUTPUT", socket_type="NodeSocketVector")
        gin, gout = group.nodes.new("NodeGroupInput"), group.nodes.new("NodeGroupOutput")
        sep, comb = group.nodes.new("ShaderNodeSeparateXYZ"), group.nodes.new("ShaderNodeCombineXYZ")
        group.links.new(gin.outputs[0], sep.inputs[0])
        group.links.new(sep.outputs[0], comb.inputs[1])
        group.links.new(sep.outputs[1], comb.inputs[0])
        group.links.new(comb.outputs[0], gout.inputs[0])
        node = tree.nodes.new("ShaderNodeGroup")
        node.node_tree = group
        reroute = tree.nodes.new("NodeReroute")
        tree.links.new(s["probe"], reroute.inputs[0])
        muted = tree.nodes.new("ShaderNodeSeparateXYZ")   # muted: passes nothing on, its consumer's value
        muted.mute = True
        tree.links.new(reroute.outputs[0], node.inputs[0])
        return node.outputs[0]

    cycles, ember = probe_both(build, {"probe": points})
    np.testing.assert_allclose(ember, cycles, rtol=1e-6, atol=1e-6)


def test_unsupported_node_warns_and_keeps_the_inputs_value():
    new_scene(8, 8)
    mat = bpy.data.materials.new("Odd")
    tree = mat.node_tree
    bsdf = tree.nodes["Principled BSDF"]
    stroke = tree.nodes.new("ShaderNodeUVAlongStroke")
    tree.links.new(stroke.outputs["UV"], bsdf.inputs["Base Color"])
    bsdf.inputs["Base Color"].default_value = (0.1, 0.2, 0.3, 1.0)
    mesh_object("Quad", [(-1, 0, 0), (1, 0, 0), (1, 0, 2), (-1, 0, 2)], [(0, 1, 2, 3)], mat)
    exported = export_current()
    assert any("UV Along Stroke" in w and "Odd" in w and "Base Color" in w for w in exported.warnings), \
        exported.warnings
    shader = next(s for s in exported.scene.materials.shaders if s.name == "Odd")
    base = shader.closures[0].input("Base Color")
    assert base.link is None and base.value == pytest.approx((0.1, 0.2, 0.3))


# ---------------------------------------------------------------- images: parity with noise tolerances
def _emission_plane(scene, build, size=4.0):
    """A plane facing the camera whose emission is the built node's output."""
    mat = emission_material("Shown", build=build)
    h = size / 2
    obj = mesh_object("Plane", [(-h, 0, -h + 1), (h, 0, -h + 1), (h, 0, h + 1), (-h, 0, h + 1)], [(0, 1, 2, 3)], mat)
    layer = obj.data.uv_layers.new(name="UVMap")
    for loop, uv in zip(obj.data.loops, [(0, 0), (1, 0), (1, 1), (0, 1)]):
        layer.data[loop.index].uv = uv
    return obj


def _uv_sphere(mat, radius, location, segments=48, ring_count=24, smooth=True, rotation=None, scale=None):
    """A UV sphere (smooth-shaded unless smooth is False, turned and scaled if asked) of material mat."""
    bpy.ops.mesh.primitive_uv_sphere_add(radius=radius, location=location, segments=segments, ring_count=ring_count)
    if smooth:
        bpy.ops.object.shade_smooth()
    ob = bpy.context.active_object
    if rotation is not None:
        ob.rotation_euler = rotation
    if scale is not None:
        ob.scale = scale
    ob.data.materials.append(mat)
    return ob


def _shown_positive(tree, vector):
    """|v| + 0.05: positive and away from zero, so relative block errors mean something."""
    m = tree.nodes.new("ShaderNodeVectorMath")
    m.operation = "ABSOLUTE"
    tree.links.new(vector, m.inputs[0])
    add = tree.nodes.new("ShaderNodeVectorMath")
    add.operation = "ADD"
    add.inputs[1].default_value = (0.05, 0.05, 0.05)
    tree.links.new(m.outputs[0], add.inputs[0])
    return add.outputs[0]


@pytest.mark.parametrize("output", ["Generated", "UV", "Object", "Camera", "Window", "Normal", "Reflection"])
def test_texture_coordinates_against_cycles(output):
    scene = new_scene(32, 32)
    set_world(scene, color=(0, 0, 0))

    def build(tree):
        return _shown_positive(tree, tree.nodes.new("ShaderNodeTexCoord").outputs[output])

    # Large enough to fill the frame: no silhouette, whose coverage noise the replicates cannot measure.
    obj = _emission_plane(scene, build, size=14.0)
    obj.location = (0.3, 0.5, -0.2)
    obj.rotation_euler = (0.2, 0.0, 0.3)
    compare_to_cycles(scene, samples=16, max_bounces=0)


def test_generated_coordinates_of_a_deformed_mesh_are_its_undeformed_ones_as_in_cycles():
    """Generated on a mesh its modifiers deform (a public fire whose Wave and Displace modifiers shape a cube, its
    flames a gradient on Generated: +2.0% and blocks 32 standard errors off before): Cycles reads the mesh before
    its deforming modifiers (the ORCO layer a render's depsgraph computes), so the colours stay on the shape as
    modelled. Here a Displace modifier slides a plane 0.7 sideways (direction X, no texture); Ember read the moved
    positions, its colours sliding across the plane."""
    scene = new_scene(32, 32)
    set_world(scene, color=(0, 0, 0))

    def build(tree):
        return _shown_positive(tree, tree.nodes.new("ShaderNodeTexCoord").outputs["Generated"])

    obj = _emission_plane(scene, build, size=14.0)
    slide = obj.modifiers.new("Slide", "DISPLACE")
    slide.direction, slide.strength, slide.mid_level = "X", 0.7, 0.0
    obj.rotation_euler = (0.2, 0.0, 0.3)
    compare_to_cycles(scene, samples=16, max_bounces=0)


@pytest.mark.parametrize("output", ["Position", "Normal", "True Normal", "Incoming", "Parametric", "Backfacing"])
def test_geometry_outputs_against_cycles(output):
    scene = new_scene(32, 32)
    set_world(scene, color=(0, 0, 0))

    def build(tree):
        return _shown_positive(tree, tree.nodes.new("ShaderNodeNewGeometry").outputs[output])

    obj = _emission_plane(scene, build, size=14.0)
    obj.rotation_euler = (0.0, 0.0, 0.5 if output != "Backfacing" else 3.0)
    compare_to_cycles(scene, samples=16, max_bounces=0)


@pytest.mark.parametrize("node,output", [("ShaderNodeLayerWeight", "Fresnel"), ("ShaderNodeLayerWeight", "Facing"),
                                         ("ShaderNodeFresnel", "Fac")])
def test_view_dependent_weights_on_a_sphere(node, output):
    scene = new_scene(32, 32)
    set_world(scene, color=(0, 0, 0))

    def build(tree):
        weight = tree.nodes.new(node)
        if node == "ShaderNodeLayerWeight":
            weight.inputs["Blend"].default_value = 0.3
        return weight.outputs[output]

    _uv_sphere(emission_material("Weight", build=build, into="Strength"), 1.0, (0, 0, 1.2))
    # The image is the sphere's edge, where Fresnel is brightest: at 16 samples one engine's image mean
    # has a 1.5% standard deviation (10 sets of 4 seeds), too close to compare_to_cycles' 2% tolerance.
    compare_to_cycles(scene, samples=256, max_bounces=0)


@pytest.mark.parametrize("axis", ["GEOMETRY", "X", "Y", "Z"])
def test_radial_tangents_on_a_sphere_against_cycles(axis):
    """Geometry's Tangent and the Tangent node's radial directions (on a plane the Z one would lie along
    the normal: degenerate, so a rotated sphere)."""
    scene = new_scene(32, 32)

    def build(tree):
        if axis == "GEOMETRY":
            return tree.nodes.new("ShaderNodeNewGeometry").outputs["Tangent"]
        node = tree.nodes.new("ShaderNodeTangent")
        node.direction_type, node.axis = "RADIAL", axis
        return node.outputs["Tangent"]

    _sphere_showing(scene, build, name="Tangents", location=(0.2, 0, 1.2))


def _sphere_showing(scene, build, samples=64, name="Shown", location=(0.2, 0.1, 1.2)):
    """A transformed sphere whose emission is |build(tree)| + 0.05, compared with Cycles. 64 samples: 16 per
    replicate, so that the replicates can measure the coverage noise of silhouette pixels (at 4, of which
    sample 0 looks through the pixel's centre in every replicate, a block on the silhouette read z = 7)."""
    set_world(scene, color=(0, 0, 0))
    mat = emission_material(name, build=lambda tree: _shown_positive(tree, build(tree)))
    _uv_sphere(mat, 1.3, location, rotation=(0.4, 0.2, 0.7), scale=(1.0, 0.8, 1.2))
    compare_to_cycles(scene, samples=samples, max_bounces=0)


@pytest.mark.parametrize("kind,source,target", [
    ("POINT", "WORLD", "OBJECT"), ("POINT", "OBJECT", "CAMERA"), ("POINT", "CAMERA", "WORLD"),
    ("VECTOR", "WORLD", "CAMERA"), ("VECTOR", "OBJECT", "WORLD"), ("VECTOR", "CAMERA", "OBJECT"),
    ("NORMAL", "WORLD", "OBJECT"), ("NORMAL", "OBJECT", "CAMERA"), ("NORMAL", "CAMERA", "WORLD")])
def test_vector_transform_against_cycles(kind, source, target):
    scene = new_scene(32, 32)

    def build(tree):
        coords = tree.nodes.new("ShaderNodeTexCoord")
        node = tree.nodes.new("ShaderNodeVectorTransform")
        node.vector_type, node.convert_from, node.convert_to = kind, source, target
        tree.links.new(coords.outputs["Object"], node.inputs["Vector"])
        return node.outputs["Vector"]

    _sphere_showing(scene, build)


@pytest.mark.parametrize("output", ["View Vector", "View Z Depth", "View Distance", "Dot"])
def test_camera_data_and_normal_nodes_against_cycles(output):
    scene = new_scene(32, 32)

    def build(tree):
        if output == "Dot":
            node = tree.nodes.new("ShaderNodeNormal")
            node.outputs["Normal"].default_value = (0.3, -0.8, 0.5)
            geometry = tree.nodes.new("ShaderNodeNewGeometry")
            tree.links.new(geometry.outputs["Normal"], node.inputs["Normal"])
            return node.outputs["Dot"]
        return tree.nodes.new("ShaderNodeCameraData").outputs[output]

    _sphere_showing(scene, build)


@pytest.mark.parametrize("pixel_size", [False, True])
def test_wireframe_against_cycles(pixel_size):
    scene = new_scene(48, 48)
    set_world(scene, color=(0, 0, 0))

    def build(tree):
        wire = tree.nodes.new("ShaderNodeWireframe")
        wire.use_pixel_size = pixel_size
        wire.inputs["Size"].default_value = 1.5 if pixel_size else 0.04
        return wire.outputs["Fac"]

    _uv_sphere(emission_material("Wire", build=build, into="Strength"), 1.3, (0, 0, 1.3), segments=12, ring_count=6,
               smooth=False)
    compare_to_cycles(scene, samples=64, max_bounces=0)


def test_object_info_and_vertex_colors_against_cycles():
    scene = new_scene(32, 32)
    set_world(scene, color=(0, 0, 0))

    def build(tree):
        info = tree.nodes.new("ShaderNodeObjectInfo")
        vc = tree.nodes.new("ShaderNodeVertexColor")
        comb = tree.nodes.new("ShaderNodeCombineXYZ")
        tree.links.new(info.outputs["Random"], comb.inputs[0])
        tree.links.new(info.outputs["Color"], comb.inputs[1])
        tree.links.new(vc.outputs["Color"], comb.inputs[2])
        return comb.outputs[0]

    obj = _emission_plane(scene, build, size=14.0)
    obj.color = (0.2, 0.9, 0.4, 1.0)
    colors = obj.data.color_attributes.new("Col", "FLOAT_COLOR", "POINT")
    for i, c in enumerate([(1, 0, 0, 1), (0, 1, 0, 1), (0, 0, 1, 1), (1, 1, 1, 1)]):
        colors.data[i].color = c
    obj.data.color_attributes.render_color_index = 0
    compare_to_cycles(scene, samples=16, max_bounces=0)


IMAGE_MODES = [(i, e, "FLAT", True) for i in ("Closest", "Linear", "Cubic")
               for e in ("REPEAT", "EXTEND", "CLIP", "MIRROR")] + \
              [("Linear", "REPEAT", "SPHERE", True), ("Linear", "REPEAT", "TUBE", True),
               ("Linear", "REPEAT", "FLAT", False), ("Cubic", "CLIP", "FLAT", False)]


@pytest.mark.parametrize("interpolation,extension,projection,float_buffer", IMAGE_MODES)
def test_image_texture_modes_probe_exactly(interpolation, extension, projection, float_buffer):
    """Every interpolation and extension, and the Sphere and Tube projections, of a float and of an 8-bit
    sRGB image (filtered encoded, decoded after), at coordinates well outside [0, 1]."""
    points = sweep(-1.5, 2.5, 256, seed=7)

    def build(tree, s):
        img = bpy.data.images.new("Checks", 5, 4, float_buffer=float_buffer)
        rng = np.random.default_rng(3)
        img.pixels.foreach_set(np.concatenate([rng.uniform(0.05, 1.0, (20, 3)), np.ones((20, 1))], 1)
                               .ravel().astype(np.float32))
        tex = tree.nodes.new("ShaderNodeTexImage")
        tex.image, tex.interpolation, tex.extension, tex.projection = img, interpolation, extension, projection
        tree.links.new(s["probe"], tex.inputs["Vector"])
        return tex.outputs["Color"]

    cycles, ember = probe_both(build, {"probe": points})
    assert np.ptp(cycles) > 0.3  # the probe sees the image, not a constant
    np.testing.assert_allclose(ember, cycles, rtol=2e-6, atol=2e-6)


def test_box_projection_on_a_sphere_against_cycles():
    scene = new_scene(32, 32)
    set_world(scene, color=(0, 0, 0))
    img = bpy.data.images.new("Checks", 4, 4, float_buffer=True)
    rng = np.random.default_rng(3)
    img.pixels.foreach_set(np.concatenate([rng.uniform(0.1, 1.0, (16, 3)), np.ones((16, 1))], 1).ravel()
                           .astype(np.float32))

    def build(tree):
        tex = tree.nodes.new("ShaderNodeTexImage")
        tex.image, tex.projection, tex.projection_blend = img, "BOX", 0.3
        coords = tree.nodes.new("ShaderNodeTexCoord")
        tree.links.new(coords.outputs["Object"], tex.inputs["Vector"])
        return tex.outputs["Color"]

    _uv_sphere(emission_material("Boxed", build=build), 1.6, (0, 0, 1.2), segments=64, ring_count=32,
               rotation=(0.3, 0.2, 0.5))
    compare_to_cycles(scene, samples=64, max_bounces=0)


# ---------------------------------------------------------------- parity scenes
def test_procedural_marble_with_bump_against_cycles():
    """Noise -> Color Ramp into Base Color, the same noise through Bump into Normal, Voronoi roughness."""
    scene = scenes.lit_sphere_scene(scenes.marble_material)
    exported = export_current()
    assert not [w for w in exported.warnings if "Marble" in w], exported.warnings
    compare_to_cycles(scene, samples=64, max_bounces=4)


def test_layer_weight_mix_and_tinted_image_against_cycles():
    """A glTF-style tint (image x colour through a Mix node) in a Layer Weight mix of Diffuse and Glossy."""
    scene = scenes.lit_sphere_scene(scenes.tinted_material)
    compare_to_cycles(scene, samples=64, max_bounces=4)


@pytest.mark.parametrize("output", ["Is Glossy Ray", "Is Diffuse Ray", "Is Reflection Ray", "Is Transmission Ray",
                                    "Is Singular Ray", "Diffuse Depth", "Glossy Depth", "Transmission Depth",
                                    "Ray Depth", "Is Camera Ray", "Is Shadow Ray"])
def test_light_path_outputs_against_cycles(output):
    """A floor whose colour switches with the Light Path output, seen directly, in a rough metal ball, through
    a glass ball and a sharp mirror, lit by a lamp (shadow rays) and a grey sky."""
    scene = new_scene(48, 32)
    set_world(scene, color=(0.4, 0.45, 0.5))
    mat = bpy.data.materials.new("Switch")
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    grey, red = tree.nodes.new("ShaderNodeBsdfDiffuse"), tree.nodes.new("ShaderNodeBsdfDiffuse")
    red.inputs["Color"].default_value = (0.9, 0.1, 0.05, 1.0)
    mix = tree.nodes.new("ShaderNodeMixShader")
    path = tree.nodes.new("ShaderNodeLightPath")
    clamp = tree.nodes.new("ShaderNodeMath")
    clamp.operation, clamp.use_clamp = "MULTIPLY", True
    clamp.inputs[1].default_value = 0.5
    tree.links.new(path.outputs[output], clamp.inputs[0])
    tree.links.new(clamp.outputs[0], mix.inputs[0])
    tree.links.new(grey.outputs[0], mix.inputs[1])
    tree.links.new(red.outputs[0], mix.inputs[2])
    tree.links.new(mix.outputs[0], out.inputs["Surface"])
    bpy.ops.mesh.primitive_plane_add(size=12)
    bpy.context.active_object.data.materials.append(mat)
    for x, (name, inputs) in zip((-1.3, 0.0, 1.3), (
            ("Rough Metal", {"Metallic": 1.0, "Roughness": 0.3}),
            ("Glass", {"Transmission Weight": 1.0, "Roughness": 0.0}),
            ("Mirror", {"Metallic": 1.0, "Roughness": 0.0}))):
        ball = bpy.data.materials.new(name)
        bsdf = ball.node_tree.nodes["Principled BSDF"]
        for key, value in inputs.items():
            bsdf.inputs[key].default_value = value
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.6, location=(x, 0, 0.6), segments=32, ring_count=16)
        bpy.ops.object.shade_smooth()
        bpy.context.active_object.data.materials.append(ball)
    lamp = bpy.data.lights.new("Lamp", "POINT")
    lamp.energy, lamp.shadow_soft_size = 300.0, 0.3
    lamp_object = bpy.data.objects.new("Lamp", lamp)
    lamp_object.location = (1.5, -2.0, 3.0)
    scene.collection.objects.link(lamp_object)
    compare_to_cycles(scene, samples=64, max_bounces=4)


# ---------------------------------------------------------------- bad graphs
def test_a_cycle_in_the_node_tree_is_cut_not_followed():
    """Blender marks a link that closes a loop invalid; the program sees the loop open, as Cycles does,
    and the render finishes with finite values."""
    new_scene(8, 8)
    mat = bpy.data.materials.new("Loop")
    tree = mat.node_tree
    bsdf = tree.nodes["Principled BSDF"]
    a, b = tree.nodes.new("ShaderNodeMath"), tree.nodes.new("ShaderNodeMath")
    tree.links.new(a.outputs[0], b.inputs[0])
    tree.links.new(b.outputs[0], a.inputs[0])
    tree.links.new(b.outputs[0], bsdf.inputs["Roughness"])
    mesh_object("Quad", [(-1, 0, 0), (1, 0, 0), (1, 0, 2), (-1, 0, 2)], [(0, 1, 2, 3)], mat)
    exported = export_current()
    shader = next(s for s in exported.scene.materials.shaders if s.name == "Loop")
    assert len(shader.program.ops) <= 2
    from ember.kernels import Renderer, RenderSettings
    with Renderer(exported.scene, threads=1) as renderer:
        assert np.isfinite(renderer.render(RenderSettings(samples=2, max_bounces=2)).image).all()


def test_a_missing_image_inside_a_group_renders_magenta_with_a_warning():
    points = sweep(0.0, 1.0, 64)

    def build(tree, s):
        group = bpy.data.node_groups.new("Textured", "ShaderNodeTree")
        group.interface.new_socket("Vector", in_out="INPUT", socket_type="NodeSocketVector")
        group.interface.new_socket("Color", in_out="OUTPUT", socket_type="NodeSocketColor")
        gin, gout = group.nodes.new("NodeGroupInput"), group.nodes.new("NodeGroupOutput")
        tex = group.nodes.new("ShaderNodeTexImage")   # no image
        group.links.new(gin.outputs[0], tex.inputs["Vector"])
        group.links.new(tex.outputs["Color"], gout.inputs[0])
        node = tree.nodes.new("ShaderNodeGroup")
        node.node_tree = group
        tree.links.new(s["probe"], node.inputs[0])
        return node.outputs[0]

    scene, count = probe_scene(build, {"probe": points})
    exported = export_current()
    assert any("Image Texture" in w and "no image" in w and "Probe" in w for w in exported.warnings), \
        exported.warnings
    cycles, ember = render_probe(scene, count, "CYCLES"), render_probe(scene, count, "EMBER")
    np.testing.assert_allclose(cycles, np.tile([1.0, 0.0, 1.0], (count, 1)), atol=1e-6)
    np.testing.assert_allclose(ember, cycles, atol=1e-6)


@pytest.mark.parametrize("space", ["ACEScg", "ACES2065-1", "Linear Rec.2020", "Linear CIE-XYZ D65"])
def test_byte_images_in_linear_colour_spaces_convert_as_cycles(space):
    """8-bit images in a linear space other than scene linear are converted at load (Cycles: to half
    floats, negative out of gamut). Tolerance: Blender's mathutils conversion against Cycles' OCIO
    processor (both Blender's config) differ by up to 0.2%, plus half-float rounding."""
    points = sweep(0.0, 1.0, 64)

    def build(tree, s):
        img = bpy.data.images.new("Bytes", 4, 4, float_buffer=False)
        img.colorspace_settings.name = space
        rng = np.random.default_rng(1)
        img.pixels.foreach_set(np.concatenate([rng.uniform(0.0, 1.0, (16, 3)), np.ones((16, 1))], 1).ravel()
                               .astype(np.float32))
        tex = tree.nodes.new("ShaderNodeTexImage")
        tex.image, tex.interpolation = img, "Closest"
        tree.links.new(s["probe"], tex.inputs["Vector"])
        return tex.outputs["Color"]

    cycles, ember = probe_both(build, {"probe": points})
    assert cycles.min() < 0 or space == "Linear CIE-XYZ D65"  # out-of-gamut colours stay negative
    np.testing.assert_allclose(ember, cycles, rtol=3e-3, atol=5e-4)
