"""Node graphs of any depth: long chains of shader nodes (Math nodes in series, nested Mix Shaders, node
groups inside node groups, reroutes) compile without recursion (engine/export/graph.py) and run without
it (kernels/shading/program.py), and render the value Cycles renders, or where Cycles gives up (its SVM
stack holds about 250 nested Mix Shaders with a varying factor), the closed form. A loop in a node tree,
which Blender cannot evaluate, renders the material or world black as in Cycles, with a warning naming its
nodes; links Blender marks invalid for other reasons are left out, as in Cycles, with a warning.

Export times are printed (pytest -s), not asserted.
"""
import bpy
import numpy as np
import pytest

from bpy_helpers import export_current, new_scene, render_to_array
from node_probe import probe_scene, render_probe, sweep

from ember.engine.export.graph import run_nested


def _add(tree, value_socket, amount: float):
    node = tree.nodes.new("ShaderNodeMath")
    node.operation = "ADD"
    node.inputs[1].default_value = amount
    tree.links.new(value_socket, node.inputs[0])
    return node.outputs[0]


def _x(tree, probe):
    """The probe point's x as a float socket."""
    sep = tree.nodes.new("ShaderNodeSeparateXYZ")
    tree.links.new(probe, sep.inputs[0])
    return sep.outputs[0]


def _probe_both(build, points, label: str):
    scene, count = probe_scene(build, {"probe": points})
    exported = export_current()
    print(f"{label}: export {exported.seconds:.2f} s")
    return render_probe(scene, count, "CYCLES"), render_probe(scene, count, "EMBER"), exported


def test_a_thousand_math_nodes_in_series_render_as_cycles():
    points = sweep(0.0, 1.0, 16)
    count = 1000

    def build(tree, s):
        value = _x(tree, s["probe"])
        for _ in range(count):
            value = _add(tree, value, 0.001)
        return value

    cycles, ember, exported = _probe_both(build, points, "1000 Math nodes")
    program = next(s.program for s in exported.scene.materials.shaders if s.name == "Probe")
    assert len(program) == count + 2  # the attribute, Separate XYZ, then one op per node
    np.testing.assert_allclose(ember, cycles, rtol=1e-6, atol=1e-6)
    # float32 rounds each of the 1000 additions by at most half an ulp of 2
    np.testing.assert_allclose(ember[:, 0], points[:, 0] + 1.0, atol=count * 2.0 ** -23)


def _nested_shaders(kind: str, depth: int):
    """The probe material rewired to `depth` nested Mix or Add Shaders over Emissions.

    Mix: each mixes the one below (Emission 1 at the bottom) with an Emission of 0.5 by the probe's x,
    showing 0.5 + 0.5 (1 - x)^depth. Add: each adds an Emission of 0.001 to the one below (the probe's
    Emission at the bottom), showing x + 0.001 depth."""
    tree = bpy.data.materials["Probe"].node_tree
    probe = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeAttribute").outputs["Vector"]
    output = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    fac = _x(tree, probe)
    other = tree.nodes.new("ShaderNodeEmission")
    if kind == "Mix":
        other.inputs["Color"].default_value = (0.5, 0.5, 0.5, 1.0)
        shader = tree.nodes.new("ShaderNodeEmission").outputs[0]
    else:
        other.inputs["Strength"].default_value = 0.001
        shader = output.inputs["Surface"].links[0].from_socket
    for _ in range(depth):
        node = tree.nodes.new(f"ShaderNode{kind}Shader")
        if kind == "Mix":
            tree.links.new(fac, node.inputs[0])
        tree.links.new(shader, node.inputs[-2])
        tree.links.new(other.outputs[0], node.inputs[-1])
        shader = node.outputs[0]
    tree.links.new(shader, output.inputs["Surface"])


@pytest.mark.parametrize("kind, depth", [("Mix", 200), ("Mix", 500), ("Add", 500)])
def test_nested_mix_and_add_shaders_render_their_closed_form(kind, depth):
    """Against Cycles too, but for 500 Mix Shaders: there Cycles stops ("out of SVM stack space", from
    about 250 with a varying factor) and renders black."""
    points = sweep(0.0, 0.01 if kind == "Mix" else 1.0, 16)
    scene, count = probe_scene(lambda tree, s: s["probe"], {"probe": points})
    _nested_shaders(kind, depth)
    exported = export_current()
    print(f"{depth} nested {kind} Shaders: export {exported.seconds:.2f} s")
    ember = render_probe(scene, count, "EMBER")
    x = points[:, 0].astype(np.float64)
    expected = 0.5 + 0.5 * (1.0 - x) ** depth if kind == "Mix" else x + 0.001 * depth
    # float32 products (Mix weights) and sums (Add) of `depth` terms
    np.testing.assert_allclose(ember[:, 0], expected, rtol=depth * 2.0 ** -22)
    if (kind, depth) != ("Mix", 500):
        np.testing.assert_allclose(ember, render_probe(scene, count, "CYCLES"), rtol=depth * 2.0 ** -22)


def _float_group(name: str):
    group = bpy.data.node_groups.new(name, "ShaderNodeTree")
    group.interface.new_socket("In", in_out="INPUT", socket_type="NodeSocketFloat")
    group.interface.new_socket("Out", in_out="OUTPUT", socket_type="NodeSocketFloat")
    return group, group.nodes.new("NodeGroupInput"), group.nodes.new("NodeGroupOutput")


def _group_node(tree, group, value):
    node = tree.nodes.new("ShaderNodeGroup")
    node.node_tree = group
    tree.links.new(value, node.inputs[0])
    return node.outputs[0]


def test_deeply_nested_node_groups_and_long_group_series_render_as_cycles():
    """Groups 300 deep, each adding 0.001 after the one inside it, then 300 instances of one group in
    series, each adding 0.001. Blender 5.3 evaluates groups nested at most 101 deep (a deeper one makes
    the group holding it output 0 in Cycles; Ember evaluates any depth): 100 deep there."""
    points = sweep(0.0, 1.0, 16)
    depth = series = 300
    if bpy.app.version[:2] >= (5, 3):
        depth = 100

    def build(tree, s):
        inner = None
        for d in range(depth):
            group, group_in, group_out = _float_group(f"Nested{d}")
            value = group_in.outputs[0]
            if inner is not None:
                value = _group_node(group, inner, value)
            group.links.new(_add(group, value, 0.001), group_out.inputs[0])
            inner = group
        value = _group_node(tree, inner, _x(tree, s["probe"]))
        step, step_in, step_out = _float_group("Step")
        step.links.new(_add(step, step_in.outputs[0], 0.001), step_out.inputs[0])
        for _ in range(series):
            value = _group_node(tree, step, value)
        return value

    cycles, ember, _ = _probe_both(build, points, f"groups {depth} deep + {series} in series")
    np.testing.assert_allclose(ember, cycles, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(ember[:, 0], points[:, 0] + (depth + series) * 0.001,
                               atol=(depth + series) * 2.0 ** -23)


def test_a_long_reroute_chain_renders_as_cycles():
    points = sweep(0.0, 1.0, 16)

    def build(tree, s):
        value = _x(tree, s["probe"])
        for _ in range(200):
            reroute = tree.nodes.new("NodeReroute")
            tree.links.new(value, reroute.inputs[0])
            value = reroute.outputs[0]
        return _add(tree, value, 0.25)

    cycles, ember, _ = _probe_both(build, points, "200 reroutes")
    np.testing.assert_allclose(ember, cycles, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(ember[:, 0], points[:, 0] + 0.25, rtol=1e-6)


def test_a_world_of_500_nested_mix_shaders_renders_its_closed_form():
    """Backgrounds mixed 500 deep by 0.001 x Is Camera Ray: the camera sees 0.5 + 0.5 x 0.999^500."""
    depth = 500
    scene = new_scene(4, 4)
    world = bpy.data.worlds.new("Deep")
    scene.world = world
    world.cycles.sampling_method = "MANUAL"
    world.cycles.sample_map_resolution = 4   # the bake for light sampling: not what is tested
    tree = world.node_tree
    tree.nodes.clear()
    output = tree.nodes.new("ShaderNodeOutputWorld")
    camera_ray = tree.nodes.new("ShaderNodeLightPath").outputs["Is Camera Ray"]
    fac = tree.nodes.new("ShaderNodeMath")
    fac.operation = "MULTIPLY"
    fac.inputs[1].default_value = 0.001
    tree.links.new(camera_ray, fac.inputs[0])
    half = tree.nodes.new("ShaderNodeBackground")
    half.inputs["Color"].default_value = (0.5, 0.5, 0.5, 1.0)
    white = tree.nodes.new("ShaderNodeBackground")
    white.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    shader = white.outputs[0]
    for _ in range(depth):
        mix = tree.nodes.new("ShaderNodeMixShader")
        tree.links.new(fac.outputs[0], mix.inputs[0])
        tree.links.new(shader, mix.inputs[1])
        tree.links.new(half.outputs[0], mix.inputs[2])
        shader = mix.outputs[0]
    tree.links.new(shader, output.inputs["Surface"])
    exported = export_current()
    print(f"world of {depth} nested Mix Shaders: export {exported.seconds:.2f} s")
    assert exported.scene.world.program is not None
    image = render_to_array(scene, "EMBER", 1, max_bounces=0)
    np.testing.assert_allclose(image[..., :3], 0.5 + 0.5 * 0.999 ** depth, rtol=depth * 2.0 ** -22)


def _loop(tree, names=("Loop Start", "Loop End")):
    """Two Math nodes feeding each other (Blender marks the second link invalid)."""
    first, second = tree.nodes.new("ShaderNodeMath"), tree.nodes.new("ShaderNodeMath")
    first.name, second.name = names
    tree.links.new(first.outputs[0], second.inputs[0])
    tree.links.new(second.outputs[0], first.inputs[0])
    return second


def _group_with_loop():
    group, group_in, group_out = _float_group("Looped")
    _loop(group)
    group.links.new(group_in.outputs[0], group_out.inputs[0])
    return group


@pytest.mark.parametrize("where, black", [("the material's tree, unconnected", True),
                                          ("a group the material reads", True),
                                          ("a group nothing reads", False)])
def test_a_loop_in_a_node_tree_renders_as_in_cycles_with_a_warning(where, black):
    """Blender 5's shader inlining, which Cycles renders from, gives up on a tree holding a loop (or
    reading a group that holds one): the material renders black. Ember renders it so, and says why."""
    points = sweep(0.0, 1.0, 16)

    def build(tree, s):
        value = _x(tree, s["probe"])
        if where == "the material's tree, unconnected":
            _loop(tree)
        elif where == "a group the material reads":
            value = _group_node(tree, _group_with_loop(), value)
        else:
            tree.nodes.new("ShaderNodeGroup").node_tree = _group_with_loop()
        return value

    cycles, ember, exported = _probe_both(build, points, "loop")
    np.testing.assert_array_equal(ember, cycles)
    warning = next((w for w in exported.warnings if w.startswith("Material 'Probe'")), "")
    if black:
        assert not ember.any()
        assert "loop (Math 'Loop Start' -> Math 'Loop End' -> Math 'Loop Start'" in warning and "black" in warning, \
            exported.warnings
    else:
        np.testing.assert_array_equal(ember[:, 0], points[:, 0])


def test_a_link_blender_marks_invalid_is_left_out_as_in_cycles_with_a_warning():
    """A shader output into a float input: Blender marks the link invalid, Cycles leaves it out."""
    points = sweep(0.0, 1.0, 16)

    def build(tree, s):
        add = tree.nodes.new("ShaderNodeMath")
        add.inputs[1].default_value = 0.25
        tree.links.new(tree.nodes.new("ShaderNodeBsdfDiffuse").outputs[0], add.inputs[1])
        tree.links.new(_x(tree, s["probe"]), add.inputs[0])
        return add.outputs[0]

    cycles, ember, exported = _probe_both(build, points, "invalid link")
    np.testing.assert_array_equal(ember, cycles)
    np.testing.assert_allclose(ember[:, 0], points[:, 0] + 0.25, rtol=1e-6)
    assert any("link from Diffuse BSDF 'Diffuse BSDF' to Math 'Math' Value is invalid" in w
               for w in exported.warnings), exported.warnings


def test_a_loop_in_the_world_renders_black_as_in_cycles_with_a_warning():
    scene = new_scene(4, 4)
    world = bpy.data.worlds.new("Looped")
    scene.world = world
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.5, 0.5, 0.5, 1.0)
    _loop(world.node_tree)
    exported = export_current()
    assert any(w.startswith("World 'Looped'") and "loop" in w for w in exported.warnings), exported.warnings
    assert not render_to_array(scene, "EMBER", 1, max_bounces=0)[..., :3].any()
    assert not render_to_array(scene, "CYCLES", 1, max_bounces=0)[..., :3].any()


def test_nested_steps_run_in_call_order_and_raise_where_a_call_would():
    """graph.run_nested: 100,000 levels, the order a recursion takes; an exception reaches the callers'
    handlers."""
    visited = []

    def count_down(n):
        visited.append(n)
        return 0 if n == 0 else 1 + (yield count_down(n - 1))

    assert run_nested(count_down(100_000)) == 100_000
    assert visited == list(range(100_000, -1, -1))

    cleaned = []

    def failing(n):
        try:
            if n == 0:
                raise ValueError("bottom")
            return (yield failing(n - 1))
        finally:
            cleaned.append(n)

    with pytest.raises(ValueError, match="bottom"):
        run_nested(failing(5000))
    assert cleaned == list(range(5001))
