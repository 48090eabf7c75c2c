"""Light groups (View Layer > Light Groups; engine/export/light_groups.py, kernels/light_groups.py): a Combined_<name>
pass per group holding the light of its emitters, against Cycles' own passes.

Parity scenes render both engines to multilayer OpenEXR files with four seeds each (replicate renders: their
spread is the noise): every 8 x 8 block within 4.5 standard errors, the whole pass within 4. Then Ember alone:
the groups add up to Combined to float rounding with every kind of emitter and accumulation in a group of its own
(clamping on and off), Combined does not change with groups, the transparent film's world as Cycles writes it,
what the export reads, and the panels.
"""
from __future__ import annotations

import bpy
import numpy as np
import pytest

from bpy_helpers import (REPLICATE_SEEDS, add_lamp, configure_engine, diffuse_material, emission_material,
                         new_scene, node_material, quad_object, set_world)
from exr import render_multilayer

SAMPLES = 64
GROUPS = ("Key", "Fill", "Sky")


def _ball(name, location, radius, material):
    bpy.ops.mesh.primitive_uv_sphere_add(segments=24, ring_count=12, radius=radius, location=location)
    ball = bpy.context.object
    ball.name = name
    ball.data.materials.append(material)
    return ball


def _groups(scene, names):
    layer = scene.view_layers[0]
    for name in names:
        layer.lightgroups.add(name=name)
    return layer


def _three_groups():
    """A floor, a glossy and a matte ball under an HDRI sky (group Sky), an area key lamp (Key), a soft point lamp
    and an emissive panel (Fill), and a sun in no group, whose disc the glossy ball reflects."""
    scene = new_scene(48, 32)
    set_world(scene, hdri="sunset.exr")
    quad_object("Floor", (-6, -4, 0), (12, 0, 0), (0, 10, 0), diffuse_material("Floor", (0.6, 0.6, 0.6)))
    _ball("Gloss", (-0.9, 0, 0.7), 0.7, node_material("Gloss", "ShaderNodeBsdfGlossy", Color=(0.8, 0.8, 0.8),
                                                      Roughness=0.25))
    _ball("Matte", (0.9, 0.3, 0.6), 0.6, diffuse_material("Matte", (0.8, 0.5, 0.3)))
    key = add_lamp(scene, "Key", "AREA", (0, -2.5, 3.5), (0.6, 0, 0), energy=200.0, size=1.0)
    fill = add_lamp(scene, "Fill", "POINT", (2.5, -1.5, 2.0), energy=100.0, shadow_soft_size=0.2)
    add_lamp(scene, "Sun", "SUN", (0, 0, 5), (0.7, 0.3, 0.5), energy=2.0, angle=0.2)
    panel = quad_object("Panel", (-2.5, 1.5, 0.3), (1.2, 0, 0), (0, 0.3, 1.0),
                        emission_material("Glow", (1, 0.6, 0.3), 6.0))
    _groups(scene, GROUPS)
    key.lightgroup, fill.lightgroup, panel.lightgroup, scene.world.lightgroup = "Key", "Fill", "Fill", "Sky"
    return scene


def _layers(scene, engine: str, samples: int, seed: int, names) -> dict:
    """{"Combined": (H, W, 3), "Combined_<group>": (H, W, 3) per group} of one render to a multilayer file."""
    configure_engine(scene, engine, samples, seed)
    parts, _ = render_multilayer(scene)
    layer = scene.view_layers[0].name
    return {name: np.stack([parts[f"{layer}.{name}"][c] for c in "RGB"], axis=-1).astype(np.float64)
            for name in ["Combined"] + [f"Combined_{n}" for n in names]}


def _replicates(scene, engine: str, names, samples: int = SAMPLES) -> tuple[dict, dict]:
    """Each pass's mean over renders with REPLICATE_SEEDS splitting `samples`, and that mean's variance per pixel;
    "ungrouped" is Combined less the groups' passes (the light of emitters in no group)."""
    renders = [_layers(scene, engine, samples // len(REPLICATE_SEEDS), seed, names) for seed in REPLICATE_SEEDS]
    for r in renders:
        r["ungrouped"] = r["Combined"] - sum(r[f"Combined_{n}"] for n in names)
    out = {}, {}
    for name in renders[0]:
        stack = np.stack([r[name] for r in renders])
        out[0][name], out[1][name] = stack.mean(axis=0), stack.var(axis=0, ddof=1) / len(renders)
    return out


def _assert_same(name, cycles, var_c, ember, var_e, block: int = 8) -> None:
    """Ember's pass equals Cycles' within noise: every block x block sum within 4.5 standard errors of the
    difference and the whole pass within 4 (a floor of 1e-4 of a block's value on its standard error: the sky
    seen directly has no noise, and the two engines' lookups differ by float rounding). Prints the figures."""
    h, w, _ = cycles.shape

    def blocks(x):
        return x[:h // block * block, :w // block * block].reshape(h // block, block, w // block, block, 3).sum(
            axis=(1, 3))
    se = np.maximum(np.sqrt(blocks(var_c) + blocks(var_e)), 1e-4 * np.maximum(np.abs(blocks(cycles)), 1e-3))
    z_blocks = np.abs(blocks(ember) - blocks(cycles)) / se
    z = (ember.sum() - cycles.sum()) / np.sqrt(var_c.sum() + var_e.sum())
    print(f"{name}: mean Cycles {cycles.mean():.4f} Ember {ember.mean():.4f} "
          f"({ember.mean() / cycles.mean() - 1:+.2%}), whole z {z:+.2f}, worst block z {z_blocks.max():.2f}")
    assert cycles.mean() > 1e-3, name   # the pass has light to compare
    assert z_blocks.max() < 4.5 and abs(z) < 4.0, (name, z_blocks.max(), z)


@pytest.fixture(scope="module")
def three_groups():
    scene = _three_groups()
    return {engine: _replicates(scene, engine, GROUPS) for engine in ("CYCLES", "EMBER")}


@pytest.mark.parametrize("name", [f"Combined_{n}" for n in GROUPS] + ["ungrouped"])
def test_group_passes_match_cycles(three_groups, name):
    """Each group's pass (Key: an area lamp; Fill: a point lamp and an emissive panel; Sky: the world), and what
    they leave of Combined (a sun in no group, direct and in the glossy ball), against Cycles'."""
    (cycles, var_c), (ember, var_e) = three_groups["CYCLES"], three_groups["EMBER"]
    _assert_same(name, cycles[name], var_c[name], ember[name], var_e[name])


def _glow_cube(scene, name="Glow"):
    """A cube of emissive, thin fog (Principled Volume), centred 1 m above the origin."""
    bpy.ops.mesh.primitive_cube_add(size=1.2, location=(0, 0, 1.0))
    cube = bpy.context.object
    cube.name = name
    material = bpy.data.materials.new(name)
    tree = material.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    volume = tree.nodes.new("ShaderNodeVolumePrincipled")
    volume.inputs["Density"].default_value = 0.5
    volume.inputs["Emission Strength"].default_value = 2.0
    volume.inputs["Emission Color"].default_value = (1.0, 0.5, 0.2, 1.0)
    tree.links.new(volume.outputs[0], out.inputs["Volume"])
    cube.data.materials.append(material)
    return cube


def test_volume_emission_group_matches_cycles():
    """A volume's emission is in its object's group (Cycles' shade_volume.h), seen directly and lighting the
    floor through rays that cross it; the world (a constant grey, found by rays only) in its own."""
    scene = new_scene(32, 24)
    set_world(scene, color=(0.05, 0.05, 0.05))
    quad_object("Floor", (-6, -4, 0), (12, 0, 0), (0, 10, 0), diffuse_material("Floor", (0.6, 0.6, 0.6)))
    cube = _glow_cube(scene)
    _groups(scene, ("Glow", "Sky"))
    cube.lightgroup, scene.world.lightgroup = "Glow", "Sky"
    (cycles, var_c), (ember, var_e) = (_replicates(scene, engine, ("Glow", "Sky")) for engine in ("CYCLES", "EMBER"))
    for name in ("Combined_Glow", "Combined_Sky"):
        _assert_same(name, cycles[name], var_c[name], ember[name], var_e[name])


def test_transparent_film_leaves_the_world_in_its_group_as_cycles():
    """With a transparent film Combined leaves out the world the camera sees, but Cycles still writes it to the
    world's group when the Environment pass is on (integrate_background evaluates it for that pass, and
    film_write_background hands it to the groups): the sky's pixels of the group, as Cycles', exactly."""
    scene = new_scene(16, 16)
    set_world(scene, color=(0.2, 0.4, 0.8))
    quad_object("Floor", (-6, -4, 0), (12, 0, 0), (0, 10, 0), diffuse_material("Floor", (0.6, 0.6, 0.6)))
    layer = _groups(scene, ("Sky",))
    scene.world.lightgroup = "Sky"
    scene.render.film_transparent = True
    for environment in (False, True):
        layer.use_pass_environment = environment
        sky = {engine: _layers(scene, engine, 4, 1, ("Sky",))["Combined_Sky"][0] for engine in ("CYCLES", "EMBER")}
        np.testing.assert_allclose(sky["EMBER"], sky["CYCLES"], rtol=1e-6)   # the top row: the sky alone
        expected = np.broadcast_to((0.2, 0.4, 0.8) if environment else (0.0, 0.0, 0.0), sky["EMBER"].shape)
        np.testing.assert_allclose(sky["EMBER"], expected, rtol=1e-6)


# ---------------------------------------------------------------- Ember alone
def _every_emitter():
    """Every kind of emitter and accumulation, each emitter in a group of its own: area, soft point and spot lamps,
    a sun with a disc (seen in the glossy ball and through the smooth glass one, whose other branch the kernel
    traces), an emissive panel, an HDRI world, an emissive fog cube, and a lamp whose shadows only some objects
    cast (shadow linking's dedicated rays)."""
    scene = new_scene(48, 32)
    set_world(scene, hdri="sunset.exr")
    quad_object("Floor", (-6, -4, 0), (12, 0, 0), (0, 10, 0), diffuse_material("Floor", (0.6, 0.6, 0.6)))
    _ball("Gloss", (-1.6, 0, 0.6), 0.6, node_material("Gloss", "ShaderNodeBsdfGlossy", Color=(0.8, 0.8, 0.8),
                                                      Roughness=0.2))
    _ball("Glass", (1.6, 0, 0.6), 0.6, node_material("Glass", "ShaderNodeBsdfGlass", Roughness=0.0))
    matte = _ball("Matte", (0.0, 1.5, 0.5), 0.5, diffuse_material("Matte", (0.8, 0.5, 0.3)))
    emitters = {
        "Area": add_lamp(scene, "Area", "AREA", (0, -2.5, 3.5), (0.6, 0, 0), energy=150.0, size=1.0),
        "Point": add_lamp(scene, "Point", "POINT", (2.5, -1.5, 2.0), energy=80.0, shadow_soft_size=0.2),
        "Spot": add_lamp(scene, "Spot", "SPOT", (-2.5, -2.0, 3.0), (0.6, 0, -0.8), energy=300.0, spot_size=0.8),
        "Sun": add_lamp(scene, "Sun", "SUN", (0, 0, 5), (0.7, 0.3, 0.5), energy=2.0, angle=0.2),
        "Linked": add_lamp(scene, "Linked", "AREA", (0, 3.0, 2.5), (-0.8, 0, 0), energy=100.0, size=0.5),
        "Panel": quad_object("Panel", (-2.5, 1.5, 0.3), (1.2, 0, 0), (0, 0.3, 1.0),
                             emission_material("Glow", (1, 0.6, 0.3), 6.0)),
        "Fog": _glow_cube(scene, "Fog"),
    }
    blockers = bpy.data.collections.new("Blockers")   # every object casts the Linked lamp's shadow but the matte ball
    blockers.objects.link(matte)
    blockers.collection_objects[0].light_linking.link_state = "EXCLUDE"
    emitters["Linked"].light_linking.blocker_collection = blockers
    _groups(scene, list(emitters) + ["Sky"])
    for name, ob in emitters.items():
        ob.lightgroup = name
    scene.world.lightgroup = "Sky"
    return scene, list(emitters) + ["Sky"]


@pytest.mark.parametrize("clamp", [(0.0, 0.0), (1.0, 0.5)])
def test_groups_add_up_to_combined_exactly(clamp):
    """With every emitter in a group, the groups' passes add up to Combined pixel by pixel to float rounding (with
    sample clamping too: each contribution's parts are clamped as it is), each group has light, and Combined is
    the same bit for bit as without light groups (they only add passes)."""
    from test_passes import render
    scene, names = _every_emitter()
    settings = dict(use_denoising=False, sample_clamp_direct=clamp[0], sample_clamp_indirect=clamp[1])
    engine = render(scene, samples=8, **settings)
    assert engine.reports == [], engine.reports
    combined = engine.image("Combined")[..., :3]
    groups = {name: engine.image(f"Combined_{name}") for name in names}
    for name, image in groups.items():
        assert np.isfinite(image).all() and image.max() > 0, name
    np.testing.assert_allclose(sum(groups.values()), combined, rtol=1e-5, atol=1e-6 * combined.max())
    for ob in scene.objects:
        ob.lightgroup = ""
    scene.world.lightgroup = ""
    groups = scene.view_layers[0].lightgroups
    while len(groups):
        groups.remove(groups[0])
    plain = render(scene, samples=8, **settings).image("Combined")
    np.testing.assert_array_equal(plain, engine.image("Combined"))


def test_export_reads_groups_as_cycles():
    """Group numbers follow the view layer's list; an object's group is its own, or its instancer's where its own
    is empty; a name the view layer does not list is no group; the world and the lamps have theirs. Without light
    groups nothing is exported for them, and no warning is given."""
    from bpy_helpers import export_current
    from ember.kernels.scene import NO_GROUP
    scene = new_scene(16, 16)
    set_world(scene, color=(0.1, 0.1, 0.1))
    red = emission_material("Red", (1, 0, 0), 2.0)
    own = quad_object("Own", (-1, 0, 0), (0.5, 0, 0), (0, 0, 0.5), red)
    stray = quad_object("Stray", (0, 0, 0), (0.5, 0, 0), (0, 0, 0.5), red)
    source = bpy.data.collections.new("Source")   # instanced only: its objects render as the instancer's instances
    plain = quad_object("Plain", (0, 0, 1), (0.5, 0, 0), (0, 0, 0.5), red)
    mine = quad_object("Mine", (1, 0, 1), (0.5, 0, 0), (0, 0, 0.5), red)
    for ob in (plain, mine):
        scene.collection.objects.unlink(ob)
        source.objects.link(ob)
    holder = bpy.data.objects.new("Holder", None)
    holder.instance_type, holder.instance_collection = "COLLECTION", source
    scene.collection.objects.link(holder)
    lamp = add_lamp(scene, "Lamp", "POINT", (0, -2, 2), energy=10.0)
    bare = add_lamp(scene, "Bare", "POINT", (0, -2, 3), energy=10.0)
    before = export_current()
    assert before.scene.light_groups is None and before.scene.lights.light_groups is None
    _groups(scene, ("A", "B", "C"))
    own.lightgroup, stray.lightgroup, mine.lightgroup, holder.lightgroup = "B", "Nope", "A", "C"
    lamp.lightgroup, scene.world.lightgroup = "C", "A"
    result = export_current()
    assert result.warnings == [], result.warnings
    rows = {key[0]: g for key, g in zip(result.index.instance_keys, result.scene.light_groups.objects)}
    assert rows == {"Own": 1, "Stray": NO_GROUP, "Plain": 2, "Mine": 0}, rows
    assert result.scene.light_groups.world == 0
    lamps = dict(zip(np.round(result.scene.lights.position[:, 2]).astype(int), result.scene.lights.light_groups))
    assert lamps == {2: 2, 3: NO_GROUP}, lamps
    assert bare.lightgroup == ""


def test_panels_users_set_groups_in():
    """View Layer > Passes > Light Groups (Ember's), Object > Shading > Light Group and World > Settings > Light
    Group (Cycles' panels, which Ember adds itself to)."""
    from bpy_helpers import ensure_registered
    ensure_registered()
    assert hasattr(bpy.types, "EMBER_VIEWLAYER_PT_passes_lightgroups")
    for name in ("CYCLES_OBJECT_PT_lightgroup", "CYCLES_WORLD_PT_settings", "CYCLES_WORLD_PT_settings_light_group",
                 "OBJECT_PT_shading"):
        assert "EMBER" in getattr(bpy.types, name).COMPAT_ENGINES, name


def test_worker_processes_write_the_same_group_passes():
    """Waves rendered in worker processes (kernels/workers.py) bring their groups' passes back bit for bit."""
    from bpy_helpers import export_current
    from ember.kernels import Renderer, RenderSettings
    from ember.kernels.passes import group_pass
    _three_groups()
    scene = export_current().scene
    settings = RenderSettings(samples=4, seed=3, wave_size=1024, passes=tuple(group_pass(k) for k in range(3)))
    images = []
    for processes in (False, True):
        with Renderer(scene, threads=2, processes=processes) as renderer:
            if processes:
                assert renderer.crew.wait_for_workers() == 1, renderer.crew.worker_failures
            film = renderer.render(settings).film
            assert not processes or renderer.crew.remote_waves > 0
            images.append({name: np.asarray(values) for name, values in film.aux.items()})
    for name in images[0]:
        assert images[0][name].max() > 0, name
        np.testing.assert_array_equal(images[1][name], images[0][name], err_msg=name)


def test_scene_validation_names_the_light_groups_fields():
    """A group table that does not fit the object table, or groups below NO_GROUP, are refused by name."""
    import dataclasses

    from ember.kernels.scene import LightGroups, Lights
    from ember.kernels.shapes import cornell_box
    scene = cornell_box(8, 8)
    k = 0 if scene.objects is None else len(scene.objects)
    with pytest.raises(ValueError, match="light_groups.objects"):
        dataclasses.replace(scene, light_groups=LightGroups(np.zeros(k + 1, np.int32))).validate()
    with pytest.raises(ValueError, match="light_groups.world"):
        dataclasses.replace(scene, light_groups=LightGroups(np.zeros(k, np.int32), world=-2)).validate()
    lights = Lights(kind=np.zeros(1, np.int32), position=np.zeros((1, 3), np.float32),
                    frame=np.eye(3, dtype=np.float32)[None], radiance=np.ones((1, 3), np.float32),
                    radius=np.zeros(1, np.float32), size=np.zeros((1, 2), np.float32),
                    spot_cos=np.zeros((1, 2), np.float32), sun_half_angle=np.zeros(1, np.float32),
                    light_groups=np.array([-3], np.int32))
    with pytest.raises(ValueError, match="lights.light_groups"):
        lights.validate()
