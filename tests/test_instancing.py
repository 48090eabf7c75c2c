"""Instancing without copies (kernels.scene.Instances): a mesh stored once in object space and placed by
transforms must trace, shade and light exactly as its flattened world-space copies do.

Kernel level: every per-triangle query of the triangle table, the light sampler's emissive table, and a
whole render, against the flattened scene (kernels.geometry.flatten_instances). Blender level: linked
duplicates, collection instances and geometry-nodes instances exported as instances, rendered like the
same scene copied into world space; and the memory of 1,000 instances of a 100k-triangle mesh.
"""
from __future__ import annotations

import sys

import numpy as np
import pytest

from ember.kernels import Camera, Materials, Renderer, RenderSettings, SceneArrays, World
from ember.kernels.geometry import TriangleTable, flatten_instances
from ember.kernels.lights import LightSampler
from ember.kernels.scene import OBJ_RANDOM, Instances, Prototype, object_row
from ember.kernels.shapes import look_at, uv_sphere


def _matrix(t, scale=(1.0, 1.0, 1.0), angle=0.0) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    m = np.eye(4)
    m[:3, :3] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ np.diag(scale)
    m[:3, 3] = t
    return m


def _scene(width=48, height=36) -> SceneArrays:
    """A floor (plain triangles), three instances of a smooth sphere (one rotated and squashed, one
    mirrored), and an emissive small sphere instanced twice; tangents and an attribute on the sphere."""
    sp, sn = uv_sphere(12, smooth=True)
    t = len(sp)
    rng = np.random.default_rng(7)
    tangents = np.concatenate([rng.normal(size=(t, 3, 3)), np.sign(rng.normal(size=(t, 3, 1)))], axis=2)
    tangents[..., :3] /= np.linalg.norm(tangents[..., :3], axis=2, keepdims=True)
    uvs = rng.uniform(size=(t, 3, 2)).astype(np.float32)
    ball = Prototype(sp, sn, uvs, np.zeros(t, np.int32), tangents.astype(np.float32),
                     (("attr:heat", rng.uniform(size=(t, 3, 1)).astype(np.float32)),))
    lamp = Prototype(sp * np.float32(0.25), sn, np.zeros((t, 3, 2), np.float32), np.full(t, 2, np.int32))
    mats = np.array([_matrix((-1.5, 0, 1)), _matrix((0, 0.3, 0.8), (0.8, 1.3, 0.7), 0.6),
                     _matrix((1.5, 0, 1), (-1, 1, 1)), _matrix((-0.8, -1.2, 2.4)), _matrix((0.9, -1.0, 2.2))])
    floor = np.array([[[-6, -6, 0], [6, -6, 0], [6, 6, 0]], [[-6, -6, 0], [6, 6, 0], [-6, 6, 0]]], np.float32)
    objects = np.stack([object_row(np.eye(4))] + [object_row(m) for m in mats])
    return SceneArrays(
        positions=floor, normals=np.tile(np.float32([0, 0, 1]), (2, 3, 1)), uvs=np.zeros((2, 3, 2), np.float32),
        material_ids=np.array([1, 1], np.int32),
        materials=Materials.diffuse(np.array([[0.8, 0.3, 0.3], [0.7, 0.7, 0.7], [0.5, 0.5, 0.5]], np.float32),
                                    emission=np.array([[0, 0, 0], [0, 0, 0], [30, 25, 20]], np.float32)),
        world=World(color=np.array([0.05, 0.05, 0.08], np.float32)),
        camera=Camera(world_from_camera=look_at((0, -7, 3), (0, 0, 1)), width=width, height=height,
                      fov_rad=np.radians(50)),
        tangents=np.zeros((2, 3, 4), np.float32), objects=objects, object_ids=np.zeros(2, np.int32),
        instances=Instances((ball, lamp), np.array([0, 0, 0, 1, 1], np.int32), mats,
                            np.arange(1, 6, dtype=np.int32)))


def test_numbering_and_validation():
    scene = _scene()
    inst = scene.instances
    t = inst.prototypes[0].triangle_count
    np.testing.assert_array_equal(inst.bases(2), [2, 2 + t, 2 + 2 * t, 2 + 3 * t, 2 + 3 * t + t])
    assert scene.instanced_triangle_count == 5 * t
    bad = SceneArrays(**{**scene.__dict__, "instances": Instances(inst.prototypes, np.array([0, 5], np.int32),
                                                                  inst.world_from_object[:2], inst.object_ids[:2])})
    with pytest.raises(ValueError, match="instances.prototype"):
        bad.validate()
    # A singular or non-finite placement is dropped like its flattened copy's degenerate triangles.
    mats = inst.world_from_object.copy()
    mats[1, :3, :3] = 0.0
    mats[2, 0, 0] = np.nan
    checked = SceneArrays(**{**scene.__dict__, "instances": Instances(inst.prototypes, inst.prototype, mats,
                                                                      inst.object_ids)}).validate()
    assert checked.scene.instances.count == 3 and checked.dropped_triangles == 2 * t
    assert checked.nonfinite_triangles == t   # the NaN one; the flattened one is only degenerate


def test_table_queries_match_the_flattened_copies():
    scene = _scene().validate().scene
    flat = flatten_instances(scene).validate().scene
    table, reference = TriangleTable(scene), TriangleTable(flat)
    total = len(flat.positions)
    assert total == 2 + scene.instanced_triangle_count
    prim = np.random.default_rng(1).permutation(total).astype(np.int32)   # any order, plain and instanced
    np.testing.assert_allclose(table.gather(prim), reference.gather(prim), atol=2e-6, rtol=1e-5)
    np.testing.assert_array_equal(table.materials(prim), reference.materials(prim))
    np.testing.assert_array_equal(table.object_rows(prim), reference.object_rows(prim))
    np.testing.assert_array_equal(table.attribute("attr:heat", prim), reference.attribute("attr:heat", prim))
    b1, b2 = np.float32(0.2) * np.ones(total, np.float32), np.float32(0.3) * np.ones(total, np.float32)
    for got, want in zip(table.tangent_frame(prim, b1, b2), reference.tangent_frame(prim, b1, b2)):
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), atol=2e-6)


class _Emission:
    """The light sampler's view of the materials, for a scene whose emissive material is row 2."""
    emissive = np.array([False, False, True])
    varies = np.array([False, False, False])

    def __call__(self, tri, b1=None, b2=None, toward=None, dist=None):
        return np.tile(np.float32([[30], [25], [20]]), (1, len(tri)))


def test_instanced_emitters_are_lights_of_their_own():
    scene = _scene().validate().scene
    flat = flatten_instances(scene).validate().scene
    from ember.kernels.environment import Environment
    got = LightSampler(scene, Environment(scene.world), _Emission())
    want = LightSampler(flat, Environment(flat.world), _Emission())
    np.testing.assert_array_equal(got.tri_ids, want.tri_ids)
    # The flattened copies' corners were rounded to float32 in world space (3e-7 at these coordinates);
    # unit normals of the lamp's 0.06-wide triangles carry that rounding over their edge length.
    np.testing.assert_allclose(got.tri_table, want.tri_table, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(got.pmf32, want.pmf32, rtol=1e-5)
    # MIS on a BSDF ray's hit finds the same light, plain or instanced triangle numbers alike.
    tri = np.concatenate([got.tri_ids[::7], [0, 1, 5, len(flat.positions) - 1]])
    ones = np.ones(len(tri), np.float32)
    np.testing.assert_allclose(got.pdf_triangle_hit(tri, ones, ones, 0 * ones, -5 * ones, 3 * ones),
                               want.pdf_triangle_hit(tri, ones, ones, 0 * ones, -5 * ones, 3 * ones), rtol=1e-5)


def test_render_equals_the_flattened_scene():
    """Same sample sequence, same paths: the images differ only where float rounding in the instance
    transforms sends a path another way, which a handful of pixels may show."""
    scene = _scene()
    settings = RenderSettings(samples=16, seed=3)
    images = []
    for s in (scene, flatten_instances(scene)):
        with Renderer(s, threads=2) as renderer:
            images.append(renderer.render(settings).image)
    a, b = images
    assert a[..., :3].mean() > 0.05
    close = np.isclose(a, b, rtol=1e-3, atol=1e-4).all(axis=2)
    assert close.mean() > 0.98, close.mean()
    assert abs(a[..., :3].mean() / b[..., :3].mean() - 1) < 2e-3


# ---- Through Blender ------------------------------------------------------------------------------------

def _blender_scene():
    """A floor, a 1,280-triangle icosphere placed by linked duplicates (one mirrored and squashed) and by
    a collection instance, coloured per instance by Object Info > Random; a sun."""
    import bpy
    from bpy_helpers import new_scene, quad_object, diffuse_material, set_world
    scene = new_scene(48, 36)
    set_world(scene, color=(0.2, 0.22, 0.25))
    quad_object("Floor", (-6, -6, 0), (12, 0, 0), (0, 12, 0), diffuse_material("Floor"))
    mat = bpy.data.materials.new("PerInstance")
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = nodes["Principled BSDF"]
    info = nodes.new("ShaderNodeObjectInfo")
    ramp = nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = (0.9, 0.2, 0.1, 1)
    ramp.color_ramp.elements[1].color = (0.1, 0.3, 0.9, 1)
    links.new(info.outputs["Random"], ramp.inputs["Fac"])
    links.new(ramp.outputs["Color"], bsdf.inputs["Base Color"])
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=4, radius=0.6)
    source = bpy.context.object
    source.data.materials.append(mat)
    source.data.shade_smooth()
    source.location = (-2, 0, 0.6)
    placements = [((0, 0, 0.6), (1, 1, 1), 0.0), ((2, 0, 0.6), (-1, 1, 0.6), 0.4), ((-1, 1.5, 0.6), (1, 1, 1), 1.0)]
    for i, (location, scale, angle) in enumerate(placements):
        ob = bpy.data.objects.new(f"Copy{i}", source.data)
        ob.location, ob.scale, ob.rotation_euler = location, scale, (0, angle, angle)
        scene.collection.objects.link(ob)
    group = bpy.data.collections.new("Group")
    group.objects.link(bpy.data.objects.new("InGroup", source.data))
    empty = bpy.data.objects.new("GroupInstance", None)
    empty.instance_type, empty.instance_collection = "COLLECTION", group
    empty.location = (1, 1.6, 0.6)
    scene.collection.objects.link(empty)
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy = 3.0
    sun.rotation_euler = (0.5, 0.3, 0.2)
    scene.collection.objects.link(sun)
    return scene


def test_blender_instances_are_exported_once_and_render_as_copies(monkeypatch):
    import ember.engine.export.instances as instances_export
    from bpy_helpers import export_current, render_to_array
    scene = _blender_scene()
    monkeypatch.setattr(instances_export, "INSTANCE_MIN_TRIANGLES", 1)
    result = export_current()
    inst = result.scene.instances
    assert inst is not None and len(inst.prototypes) == 1 and inst.count == 5
    assert result.triangle_count == 2 + 5 * 1280 and len(result.scene.positions) == 2
    # Each instance keeps its own object row (Object Info > Random differs per copy).
    assert len(set(result.scene.objects[inst.object_ids, OBJ_RANDOM].tolist())) == 5
    instanced = render_to_array(scene, "EMBER", 16, seed=5)
    monkeypatch.setattr(instances_export, "INSTANCE_MIN_TRIANGLES", 10**12)
    assert export_current().scene.instances is None
    flat = render_to_array(scene, "EMBER", 16, seed=5)
    assert instanced[..., :3].mean() > 0.05
    close = np.isclose(instanced, flat, rtol=1e-3, atol=1e-4).all(axis=2)
    assert close.mean() > 0.98, close.mean()
    assert abs(instanced[..., :3].mean() / flat[..., :3].mean() - 1) < 2e-3


def test_moving_instances_stay_plain(monkeypatch):
    """Motion blur moves plain triangles: a mesh with a moving instance is not instanced."""
    import bpy
    import ember.engine.export.instances as instances_export
    scene = _blender_scene()
    monkeypatch.setattr(instances_export, "INSTANCE_MIN_TRIANGLES", 1)
    mover = bpy.data.objects["Copy0"]
    mover.keyframe_insert("location", frame=1)
    mover.location.x += 1
    mover.keyframe_insert("location", frame=2)
    scene.frame_set(1)
    scene.render.use_motion_blur = True
    from ember.engine.export import export_scene
    from ember.engine.export.motion import MotionSamples
    depsgraph = bpy.context.evaluated_depsgraph_get()
    mover_key = ("Copy0", "", ())
    result = export_scene(depsgraph, motion=MotionSamples(objects={mover_key: np.stack([np.eye(4)] * 2)}))
    assert result.scene.instances is None and len(result.scene.positions) == 2 + 5 * 1280


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="peak memory is read from /proc/self")
def test_thousand_instances_cost_the_memory_of_one_copy():
    """Instances are transforms of one stored mesh, never copies: 960 more instances of a 100k-triangle mesh
    (64 -> 1,024 on a grid, 6.4M -> 102M triangles flattened) cost less memory than one more copy of the
    mesh would (the peak of rendering the mesh alone), where copies would cost 960 times that. Each render
    runs in a fresh process (bench/big_scenes.py), its peak resident memory over the render call measured;
    comparing two forests leaves out what every forest holds alike (the two-level BVH's top, the working
    set of a frame full of hits), which made a ratio to the lone mesh's peak swing between machines."""
    from bench.big_scenes import measure
    one = measure("EMBER", "mesh", 100_000)
    few = measure("EMBER", "instances", 100_000, 64)
    many = measure("EMBER", "instances", 100_000, 1024)
    assert one["peak_growth_mb"] > 0 and few["peak_growth_mb"] > 0, (one, few)
    assert many["peak_growth_mb"] - few["peak_growth_mb"] < one["peak_growth_mb"], (one, few, many)


def test_an_indexed_bvh_traces_the_same_triangles():
    """SceneArrays.bvh_vertices / bvh_indices (what the export hands Embree to build from, shared vertices)
    give the image of the corners alone, bit for bit, and follow validate() when it drops triangles."""
    sp, sn = uv_sphere(16, smooth=True)
    vertices, inverse = np.unique(sp.reshape(-1, 3), axis=0, return_inverse=True)
    inverse = inverse.reshape(-1, 3)
    inverse[5, 1] = inverse[5, 0]          # one triangle collapsed to an edge: validate() drops it
    sp = vertices[inverse].astype(np.float32)
    scene = SceneArrays(positions=sp, normals=sn, uvs=np.zeros((len(sp), 3, 2), np.float32),
                        material_ids=np.zeros(len(sp), np.int32), world=World(color=np.float32([0.5, 0.6, 0.7])),
                        camera=Camera(world_from_camera=look_at((0, -4, 1), (0, 0, 0)), width=24, height=24))
    indexed = SceneArrays(**{**scene.__dict__, "bvh_vertices": vertices.astype(np.float32),
                             "bvh_indices": inverse.astype(np.uint32)})
    checked = indexed.validate()
    assert checked.dropped_triangles == 1
    kept = checked.scene
    np.testing.assert_array_equal(kept.bvh_vertices[kept.bvh_indices], kept.positions)
    images = []
    for s in (scene, indexed):
        with Renderer(s, threads=2) as renderer:
            images.append(renderer.render(RenderSettings(samples=4, seed=1)).image)
    np.testing.assert_array_equal(images[0], images[1])
    with pytest.raises(ValueError, match="bvh_indices"):
        SceneArrays(**{**indexed.__dict__, "bvh_indices": np.full((len(sp), 3), 10**6, np.uint32)}).validate()


def test_packets_alone_trace_what_embreex_traces(monkeypatch):
    """Where embreex's scene handle cannot be located (another embreex build), every query runs through
    kernels.embree's 16-ray packets: the same image, bit for bit, plain and instanced."""
    from ember.kernels import embree
    scene = _scene()
    settings = RenderSettings(samples=4, seed=9)
    images = []
    assert embree._embreex_slot() is not False, "embreex's loop should trace our scenes with the pinned embreex"
    for slot in (embree._embreex_slot(), False):
        monkeypatch.setattr(embree, "_EMBREEX_SLOT", slot)
        for s in (scene, flatten_instances(scene)):
            with Renderer(s, threads=2) as renderer:
                images.append(renderer.render(settings).image)
    np.testing.assert_array_equal(images[0], images[2])   # instanced: embreex for shadows / packets alone
    np.testing.assert_array_equal(images[1], images[3])   # plain: embreex's loop / packets alone


def test_validate_skips_triangles_a_clean_scene_already_holds():
    """validate(clean=...) (Persistent Data's next frame): triangles equal to the clean scene's are not
    looked at again; raw triangles that validate() had to clean are cleaned again, to the same result."""
    scene = _scene().validate().scene
    again = scene.validate(clean=scene)
    assert again.dropped_triangles == 0 and again.scene.positions is scene.positions
    assert again.scene.instances.prototypes[0] is scene.instances.prototypes[0]
    raw = _scene()
    broken = raw.positions.copy()
    broken[0, 1] = broken[0, 0]                                   # the floor's first triangle collapses
    raw = SceneArrays(**{**raw.__dict__, "positions": broken})
    first = raw.validate()
    second = raw.validate(clean=first.scene)
    assert first.dropped_triangles == second.dropped_triangles == 1
    np.testing.assert_array_equal(first.scene.positions, second.scene.positions)
