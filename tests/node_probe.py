"""Probe a shader node's values in Cycles at exact input points, one pixel per point.

A grid of quads, one per pixel, lies under an orthographic camera; each quad carries the probe points as
face attributes ("probe", "probe2", ...: FLOAT_VECTOR, constant over the face), which an Attribute node
reads and the node under test consumes; its output drives an Emission shader of strength 1, so the pixel
is the node's value (Cycles: 1 sample, a 0.01 px Gaussian filter, no bounces, so every sample lands inside
its own quad). The value does not depend on where inside the pixel the sample lands: the probe is exact to
float32, which is how Cycles evaluates its nodes. Negative and large values pass through the film as they
are (linear float EXR).

    values = cycles_probe(build, {"probe": points})     # points (K, 3) -> values (K, 3) float32

`build(tree, inputs)` gets the material's node tree and a dict name -> the Attribute node's Vector socket
(also `inputs[name + ".fac"]`, its Fac socket: Cycles gives the average of the three components; use
a Separate XYZ for one component) and returns the
output socket to show (a float output is shown grey: all three channels equal). The same material renders
with Ember (`engine="EMBER"`), so one probe serves the kernel functions and the end-to-end path.
"""
from __future__ import annotations

import ctypes
import ctypes.util

import bpy
import numpy as np

from tests.bpy_helpers import ensure_registered, render_to_array

MAX_WIDTH = 64


def _cpu_has_avx2_fma() -> bool:
    try:
        with open("/proc/cpuinfo") as f:
            flags = next((line for line in f if line.startswith("flags")), "").split()
    except OSError:
        return False
    return "avx2" in flags and "fma" in flags


# Cycles' CPU kernel on AVX2 + FMA machines fuses multiply-adds; node functions that mirror it are exact
# there (tests compare bit for bit), elsewhere to float precision.
AVX2_KERNEL = _cpu_has_avx2_fma()


def glibc_libm(*functions):
    """The C library's libm through ctypes, the float functions named ((name, arity) pairs) declared, or None
    where the C library is not glibc: Cycles calls its float functions (sinf, atan2f...)."""
    name = ctypes.util.find_library("m")
    libc = ctypes.util.find_library("c") or ""
    if not name or "libc.so.6" not in libc:
        return None
    libm = ctypes.CDLL(name)
    for function, arity in functions:
        fn = getattr(libm, function)
        fn.restype, fn.argtypes = ctypes.c_float, [ctypes.c_float] * arity
    return libm


def probe_scene(build, points: dict, *, name: str = "Probe") -> tuple[bpy.types.Scene, int]:
    """Build the probe scene for the given points (dict name -> (K, 3)); return (scene, K)."""
    arrays = {k: np.asarray(v, np.float32).reshape(-1, 3) for k, v in points.items()}
    count = len(next(iter(arrays.values())))
    assert all(len(a) == count for a in arrays.values()), "every probe array needs the same number of points"
    width = max(min(count, MAX_WIDTH), 4)   # Blender renders at least 4 x 4 pixels
    height = max(-(-count // width), 4)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    ensure_registered()
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False

    # Quads: pixel (row r from the top, column c) is the square [c, c+1] x [height-r-1, height-r] at z = 0.
    xs, ys = np.meshgrid(np.arange(width + 1, dtype=np.float64), np.arange(height + 1, dtype=np.float64))
    verts = np.stack([xs, ys, np.zeros_like(xs)], -1).reshape(-1, 3)
    idx = np.arange((width + 1) * (height + 1)).reshape(height + 1, width + 1)
    faces = []
    for r in range(height):              # face order: row 0 at the top, left to right
        y = height - r - 1
        for c in range(width):
            faces.append((idx[y, c], idx[y, c + 1], idx[y + 1, c + 1], idx[y + 1, c]))
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([tuple(v) for v in verts], [], faces)
    for key, a in arrays.items():
        padded = np.zeros((width * height, 3), np.float32)
        padded[:count] = a
        attr = mesh.attributes.new(key, "FLOAT_VECTOR", "FACE")
        attr.data.foreach_set("vector", padded.ravel())
    mat = bpy.data.materials.new(name)
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    emission = tree.nodes.new("ShaderNodeEmission")
    emission.inputs["Strength"].default_value = 1.0
    sockets = {}
    for key in arrays:
        node = tree.nodes.new("ShaderNodeAttribute")
        node.attribute_type = "GEOMETRY"
        node.attribute_name = key
        sockets[key] = node.outputs["Vector"]
        sockets[key + ".fac"] = node.outputs["Fac"]
    shown = build(tree, sockets)
    tree.links.new(shown, emission.inputs["Color"])
    tree.links.new(emission.outputs[0], out.inputs["Surface"])
    mesh.materials.append(mat)
    obj = bpy.data.objects.new(name, mesh)
    scene.collection.objects.link(obj)

    cam_data = bpy.data.cameras.new("ProbeCamera")
    cam_data.type = "ORTHO"
    cam_data.ortho_scale = float(max(width, height))
    cam = bpy.data.objects.new("ProbeCamera", cam_data)
    scene.collection.objects.link(cam)
    cam.location = (width / 2, height / 2, 10.0)
    cam.rotation_euler = (0.0, 0.0, 0.0)
    scene.camera = cam
    world = bpy.data.worlds.new("ProbeWorld")
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    scene.world = world
    return scene, count


def render_probe(scene, count: int, engine: str = "CYCLES") -> np.ndarray:
    """Render a probe scene; return the K probed values (K, 3) float32."""
    if engine == "CYCLES":
        image = _render_cycles(scene)
    else:
        image = render_to_array(scene, "EMBER", 1, max_bounces=0)
    return image[..., :3].reshape(-1, 3)[:count]


def _render_cycles(scene) -> np.ndarray:
    from tests.bpy_helpers import configure_cycles
    scene.render.engine = "CYCLES"
    configure_cycles(scene, 1, 0, 0)
    scene.cycles.pixel_filter_type = "GAUSSIAN"
    scene.cycles.filter_width = 0.01
    return render_to_array_configured(scene)


def render_to_array_configured(scene) -> np.ndarray:
    """render_to_array without re-configuring the engine (the probe's filter must stay)."""
    import os
    import tempfile
    from tests.bpy_helpers import load_exr
    render = scene.render
    render.threads_mode = "FIXED"
    render.threads = 2
    render.image_settings.file_format = "OPEN_EXR"
    render.image_settings.color_depth = "32"
    render.use_file_extension = True
    with tempfile.TemporaryDirectory() as tmp:
        render.filepath = os.path.join(tmp, "frame.exr")
        bpy.ops.render.render(write_still=True)
        return load_exr(render.filepath)


def cycles_probe(build, points: dict) -> np.ndarray:
    """The node graph's values in Cycles at the given points: (K, 3) float32."""
    scene, count = probe_scene(build, points)
    return render_probe(scene, count, "CYCLES")


def sweep(lo, hi, count: int, seed: int = 0, dims: int = 3) -> np.ndarray:
    """`count` points (K, 3) float32 spread over the box [lo, hi]^dims (z = 0 beyond dims): a fixed
    random sample, so lattice-aligned and in-between coordinates both occur."""
    rng = np.random.default_rng(seed)
    p = np.zeros((count, 3), np.float32)
    p[:, :dims] = rng.uniform(lo, hi, (count, dims))
    return p


