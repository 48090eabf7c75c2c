"""The scene as plain arrays: what the kernel renders, and the only thing the engine hands it.

Everything is in Blender world space (right-handed, Z up), linear scene-referred RGB.
Shapes use named letters: T triangles, M materials, L lights.

Texture arrays follow Blender's pixel order: row 0 is the bottom of the image (v = 0), so a lookup
at UV (u, v) reads row v * H and column u * W. Rendered images (the film) have row 0 at the top.

The kernel's public data model, one module per part, every name importable from here:
    arrays      SceneArrays, the record the engine hands the kernel, and its validation (ValidatedScene)
    camera      Camera
    lights      Lights, the light table (LIGHT_KINDS)
    world       World, what rays that leave the scene see
    materials   Materials of Shaders, Closures and their inputs (Param, NormalMap, Tangent)
    objects     the object table's columns (OBJ_*) and rows
    links       LightLinks: Light and Shadow Linking per object row (ALL_SETS)
    light_groups LightGroups: the light groups of the object rows and the world (NO_GROUP)
    triangles   per-triangle arrays: CornerRows, comparing, checking and cleaning them
    instances   Prototype and Instances: meshes stored once, placed many times; ShapeInstances: curves and
                points stored once, placed many times
    curves      Curves: curves with a radius along them, one shape per record (CURVE_SHAPES)
    points      Points: spheres
    checks      the validation vocabulary the parts share (require, check_array)
"""
from __future__ import annotations

from .arrays import SceneArrays, ValidatedScene
from .camera import CAMERA_KINDS, PIXEL_FILTERS, SENSOR_FITS, Camera
from .curves import CURVE_SHAPES, Curves
from .instances import Instances, Prototype, ShapeInstances, usable_placements
from .light_groups import NO_GROUP, LightGroups
from .lights import LIGHT_KINDS, Lights
from .links import ALL_SETS, MAX_LINK_SETS, LightLinks
from .materials import (CLOSURE_KINDS, INPUT_NODES, NORMAL_MAP_SPACES, VOLUME_KINDS, Closure, Materials, NormalMap,
                        Param, Shader, Tangent, diffuse_shader)
from .points import Points
from .objects import (OBJ_COLOR, OBJ_FROM_WORLD, OBJ_LOCATION, OBJ_OBJECT_SPACE_NORMALS, OBJ_PASS_INDEX, OBJ_RANDOM,
                      OBJ_SHADING_OFFSET, OBJ_TERMINATOR, OBJ_TEXSPACE_LOC, OBJ_TEXSPACE_SIZE, OBJ_WORLD_LINEAR,
                      OBJECT_COLUMNS, TERMINATOR_OFFSET, mirrored_objects, object_row, object_rows,
                      object_space_objects)
from .triangles import CornerRows, corner_values, padded_triangles, same_arrays, same_triangles
from .world import World

__all__ = [
    "SceneArrays", "ValidatedScene",
    "CAMERA_KINDS", "PIXEL_FILTERS", "SENSOR_FITS", "Camera",
    "CURVE_SHAPES", "Curves", "Points",
    "Instances", "Prototype", "ShapeInstances", "usable_placements",
    "LIGHT_KINDS", "Lights",
    "ALL_SETS", "MAX_LINK_SETS", "LightLinks",
    "NO_GROUP", "LightGroups",
    "CLOSURE_KINDS", "INPUT_NODES", "NORMAL_MAP_SPACES", "VOLUME_KINDS", "Closure", "Materials", "NormalMap", "Param", "Shader",
    "Tangent", "diffuse_shader",
    "OBJ_COLOR", "OBJ_FROM_WORLD", "OBJ_LOCATION", "OBJ_OBJECT_SPACE_NORMALS", "OBJ_PASS_INDEX", "OBJ_RANDOM",
    "OBJ_SHADING_OFFSET", "OBJ_TERMINATOR", "OBJ_TEXSPACE_LOC", "OBJ_TEXSPACE_SIZE", "OBJ_WORLD_LINEAR", "OBJECT_COLUMNS",
    "TERMINATOR_OFFSET", "mirrored_objects", "object_row", "object_rows", "object_space_objects",
    "CornerRows", "corner_values", "padded_triangles", "same_arrays", "same_triangles",
    "World",
]
