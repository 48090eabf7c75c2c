"""Real-content scenes for bench/real_content.py: published glTF sample models imported with Blender's own
glTF importer (bpy.ops.import_scene.gltf), framed by a camera and lit as a user would light them (a bundled
HDRI, a sun, or the model's own lights), with a floor where the model stands on one.

The models are not part of Ember. They come from the Khronos glTF sample collection,
https://github.com/KhronosGroup/glTF-Sample-Assets (Models/<Name>/<variant>/..., the layout MODELS keeps; the
CAD models are also in the older https://github.com/KhronosGroup/glTF-Sample-Models under 2.0/). Get them with

    git clone --depth 1 https://github.com/KhronosGroup/glTF-Sample-Assets
    bench/real_content.py --models glTF-Sample-Assets/Models

or copy only the folders MODELS names into a folder of your own (default /work/gltf): each scene's path is
relative to it. A scene whose model is missing is skipped with a message naming the file.

    scene = build("punctual_lamp", "/work/gltf", 160, 120)
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass

import bpy
import numpy as np
from mathutils import Vector

from bench.scenes import add_mesh, grid
from tests.bpy_helpers import add_camera, diffuse_material, ensure_registered, set_world

DEFAULT_MODELS_DIR = "/work/gltf"
CAMERA_LENS_MM = 50.0


@dataclass(frozen=True)
class RealScene:
    name: str
    model: str                  # relative to the models folder
    title: str                  # what the scene is and what it exercises
    view: tuple = (30.0, 15.0)  # camera azimuth and elevation about the model's centre, degrees
    margin: float = 1.1         # the framed bounding sphere's radius times this fills the shorter side
    hdri: str | None = None     # one of Blender's bundled studio lights (datafiles/studiolights/world)
    hdri_strength: float = 1.0
    sun: tuple | None = None    # (strength W/m2, elevation deg, azimuth deg, angle deg)
    world_color: tuple = (0.0, 0.0, 0.0)
    floor: bool = False         # a grey floor under the model
    crowd: tuple | None = None  # (rows, columns): the model as collection instances in a grid


SCENES = (
    RealScene("damaged_helmet", "DamagedHelmet/glTF-Binary/DamagedHelmet.glb",
              "Damaged Helmet: five 2048x2048 textures (colour, metal-roughness, normal, emission, occlusion)",
              view=(20.0, 10.0), hdri="courtyard.exr"),
    RealScene("toy_car", "ToyCar/glTF/ToyCar.gltf",
              "Toy Car: textured clearcoat paint, sheen fabric, a glass windscreen, on a floor",
              view=(35.0, 20.0), margin=0.7, hdri="sunrise.exr", floor=True),
    RealScene("glass_vase", "GlassVaseFlowers/glTF-Binary/GlassVaseFlowers.glb",
              "Glass Vase Flowers: thick glass with absorption, alpha-cut textured leaves, on a floor",
              view=(15.0, 12.0), hdri="interior.exr", floor=True),
    RealScene("candle_holder", "GlassHurricaneCandleHolder/glTF-Binary/GlassHurricaneCandleHolder.glb",
              "Glass Hurricane Candle Holder: rough glass with 2048x2048 textures, on a floor",
              view=(25.0, 18.0), hdri="studio.exr", floor=True),
    RealScene("stained_glass_lamp", "StainedGlassLamp/glTF/StainedGlassLamp.gltf",
              "Stained Glass Lamp: transmission, roughness and colour from textures (18 of 2048 px), under a sun",
              view=(20.0, 12.0), hdri="forest.exr", sun=(3.0, 40.0, 60.0, 2.0), floor=True),
    RealScene("punctual_lamp", "LightsPunctualLamp/glTF/LightsPunctualLamp.gltf",
              "Lights Punctual Lamp: lit only by its own point lights, which sit inside its glass shade, "
              "on a floor in a dark room", view=(10.0, 15.0), world_color=(0.02, 0.02, 0.02), floor=True),
    RealScene("transmission_test", "TransmissionTest/glTF-Binary/TransmissionTest.glb",
              "Transmission Test: textured transmission masks, rough and metallic transmission, 14 materials",
              view=(0.0, 20.0), margin=0.75, hdri="city.exr"),
    RealScene("engine", "2CylinderEngine/glTF-Binary/2CylinderEngine.glb",
              "2 Cylinder Engine: a CAD assembly of 67 parts and 34 materials",
              view=(35.0, 25.0), hdri="studio.exr", sun=(2.0, 50.0, 130.0, 5.0)),
    RealScene("buggy", "Buggy/glTF-Draco/Buggy.gltf",
              "Buggy: a CAD assembly of 190 parts, 148 materials, 474k triangles (Draco-compressed)",
              view=(40.0, 25.0), hdri="sunset.exr", floor=True),
    RealScene("crowd", "CesiumMan/glTF-Binary/CesiumMan.glb",
              "Crowd: 182 collection instances of the skinned, textured Cesium Man (850k triangles), "
              "on a floor under a sun", view=(30.0, 22.0), margin=0.55, hdri="forest.exr", hdri_strength=0.5,
              sun=(3.0, 35.0, 200.0, 3.0), floor=True, crowd=(13, 14)),
)
BY_NAME = {s.name: s for s in SCENES}


def model_path(spec: RealScene, models_dir: str) -> str:
    return os.path.join(models_dir, spec.model)


def build(name: str, models_dir: str, width: int, height: int) -> bpy.types.Scene:
    """Replace the open file with the scene: the model imported, framed, lit. Raises FileNotFoundError
    naming the model file if it is not there."""
    spec = BY_NAME[name]
    path = model_path(spec, models_dir)
    if not os.path.exists(path):
        raise FileNotFoundError(f"{spec.name}: {path} is missing (see bench/real_scenes.py for where to get it)")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    ensure_registered()
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    bpy.ops.import_scene.gltf(filepath=path)
    if spec.crowd:
        _crowd(scene, *spec.crowd)
    low, high = _bounds(scene)
    if spec.floor:
        _floor(low, high)
    _frame(scene, spec, low, high)
    _light(scene, spec)
    return scene


def _bounds(scene) -> tuple[np.ndarray, np.ndarray]:
    """World-space bounding box of the rendered meshes (instances included)."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    corners = []
    for inst in depsgraph.object_instances:
        ob = inst.object
        if ob.type == "MESH":
            m = inst.matrix_world
            corners += [tuple(m @ Vector(c)) for c in ob.bound_box]
    pts = np.asarray(corners, np.float64)
    return pts.min(axis=0), pts.max(axis=0)


def triangle_count() -> int:
    """Triangles the current scene renders, instances counted each."""
    depsgraph = bpy.context.evaluated_depsgraph_get()
    total = 0
    for inst in depsgraph.object_instances:
        if inst.object.type == "MESH":
            total += len(inst.object.data.loop_triangles)
    return total


def _floor(low, high) -> None:
    """A grey diffuse floor at the model's lowest point, ten times its footprint."""
    size = 10.0 * float(max(high[0] - low[0], high[1] - low[1]))
    cx, cy = (low[:2] + high[:2]) / 2
    add_mesh("Floor", *grid((cx - size / 2, cy - size / 2, low[2]), (size, 0, 0), (0, size, 0), 1),
             diffuse_material("Floor", (0.5, 0.5, 0.5)))


def _frame(scene, spec: RealScene, low, high) -> None:
    """A 50 mm camera looking at the bounding box's centre from spec.view, far enough that the bounding
    sphere (times spec.margin) fits the shorter side of the frame."""
    center = (low + high) / 2
    radius = float(np.linalg.norm(high - low)) / 2 * spec.margin
    az, el = (math.radians(a) for a in spec.view)
    direction = np.array([math.sin(az) * math.cos(el), -math.cos(az) * math.cos(el), math.sin(el)])
    # Blender's default 36 mm sensor spans the longer side of the frame (sensor fit AUTO).
    short = min(scene.render.resolution_x, scene.render.resolution_y) / max(scene.render.resolution_x,
                                                                           scene.render.resolution_y)
    distance = radius / math.sin(math.atan(36.0 * short / 2 / CAMERA_LENS_MM))
    cam = add_camera(scene, tuple(center + direction * distance), tuple(center), lens=CAMERA_LENS_MM)
    cam.data.clip_start = distance / 1000
    cam.data.clip_end = distance * 100


def _light(scene, spec: RealScene) -> None:
    if spec.hdri:
        set_world(scene, hdri=spec.hdri, strength=spec.hdri_strength)
    else:
        set_world(scene, color=spec.world_color)
    if spec.sun:
        strength, elevation, azimuth, angle = spec.sun
        data = bpy.data.lights.new("Sun", "SUN")
        data.energy, data.angle = strength, math.radians(angle)
        sun = bpy.data.objects.new("Sun", data)
        sun.rotation_euler = (math.radians(90.0 - elevation), 0.0, math.radians(azimuth))
        scene.collection.objects.link(sun)


def _crowd(scene, rows: int, columns: int) -> None:
    """Move what the importer made into a collection of its own, hidden, and instance it on a grid spaced
    by the model's footprint, each instance turned a little."""
    low, high = _bounds(scene)
    source = bpy.data.collections.new("Model")
    scene.collection.children.link(source)
    for ob in list(scene.collection.objects):
        scene.collection.objects.unlink(ob)
        source.objects.link(ob)
    bpy.context.view_layer.layer_collection.children[source.name].exclude = True
    step = 1.3 * float(max(high[0] - low[0], high[1] - low[1]))
    rng = np.random.default_rng(7)
    for r in range(rows):
        for c in range(columns):
            empty = bpy.data.objects.new(f"Person{r}_{c}", None)
            empty.instance_type = "COLLECTION"
            empty.instance_collection = source
            empty.location = ((c - (columns - 1) / 2) * step, (r - (rows - 1) / 2) * step, 0.0)
            empty.rotation_euler = (0.0, 0.0, float(rng.uniform(-0.6, 0.6)))
            scene.collection.objects.link(empty)
