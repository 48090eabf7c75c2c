"""Benchmark scenes built in bpy, in code: the Cornell box of kernels.shapes.cornell_box (same walls, light,
sphere and camera) with a small emissive quad, the same open-fronted box lit only by a bundled HDRI, and
the box with a high-resolution sphere for export timing.

Meshes are made from numpy arrays with foreach_set (a 1M-triangle sphere takes well under a second;
from_pydata would take tens of seconds), so every scene is quick to rebuild.

    scene = cornell_scene(256, 256)            # about 1k triangles, black world
    scene = hdri_scene(128, 128)               # same box without the lamp, forest.exr world
    scene = cornell_scene(64, 64, sphere_triangles=1_000_000)
    scene = materials_scene(128, 128)          # eight Principled spheres, forest.exr world
    scene = lit_sphere_scene(marble_material)  # a procedural marble (node programs) under a constant sky
"""
from __future__ import annotations

import math

import bpy
import numpy as np

from tests.bpy_helpers import add_camera, diffuse_material, emission_material, ensure_registered, mesh_object, \
    new_scene, set_world

# The kernel benchmark's box (kernels.shapes.cornell_box): 2 units wide, camera 3.9 in front, 39.3 deg fov.
WALL_SUBDIVISIONS = 7
SPHERE_SEGMENTS = 24          # around; rings = SPHERE_SEGMENTS / 2 -> 528 triangles
SPHERE_CENTER, SPHERE_RADIUS = (0.3, 0.25, 0.45), 0.45
LIGHT_SIZE, LIGHT_RADIANCE = 0.5, 15.0
CAMERA_LOCATION, CAMERA_TARGET, CAMERA_FOV_DEG = (0.0, -3.9, 1.0), (0.0, 0.0, 1.0), 39.3
WHITE, RED, GREEN, SPHERE = (0.73, 0.73, 0.73), (0.65, 0.05, 0.05), (0.12, 0.45, 0.15), (0.6, 0.6, 0.6)
HDRI = "forest.exr"


def cornell_scene(width: int, height: int, *, light: bool = True, hdri: str | None = None,
                  sphere_triangles: int | None = None) -> bpy.types.Scene:
    """Replace the open file with the box. light: the small emissive quad under the ceiling;
    hdri: a bundled HDRI as the world (else black); sphere_triangles: about this many triangles in
    the sphere instead of the usual 528."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    ensure_registered()
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    white, red, green = (diffuse_material(n, c) for n, c in (("White", WHITE), ("Red", RED), ("Green", GREEN)))
    s = WALL_SUBDIVISIONS
    # Corner, edge_u, edge_v, facing edge_u x edge_v (into the box), as in kernels.shapes.cornell_box.
    walls = [((-1, -1, 0), (0, 2, 0), (2, 0, 0), white, "Floor"),
             ((-1, -1, 2), (2, 0, 0), (0, 2, 0), white, "Ceiling"),
             ((-1, 1, 0), (0, 0, 2), (2, 0, 0), white, "Back"),
             ((-1, -1, 0), (0, 0, 2), (0, 2, 0), red, "Left"),
             ((1, -1, 0), (0, 2, 0), (0, 0, 2), green, "Right")]
    for corner, eu, ev, mat, name in walls:
        add_mesh(name, *grid(corner, eu, ev, s), mat)
    if light:
        h = LIGHT_SIZE / 2
        add_mesh("Lamp", *grid((-h, -h, 1.99), (0, 2 * h, 0), (2 * h, 0, 0), 1),
                 emission_material("Lamp", strength=LIGHT_RADIANCE))
    segments = SPHERE_SEGMENTS if sphere_triangles is None else max(4, int(math.sqrt(sphere_triangles)))
    rings = max(3, segments // 2) if sphere_triangles is None else max(3, sphere_triangles // (2 * segments) + 1)
    add_mesh("Sphere", *uv_sphere(segments, rings, SPHERE_RADIUS, SPHERE_CENTER),
             diffuse_material("Sphere", SPHERE), smooth=True)
    cam = add_camera(scene, CAMERA_LOCATION, CAMERA_TARGET)
    cam.data.angle = math.radians(CAMERA_FOV_DEG)
    if hdri is None:
        set_world(scene, color=(0.0, 0.0, 0.0))
    else:
        set_world(scene, hdri=hdri, strength=1.0)
    return scene


def hdri_scene(width: int, height: int, *, hdri: str = HDRI) -> bpy.types.Scene:
    """The box without its lamp, lit only by the HDRI through its open front."""
    return cornell_scene(width, height, light=False, hdri=hdri)


# The materials scene: a row of Principled spheres (metal smooth and rough, plastic, glass, frosted glass,
# coat, sheen, rough diffuse) on a grey floor under forest.exr, as tests/test_parity_materials.py has it.
PRINCIPLED_ROW = (
    ("Chrome", {"Base Color": (0.9, 0.8, 0.6), "Metallic": 1.0, "Roughness": 0.0}),
    ("Brushed", {"Base Color": (0.8, 0.5, 0.3), "Metallic": 1.0, "Roughness": 0.35, "Specular Tint": (0.6, 0.8, 1.0)}),
    ("Plastic", {"Base Color": (0.7, 0.1, 0.1), "Roughness": 0.3}),
    ("Glass", {"Base Color": (0.9, 1.0, 0.9), "Transmission Weight": 1.0, "Roughness": 0.0}),
    ("Frosted", {"Transmission Weight": 1.0, "Roughness": 0.3, "IOR": 1.45}),
    ("Coated", {"Base Color": (0.1, 0.2, 0.7), "Roughness": 0.6, "Coat Weight": 1.0, "Coat Roughness": 0.05,
                "Coat Tint": (0.9, 0.8, 0.6)}),
    ("Velvet", {"Base Color": (0.3, 0.05, 0.1), "Sheen Weight": 1.0, "Sheen Roughness": 0.4}),
    ("Rough Diffuse", {"Base Color": (0.6, 0.6, 0.5), "Diffuse Roughness": 1.0, "Roughness": 0.7}),
)


def materials_scene(width: int, height: int, *, hdri: str = HDRI) -> bpy.types.Scene:
    """Eight Principled spheres in two rows of four on a floor, lit by the HDRI (about 18k triangles)."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    ensure_registered()
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    for i, (name, inputs) in enumerate(PRINCIPLED_ROW):
        mat = bpy.data.materials.new(name)
        bsdf = mat.node_tree.nodes["Principled BSDF"]
        for key, value in inputs.items():
            bsdf.inputs[key].default_value = (*value, 1.0) if isinstance(value, tuple) else value
        row, col = divmod(i, 4)
        add_mesh(name, *uv_sphere(48, 24, 0.45, (col - 1.5, 0.0, 1.5 - row)), mat, smooth=True)
    add_mesh("Floor", *grid((-6, -6, 0), (12, 0, 0), (0, 12, 0), 1), diffuse_material("Floor", (0.4, 0.4, 0.4)))
    add_camera(scene, (0.0, -5.2, 1.0), (0.0, 0.0, 1.0)).data.lens = 45
    set_world(scene, hdri=hdri, strength=1.0, rotation=(0.0, 0.0, 0.6))
    return scene


# The node-program scenes (issue 9), also tests/test_node_programs.py's parity scenes.
def lit_sphere_scene(make_material, size=(48, 32)) -> bpy.types.Scene:
    """A smooth sphere with make_material() on a floor without a material, under a constant sky."""
    scene = new_scene(*size)
    set_world(scene, color=(0.6, 0.7, 0.8), strength=1.0)
    material = make_material()
    bpy.ops.mesh.primitive_uv_sphere_add(radius=1.0, location=(0, 0, 1.1), segments=48, ring_count=24)
    bpy.ops.object.shade_smooth()
    bpy.context.active_object.data.materials.append(material)
    mesh_object("Floor", [(-6, -6, 0), (6, -6, 0), (6, 6, 0), (-6, 6, 0)], [(0, 1, 2, 3)])
    return scene


def marble_material():
    """Noise -> Color Ramp into Base Color, the same noise through Bump into Normal, Voronoi roughness."""
    mat = bpy.data.materials.new("Marble")
    tree = mat.node_tree
    bsdf = tree.nodes["Principled BSDF"]
    noise = tree.nodes.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = 3.0
    noise.inputs["Detail"].default_value = 4.0
    noise.inputs["Distortion"].default_value = 1.5
    ramp = tree.nodes.new("ShaderNodeValToRGB")
    ramp.color_ramp.elements[0].color = (0.9, 0.88, 0.85, 1.0)
    ramp.color_ramp.elements[1].position = 0.7
    ramp.color_ramp.elements[1].color = (0.15, 0.12, 0.1, 1.0)
    tree.links.new(noise.outputs["Fac"], ramp.inputs["Fac"])
    tree.links.new(ramp.outputs["Color"], bsdf.inputs["Base Color"])
    bump = tree.nodes.new("ShaderNodeBump")
    bump.inputs["Strength"].default_value = 0.6
    tree.links.new(noise.outputs["Fac"], bump.inputs["Height"])
    tree.links.new(bump.outputs["Normal"], bsdf.inputs["Normal"])
    voronoi = tree.nodes.new("ShaderNodeTexVoronoi")
    rough = tree.nodes.new("ShaderNodeMapRange")
    rough.inputs["To Min"].default_value = 0.2
    rough.inputs["To Max"].default_value = 0.6
    tree.links.new(voronoi.outputs["Distance"], rough.inputs["Value"])
    tree.links.new(rough.outputs["Result"], bsdf.inputs["Roughness"])
    return mat


def _input(node, identifier):
    return next(s for s in node.inputs if s.identifier == identifier)


def tinted_material():
    """An image tinted by a Mix node (as glTF imports build it) in a Layer Weight mix of Diffuse and Glossy."""
    img = bpy.data.images.new("Cloth", 8, 8, float_buffer=True)
    rng = np.random.default_rng(5)
    img.pixels.foreach_set(np.concatenate([rng.uniform(0.2, 1.0, (64, 3)), np.ones((64, 1))], 1).ravel()
                           .astype(np.float32))
    mat = bpy.data.materials.new("Tinted")
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    tex = tree.nodes.new("ShaderNodeTexImage")
    tex.image = img
    tint = tree.nodes.new("ShaderNodeMix")
    tint.data_type, tint.blend_type = "RGBA", "MULTIPLY"
    _input(tint, "Factor_Float").default_value = 1.0
    _input(tint, "B_Color").default_value = (0.9, 0.5, 0.2, 1.0)
    tree.links.new(tex.outputs["Color"], _input(tint, "A_Color"))
    diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
    tree.links.new(next(o for o in tint.outputs if o.identifier == "Result_Color"), diffuse.inputs["Color"])
    glossy = tree.nodes.new("ShaderNodeBsdfAnisotropic")
    glossy.inputs["Roughness"].default_value = 0.2
    weight = tree.nodes.new("ShaderNodeLayerWeight")
    weight.inputs["Blend"].default_value = 0.4
    mix = tree.nodes.new("ShaderNodeMixShader")
    tree.links.new(weight.outputs["Fresnel"], mix.inputs["Fac"])
    tree.links.new(diffuse.outputs[0], mix.inputs[1])
    tree.links.new(glossy.outputs[0], mix.inputs[2])
    tree.links.new(mix.outputs[0], out.inputs["Surface"])
    return mat


def interior_scene(width: int, height: int) -> bpy.types.Scene:
    """A sphere, a floor and a wall lit only by Blender's interior.exr, a studio HDRI of a few small,
    very bright windows (issue 11's hard case for world sampling)."""
    scene = new_scene(width, height)
    set_world(scene, hdri="interior.exr", strength=1.0)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=1.0, location=(0, 0, 1.0))
    bpy.ops.object.shade_smooth()
    bpy.context.active_object.data.materials.append(diffuse_material("Sphere", (0.7, 0.7, 0.7)))
    mesh_object("Floor", [(-5, -5, 0), (5, -5, 0), (5, 5, 0), (-5, 5, 0)], [(0, 1, 2, 3)],
                diffuse_material("Floor", (0.5, 0.5, 0.5)))
    mesh_object("Wall", [(-5, 3, 0), (5, 3, 0), (5, 3, 5), (-5, 3, 5)], [(0, 1, 2, 3)],
                diffuse_material("Wall", (0.6, 0.6, 0.6)))
    return scene


def lamps_scene(width: int, height: int, count: int = 200, seed: int = 3) -> bpy.types.Scene:
    """A floor with a few boxes under `count` small coloured point lamps of spread-out powers, black world
    (issue 11's many-lights case: Cycles and Ember both pick lamps with a light tree)."""
    scene = new_scene(width, height)
    set_world(scene, color=(0.0, 0.0, 0.0))
    rng = np.random.default_rng(seed)
    mesh_object("Floor", [(-8, -8, 0), (8, -8, 0), (8, 8, 0), (-8, 8, 0)], [(0, 1, 2, 3)],
                diffuse_material("Floor", (0.6, 0.6, 0.6)))
    for i, (x, y) in enumerate(rng.uniform(-3, 3, (6, 2))):
        bpy.ops.mesh.primitive_cube_add(size=0.8, location=(x, y, 0.4))
        bpy.context.active_object.data.materials.append(diffuse_material(f"Box{i}", tuple(rng.uniform(0.2, 0.8, 3))))
    for i in range(count):
        data = bpy.data.lights.new(f"Lamp{i}", "POINT")
        data.energy = float(rng.lognormal(2.0, 1.0))
        data.shadow_soft_size = 0.05
        data.color = tuple(rng.uniform(0.3, 1.0, 3))
        lamp = bpy.data.objects.new(f"Lamp{i}", data)
        lamp.location = (*rng.uniform(-6, 6, 2), float(rng.uniform(0.3, 2.5)))
        scene.collection.objects.link(lamp)
    return scene


def triangle_count(scene) -> int:
    """Triangles of the scene's meshes after triangulation (quads count two)."""
    total = 0
    for ob in scene.objects:
        if ob.type == "MESH":
            sizes = np.empty(len(ob.data.polygons), np.int32)
            ob.data.polygons.foreach_get("loop_total", sizes)
            total += int((sizes - 2).sum())
    return total


# ---------------------------------------------------------------- numpy -> bpy meshes
def grid(corner, edge_u, edge_v, n: int):
    """An n x n grid of quads over the parallelogram, facing edge_u x edge_v.
    Returns vertices (V, 3) float64, corner vertex indices (L,) int32, face sizes (F,) int32."""
    c, eu, ev = (np.asarray(x, np.float64) for x in (corner, edge_u, edge_v))
    s = np.arange(n + 1) / n
    i, j = np.meshgrid(s, s, indexing="ij")
    verts = (c + i[..., None] * eu + j[..., None] * ev).reshape(-1, 3)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    quads = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 4)
    return verts, quads.ravel().astype(np.int32), np.full(len(quads), 4, np.int32)


def uv_sphere(segments: int, rings: int, radius: float, center):
    """A UV sphere: triangle fans at the poles, quads between; 2 * segments * (rings - 1) triangles.
    Same return as grid(); faces point out."""
    theta = np.linspace(0.0, np.pi, rings + 1)[1:-1]                  # inner rings, north to south
    phi = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring_verts = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    verts = np.concatenate([[(0, 0, 1)], ring_verts, [(0, 0, -1)]]) * radius + np.asarray(center)
    north, south = 0, len(verts) - 1
    ring = 1 + np.arange((rings - 1) * segments).reshape(rings - 1, segments)
    nxt = np.roll(ring, -1, axis=1)
    # Counter-clockwise seen from outside: down the meridian, then east.
    top = np.stack([np.full(segments, north), ring[0], nxt[0]], -1)
    bottom = np.stack([ring[-1], np.full(segments, south), nxt[-1]], -1)
    quads = np.stack([ring[:-1], ring[1:], nxt[1:], nxt[:-1]], -1).reshape(-1, 4)
    corners = np.concatenate([top.ravel(), quads.ravel(), bottom.ravel()]).astype(np.int32)
    sizes = np.concatenate([np.full(segments, 3), np.full(len(quads), 4), np.full(segments, 3)]).astype(np.int32)
    return verts, corners, sizes


def add_mesh(name, verts, corners, sizes, material=None, smooth=False):
    """A mesh object linked to the current scene, built with foreach_set."""
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(verts))
    mesh.vertices.foreach_set("co", np.ascontiguousarray(verts, np.float32).ravel())
    mesh.loops.add(len(corners))
    mesh.loops.foreach_set("vertex_index", corners)
    mesh.polygons.add(len(sizes))
    mesh.polygons.foreach_set("loop_start", (np.cumsum(sizes) - sizes).astype(np.int32))
    mesh.update(calc_edges=True)
    if smooth:
        mesh.shade_smooth()
    if material is not None:
        mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj
