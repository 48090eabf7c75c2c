"""Motion blur of hair, Curves objects and point clouds through Blender (issue 37), against Cycles: object
transform motion and deformation motion (the keys and radii at each motion step's subframe)."""
from __future__ import annotations

import bpy
import numpy as np

from bpy_helpers import compare_to_cycles, diffuse_material, new_scene, render_to_array, set_world
from motion_helpers import node_modifier, offset_positions, store_velocity, time_driven, with_material, x_from_height
from test_curves_points import curves_object, furry_sphere, mesh_to_points, sun_and_sky
from test_motion_blur import _linear


class _FrameSetter:
    """What sample_motion asks of the render engine: frame_set (Blender's RenderEngine.frame_set)."""

    def __init__(self, scene):
        self.scene = scene

    def frame_set(self, frame: int, subframe: float) -> None:
        self.scene.frame_set(frame, subframe=subframe)


def export_blurred():
    """Export the current scene as a final render does with motion blur: its keys over the shutter first."""
    from ember.engine.export import export_scene
    from ember.engine.export.motion import sample_motion
    depsgraph = bpy.context.evaluated_depsgraph_get()
    scene = bpy.context.scene
    return export_scene(depsgraph, motion=sample_motion(_FrameSetter(scene), depsgraph, scene.camera))


def blurred_scene(width=48, height=48):
    scene = new_scene(width, height)
    scene.render.use_motion_blur = True
    scene.render.motion_blur_shutter = 1.0
    return scene


def moving_hair_ball(scene, steps=1, turn=0.0):
    """A furry ball (3D Curves) sliding and rising (and turning `turn` radians about z) over a one-frame shutter,
    keyed on frames 1 and 2."""
    sun_and_sky(scene)
    scene.cycles_curves.shape = "THICK"
    ball = furry_sphere(scene, count=400, location=(-0.6, 0, 1), radius=0.7)
    ball.cycles.motion_steps = steps
    ball.keyframe_insert("location", frame=1)
    ball.keyframe_insert("rotation_euler", frame=1)
    ball.location = (0.6, 0.2, 1.3)
    ball.rotation_euler = (0, 0, turn)
    ball.keyframe_insert("location", frame=2)
    ball.keyframe_insert("rotation_euler", frame=2)
    _linear(ball)
    scene.frame_set(1)
    return ball


def test_moving_hair_ball_matches_cycles():
    """A ball sliding, rising and turning half a circle in the shutter: its hair follows the arc between motion
    steps (Cycles slerps object motion; world-space keys mixed linearly would cut the chord: a block 12.9
    standard errors off here, against 2.5 at most for the arc)."""
    scene = blurred_scene()
    moving_hair_ball(scene, turn=np.pi)
    exported = export_blurred()
    assert not exported.warnings, exported.warnings
    compare_to_cycles(scene, samples=64, max_bounces=3)


def test_moving_hair_ball_blurs_and_a_still_one_is_unchanged():
    """The moving ball smears; with its Motion Blur off it renders sharp at the frame, as with motion blur off,
    bit for bit (its curves get no time steps, its instance none)."""
    scene = blurred_scene(24, 24)
    ball = moving_hair_ball(scene)
    exported = export_blurred().scene
    placed = exported.shape_instances   # a moving object's hair stays in object space, placed with motion steps
    assert not exported.curves and placed.count == 1 and placed.motion_ids.tolist() == [0]
    assert placed.motion[0].shape == (3, 4, 4) and placed.prototypes[0].motion is None
    assert np.allclose(placed.motion[0][1], placed.world_from_object[0])   # a centred shutter's middle step
    blurred = render_to_array(scene, "EMBER", 8, max_bounces=1)
    ball.cycles.use_motion_blur = False
    sharp = render_to_array(scene, "EMBER", 8, max_bounces=1)
    scene.render.use_motion_blur = False
    np.testing.assert_array_equal(render_to_array(scene, "EMBER", 8, max_bounces=1), sharp)
    assert np.abs(blurred - sharp).max() > 0.2


def swelling_points(ob):
    """Geometry nodes turning the object's mesh into points that spread out from its centre and grow as the
    frames go by (positions and radii that change per frame: deformation, not transform, motion)."""
    tree, into, out = node_modifier(ob, "swell", "Swell")
    points = tree.nodes.new("GeometryNodeMeshToPoints")
    tree.links.new(time_driven(tree, 0.06, plus=0.04), points.inputs["Radius"])
    tree.links.new(into.outputs[0], points.inputs["Mesh"])
    position = tree.nodes.new("GeometryNodeInputPosition")
    spread = tree.nodes.new("ShaderNodeVectorMath")
    spread.operation = "SCALE"
    tree.links.new(position.outputs[0], spread.inputs[0])
    tree.links.new(time_driven(tree, 0.5), spread.inputs["Scale"])
    moved = offset_positions(tree, points.outputs[0], spread.outputs[0])
    tree.links.new(with_material(tree, moved, diffuse_material("Dots", (0.8, 0.35, 0.1))), out.inputs[0])
    return ob


def test_deforming_point_cloud_matches_cycles():
    """Points whose positions and radii change per frame (geometry nodes reading the scene's time) blur along
    their paths and swell over the shutter (the shutter's start, two motion steps: five keys), as Cycles reads
    them at each step's subframe."""
    scene = blurred_scene()
    scene.render.motion_blur_position = "START"
    set_world(scene, (0.6, 0.7, 0.8))
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=1, radius=0.5, location=(0, 0, 1))
    cloud = swelling_points(bpy.context.active_object)
    cloud.cycles.motion_steps = 2
    scene.frame_set(1)
    exported = export_blurred()
    assert not exported.warnings, exported.warnings
    points = exported.scene.points
    assert points.motion is not None and points.motion.shape == (5, 12, 4)
    assert np.allclose(points.motion[0], points.points)   # the shutter opens at the frame
    assert not np.allclose(points.motion[-1, :, 3], points.points[:, 3])   # and the radii grow over it
    compare_to_cycles(scene, samples=64, max_bounces=2)


def waving_curves(scene):
    """A Curves object of a few strands whose keys geometry nodes push along x by the frame times their height
    (a shape that changes over frames)."""
    strands = [np.array([[x, 0, 0.3], [x, 0, 0.9], [x + 0.1, 0, 1.5], [x + 0.2, 0, 2.0]]) for x in
               np.linspace(-1.0, 1.0, 7)]
    ob = curves_object("Waving", strands, radius=0.08, material=diffuse_material("Strands", (0.05, 0.02, 0.02)))
    tree, into, out = node_modifier(ob, "wave", "Wave")
    push = x_from_height(tree, "MULTIPLY", time_driven(tree, 0.6))
    tree.links.new(offset_positions(tree, into.outputs[0], push), out.inputs[0])
    return ob


def test_curves_changing_shape_over_frames_match_cycles():
    """Strands leaning further frame by frame, blurred over a shutter that opens at the frame (so the blur
    moves coverage to where they lean, not only around where they are)."""
    scene = blurred_scene()
    scene.render.motion_blur_position = "START"
    sun_and_sky(scene)
    waving_curves(scene)
    scene.frame_set(1)
    exported = export_blurred()
    assert not exported.warnings, exported.warnings
    (strands,) = exported.scene.curves
    assert strands.motion is not None and len(strands.motion) == 3
    compare_to_cycles(scene, samples=64, max_bounces=2)


def test_points_changing_in_number_are_warned_by_name():
    """Points whose count changes during the shutter get no deformation blur (as in Cycles): a warning names
    the object."""
    scene = blurred_scene(16, 16)
    set_world(scene, (0.5, 0.5, 0.5))
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=1, radius=0.5, location=(0, 0, 1))
    ob = mesh_to_points(bpy.context.active_object, 0.05)
    tree = ob.modifiers[-1].node_group
    thin = tree.nodes.new("GeometryNodeDeleteGeometry")
    compare = tree.nodes.new("FunctionNodeCompare")
    compare.data_type, compare.operation = "FLOAT", "LESS_THAN"
    index = tree.nodes.new("GeometryNodeInputIndex")
    tree.links.new(index.outputs[0], compare.inputs[0])
    tree.links.new(time_driven(tree, 4.0), compare.inputs[1])
    points = next(n for n in tree.nodes if n.bl_idname == "GeometryNodeMeshToPoints")
    output = next(n for n in tree.nodes if n.bl_idname == "NodeGroupOutput")
    tree.links.new(points.outputs[0], thin.inputs["Geometry"])
    tree.links.new(compare.outputs[0], thin.inputs["Selection"])
    tree.links.new(thin.outputs[0], output.inputs[0])
    scene.frame_set(1)
    exported = export_blurred()
    assert any(f"'{ob.name}'" in w and "change in number" in w for w in exported.warnings), exported.warnings
    assert exported.scene.points.motion is None


def test_instanced_hair_moving_with_its_instancer_matches_cycles():
    """A furry ball in a collection instanced by two empties, one of them flying: the flying instance's hair moves
    with it (an instance with motion steps), the still one stays where it is."""
    scene = blurred_scene()
    sun_and_sky(scene)
    scene.cycles_curves.shape = "THICK"
    furball = bpy.data.collections.new("Furball")
    furry_sphere(scene, count=200, location=(0, 0, 0), radius=0.5, collection=furball)
    empties = []
    for k, x in enumerate((-1.0, 1.0)):
        empty = bpy.data.objects.new(f"Ball {k}", None)
        empty.instance_type, empty.instance_collection = "COLLECTION", furball
        empty.location = (x, 0, 1)
        scene.collection.objects.link(empty)
        empties.append(empty)
    flying = empties[1]
    flying.keyframe_insert("location", frame=1)
    flying.location = (1.0, 0.0, 2.0)
    flying.keyframe_insert("location", frame=2)
    _linear(flying)
    scene.frame_set(1)
    exported = export_blurred().scene
    placed = exported.shape_instances   # the still ball is copied into world space (few strands), as without it
    assert placed.count == 1 and len(placed.motion) == 1 and placed.motion_ids.tolist() == [0]
    assert len(exported.curves) == 1 and exported.curves[0].motion is None
    compare_to_cycles(scene, samples=64, max_bounces=3)


def test_deformation_off_leaves_the_points_still():
    """Object Properties > Motion Blur > Deformation off (Cycles' use_deform_motion): no motion keys."""
    scene = blurred_scene(16, 16)
    set_world(scene, (0.5, 0.5, 0.5))
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=1, radius=0.5, location=(0, 0, 1))
    cloud = swelling_points(bpy.context.active_object)
    scene.frame_set(1)
    assert export_blurred().scene.points.motion is not None
    cloud.cycles.use_deform_motion = False
    assert export_blurred().scene.points.motion is None


def test_curves_changing_their_key_count_are_read_along_themselves():
    """Curves resampled to more points frame by frame keep their number: each curve's keys at a motion step are
    read along the step's curve (Cycles' interpolate_curve_points, which counts that as motion), without a
    warning. The closed form on a straight strand: its keys stay evenly along the line."""
    scene = blurred_scene(16, 16)
    set_world(scene, (0.5, 0.5, 0.5))
    ob = curves_object("Growing", [np.array([[0, 0, 0], [0, 0, 1], [0, 0, 2]], float)], radius=0.05)
    tree, into, out = node_modifier(ob, "grow", "Grow")
    resample = tree.nodes.new("GeometryNodeResampleCurve")
    tree.links.new(time_driven(tree, 4.0, plus=3.0), resample.inputs["Count"])
    tree.links.new(into.outputs[0], resample.inputs["Curve"])
    tree.links.new(resample.outputs[0], out.inputs[0])
    scene.frame_set(1)
    exported = export_blurred()
    assert not exported.warnings, exported.warnings
    (strand,) = exported.scene.curves
    assert len(strand.keys) == 7 and strand.motion is not None and strand.motion.shape == (3, 7, 4)
    assert np.allclose(strand.motion[:, :, :2], 0.0, atol=1e-6)   # still on the line x = y = 0
    assert np.allclose(strand.motion[:, :, 2], np.linspace(0, 2, 7), atol=1e-5)   # evenly along it


def streaking_points(ob, speed=20.0):
    """Geometry nodes turning the mesh into still points that carry a `velocity` attribute (units per second):
    x speed times the point's height."""
    tree, into, out = node_modifier(ob, "streak", "Streak")
    points = tree.nodes.new("GeometryNodeMeshToPoints")
    points.inputs["Radius"].default_value = 0.12
    tree.links.new(into.outputs[0], points.inputs["Mesh"])
    streaks = store_velocity(tree, points.outputs[0], x_from_height(tree, "MULTIPLY", speed))
    tree.links.new(with_material(tree, streaks, diffuse_material("Streaks", (0.02, 0.04, 0.1))), out.inputs[0])
    return ob


def test_points_with_a_velocity_attribute_match_cycles():
    """Still points with a `velocity` attribute blur along it, half the shutter's seconds each way of the frame
    (Cycles' attr_create_motion_from_velocity), here with the shutter opening at the frame (Cycles centres the
    velocity's steps on the frame all the same)."""
    scene = blurred_scene()
    scene.render.motion_blur_position = "START"
    set_world(scene, (0.6, 0.7, 0.8))
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=2, radius=0.9, location=(0, 0, 1))
    streaking_points(bpy.context.active_object)
    scene.frame_set(1)
    exported = export_blurred()
    assert not exported.warnings, exported.warnings
    points = exported.scene.points
    assert points.motion is not None and len(points.motion) == 3
    half = 0.5 / (scene.render.fps / scene.render.fps_base)   # half the one-frame shutter, in seconds
    z = points.points[:, 2] - 1.0   # the object sits at z = 1: its points' own heights
    assert np.allclose(points.motion[2, :, 0] - points.points[:, 0], 20.0 * z * half, atol=1e-4)
    assert np.allclose(points.motion[1], points.points)
    compare_to_cycles(scene, samples=64, max_bounces=2, blocks=12)


def test_curves_with_a_velocity_attribute_match_cycles():
    """A Curves object whose points carry a `velocity` attribute (no modifier): three steps along it, as Cycles'
    attr_create_motion_from_velocity for hair; the radius stays. (Without the velocity: a block 12.6 standard
    errors off; with it 1.7 at most.)"""
    scene = blurred_scene()
    sun_and_sky(scene)
    strands = [np.array([[x, 0, 0.3], [x, 0, 1.0], [x + 0.1, 0, 1.8]]) for x in np.linspace(-1.0, 1.0, 6)]
    ob = curves_object("Drifting", strands, radius=0.07, material=diffuse_material("Drift", (0.05, 0.02, 0.02)))
    velocity = ob.data.attributes.new("velocity", "FLOAT_VECTOR", "POINT")
    heights = np.concatenate(strands)[:, 2]
    velocity.data.foreach_set("vector", np.stack([12.0 * heights, np.zeros_like(heights), np.zeros_like(heights)],
                                                 axis=1).astype(np.float32).ravel())
    scene.frame_set(1)
    exported = export_blurred()
    assert not exported.warnings, exported.warnings
    (curves,) = exported.scene.curves
    half = 0.5 / (scene.render.fps / scene.render.fps_base)
    assert curves.motion.shape == (3,) + curves.keys.shape
    assert np.allclose(curves.motion[0, :, 0], curves.keys[:, 0] - 12.0 * heights * half, atol=1e-5)
    assert np.array_equal(curves.motion[:, :, 3], np.broadcast_to(curves.keys[:, 3], (3, len(heights))))
    compare_to_cycles(scene, samples=64, max_bounces=2, blocks=12)
