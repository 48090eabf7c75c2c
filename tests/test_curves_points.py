"""Curves and points (kernels/geometry/curves.py, points.py, primitives.py; engine/export/curves.py, points.py,
shapes.py): rays against their closed forms through Embree, what a hit yields, rays skipping the curve or point
they leave, instanced and world-space copies alike, and renders of them through Blender against Cycles."""
import dataclasses
import math

import bpy
import numpy as np
import pytest

from bpy_helpers import compare_to_cycles, diffuse_material, export_current, mesh_object, new_scene, set_world
from ember.kernels import Camera, Materials, Renderer, RenderSettings, SceneArrays, World, render
from ember.kernels.interaction import SurfaceHit
from ember.kernels.scene import Curves, Points, ShapeInstances, object_row
from ember.kernels.shapes import look_at
from ember.kernels.visibility import skip_hidden


def shape_scene(**fields) -> SceneArrays:
    """A scene of no triangles, one grey diffuse material, a white world, with the given curves or points."""
    empty = np.zeros((0, 3, 3), np.float32)
    cam = Camera(world_from_camera=look_at((0, -5, 0), (0, 0, 0)), width=16, height=16, fov_rad=np.radians(30))
    return SceneArrays(positions=empty, normals=empty, uvs=np.zeros((0, 3, 2), np.float32),
                       material_ids=np.zeros(0, np.int32), materials=Materials.diffuse(np.full((1, 3), 0.5, np.float32)),
                       world=World(color=np.ones(3, np.float32)), camera=cam, **fields)


def trace(scene: SceneArrays, origins, dirs, keys=None):
    """(hits, SurfaceHit of the rays that hit, their rows) of rays through a Renderer of the scene; keys: the
    curve or point each ray leaves (skipped)."""
    origins, dirs = np.asarray(origins, np.float32), np.asarray(dirs, np.float32)
    t_max = np.full(len(origins), np.inf, np.float32)
    with Renderer(scene, threads=1) as r:
        hits = r.accel.intersect(origins, dirs, t_max)
        if keys is not None:
            skip_hidden(r, origins, dirs, t_max, hits, None, keys=np.asarray(keys, np.int64))
        found = np.flatnonzero(hits.prim >= 0)
        d = tuple(dirs[found, k] for k in range(3))
        hit = SurfaceHit(r.triangles, hits.prim[found], hits.u[found], hits.v[found], d, False,
                         ray=(origins[found], hits.t[found]))
        return hits, hit, found, r.triangles.self_keys(hits.prim[found])


# ---------------------------------------------------------------- points
def random_spheres(count=40, seed=3):
    rng = np.random.default_rng(seed)
    return np.concatenate([rng.uniform(-2, 2, (count, 3)), rng.uniform(0.05, 0.4, (count, 1))], axis=1) \
        .astype(np.float32)


def nearest_sphere(spheres, o, d):
    """The closed form: each ray's nearest sphere hit (the near root; the far one from inside), and which."""
    best_t, best = np.full(len(o), np.inf), np.full(len(o), -1)
    for i, (cx, cy, cz, r) in enumerate(spheres.astype(np.float64)):
        oc = o - (cx, cy, cz)
        b = np.einsum("ij,ij->i", oc, d)
        c = np.einsum("ij,ij->i", oc, oc) - r * r
        disc = b * b - c
        root = np.sqrt(np.maximum(disc, 0))
        t = np.where(-b - root > 0, -b - root, -b + root)
        ok = (disc > 0) & (t > 0) & (t < best_t)
        best_t, best = np.where(ok, t, best_t), np.where(ok, i, best)
    return best_t, best


def test_rays_meet_points_as_the_spheres_they_are():
    spheres = random_spheres()
    scene = shape_scene(points=Points(spheres, np.zeros(len(spheres), np.int32)))
    rng = np.random.default_rng(7)
    o = rng.uniform(-4, 4, (4000, 3))
    d = rng.normal(size=(4000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    hits, hit, found, _ = trace(scene, o, d)
    t, which = nearest_sphere(spheres, o, d)
    assert np.array_equal(hits.prim >= 0, which >= 0)
    assert np.array_equal(hits.prim[found], which[found])      # no triangles: point j is number j
    assert np.allclose(hits.t[found], t[found], rtol=1e-4, atol=1e-5)
    centre = spheres[which[found], :3]
    p = np.stack(hit.p, axis=1)
    assert np.allclose(np.linalg.norm(p - centre, axis=1), spheres[which[found], 3], rtol=1e-3, atol=1e-5)
    # The normal points from the centre to the hit (Cycles' point_shader_setup), turned toward the viewer.
    outward = (p - centre) / spheres[which[found], 3:4]
    ns = np.stack(hit.ns, axis=1)
    facing = np.where(hit.backfacing, -1.0, 1.0)[:, None]
    assert np.allclose(ns, outward * facing, atol=2e-3)
    assert np.array_equal(hit.backfacing, np.einsum("ij,ij->i", outward, d[found]) > 0)


def test_instanced_points_hit_as_their_world_space_copies():
    spheres = random_spheres(12)
    angles = (0.0, 0.7, 2.1)
    matrices = np.stack([_rotation_z(a, (1.5 * k, 0.3, -0.2 * k), 1.0 + 0.25 * k) for k, a in enumerate(angles)])
    placed = ShapeInstances((Points(spheres, np.zeros(12, np.int32)),), np.zeros(3, np.int32), matrices,
                            np.arange(3, dtype=np.int32))
    copies = [Points(_moved(spheres, m), np.zeros(12, np.int32), np.full(12, k, np.int32))
              for k, m in enumerate(matrices)]
    objects = np.repeat(object_row(np.eye(4))[None], 3, axis=0)
    flat = Points(np.concatenate([c.points for c in copies]), np.zeros(36, np.int32),
                  np.concatenate([c.object_ids for c in copies]))
    rng = np.random.default_rng(11)
    o = rng.uniform(-3, 5, (3000, 3))
    d = rng.normal(size=(3000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    no_triangles = np.zeros(0, np.int32)
    a, hit_a, found_a, keys_a = trace(shape_scene(shape_instances=placed, objects=objects, object_ids=no_triangles),
                                      o, d)
    b, hit_b, found_b, keys_b = trace(shape_scene(points=flat, objects=objects, object_ids=no_triangles), o, d)
    assert np.array_equal(found_a, found_b) and len(found_a) > 150
    assert np.allclose(a.t[found_a], b.t[found_b], rtol=1e-4, atol=1e-5)
    assert np.array_equal(a.prim, b.prim)   # numbered instance by instance either way
    assert np.array_equal(keys_a, keys_b)
    assert np.allclose(np.stack(hit_a.ns), np.stack(hit_b.ns), atol=1e-3)


def test_a_ray_leaving_a_point_skips_it():
    """A ray leaving a sphere inward meets its far side in Embree; leaving from it (its key), it passes through
    to the sphere behind, as Cycles' rays skip the primitive they leave."""
    spheres = np.array([[0, 0, 0, 0.5], [0, 3, 0, 0.5]], np.float32)
    scene = shape_scene(points=Points(spheres, np.zeros(2, np.int32)))
    o, d = [[0, -0.49, 0]], [[0, 1, 0]]      # just below the surface it leaves, as a spawned ray starts
    hits, _, _, keys = trace(scene, o, d)
    assert hits.prim[0] == 0 and abs(hits.t[0] - 0.99) < 1e-4         # the far side of its own sphere
    skipped, _, _, _ = trace(scene, o, d, keys=keys)
    assert skipped.prim[0] == 1 and abs(skipped.t[0] - 2.99) < 1e-4    # the next sphere


def test_point_spheres_in_a_furnace_reflect_their_albedo():
    """Convex spheres alone under a uniform world: every pixel on them is albedo x world, up to float rounding
    (their own shadow rays and bounces skip them)."""
    result = render(shape_scene(points=Points(np.array([[0, 0, 0, 0.8]], np.float32), np.zeros(1, np.int32))),
                    RenderSettings(samples=4))
    image = result.image[..., :3]
    assert np.allclose(image[8, 8], 0.5, atol=1e-5) and np.allclose(image[0, 0], 1.0)


def _rotation_z(angle, offset, scale):
    c, s = math.cos(angle), math.sin(angle)
    m = np.eye(4)
    m[:3, :3] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) * scale
    m[:3, 3] = offset
    return m


def _moved(values, m):
    out = values.copy()
    out[:, :3] = values[:, :3] @ m[:3, :3].T + m[:3, 3]
    out[:, 3] = values[:, 3] * abs(np.linalg.det(m[:3, :3])) ** (1 / 3)
    return out


# ---------------------------------------------------------------- through Blender
def mesh_to_points(ob, radius: float, material=None):
    """A geometry-nodes modifier turning the object's mesh into points of `radius` (on `material`)."""
    tree = bpy.data.node_groups.new("To Points", "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    into, out = tree.nodes.new("NodeGroupInput"), tree.nodes.new("NodeGroupOutput")
    points = tree.nodes.new("GeometryNodeMeshToPoints")
    points.inputs["Radius"].default_value = radius
    tree.links.new(into.outputs[0], points.inputs["Mesh"])
    last = points.outputs[0]
    if material is not None:
        setter = tree.nodes.new("GeometryNodeSetMaterial")
        setter.inputs["Material"].default_value = material
        tree.links.new(last, setter.inputs["Geometry"])
        last = setter.outputs[0]
    tree.links.new(last, out.inputs[0])
    ob.modifiers.new("points", "NODES").node_group = tree
    return ob


def lit_floor(scene):
    """A grey floor, a sun from the side and a dim sky."""
    mesh_object("Floor", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], [(0, 1, 2, 3)],
                diffuse_material("Floor", (0.5, 0.5, 0.5)))
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.data.energy = 3.0
    sun.rotation_euler = (math.radians(35), math.radians(20), math.radians(30))
    scene.collection.objects.link(sun)
    set_world(scene, (0.25, 0.3, 0.35))


def test_point_cloud_from_mesh_to_points_matches_cycles():
    scene = new_scene(48, 48)
    lit_floor(scene)
    bpy.ops.mesh.primitive_ico_sphere_add(subdivisions=2, radius=1.1, location=(0, 0, 1.2))
    cloud = bpy.context.active_object
    mat = diffuse_material("Dots", (0.8, 0.35, 0.1), principled=True)
    mat.node_tree.nodes["Principled BSDF"].inputs["Roughness"].default_value = 0.4
    mat.node_tree.nodes["Principled BSDF"].inputs["Specular IOR Level"].default_value = 0.5
    mesh_to_points(cloud, 0.16, mat)
    exported = export_current()
    assert exported.scene.points is not None and exported.scene.points.count == 42, exported.warnings
    assert not exported.warnings
    compare_to_cycles(scene, samples=64, max_bounces=3)
