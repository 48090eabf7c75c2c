"""Light and shadow linking (engine/export/light_linking.py, kernels/lights/links.py, kernels/shadow_linking.py),
against Cycles.

The scene of issue 39: three spheres on a floor under a key light. Each parity test links something, checks that
the link changes Ember's image (so the comparison tests it), and compares Ember with Cycles with tolerances
from the renders' own noise (replicate_render: every 8 x 8 block within 4.5 standard errors, the whole image
within 4). Then the export's sets against Blender's rules, the kernel's choice per receiver set against its
pmf, and that linked volumes no longer warn.
"""
from __future__ import annotations

import numpy as np
import pytest

SAMPLES = 64


def _spheres(kind="AREA"):
    """Floor, three matte spheres (Ball0..2, left to right) and a key light (AREA or SUN) above the front."""
    import bpy
    from bpy_helpers import diffuse_material, new_scene, quad_object, set_world
    scene = new_scene(48, 32)
    set_world(scene, color=(0.05, 0.05, 0.05))
    quad_object("Floor", (-6, -4, 0), (12, 0, 0), (0, 10, 0), diffuse_material("Floor", (0.6, 0.6, 0.6)))
    balls = []
    for i, x in enumerate((-1.6, 0.0, 1.6)):
        bpy.ops.mesh.primitive_uv_sphere_add(segments=24, ring_count=12, radius=0.7, location=(x, 0, 0.7))
        ball = bpy.context.object
        ball.name = f"Ball{i}"
        ball.data.materials.append(diffuse_material(f"Matte{i}", (0.8, 0.8, 0.8)))
        balls.append(ball)
    key = bpy.data.objects.new("Key", bpy.data.lights.new("Key", kind))
    if kind == "SUN":
        key.data.energy, key.data.angle = 3.0, 0.1
    else:
        key.data.energy, key.data.size = 300.0, 1.0
    key.location, key.rotation_euler = (0, -2.5, 3.5), (0.6, 0, 0)
    scene.collection.objects.link(key)
    return scene, balls, key


def _linking(name, objects, state="INCLUDE"):
    """A linking collection holding `objects`, each with link state `state`."""
    import bpy
    collection = bpy.data.collections.new(name)
    for ob in objects:
        collection.objects.link(ob)
    for entry in collection.collection_objects:
        entry.light_linking.link_state = state
    return collection


def _matches_cycles(scene, samples=SAMPLES, **kwargs):
    """Ember's image (H, W, 3) after asserting it equals Cycles' within noise: every 8 x 8 block within 4.5
    standard errors of the difference and the whole image within 4 (compare_to_cycles' floor on the standard
    error: blocks without noise, the world seen directly, differ by float rounding only); prints the means and
    the whole image's z-score (the report's figures)."""
    from bpy_helpers import replicate_render
    cycles, var_c = replicate_render(scene, "CYCLES", samples, **kwargs)
    ember, var_e = replicate_render(scene, "EMBER", samples, **kwargs)
    return within_noise(ember, var_e, cycles, var_c)


def within_noise(ember, var_e, cycles, var_c):
    """_matches_cycles' assertion on two 48 x 32 images and their variances; returns Ember's."""
    def blocks(x):
        return x.reshape(4, 8, 6, 8, 3).sum(axis=(1, 3))
    se = np.maximum(np.sqrt(blocks(var_c) + blocks(var_e)), 1e-4 * np.maximum(np.abs(blocks(cycles)), 1e-3))
    z_blocks = np.abs(blocks(ember) - blocks(cycles)) / se
    z = (ember.sum() - cycles.sum()) / np.sqrt(var_c.sum() + var_e.sum())
    print(f"mean Cycles {cycles.mean():.4f} Ember {ember.mean():.4f} ({ember.mean() / cycles.mean() - 1:+.2%}), "
          f"whole-image z {z:+.2f}, worst block z {z_blocks.max():.2f}")
    assert z_blocks.max() < 4.5 and abs(z) < 4.0, (z_blocks.max(), z)
    return ember


def _plain(scene):
    """A quick Ember render of the scene as it is (before the link under test)."""
    from bpy_helpers import render_to_array
    return render_to_array(scene, "EMBER", 16, seed=3)[..., :3]


def _changed(linked, plain, by=0.1):
    """Some 8 x 8 block's mean moved by more than `by` x the image's mean: the link is in the picture."""
    def blocks(x):
        return x.reshape(4, 8, 6, 8, 3).mean(axis=(1, 3, 4))
    moved = np.abs(blocks(linked) - blocks(plain)).max() / plain.mean()
    print(f"largest block change {moved:.2f} x the image mean")
    return moved > by


@pytest.mark.parametrize("state", ["INCLUDE", "EXCLUDE"])
def test_key_light_linked_to_one_sphere_matches_cycles(state):
    """The issue's case: a key light meant for the middle sphere (INCLUDE: only it; EXCLUDE: all but it)."""
    from bpy_helpers import export_current
    scene, balls, key = _spheres()
    plain = _plain(scene)
    key.light_linking.receiver_collection = _linking("KeyReceivers", [balls[1]], state)
    assert export_current().warnings == []
    assert _changed(_matches_cycles(scene), plain)


@pytest.mark.parametrize("kind, state", [("AREA", "EXCLUDE"), ("SUN", "INCLUDE")])
def test_blocker_collection_matches_cycles(kind, state):
    """Shadow linking: EXCLUDE, the middle sphere casts no shadow from the key; INCLUDE, only the left one does."""
    scene, balls, key = _spheres(kind)
    plain = _plain(scene)
    key.light_linking.blocker_collection = _linking("KeyBlockers", [balls[1] if state == "EXCLUDE" else balls[0]],
                                                    state)
    assert _changed(_matches_cycles(scene), plain)


@pytest.mark.parametrize("linking", ["receiver_collection", "blocker_collection"])
def test_emissive_mesh_linked_as_a_light_matches_cycles(linking):
    """An emissive panel as the linked emitter: lighting only the right sphere, or shadowed by all but it (its
    light then found by BSDF rays through the dedicated rays of shadow linking)."""
    from bpy_helpers import emission_material, quad_object
    scene, balls, key = _spheres()
    key.data.energy = 30.0
    panel = quad_object("Panel", (-1, -1.5, 2.8), (2, 0, 0), (0, 0.8, 0.4),
                        emission_material("Glow", (1, 0.9, 0.8), 8.0))
    plain = _plain(scene)
    state = "INCLUDE" if linking == "receiver_collection" else "EXCLUDE"
    setattr(panel.light_linking, linking, _linking("PanelLinks", [balls[2]], state))
    assert _changed(_matches_cycles(scene), plain)


def _glossy_scene():
    """A glossy floor that shows a key lamp linked to it alone, and a fill lamp that lights all but the floor (so
    the floor's choice of lights differs from the scene's) beside a matte ball."""
    import bpy
    from bpy_helpers import add_camera, diffuse_material, new_scene, node_material, quad_object, set_world
    scene = new_scene(48, 32)
    add_camera(scene, (0, -6, 2.2), (0, 0, 0.2))
    set_world(scene, color=(0.02, 0.02, 0.02))
    floor = quad_object("Floor", (-6, -4, 0), (12, 0, 0), (0, 10, 0),
                        node_material("Gloss", "ShaderNodeBsdfGlossy", Color=(0.8, 0.8, 0.8), Roughness=0.3))
    bpy.ops.mesh.primitive_uv_sphere_add(segments=24, ring_count=12, radius=0.7, location=(1.6, 0.5, 0.7))
    ball = bpy.context.object
    ball.name = "Ball"
    ball.data.materials.append(diffuse_material("Matte", (0.8, 0.8, 0.8)))
    key = bpy.data.objects.new("Key", bpy.data.lights.new("Key", "AREA"))
    fill = bpy.data.objects.new("Fill", bpy.data.lights.new("Fill", "AREA"))
    for lamp, location, rotation in ((key, (-0.5, 2.5, 1.6), (-1.3, 0, 0)), (fill, (1.5, -1.5, 3.0), (0.5, 0, 0))):
        lamp.data.energy, lamp.data.size = 200.0, 1.5
        lamp.location, lamp.rotation_euler = location, rotation
        scene.collection.objects.link(lamp)
    return scene, floor, ball, key, fill


@pytest.mark.parametrize("shadow_linked", [False, True])
def test_linked_light_in_a_glossy_reflection_matches_cycles(shadow_linked):
    """MIS with linked lights: the key's highlight on the glossy floor is found by light samples and by BSDF rays
    (or, shadow-linked, by the dedicated rays), each weighed against the floor's own choice of lights (the key
    alone). Weighing BSDF rays with the scene's choice (key and fill) made this image 15% too bright (45
    standard errors)."""
    scene, floor, ball, key, fill = _glossy_scene()
    plain = _plain(scene)
    key.light_linking.receiver_collection = _linking("KeyReceivers", [floor])
    fill.light_linking.receiver_collection = _linking("FillReceivers", [floor], "EXCLUDE")
    if shadow_linked:
        key.light_linking.blocker_collection = _linking("KeyBlockers", [ball], "EXCLUDE")
    assert _changed(_matches_cycles(scene), plain)


def test_a_shadow_linked_lamp_s_ray_visibility_matches_cycles():
    """A shadow-linked key that glossy rays do not see: its light samples leave the glossy floor out, and the
    dedicated rays that find it from the floor get nothing (shade_dedicated_light.h), as in Cycles; before, its
    highlight came back through them (with a warning)."""
    from bpy_helpers import export_current
    scene, floor, ball, key, fill = _glossy_scene()
    key.light_linking.blocker_collection = _linking("KeyBlockers", [ball], "EXCLUDE")
    plain = _plain(scene)
    key.visible_glossy = False
    assert export_current().warnings == []
    assert _changed(_matches_cycles(scene), plain)


def test_fog_receives_light_as_its_object():
    """A volume receives as its object: a fog box lit by a key linked to the middle sphere and the fog."""
    import bpy
    from bpy_helpers import node_material
    scene, balls, key = _spheres()
    # Lifted off the floor: Cycles renders a volume face lying on the floor unlike a lifted one (docs/volumes.md).
    bpy.ops.mesh.primitive_cube_add(size=2.6, location=(0, 0, 1.35))
    fog = bpy.context.object
    fog.data.materials.append(node_material("Fog", "ShaderNodeVolumePrincipled", output="Volume", Density=0.3))
    plain = _plain(scene)
    key.light_linking.receiver_collection = _linking("KeyReceivers", [balls[1], fog])
    assert _changed(_matches_cycles(scene), plain)


def _fog(name, location, size, shader="ShaderNodeVolumePrincipled", **inputs):
    """A box of a volume shader (Principled Volume by default) in a Volume output, named `name`."""
    import bpy
    from bpy_helpers import node_material
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=location)
    fog = bpy.context.object
    fog.name = name
    fog.scale = size
    fog.data.materials.append(node_material(name, shader, output="Volume", **inputs))
    return fog


@pytest.mark.parametrize("shader", ["principled", "emission"])
def test_emissive_fog_linked_to_one_sphere_matches_cycles(shader):
    """A glowing slab over the spheres (a thin Principled Volume with emission, or an Emission shader in the
    Volume output), its Light Linking including the right sphere only: its emission is counted by the paths that
    leave that sphere alone (Cycles' volume emission checks the path's receiver, kernel/integrator/
    shade_volume.h); camera rays (the world's set), the floor and the other spheres no longer see it, nor do
    paths scattered in the fog itself. Before, Ember counted it everywhere: +407% (z 1044). The Emission one
    also has a Shadow Linking collection, which changes nothing: no shadow ray goes to a volume's emission."""
    from bpy_helpers import export_current
    scene, balls, key = _spheres()
    key.data.energy = 60.0
    if shader == "principled":
        fog = _fog("Glow", (0, 0, 2.1), (5.0, 2.0, 0.6), Density=0.05, Emission_Strength=3.0,
                   Emission_Color=(1.0, 0.7, 0.4))
    else:
        fog = _fog("Glow", (0, 0, 2.1), (5.0, 2.0, 0.6), "ShaderNodeEmission", Color=(0.4, 0.7, 1.0), Strength=2.0)
    plain = _plain(scene)
    fog.light_linking.receiver_collection = _linking("GlowReceivers", [balls[2]])
    if shader == "emission":
        fog.light_linking.blocker_collection = _linking("GlowBlockers", [balls[1]], "EXCLUDE")
    assert export_current().warnings == []
    assert _changed(_matches_cycles(scene), plain)


@pytest.mark.parametrize("where", ["between", "around"])
def test_fog_excluded_from_a_key_s_blockers_matches_cycles(where):
    """A fog box excluded from the key's blockers, between the key and the middle sphere or around that sphere.
    Its boundary is skipped by shadow rays toward the key (kernel/bvh/util.h intersection_skip_shadow_link), so
    it never enters their volume stack: from outside it they pass without its attenuation. From inside it (the
    sphere, the fog's own scattering) it is on the stack they start with and stays there, its exit skipped too
    (kernel/integrator/shade_shadow.h): they are dimmed all the way to the key. Camera rays still meet it."""
    from bpy_helpers import export_current
    scene, balls, key = _spheres()
    if where == "between":
        fog = _fog("Fog", (0, -1.3, 2.3), (1.6, 1.2, 0.8), Density=2.0)
    else:   # lifted off the floor: a volume's face lying on another surface renders differently
        fog = _fog("Fog", (0, 0, 0.85), (1.7, 1.7, 1.6), Density=0.4)
    plain = _plain(scene)
    key.light_linking.blocker_collection = _linking("KeyBlockers", [fog], "EXCLUDE")
    assert export_current().warnings == []
    assert _changed(_matches_cycles(scene), plain)


# ---- Export: Blender's sets ------------------------------------------------------------------------------------

def test_sets_follow_blenders_rules():
    """Light sets and memberships as Blender's depsgraph makes them: an INCLUDE collection lights only its
    objects, an EXCLUDE one all others, a child collection's objects take the state of the child, emitters
    sharing a collection share its membership, an instance takes its instancer's set, an emitter without a
    collection reaches every set, and the lamps' masks reach the kernel's Lights."""
    import bpy
    from bpy_helpers import camera_only_scene, export_current
    from ember.engine.export.light_linking import ALL_MASK, link_table
    from ember.kernels.lights.links import reaches
    scene = camera_only_scene()

    def cube(name, x):
        bpy.ops.mesh.primitive_cube_add(size=0.5, location=(x, 0, 0))
        bpy.context.object.name = name
        return bpy.context.object
    a, b, c, d = cube("A", -3), cube("B", -1), cube("C", 1), cube("D", 3)
    lamps = []
    for name in ("L1", "L2", "L3", "L4"):
        lamp = bpy.data.objects.new(name, bpy.data.lights.new(name, "POINT"))
        scene.collection.objects.link(lamp)
        lamps.append(lamp)
    only_a = _linking("OnlyA", [a])
    lamps[0].light_linking.receiver_collection = only_a
    lamps[1].light_linking.receiver_collection = only_a               # shares L1's collection
    not_b = _linking("NotB", [b], "EXCLUDE")
    child = bpy.data.collections.new("Child")
    child.objects.link(c)
    not_b.children.link(child)
    not_b.collection_children[0].light_linking.link_state = "EXCLUDE"   # C excluded through the child
    lamps[2].light_linking.receiver_collection = not_b
    table = link_table(bpy.context.evaluated_depsgraph_get())

    def lights(lamp, ob):
        return bool(reaches(np.uint64(table.memberships(lamp)[0]), np.uint8(table.object_sets(ob)[0])))
    assert [lights(lamps[0], ob) for ob in (a, b, c, d)] == [True, False, False, False]
    assert table.memberships(lamps[1]) == table.memberships(lamps[0])
    assert [lights(lamps[2], ob) for ob in (a, b, c, d)] == [True, False, False, True]
    assert table.memberships(lamps[3]) == (ALL_MASK, ALL_MASK)
    assert table.object_sets(d) == (0, 0) and table.object_sets(d, parent=a) == table.object_sets(a)
    assert table.object_sets(a, parent=d) == table.object_sets(a)     # an instancer in set 0 changes nothing
    lights_ = export_current().scene.lights
    assert lights_.light_sets is not None and lights_.shadow_sets is None
    assert lights_.light_sets.tolist()[3] == ALL_MASK


def test_linked_volumes_do_not_warn_and_unlinked_scenes_take_no_path():
    """A volume's linked emission and a volume among blockers render as in Cycles (the parity tests above), with
    no warning; a scene without linking has no LightLinks, and its renderer no linking tables (every stage skips
    linking)."""
    import bpy
    from bpy_helpers import export_current, node_material
    from ember.kernels import Renderer
    scene, balls, key = _spheres()
    result = export_current()
    assert result.scene.light_links is None
    with Renderer(result.scene.validate().scene, threads=1, processes=False) as renderer:
        assert renderer.links is None and renderer.lights.links is None
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0, -2, 0.5))
    fog = bpy.context.object
    fog.name = "Fog"
    fog.data.materials.append(node_material("Fog", "ShaderNodeVolumePrincipled", output="Volume", Density=0.3))
    fog.light_linking.receiver_collection = _linking("FogReceivers", [balls[0]])
    key.light_linking.blocker_collection = _linking("KeyBlockers", [fog])
    result = export_current()
    assert result.warnings == [] and result.scene.light_links is not None


def test_the_linking_panels_show_with_ember():
    """Blender's Light Linking and Shadow Linking panels sit under Object > Shading, which Ember shows."""
    import bpy
    from bpy_helpers import ensure_registered
    ensure_registered()
    assert "EMBER" in bpy.types.OBJECT_PT_shading.COMPAT_ENGINES
    assert bpy.types.OBJECT_PT_light_linking.bl_parent_id == bpy.types.OBJECT_PT_shadow_linking.bl_parent_id == \
        "OBJECT_PT_shading"


def test_a_linking_change_makes_the_viewport_export_again():
    """The viewport's partial updates (engine/export/updates.py) give way to a full export when linking changes."""
    import bpy
    from bpy_helpers import export_current
    from ember.engine.export.updates import LIGHTS, export_changes
    scene, balls, key = _spheres()
    result = export_current()
    depsgraph = bpy.context.evaluated_depsgraph_get()
    assert export_changes(depsgraph, result.index, frozenset({LIGHTS}), result.scene) is not None
    key.light_linking.receiver_collection = _linking("KeyReceivers", [balls[1]])
    depsgraph = bpy.context.evaluated_depsgraph_get()
    assert export_changes(depsgraph, result.index, frozenset({LIGHTS}), result.scene) is None


# ---- Kernel: the choice per receiver set ------------------------------------------------------------------------

def test_each_receiver_set_chooses_among_its_lights_by_its_pmf():
    """Five point lamps over a floor (a light tree per set), receivers in sets 0 and 1 with lamps 0-1 reaching
    set 1 only and lamps 2-4 set 0 only: choose_at with a receiver set picks only the lamps that reach it, with the
    frequencies selection_pmf gives them (chi-square), and selection_pmf is 0 for the others."""
    import dataclasses
    from ember.kernels import Lights, Materials, Renderer
    from ember.kernels.scene import LIGHT_KINDS, LightLinks
    from stats import assert_chi2
    from test_instancing import _scene as instanced_scene
    base = instanced_scene()
    k = len(base.objects)
    n = 5
    lamps = Lights(kind=np.full(n, LIGHT_KINDS["POINT"], np.int32),
                   position=np.array([[x, 0.5 * x, 2.0] for x in np.linspace(-2, 2, n)], np.float32),
                   frame=np.repeat(np.eye(3, dtype=np.float32)[None], n, axis=0),
                   radiance=np.linspace(1, 3, n)[:, None].repeat(3, 1).astype(np.float32),
                   radius=np.full(n, 0.1, np.float32), size=np.zeros((n, 2), np.float32),
                   spot_cos=np.tile(np.float32([1, 0]), (n, 1)), sun_half_angle=np.zeros(n, np.float32),
                   light_sets=np.array([2, 2, 1, 1, 1], np.uint64))
    receiver = np.zeros(k, np.uint8)
    receiver[1] = 1
    links = LightLinks(receiver, np.zeros(k, np.uint8), np.full(k, 2 ** 64 - 1, np.uint64),
                       np.full(k, 2 ** 64 - 1, np.uint64))
    matte = Materials.diffuse(np.full((3, 3), 0.6, np.float32))   # no emissive spheres: the lamps alone
    scene = dataclasses.replace(base, lights=lamps, light_links=links, materials=matte).validate().scene
    rng = np.random.default_rng(5)
    with Renderer(scene, threads=1, processes=False) as renderer:
        sampler = renderer.lights
        emitters = sampler.world_index + 1
        for s, reached in ((1, [0, 1]), (0, [2, 3, 4])):
            p = np.float32([0.3, -0.2, 0.4])
            m = 20_000
            at = tuple(np.full(m, c, np.float32) for c in p)
            sets = np.full(m, s, np.uint8)
            chosen, select = sampler.choose_at(rng.random(m, dtype=np.float32), *at, sets)
            assert set(np.unique(chosen)) <= set(reached)
            every = np.arange(emitters)
            pmf = sampler.selection_pmf(every, *(np.full(emitters, c, np.float32) for c in p),
                                        np.full(emitters, s, np.uint8)).astype(np.float64)
            assert np.all(pmf[[e for e in range(emitters) if e not in reached]] == 0)
            assert abs(pmf.sum() - 1) < 1e-5
            np.testing.assert_allclose(select, pmf[chosen], rtol=1e-5)
            assert_chi2(np.bincount(chosen, minlength=emitters), pmf * m)
