"""The Particle Info node on objects instanced by a particle system, against Cycles: Index, Random, Age,
Lifetime, Location, Size, Velocity and Angular Velocity of each instance's particle, as Cycles'
sync_dupli_particle stores them (read at export per instance). Before, the node passed its consumer's own value
with a warning."""
import bpy
import pytest

from bpy_helpers import add_camera, compare_to_cycles, export_current, new_scene, set_world

COUNT = 40


def particle_scene(outputs, scales):
    """A plane emitting COUNT particles over frames 1-10, rendered at frame 12 (all alive) as small spheres whose emission
    colour is (r, g, b) = outputs (Particle Info output names; a vector output's x, y, z spread over the channels
    when given alone) times scales; a black world."""
    scene = new_scene(48, 48)
    add_camera(scene, (0, -5.5, 4.5), (0, 0, 0.5), lens=35)
    set_world(scene, color=(0, 0, 0))
    bpy.ops.mesh.primitive_plane_add(size=4)
    emitter = bpy.context.active_object
    emitter.hide_render = False
    emitter.show_instancer_for_render = False
    bpy.ops.mesh.primitive_ico_sphere_add(radius=0.25, subdivisions=1, location=(20, 20, 20))
    ball = bpy.context.active_object
    ball.hide_render = True
    material = bpy.data.materials.new("Particles")
    tree = material.node_tree
    tree.nodes.clear()
    out, emission = tree.nodes.new("ShaderNodeOutputMaterial"), tree.nodes.new("ShaderNodeEmission")
    info = tree.nodes.new("ShaderNodeParticleInfo")
    if len(outputs) == 1:
        scaled = tree.nodes.new("ShaderNodeVectorMath")
        scaled.operation = "MULTIPLY"
        scaled.inputs[1].default_value = (scales[0],) * 3
        absolute = tree.nodes.new("ShaderNodeVectorMath")
        absolute.operation = "ABSOLUTE"
        tree.links.new(info.outputs[outputs[0]], scaled.inputs[0])
        tree.links.new(scaled.outputs[0], absolute.inputs[0])
        tree.links.new(absolute.outputs[0], emission.inputs["Color"])
    else:
        join = tree.nodes.new("ShaderNodeCombineColor")
        for channel, (name, scale) in enumerate(zip(outputs, scales)):
            times = tree.nodes.new("ShaderNodeMath")
            times.operation = "MULTIPLY"
            times.inputs[1].default_value = scale
            tree.links.new(info.outputs[name], times.inputs[0])
            tree.links.new(times.outputs[0], join.inputs[channel])
        tree.links.new(join.outputs[0], emission.inputs["Color"])
    tree.links.new(emission.outputs[0], out.inputs["Surface"])
    ball.data.materials.append(material)
    system = emitter.modifiers.new("Particles", "PARTICLE_SYSTEM").particle_system
    settings = system.settings
    settings.count, settings.frame_start, settings.frame_end, settings.lifetime = COUNT, 1, 10, 40
    settings.lifetime_random = 0.5
    settings.render_type, settings.instance_object = "OBJECT", ball
    settings.particle_size, settings.size_random = 1.0, 0.6
    settings.normal_factor, settings.factor_random = 1.0, 0.5
    settings.effector_weights.gravity = 0.2
    settings.use_rotations, settings.angular_velocity_mode, settings.angular_velocity_factor = True, "RAND", 2.0
    scene.frame_set(12)
    return scene


@pytest.mark.parametrize("outputs,scales", [
    (("Random", "Index", "Age"), (1.0, 1.0 / COUNT, 0.1)),
    (("Lifetime", "Size", "Random"), (1.0 / 60, 1.0, 1.0)),
    (("Location",), (0.5,)),
    (("Velocity",), (0.5,)),
    (("Angular Velocity",), (0.3,)),
])
def test_particle_info_matches_cycles(outputs, scales):
    compare_to_cycles(particle_scene(outputs, scales), samples=32, max_bounces=1)


def test_particle_info_is_read_per_instance_without_a_warning():
    particle_scene(("Random", "Index", "Age"), (1.0, 1.0 / COUNT, 0.1))
    exported = export_current()
    assert not [w for w in exported.warnings if "Particle Info" in w], exported.warnings
    table = dict(exported.scene.object_attributes)
    index = table["particle:index"][:, 0]
    assert sorted(set(index.tolist()) - {0.0}) == [float(i) for i in range(1, COUNT)]
