"""Lamps seen by camera rays (a light object's Ray Visibility > Camera; kernels/emitters_seen.py), against Cycles.

A small scene per lamp kind with the camera looking at the lamp: a point lamp with a radius (a sphere), spots of a
size and blend seen from inside their cone and from its blend, square, rectangle, disk and ellipse area lamps seen
at an angle (two of them with a Spread below 180 degrees), and a sun whose disc is in the frame. Combined against
Cycles within noise (replicate renders), then alpha on a transparent film, the Emission and light group passes,
and Ember alone: Camera off (the default) leaves everything as it was, Camera on warns no more.
"""
from __future__ import annotations

import math

import bpy
import numpy as np
import pytest

from bpy_helpers import (add_camera, configure_engine, diffuse_material, export_current, new_scene, quad_object,
                         render_to_array, set_world)
from exr import render_multilayer

SAMPLES = 64
# Replicate renders splitting SAMPLES: their spread is the noise. Eight, not bpy_helpers' four: a lamp's edge
# pixels (0.1 beside 80) make the blocks' noise lumpy, and with three degrees of freedom per block an estimated
# variance falls short often enough that one of 64 blocks would pass 4.5 standard errors by chance.
SEEDS = (11, 29, 47, 83, 101, 131, 167, 199)


def _lamp(scene, name, kind, location, rotation=(0, 0, 0), camera=True, **settings):
    lamp = bpy.data.objects.new(name, bpy.data.lights.new(name, kind))
    for key, value in settings.items():
        setattr(lamp.data, key, value)
    lamp.location, lamp.rotation_euler = location, rotation
    lamp.visible_camera = camera
    scene.collection.objects.link(lamp)
    return lamp


def _stage(floor: bool = True):
    """A 32 x 32 camera looking along +y at z = 1 over a grey floor (when floor), a dim world."""
    scene = new_scene(32, 32)
    add_camera(scene, (0, -5, 1.2), (0, 0, 1.0))
    set_world(scene, color=(0.05, 0.05, 0.06))
    if floor:
        quad_object("Floor", (-5, -5, 0), (10, 0, 0), (0, 10, 0), diffuse_material("Floor", (0.6, 0.6, 0.6)))
    return scene


# The lamps of each scene: (name, kind, location, rotation, settings). Blender's lamps shine down their -Z: a
# rotation of about -1.3 about x turns an area lamp toward the camera (and a little down, onto the floor).
KINDS = {
    "point": [("Bulb", "POINT", (-0.6, 0, 1.1), (0, 0, 0), dict(energy=100.0, shadow_soft_size=0.3))],
    # One spot aimed at the camera (inside its cone), one aimed 40 degrees away, in its blend.
    "spot": [("Spot", "SPOT", (-0.8, 0, 1.1), (-math.pi / 2, 0, 0),
              dict(energy=150.0, shadow_soft_size=0.25, spot_size=math.radians(110), spot_blend=0.6)),
             ("Blend", "SPOT", (0.8, 0, 1.1), (-math.pi / 2, 0, math.radians(40)),
              dict(energy=150.0, shadow_soft_size=0.25, spot_size=math.radians(110), spot_blend=0.6))],
    "square": [("Square", "AREA", (0, 0, 1.1), (-1.3, 0, 0.4), dict(energy=100.0, shape="SQUARE", size=0.8))],
    "rectangle": [("Rect", "AREA", (0, 0, 1.1), (-1.3, 0.3, 0), dict(energy=100.0, shape="RECTANGLE", size=1.0,
                                                                   size_y=0.4))],
    "disk": [("Disk", "AREA", (0, 0, 1.1), (-1.2, 0, -0.3), dict(energy=100.0, shape="DISK", size=0.8))],
    "ellipse": [("Ellipse", "AREA", (0, 0, 1.1), (-1.3, 0, 0.3), dict(energy=100.0, shape="ELLIPSE", size=1.0,
                                                                     size_y=0.5))],
    # Spread below 180 degrees: its disc is brightest where the camera looks along the lamp's normal, dark past
    # half the spread. No floor: the light it casts is tested in tests/test_lights_spread.py.
    "rectangle_spread": [("RectSpread", "AREA", (-0.7, 0, 1.1), (-1.45, 0, 0.2),
                          dict(energy=100.0, shape="RECTANGLE", size=1.0, size_y=0.5, spread=math.radians(50))),
                         ("DiskSpread", "AREA", (0.8, 0, 1.1), (-1.45, 0, -0.3),
                          dict(energy=100.0, shape="DISK", size=0.8, spread=math.radians(120)))],
    "sun": [("Sun", "SUN", (0, 0, 3), (-1.45, 0, 0.1), dict(energy=3.0, angle=0.3))],
}


def _scene(kind, camera=True):
    scene = _stage(floor=kind != "rectangle_spread")
    lamps = [_lamp(scene, name, k, loc, rot, camera, **settings) for name, k, loc, rot, settings in KINDS[kind]]
    return scene, lamps


def _replicates(scene, engine, render):
    """Each of render(scene, engine, samples, seed)'s arrays (a dict of them) averaged over SEEDS splitting
    SAMPLES, and the variance of that mean."""
    renders = [render(scene, engine, SAMPLES // len(SEEDS), seed) for seed in SEEDS]
    return {name: (np.mean([r[name] for r in renders], axis=0).astype(np.float64),
                   np.var([r[name] for r in renders], axis=0, ddof=1) / len(renders)) for name in renders[0]}


def _colour(scene, engine, samples, seed):
    return {"Combined": render_to_array(scene, engine, samples, seed=seed)[..., :3]}


def _assert_matches_cycles(scene, render=_colour, block: int = 4) -> dict:
    """Every image of render (a dict) within noise of Cycles': every block x block sum within 4.5 standard errors
    of the difference (a floor of 1e-4 of the block's value on it: the sky and a lamp's inside have no noise), the
    whole image within 4. Returns Ember's mean images."""
    cycles, ember = _replicates(scene, "CYCLES", render), _replicates(scene, "EMBER", render)
    for name, (c, var_c) in cycles.items():
        e, var_e = ember[name]
        h, w, _ = c.shape

        def sums(x):
            return x.reshape(h // block, block, w // block, block, 3).sum(axis=(1, 3))
        se = np.maximum(np.sqrt(sums(var_c) + sums(var_e)), 1e-4 * np.maximum(np.abs(sums(c)), 1e-3))
        z = (np.abs(sums(e) - sums(c)) / se).max()
        whole = (e.sum() - c.sum()) / np.sqrt(var_c.sum() + var_e.sum())
        print(f"{name}: mean Cycles {c.mean():.4f} Ember {e.mean():.4f}, worst block z {z:.2f}, whole z {whole:+.2f}")
        assert c.max() > 1.0, name   # a lamp is in it
        assert z < 4.5 and abs(whole) < 4.0, (name, z, whole)
    return {name: e for name, (e, _) in ember.items()}


@pytest.mark.parametrize("kind", list(KINDS))
def test_a_lamp_the_camera_sees_matches_cycles(kind):
    scene, lamps = _scene(kind)
    warnings = export_current().warnings
    assert not [w for w in warnings if "Camera" in w]
    assert warnings == []
    # The lamp is in the frame and Camera changes the image (so the comparison below tests it).
    seen = render_to_array(scene, "EMBER", 8, seed=3)[..., :3]
    for lamp in lamps:
        lamp.visible_camera = False
    hidden = render_to_array(scene, "EMBER", 8, seed=3)[..., :3]
    assert np.abs(seen - hidden).max() > 1.0, (seen.max(), hidden.max())
    for lamp in lamps:
        lamp.visible_camera = True
    _assert_matches_cycles(scene)


def test_spread_dims_the_lamp_off_its_normal_as_cycles():
    """The spread lamps' discs where the camera sees them, pixel by pixel: every pixel inside a disc (it and its
    four neighbours lit: no anti-aliased edge; the spread still shades each pixel unevenly, hence noise) within
    4.5 standard errors of Cycles' (replicate renders); and the spread matters (a plain lamp looks other)."""
    scene, lamps = _scene("rectangle_spread")
    cycles, ember = _replicates(scene, "CYCLES", _colour)["Combined"], _replicates(scene, "EMBER", _colour)["Combined"]
    lit = cycles[0][..., 0] > 1.0
    inside = np.zeros_like(lit)
    inside[1:-1, 1:-1] = lit[1:-1, 1:-1] & lit[:-2, 1:-1] & lit[2:, 1:-1] & lit[1:-1, :-2] & lit[1:-1, 2:]
    assert inside.sum() > 10
    se = np.maximum(np.sqrt(cycles[1] + ember[1]), 1e-4 * cycles[0])[inside]
    z = np.abs(ember[0][inside] - cycles[0][inside]) / se
    print(f"spread discs: {inside.sum()} pixels, worst z {z.max():.2f}")
    assert z.max() < 4.5, z.max()
    for lamp in lamps:
        lamp.data.spread = math.pi
    plain = render_to_array(scene, "EMBER", SAMPLES, seed=1)[..., :3]
    assert np.abs(plain[inside] / ember[0][inside] - 1).max() > 0.2


def _transparent_film_matches_cycles(scene):
    """On a transparent film: colour within noise, alpha per 4 x 4 block within 0.03 of Cycles'. Returns both
    engines' images (seed 1)."""
    scene.render.film_transparent = True
    _assert_matches_cycles(scene)
    cycles = render_to_array(scene, "CYCLES", SAMPLES, seed=1)
    ember = render_to_array(scene, "EMBER", SAMPLES, seed=1)
    blocks = lambda a: a.reshape(8, 4, 8, 4).mean(axis=(1, 3))  # noqa: E731
    assert np.abs(blocks(ember[..., 3]) - blocks(cycles[..., 3])).max() < 0.03
    return cycles, ember


def test_transparent_film_keeps_alpha_and_the_lamps_colour_as_cycles():
    """A sphere lamp, an area lamp and a sun seen against the sky on a transparent film: Combined has their
    light (Cycles writes a lamp's and a sun's emission whatever the film), alpha is what is behind them: 0 for
    the sky, 1 for the floor (lamps are transparent). Colour within noise, alpha per 4 x 4 block within 0.03."""
    scene = _stage()
    for name, kind, loc, rot, settings in KINDS["point"] + KINDS["sun"]:
        _lamp(scene, name, kind, loc, rot, **settings)
    _lamp(scene, "Panel", "AREA", (0.9, 0, 0.4), (-1.3, 0, 0), energy=60.0, shape="SQUARE", size=0.6)
    cycles, ember = _transparent_film_matches_cycles(scene)
    # The sun's disc and the lamp are in Combined where alpha is 0 (the sky behind them).
    bright_sky = (cycles[..., :3].max(axis=-1) > 2.0) & (cycles[..., 3] < 0.01)
    assert bright_sky.sum() > 4
    assert np.all(ember[..., 3][bright_sky] < 0.05) and np.all(ember[..., :3].max(axis=-1)[bright_sky] > 1.0)


def _passes(scene, engine, samples, seed):
    configure_engine(scene, engine, samples, seed)
    parts, _ = render_multilayer(scene)
    layer = scene.view_layers[0].name
    return {name: np.stack([parts[f"{layer}.{name}"][c] for c in "RGB"], axis=-1)
            for name in ("Emission", "Diffuse Direct", "Combined_Lamps")}


def test_emission_and_light_group_passes_take_the_lamp_as_cycles():
    """What the camera sees of a sphere lamp and a sun goes to the Emission pass (directly visible) and to their
    light group's pass, not to Diffuse Direct (Cycles' film_write_surface_emission): each pass within noise of
    Cycles'."""
    scene, lamps = _scene("point")
    sun = _lamp(scene, "Sun", "SUN", (0, 0, 3), (-1.45, 0, 0.1), energy=3.0, angle=0.3)
    layer = scene.view_layers[0]
    layer.use_pass_emit = layer.use_pass_diffuse_direct = True
    layer.lightgroups.add(name="Lamps")
    lamps[0].lightgroup = sun.lightgroup = "Lamps"
    ember = _assert_matches_cycles(scene, _passes)
    # The lamp seen directly is in Emission, not in Diffuse Direct (which has the floor's light).
    assert ember["Emission"].max() > 10.0 and ember["Diffuse Direct"].max() < 2.0


def test_camera_off_changes_nothing():
    """Blender's default (Camera off): nothing is exported for it, no warning, and the lamp stays unseen; Camera on
    exports the lamps it is on for, with no warning."""
    scene, lamps = _scene("point", camera=False)
    exported = export_current()
    assert exported.warnings == []
    assert exported.scene.lights.camera is None and exported.scene.lights.spread is None
    image = render_to_array(scene, "EMBER", 4, seed=3)[..., :3]
    assert image.max() < 2.0   # the floor under the lamp, no lamp (28 where it is seen)
    _lamp(scene, "Other", "POINT", (1, 0, 1), camera=False, energy=10.0, shadow_soft_size=0.1)
    lamps[0].visible_camera = True
    exported = export_current()
    assert exported.warnings == []
    assert exported.scene.lights.camera.tolist() == [True, False]


def _collection(name, objects):
    collection = bpy.data.collections.new(name)
    for ob in objects:
        collection.objects.link(ob)
    return collection


def test_linked_lamps_are_seen_whatever_their_linking_as_cycles():
    """Camera rays are no receivers: a sphere lamp that lights only a ball and an area lamp whose shadows only the
    ball casts (shadow-linked) are both seen, as Cycles' lights_intersect meets them for camera rays."""
    scene = _stage()
    bpy.ops.mesh.primitive_uv_sphere_add(segments=16, ring_count=8, radius=0.3, location=(0.2, -1.0, 0.3))
    ball = bpy.context.object
    ball.data.materials.append(diffuse_material("Ball", (0.8, 0.3, 0.2)))
    bulb = _lamp(scene, "Bulb", "POINT", (-0.6, 0, 1.1), energy=100.0, shadow_soft_size=0.3)
    bulb.light_linking.receiver_collection = _collection("Lit", [ball])
    panel = _lamp(scene, "Panel", "AREA", (0.9, 0, 0.9), (-1.3, 0, 0), energy=60.0, shape="SQUARE", size=0.6)
    panel.light_linking.blocker_collection = _collection("Blockers", [ball])
    assert export_current().warnings == []
    _assert_matches_cycles(scene)


def test_a_lamp_before_a_holdout_and_a_shadow_catcher_as_cycles():
    """A lamp in front of a holdout wall keeps its colour where the wall cuts alpha to 0; one over a shadow catcher
    floor is seen in Combined and the catcher's alpha is Cycles' (a transparent film): colour within noise, alpha
    per 4 x 4 block within 0.03."""
    scene = _stage()
    scene.objects["Floor"].is_shadow_catcher = True
    wall = quad_object("Wall", (-0.2, 1.0, 0.0), (2.0, 0, 0), (0, 0, 2.5), diffuse_material("Wall", (0.5, 0.5, 0.5)))
    wall.is_holdout = True
    _lamp(scene, "Bulb", "POINT", (-0.9, 0, 0.5), energy=100.0, shadow_soft_size=0.3)
    _lamp(scene, "Panel", "AREA", (0.9, 0, 1.2), (-1.3, 0, 0), energy=60.0, shape="SQUARE", size=0.6)
    _transparent_film_matches_cycles(scene)


def test_a_lamp_the_camera_sees_is_its_denoising_albedo():
    """Paths still looking for their denoising features take the light of a lamp they see as albedo (Cycles'
    film_write_emission_or_background_pass): a dim area lamp filling an orthographic view reads its radiance,
    strength / (pi area), in Ember's and in Cycles' Denoising Albedo."""
    scene = new_scene(16, 16)
    camera = scene.camera
    camera.location, camera.rotation_euler = (0.0, 0.0, 5.0), (0.0, 0.0, 0.0)
    camera.data.type, camera.data.ortho_scale = "ORTHO", 2.0
    set_world(scene, color=(0.0, 0.0, 0.0))
    _lamp(scene, "Panel", "AREA", (0, 0, 1), (math.pi, 0, 0), energy=0.3 * math.pi * 16.0, shape="SQUARE", size=4.0,
          color=(0.8, 0.6, 0.4))
    layer = scene.view_layers[0]
    layer.cycles.denoising_store_passes = layer.ember.denoising_store_passes = True
    expected = 0.3 * np.array([0.8, 0.6, 0.4])
    for engine in ("CYCLES", "EMBER"):
        configure_engine(scene, engine, 2, 1, denoise=True)
        parts, _ = render_multilayer(scene)
        albedo = np.stack([parts[f"{layer.name}.Denoising Albedo"][c] for c in "RGB"], axis=-1)
        np.testing.assert_allclose(albedo, np.broadcast_to(expected, albedo.shape), rtol=1e-4, err_msg=engine)


def test_lamps_seen_through_a_transparent_pane_as_cycles():
    """Camera rays stay camera rays through transparent surfaces (Cycles' transparent bounce keeps the path's
    visibility): a grey Transparent BSDF pane over the left of the frame dims the sphere lamp behind it, while the
    area lamp beside it is seen directly, in the same steps as the floor's bounces."""
    from bpy_helpers import node_material
    scene, _ = _scene("point")
    _lamp(scene, "Panel", "AREA", (0.9, 0, 1.2), (-1.3, 0, 0), energy=60.0, shape="SQUARE", size=0.6)
    quad_object("Pane", (-2.0, -1.5, 0.0), (2.0, 0, 0), (0, 0, 2.5),
                node_material("Pane", "ShaderNodeBsdfTransparent", Color=(0.5, 0.5, 0.5)))
    _assert_matches_cycles(scene)


def test_a_lamp_of_soft_falloff_off_is_seen_as_cycles_sphere():
    """Cycles makes a sized point or spot lamp of Soft Falloff off a sphere (kernel/light/point.h): the camera sees it
    and the floor under it takes its light as in Cycles, without a warning."""
    scene, lamps = _scene("point")
    lamps[0].data.use_soft_falloff = False
    assert export_current().warnings == []
    _assert_matches_cycles(scene)


def test_camera_clip_end_holds_behind_transparent_surfaces_and_in_media():
    """Cycles continues a ray through a transparent surface with its tmax (only tmin moves on), so a camera ray
    ends at the far clip plane whatever it passed: a wall beyond Clip End seen through a clear plane stays
    unseen, and a fog box the clip plane cuts is lit only up to it. Before, the ray went on without end past the
    first transparent surface: the wall showed, and the fog beyond the clip plane lit the image."""
    import bpy
    from bpy_helpers import add_camera, compare_to_cycles, diffuse_material, new_scene, quad_object, set_world
    scene = new_scene(24, 16)
    add_camera(scene, (0, -6, 1), (0, 0, 1), lens=35)
    scene.camera.data.clip_end = 8.0
    set_world(scene, color=(0.2, 0.3, 0.5))
    clear = bpy.data.materials.new("Clear")
    clear.node_tree.nodes["Principled BSDF"].inputs["Alpha"].default_value = 0.0
    quad_object("Pane", (-4, -2, -2), (8, 0, 0), (0, 0, 6), clear)
    quad_object("Wall", (-4, 4, -2), (8, 0, 0), (0, 0, 6), diffuse_material("Wall", (0.9, 0.9, 0.9)))   # 10 m away
    bpy.ops.mesh.primitive_cube_add(size=2, location=(0, -0.5, 1))   # a fog box from 4.5 to 6.5 m, then the wall
    fog_box = bpy.context.active_object
    fog_box.scale = (4, 2.0, 3)
    fog = bpy.data.materials.new("Fog")
    tree = fog.node_tree
    tree.nodes.remove(tree.nodes["Principled BSDF"])
    volume = tree.nodes.new("ShaderNodeVolumePrincipled")
    volume.inputs["Density"].default_value = 0.3
    tree.links.new(volume.outputs[0], tree.nodes["Material Output"].inputs["Volume"])
    fog_box.data.materials.append(fog)
    compare_to_cycles(scene, samples=64, max_bounces=4, mean_z=4.0)
