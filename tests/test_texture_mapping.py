"""A texture node's Texture Mapping panel (the node's Properties in the sidebar), against Cycles: the Vector moved
by location, rotation and scale as a Point, a Texture (the inverse), a Vector or a Normal, with its axes
remapped, before the texture reads it (Cycles' TextureMapping::compute_transform). Before, the panel was
ignored with a warning."""
import math

import bpy
import pytest

from bpy_helpers import (add_camera, compare_to_cycles, emission_material, export_current, manual_world_map, new_scene,
                         set_world)

PANELS = {
    "point": dict(vector_type="POINT", translation=(0.3, -0.2, 0.1), rotation=(0.4, 0.2, 0.9), scale=(1.5, 0.7, 1.0)),
    "texture": dict(vector_type="TEXTURE", translation=(0.3, -0.2, 0.1), rotation=(0.0, 0.3, 0.6),
                    scale=(0.5, 2.0, 1.0)),
    "vector": dict(vector_type="VECTOR", translation=(5.0, 5.0, 5.0), rotation=(0.5, 0.0, 0.2), scale=(2.0, 1.0, 1.0)),
    "normal": dict(vector_type="NORMAL", rotation=(0.3, 0.6, 0.0), scale=(1.0, 3.0, 1.0)),
    "axes": dict(vector_type="POINT", mapping_x="Z", mapping_y="X", mapping_z="NONE", scale=(2.0, 2.0, 2.0)),
}


def textured_scene(kind, panel):
    """A sphere and a floor whose emission is a texture of kind `kind` (Checker over Generated, an Image over UV,
    Noise over Normal coordinates) moved by the panel."""
    scene = new_scene(48, 48)
    add_camera(scene, (0, -4, 2.5), (0, 0, 0.3), lens=35)
    set_world(scene, color=(0, 0, 0))

    def build(tree):
        if kind == "checker":
            texture = tree.nodes.new("ShaderNodeTexChecker")
            texture.inputs["Scale"].default_value = 4.0
        elif kind == "image":
            texture = tree.nodes.new("ShaderNodeTexImage")
            texture.image = bpy.data.images.new("Grid", 64, 64)
            texture.image.generated_type = "COLOR_GRID"
            texture.extension = "REPEAT"
        else:
            texture = tree.nodes.new("ShaderNodeTexNoise")
            coords = tree.nodes.new("ShaderNodeTexCoord")
            tree.links.new(coords.outputs["Normal"], texture.inputs["Vector"])
        for name, value in panel.items():
            setattr(texture.texture_mapping, name, value)
        return texture.outputs["Color"]

    material = emission_material("Mapped", build=build)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.8, location=(0, 0, 0.8))
    bpy.ops.object.shade_smooth()
    bpy.context.active_object.data.materials.append(material)
    bpy.ops.mesh.primitive_plane_add(size=4)
    bpy.context.active_object.data.materials.append(material)
    return scene


@pytest.mark.parametrize("kind,panel", [("checker", "point"), ("checker", "texture"), ("checker", "axes"),
                                        ("image", "texture"), ("noise", "normal"), ("noise", "vector")])
def test_texture_mapping_panel_matches_cycles(kind, panel):
    compare_to_cycles(textured_scene(kind, PANELS[panel]), samples=16, max_bounces=1)


def test_environment_texture_mapping_matches_cycles():
    """A world's Environment Texture with its panel rotated leaves the plain-HDRI path for a node program."""
    scene = new_scene(32, 32)
    add_camera(scene, (0, -4, 1.0), (0, 0, 1.0), lens=20)
    set_world(scene, color=(1.0, 1.0, 1.0))
    tree = scene.world.node_tree
    env = tree.nodes.new("ShaderNodeTexEnvironment")
    env.image = bpy.data.images.new("Sky", 64, 32)
    env.image.generated_type = "COLOR_GRID"
    env.texture_mapping.rotation = (0.0, 0.0, math.radians(70))
    tree.links.new(env.outputs["Color"], tree.nodes["Background"].inputs["Color"])
    # The map both engines bake the world program into for light sampling: 256 wide, what Ember's Automatic takes
    # for this image; Cycles' Automatic bakes 4096 x 2048 at every render, most of this test's time. The images'
    # expectation does not depend on it.
    world = scene.world
    manual_world_map(world, 256)
    assert export_current().scene.world.program is not None
    assert not [w for w in export_current().warnings if "Texture Mapping" in w]
    compare_to_cycles(scene, samples=8, max_bounces=1)
