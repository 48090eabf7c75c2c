"""The built-in demo scene, built in code: a corner of a room with a checkered floor, a few objects,
a warm emissive panel, one of the HDRIs bpy ships coming in from the open sides, and a low sun.

It replaces the current file's data in memory (like File > New) and never saves anything.
"""
from __future__ import annotations

import math
import os

import bpy
import numpy as np

DEMO_HDRI = "forest.exr"
DEMO_RESOLUTION = (800, 450)


def bundled_hdri_path(name: str) -> str:
    """Path of one of the HDRIs Blender ships (forest.exr, courtyard.exr, ...)."""
    # system_resource() finds directories only: ask for the folder, then join the file name.
    folder = bpy.utils.system_resource("DATAFILES", path=os.path.join("studiolights", "world"))
    path = os.path.join(folder, name)
    if not folder or not os.path.isfile(path):
        raise FileNotFoundError(f"Blender's HDRI {name!r} is not in {folder!r}")
    return path


def build_demo_scene() -> bpy.types.Scene:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.name = "Ember Demo"
    render = scene.render
    render.engine = "EMBER"
    render.resolution_x, render.resolution_y = DEMO_RESOLUTION
    render.resolution_percentage = 100
    scene.ember.samples = 64
    scene.ember.max_bounces = 6

    floor_tex = _checker_image("Ember Floor Checker", 512, 8, (0.80, 0.74, 0.62), (0.22, 0.20, 0.19))
    _add_mesh("Floor", _grid_plane(14.0, 14.0, uv_repeat=3.0), _material("Floor", image=floor_tex))
    wall = _material("Wall", color=(0.62, 0.6, 0.57))
    _add_mesh("Back Wall", _quad((-7, 3.5, 0), (14, 0, 0), (0, 0, 6)), wall)
    _add_mesh("Left Wall", _quad((-4.5, -7, 0), (0, 10.5, 0), (0, 0, 6)), wall, flip=True)
    panel = _material("Warm Panel", emission=((1.0, 0.62, 0.32), 6.0))
    _add_mesh("Light Panel", _quad((-4.49, -1.2, 1.0), (0, 2.6, 0), (0, 0, 2.2)), panel, flip=True)

    bpy.ops.mesh.primitive_monkey_add(size=1.6, location=(0.2, 0.4, 1.05), rotation=(math.radians(-10), 0, math.radians(35)))
    monkey = bpy.context.active_object
    monkey.modifiers.new("Subdivision", "SUBSURF").levels = 2
    bpy.ops.object.shade_smooth()
    monkey.data.materials.append(_material("Copper", color=(0.95, 0.55, 0.35), principled=True, Metallic=1.0,
                                           Roughness=0.28))

    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.7, location=(-2.1, 1.2, 0.7), segments=48, ring_count=24)
    bpy.ops.object.shade_smooth()
    bpy.context.active_object.data.materials.append(_material("Glass", color=(0.85, 0.92, 1.0), principled=True,
                                                              Transmission_Weight=1.0, Roughness=0.02))

    bpy.ops.mesh.primitive_cube_add(size=1.1, location=(2.3, 1.4, 0.55), rotation=(0, 0, math.radians(28)))
    bpy.context.active_object.data.materials.append(_material("Green", color=(0.25, 0.55, 0.25), principled=True,
                                                              Roughness=0.5, Coat_Weight=1.0, Coat_Roughness=0.05))

    bpy.ops.mesh.primitive_torus_add(location=(1.7, -1.3, 0.25), major_radius=0.6, minor_radius=0.25)
    bpy.ops.object.shade_smooth()
    bpy.context.active_object.data.materials.append(_material("Velvet", color=(0.35, 0.08, 0.18), principled=True,
                                                              Sheen_Weight=1.0, Sheen_Roughness=0.35))

    cam_data = bpy.data.cameras.new("Camera")
    cam_data.lens = 32
    cam = bpy.data.objects.new("Camera", cam_data)
    scene.collection.objects.link(cam)
    cam.location = (5.6, -7.4, 3.3)
    direction = np.array([0.0, 0.6, 0.9]) - np.array(cam.location)
    cam.rotation_euler = _look_rotation(direction)
    scene.camera = cam

    build_world(scene, hdri=DEMO_HDRI, strength=0.2, rotation=(0.0, 0.0, math.radians(15)), name="Ember Demo World")
    # An afternoon sun through the open right side: shadows fall across the floor to the left.
    sun = bpy.data.lights.new("Sun", "SUN")
    sun.energy = 5.0
    sun.angle = math.radians(3.0)
    sun.color = (1.0, 0.92, 0.82)
    sun_ob = bpy.data.objects.new("Sun", sun)
    sun_ob.rotation_euler = (math.radians(55), 0.0, math.radians(80))
    scene.collection.objects.link(sun_ob)
    return scene


def _checker_image(name, size, tiles, a, b):
    ij = (np.arange(size) * tiles // size)
    mask = (ij[:, None] + ij[None, :]) % 2 == 0
    rgb = np.where(mask[..., None], np.array(a), np.array(b))
    # A little variation per tile, so the floor does not look synthetic.
    rng = np.random.default_rng(7)
    rgb *= (0.9 + 0.2 * rng.random((tiles, tiles)))[ij[:, None], ij[None, :]][..., None]
    # Stored as an sRGB byte image, the common case for textures: Ember converts it to linear.
    encoded = np.where(rgb <= 0.0031308, rgb * 12.92, 1.055 * np.power(rgb, 1 / 2.4) - 0.055)
    image = bpy.data.images.new(name, size, size, alpha=True)
    pixels = np.concatenate([encoded, np.ones((size, size, 1))], axis=2).astype(np.float32)
    image.pixels.foreach_set(pixels.ravel())
    image.pack()
    return image


def _material(name, color=(0.8, 0.8, 0.8), image=None, emission=None, principled=False, **inputs):
    """A Diffuse or Principled material (Principled inputs by name, spaces as underscores), or an Emission."""
    mat = bpy.data.materials.new(name)
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    if emission is not None:
        shader = tree.nodes.new("ShaderNodeEmission")
        shader.inputs["Color"].default_value = (*emission[0], 1.0)
        shader.inputs["Strength"].default_value = emission[1]
        tree.links.new(shader.outputs["Emission"], out.inputs["Surface"])
        return mat
    shader = tree.nodes.new("ShaderNodeBsdfPrincipled" if principled else "ShaderNodeBsdfDiffuse")
    color_input = shader.inputs["Base Color" if principled else "Color"]
    color_input.default_value = (*color, 1.0)
    for key, value in inputs.items():
        shader.inputs[key.replace("_", " ")].default_value = value
    if image is not None:
        tex = tree.nodes.new("ShaderNodeTexImage")
        tex.image = image
        tree.links.new(tex.outputs["Color"], color_input)
    tree.links.new(shader.outputs["BSDF"], out.inputs["Surface"])
    return mat


def _quad(corner, edge_u, edge_v):
    c, u, v = (np.array(x, float) for x in (corner, edge_u, edge_v))
    verts = [c, c + u, c + u + v, c + v]
    return verts, [(0, 1, 2, 3)], [(0, 0), (1, 0), (1, 1), (0, 1)]


def _grid_plane(size_x, size_y, uv_repeat):
    hx, hy = size_x / 2, size_y / 2
    verts = [(-hx, -hy, 0), (hx, -hy, 0), (hx, hy, 0), (-hx, hy, 0)]
    r = uv_repeat
    return verts, [(0, 1, 2, 3)], [(0, 0), (r, 0), (r, r), (0, r)]


def _add_mesh(name, geometry, material, flip=False):
    verts, faces, uvs = geometry
    if flip:
        faces = [tuple(reversed(f)) for f in faces]
        uvs = list(reversed(uvs))
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([tuple(v) for v in verts], [], faces)
    layer = mesh.uv_layers.new(name="UVMap")
    for loop, uv in zip(mesh.loops, uvs):
        layer.data[loop.index].uv = uv
    mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _look_rotation(direction):
    """Euler XYZ for a camera (looking down -Z, +Y up) pointing along direction, Z up."""
    d = np.asarray(direction, float)
    d /= np.linalg.norm(d)
    pitch = math.acos(-d[2])  # rotation about X from looking straight down
    yaw = math.atan2(d[1], d[0]) - math.pi / 2
    return (pitch, 0.0, yaw)


def build_world(scene, *, color=(0.0, 0.0, 0.0), strength=1.0, hdri=None, rotation=(0.0, 0.0, 0.0),
                name="World"):
    """A world node tree as an artist builds it: Background (constant colour), or an Environment
    Texture of one of Blender's HDRIs through a Mapping rotation from Texture Coordinate."""
    world = bpy.data.worlds.new(name)
    scene.world = world
    tree = world.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputWorld")
    background = tree.nodes.new("ShaderNodeBackground")
    background.inputs["Color"].default_value = (*color, 1.0)
    background.inputs["Strength"].default_value = strength
    if hdri is not None:
        env = tree.nodes.new("ShaderNodeTexEnvironment")
        env.image = bpy.data.images.load(bundled_hdri_path(hdri), check_existing=True)
        mapping = tree.nodes.new("ShaderNodeMapping")
        mapping.inputs["Rotation"].default_value = rotation
        coords = tree.nodes.new("ShaderNodeTexCoord")
        tree.links.new(coords.outputs["Generated"], mapping.inputs["Vector"])
        tree.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
        tree.links.new(env.outputs["Color"], background.inputs["Color"])
    tree.links.new(background.outputs["Background"], out.inputs["Surface"])
    return world
