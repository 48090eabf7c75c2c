"""The Raycast node (Blender 5.3) against Cycles (svm/raycast.h): a floor and a sphere whose emission shows each
output of a ray cast from the shading point: along the normal, into the object (its own far side: Self Hit),
straight up with an unnormalized Direction (Hit Distance in its units), from a moved Position, and Only Local.
Before, the node passed its consumer's own value with a warning."""
import bpy
import pytest

from bpy_helpers import add_camera, compare_to_cycles, emission_material, export_current, new_scene, set_world

pytestmark = pytest.mark.skipif(not hasattr(bpy.types, "ShaderNodeRaycast"), reason="Blender 5.3 added the node")


def raycast_scene(output, length=2.0, direction=None, inward=False, offset=None, only_local=False):
    scene = new_scene(40, 40)
    add_camera(scene, (0, -5, 4), (0, 0, 0.3), lens=35)
    set_world(scene, color=(0, 0, 0))

    def build(tree):
        cast = tree.nodes.new("ShaderNodeRaycast")
        cast.inputs["Length"].default_value, cast.only_local = length, only_local
        geometry = tree.nodes.new("ShaderNodeNewGeometry")
        if direction is not None:
            fixed = tree.nodes.new("ShaderNodeCombineXYZ")
            for k, value in enumerate(direction):
                fixed.inputs[k].default_value = value
            tree.links.new(fixed.outputs[0], cast.inputs["Direction"])
        elif inward:
            flip = tree.nodes.new("ShaderNodeVectorMath")
            flip.operation = "SCALE"
            flip.inputs["Scale"].default_value = -1.0
            tree.links.new(geometry.outputs["Normal"], flip.inputs[0])
            tree.links.new(flip.outputs[0], cast.inputs["Direction"])
        if offset is not None:
            moved = tree.nodes.new("ShaderNodeVectorMath")
            moved.operation = "ADD"
            moved.inputs[1].default_value = offset
            tree.links.new(geometry.outputs["Position"], moved.inputs[0])
            tree.links.new(moved.outputs[0], cast.inputs["Position"])
        socket = cast.outputs[output]
        if socket.type == "VECTOR":
            absolute = tree.nodes.new("ShaderNodeVectorMath")
            absolute.operation = "ABSOLUTE"
            tree.links.new(socket, absolute.inputs[0])
            socket = absolute.outputs[0]
        return socket

    material = emission_material("Cast", build=build)
    bpy.ops.mesh.primitive_plane_add(size=4)
    bpy.context.active_object.data.materials.append(material)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.6, location=(0.3, 0.2, 1.0))
    bpy.ops.object.shade_smooth()
    bpy.context.active_object.data.materials.append(material)
    return scene


CASES = {
    "is_hit": dict(output="Is Hit"),
    "distance": dict(output="Hit Distance"),
    "position": dict(output="Hit Position"),
    "normal": dict(output="Hit Normal"),
    "self_hit_inward": dict(output="Self Hit", inward=True),
    "inward_distance": dict(output="Hit Distance", inward=True),
    "up_unnormalized": dict(output="Hit Distance", direction=(0.0, 0.0, 2.0), length=1.5),
    "moved_position": dict(output="Is Hit", offset=(0.0, 0.0, 0.3), direction=(0.0, 0.0, 1.0)),
    "only_local": dict(output="Is Hit", only_local=True, direction=(0.0, 0.0, 1.0)),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_raycast_matches_cycles(name):
    compare_to_cycles(raycast_scene(**CASES[name]), samples=16, max_bounces=1, mean_z=4.0)


def test_raycast_is_read_without_a_warning():
    raycast_scene("Is Hit")
    assert not [w for w in export_current().warnings if "Raycast" in w]
