"""The object table: the columns of SceneArrays.objects (OBJ_*), the rows made from transforms and object
settings, and which rows mirror their mesh."""
from __future__ import annotations

import numpy as np

# Columns of SceneArrays.objects: object_from_world (3 x 4, row-major), world_from_object's linear part
# (3 x 3, row-major), the location, the mesh's texture space (location, size), the object's colour
# (RGBA), its pass index, Cycles' random number (random_id / 0xFFFFFFFF), its Shadow Terminator
# Geometry Offset (the light-facing share of shading points whose shadow rays leave from a smoothed surface),
# its Shadow Terminator Shading Offset (kernels/bsdf/mixture_eval.py terminator_shift), and 1 where its corner
# normals are interpolated in object space (object_space_objects), else 0.
OBJ_FROM_WORLD, OBJ_WORLD_LINEAR, OBJ_LOCATION, OBJ_TEXSPACE_LOC, OBJ_TEXSPACE_SIZE = 0, 12, 21, 24, 27
OBJ_COLOR, OBJ_PASS_INDEX, OBJ_RANDOM, OBJ_TERMINATOR, OBJ_SHADING_OFFSET = 30, 34, 35, 36, 37
OBJ_OBJECT_SPACE_NORMALS = 38
OBJECT_COLUMNS = 39
# Cycles' default Shadow Terminator > Geometry Offset (Object > Shading).
TERMINATOR_OFFSET = 0.1
# SceneArrays.object_visibility: the rays that see an object, Cycles' PathRayVisibilityFlag bits (kernel/types.h),
# and Ember's own bits for a shadow catcher (Object > Visibility > Shadow Catcher: kernels/shadow_catcher.py) and a
# holdout object (Object > Visibility > Holdout, a holdout collection).
RAY_CAMERA, RAY_TRANSMIT, RAY_DIFFUSE, RAY_GLOSSY, RAY_SCATTER, RAY_SHADOW = 1, 2, 4, 8, 16, 32
ALL_RAYS = 63
SHADOW_CATCHER = 64
HOLDOUT = 128
# The rays that make an object's emission a light for the light sampler (Cycles' Object::usable_as_light).
BSDF_RAYS = RAY_TRANSMIT | RAY_DIFFUSE | RAY_GLOSSY | RAY_SCATTER


def object_row(world_from_object, texspace_location=(0.0, 0.0, 0.0), texspace_size=(1.0, 1.0, 1.0),
               color=(1.0, 1.0, 1.0, 1.0), pass_index: int = 0, random: float = 0.0,
               terminator: float = TERMINATOR_OFFSET) -> np.ndarray:
    """One row of SceneArrays.objects (OBJECT_COLUMNS,) float32 from a (4, 4) world_from_object."""
    return object_rows(np.asarray(world_from_object, np.float64)[None], [texspace_location], [texspace_size],
                       [color], [pass_index], [random], [terminator])[0]


def object_rows(world_from_object, texspace_location, texspace_size, color, pass_index, random,
                terminator=TERMINATOR_OFFSET, shading_offset=0.0, object_space_normals=False) -> np.ndarray:
    """(K, OBJECT_COLUMNS) float32 rows of SceneArrays.objects: world_from_object (K, 4, 4), texture spaces
    (K, 3) and (K, 3), colours (K, 4), pass indices (K,), random numbers (K,), Shadow Terminator Geometry
    Offsets and Shading Offsets (K,) or one for all, whether each interpolates its normals in object space (K,)
    or one for all. A singular matrix gets its pseudo-inverse."""
    m = np.asarray(world_from_object, np.float64).reshape(-1, 4, 4)
    k = len(m)
    rows = np.zeros((k, OBJECT_COLUMNS), np.float64)
    try:
        inv = np.linalg.inv(m)
    except np.linalg.LinAlgError:
        inv = np.empty_like(m)
        for i in range(k):
            try:
                inv[i] = np.linalg.inv(m[i])
            except np.linalg.LinAlgError:
                inv[i] = np.linalg.pinv(m[i])
    rows[:, OBJ_FROM_WORLD:OBJ_FROM_WORLD + 12] = inv[:, :3, :4].reshape(k, 12)
    rows[:, OBJ_WORLD_LINEAR:OBJ_WORLD_LINEAR + 9] = m[:, :3, :3].reshape(k, 9)
    rows[:, OBJ_LOCATION:OBJ_LOCATION + 3] = m[:, :3, 3]
    rows[:, OBJ_TEXSPACE_LOC:OBJ_TEXSPACE_LOC + 3] = texspace_location
    rows[:, OBJ_TEXSPACE_SIZE:OBJ_TEXSPACE_SIZE + 3] = texspace_size
    rows[:, OBJ_COLOR:OBJ_COLOR + 4] = color
    rows[:, OBJ_PASS_INDEX] = pass_index
    rows[:, OBJ_RANDOM] = random
    rows[:, OBJ_TERMINATOR] = terminator
    rows[:, OBJ_SHADING_OFFSET] = shading_offset
    rows[:, OBJ_OBJECT_SPACE_NORMALS] = np.asarray(object_space_normals, np.float64)
    return np.nan_to_num(rows).astype(np.float32)


def mirrored_objects(objects: np.ndarray) -> np.ndarray:
    """(K,) bool: the rows of SceneArrays.objects whose world_from_object mirrors (a negative determinant:
    an odd number of negative scale axes). Their triangles keep the winding of the object's own mesh, so
    their front, Blender's face normal, is the other side from the winding's (Cycles flips Ng for
    SD_OBJECT_NEGATIVE_SCALE in triangle_normal)."""
    linear = objects[:, OBJ_WORLD_LINEAR:OBJ_WORLD_LINEAR + 9].reshape(-1, 3, 3).astype(np.float64)
    return np.linalg.det(linear) < 0 if len(linear) else np.zeros(0, bool)


def object_space_objects(objects: np.ndarray | None) -> np.ndarray | None:
    """(K,) bool: the rows of SceneArrays.objects whose smooth normals are interpolated in object space and then
    turned into world space, as Cycles shades an object whose transform it does not apply to its mesh (a mesh
    of several users, a moving object, subsurface or true displacement: scene/object.cpp
    apply_static_transforms; triangle_smooth_normal then object_normal_transform). Under a non-uniform scale
    that differs from interpolating the world-space unit normals of the corners (an applied transform's
    normals: Mesh::apply_transform normalizes each). None when no row is."""
    if objects is None or not len(objects):
        return None
    flags = objects[:, OBJ_OBJECT_SPACE_NORMALS] > 0
    return flags if flags.any() else None
