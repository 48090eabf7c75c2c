"""Object ray visibility, holdout and indirect-only collections (kernels/visibility.py), against Cycles.

One small scene for every setting: a red ball on a floor under a sun, a mirror behind it and a glass slab
in front of part of it, so that each ray type meets the ball somewhere: the camera directly, glossy rays in
the mirror, transmission rays through the slab, diffuse rays from the floor, shadow rays from the floor.
Each test turns one setting off and compares the image (and alpha, for holdouts) with Cycles'. Kernel level:
an instanced scene with visibility renders as its flattened copy, and objects no BSDF ray sees are no lights.
"""
from __future__ import annotations

import numpy as np
import pytest

SAMPLES = 64
# Caustics off on both engines: the sun through the slab and off the mirror onto the floor would be fireflies.
CAUSTICS = dict(caustics=(False, False))


def _scene():
    import bpy
    from bpy_helpers import diffuse_material, mesh_object, new_scene, node_material, quad_object, set_world
    scene = new_scene(48, 48)
    set_world(scene, color=(0.25, 0.27, 0.3))
    quad_object("Floor", (-5, -5, 0), (10, 0, 0), (0, 10, 0), diffuse_material("Floor", (0.7, 0.7, 0.7)))
    quad_object("Mirror", (-2.5, 2.0, 0), (5, 0, 0), (0, 0, 3),
                node_material("Mirror", "ShaderNodeBsdfGlossy", Color=(0.9, 0.9, 0.9), Roughness=0.0))
    bpy.ops.mesh.primitive_uv_sphere_add(segments=24, ring_count=12, radius=0.7, location=(-0.3, 0, 0.7))
    ball = bpy.context.object
    ball.name = "Ball"
    ball.data.materials.append(diffuse_material("Red", (0.8, 0.15, 0.1)))
    # A glass slab between the camera and the ball's right half.
    x0, x1, y0, y1, z0, z1 = 0.0, 1.2, -2.0, -1.9, 0.0, 2.0
    verts = [(x, y, z) for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)]
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    mesh_object("Slab", verts, faces, node_material("Glass", "ShaderNodeBsdfGlass", Color=(1, 1, 1), Roughness=0.0,
                                                    IOR=1.45))
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy, sun.data.angle = 3.0, 0.05
    sun.rotation_euler = (0.6, 0.0, 0.9)
    scene.collection.objects.link(sun)
    return scene, ball


@pytest.mark.parametrize("setting", ["visible_camera", "visible_diffuse", "visible_glossy", "visible_transmission",
                                     "visible_shadow"])
def test_a_ray_type_off_matches_cycles(setting):
    from bpy_helpers import compare_to_cycles, export_current, render_to_array
    scene, ball = _scene()
    plain = render_to_array(scene, "EMBER", 16, seed=3, **CAUSTICS)
    setattr(ball, setting, False)
    assert export_current().warnings == []
    # The setting changes the image (so the comparison below tests it), and Ember changes it as Cycles does.
    changed = render_to_array(scene, "EMBER", 16, seed=3, **CAUSTICS)
    assert np.abs(changed[..., :3] - plain[..., :3]).max() > 0.1
    compare_to_cycles(scene, samples=SAMPLES, **CAUSTICS)


def _alpha_matches(scene, samples=SAMPLES):
    """Colour parity, and alpha: the mean of both and every 6 x 6 block within 0.03 of Cycles'."""
    from bpy_helpers import compare_to_cycles, render_to_array
    compare_to_cycles(scene, samples=samples, **CAUSTICS)
    cycles = render_to_array(scene, "CYCLES", samples, seed=1, **CAUSTICS)[..., 3]
    ember = render_to_array(scene, "EMBER", samples, seed=1, **CAUSTICS)[..., 3]
    blocks = lambda a: a.reshape(8, 6, 8, 6).mean(axis=(1, 3))  # noqa: E731
    assert abs(ember.mean() - cycles.mean()) < 0.01, (ember.mean(), cycles.mean())
    assert np.abs(blocks(ember) - blocks(cycles)).max() < 0.03
    return ember


def test_object_holdout_cuts_a_hole_in_a_transparent_film():
    scene, ball = _scene()
    scene.render.film_transparent = True
    ball.is_holdout = True
    alpha = _alpha_matches(scene)
    assert alpha.min() < 0.05   # the hole: where the camera sees the ball


def test_a_holdout_object_keeps_its_material_s_transparency_as_in_cycles():
    """Cycles' surface_shader_apply_holdout: a holdout object whose material is partly transparent (Principled
    Alpha 0.4, an emission besides) cuts 0.4 of a hole; the rest of the light comes through it, from what lies
    behind, and neither its diffuse nor its emission shows."""
    import bpy
    scene, ball = _scene()
    scene.render.film_transparent = True
    ball.is_holdout = True
    material = ball.data.materials[0] = bpy.data.materials.new("Veil")
    bsdf = material.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Alpha"].default_value = 0.4
    bsdf.inputs["Emission Color"].default_value = (1.0, 0.2, 0.1, 1.0)
    bsdf.inputs["Emission Strength"].default_value = 2.0
    alpha = _alpha_matches(scene)
    # Where the camera sees the ball in front of the mirror: two of its surfaces, each holding out 0.4 of what
    # passes, leave (1 - 0.4)^2 = 0.36: neither a whole hole nor none.
    assert (np.abs(alpha - 0.36) < 0.02).sum() >= 20


def test_collection_holdout_on_an_opaque_film():
    import bpy
    scene, ball = _scene()
    group = bpy.data.collections.new("Held")
    scene.collection.children.link(group)
    scene.collection.objects.unlink(ball)
    group.objects.link(ball)
    bpy.context.view_layer.layer_collection.children["Held"].holdout = True
    alpha = _alpha_matches(scene)
    assert alpha.min() < 0.05   # Cycles cuts the hole in alpha on an opaque film too (black in colour)


def test_indirect_only_collection_matches_cycles():
    import bpy
    from bpy_helpers import compare_to_cycles
    scene, ball = _scene()
    group = bpy.data.collections.new("Indirect")
    scene.collection.children.link(group)
    scene.collection.objects.unlink(ball)
    group.objects.link(ball)
    bpy.context.view_layer.layer_collection.children["Indirect"].indirect_only = True
    assert bpy.context.evaluated_depsgraph_get() is not None
    from bpy_helpers import export_current
    assert export_current().scene.object_visibility.tolist().count(63 - 1) == 1
    compare_to_cycles(scene, samples=SAMPLES, **CAUSTICS)


# ---- Kernel level ---------------------------------------------------------------------------------------

def test_instances_see_visibility_as_their_flattened_copies():
    """Visibility reaches the instances of the two-level BVH: the instanced scene renders as its flattened
    copy with the same object_visibility, and differently from the scene without it."""
    import dataclasses
    from ember.kernels import Renderer, RenderSettings
    from ember.kernels.geometry import flatten_instances
    from test_instancing import _scene as instanced_scene
    scene = instanced_scene()
    # Rows: floor, three balls, two lamps. Ball 1 unseen by the camera, ball 2 by shadows, ball 3 a holdout,
    # the first lamp unseen by diffuse rays (light samples still find it), the second by every BSDF ray.
    vis = np.array([63, 62, 31, 63 | 128, 63 - 4, 1 | 32], np.uint8)
    seen = dataclasses.replace(scene, object_visibility=vis)
    settings = RenderSettings(samples=16, seed=3)
    images = []
    for s in (seen, flatten_instances(seen), scene):
        with Renderer(s, threads=2) as renderer:
            images.append(renderer.render(settings).image)
    a, b, plain = images
    close = np.isclose(a, b, rtol=1e-3, atol=1e-4).all(axis=2)
    assert close.mean() > 0.98, close.mean()
    assert abs(a[..., :3].mean() / b[..., :3].mean() - 1) < 2e-3
    assert np.abs(a - plain).max() > 0.2
    assert a[..., 3].min() < 0.05 and plain[..., 3].min() > 0.99   # the holdout's hole


def test_objects_no_bsdf_ray_sees_are_no_lights():
    import dataclasses
    from ember.kernels import Renderer
    from test_instancing import _scene as instanced_scene
    scene = instanced_scene()
    vis = np.array([63, 63, 63, 63, 63, 1 | 32], np.uint8)
    with Renderer(scene, threads=1) as all_lit, \
            Renderer(dataclasses.replace(scene, object_visibility=vis), threads=1) as one_lit:
        assert len(one_lit.lights.tri_ids) * 2 == len(all_lit.lights.tri_ids) > 0


def test_scenes_without_settings_take_no_visibility_path():
    from bpy_helpers import export_current
    _scene()
    result = export_current()
    assert result.scene.object_visibility is None


def test_light_ray_visibility_warns_no_more():
    """A light's Glossy off renders (test_light_visibility.py), and so does its Camera on (test_light_camera.py):
    neither warns; Camera goes to Lights.camera, Glossy to Lights.visibility."""
    import bpy
    from bpy_helpers import export_current
    _scene()
    sun = bpy.data.objects["Sun"]
    sun.visible_glossy = False
    sun.visible_camera = True
    exported = export_current()
    assert exported.warnings == []
    assert exported.scene.lights.camera.tolist() == [True]
    from ember.kernels.scene.objects import BSDF_RAYS, RAY_GLOSSY
    assert exported.scene.lights.visibility.tolist() == [BSDF_RAYS & ~RAY_GLOSSY]
