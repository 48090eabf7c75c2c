"""Motion blur: the camera's and objects' transforms over the shutter, read as Cycles' Blender layer reads
them (blender/object.cpp sync_motion, blender/camera.cpp, blender/util.h object_motion_steps).

Render Properties > Motion Blur: on for final renders when the scene and the view layer both say so. The
shutter spans motion_blur_shutter frames around the frame (CENTER), after it (START) or before it (END).
An object (and the camera) with Cycles' per-object Motion Blur on takes 2^steps + 1 keys evenly spread
over the shutter (Object Properties > Motion Blur > Steps, default 1: three keys); Blender evaluates the
scene at each key's subframe (RenderEngine.frame_set) and the frame is restored afterwards. Objects whose
keys all equal their frame matrix are static. The kernel interpolates keys per path time (kernels.motion).

Curves, points and hair particle systems move too: their instances' transforms as any object's, and their
deformation, read as Cycles' sync_hair_motion and sync_pointcloud_motion read it (intern/cycles/blender/curves.cpp,
pointcloud.cpp): the keys (positions and radii) of each motion step's subframe (shape_steps; engine/export/shapes.py
makes them Embree's time steps).

Not done: deformation blur of meshes (armatures, shape keys; a warning names them), lights (Cycles does not blur lamps either). A perspective lens that zooms is recorded at the shutter's start
and end, as Cycles' perspective motion. The rolling shutter is
Cycles' own setting (scene.cycles: Rolling Shutter type Top, its Duration), read as Cycles reads it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ...kernels import motion as kernel_motion
from .camera import perspective_fov
from .curves import hair_systems, read_curves, read_particle_hair
from .instances import instance_key
from .points import read_points

CURVE_SAMPLES = 257  # Blender 5.0 reads the shutter curve at 257 points (curvemapping_to_array, size 256)
MAX_STEPS = 7


@dataclass
class MotionSamples:
    """What frame_set showed: per instance key, its (K, 4, 4) keys; the camera's; the shutter table."""
    objects: dict = field(default_factory=dict)
    camera: np.ndarray | None = None
    shutter_table: np.ndarray | None = None
    rolling_shutter: float | None = None
    camera_fov: tuple | None = None   # (at the shutter's start, at its end) when a perspective lens zooms
    # Per instance key of a Curves or Point Cloud object or a mesh with hair, its local keys at each of its
    # motion steps: [(offsets (C + 1,) or None for points, keys (n, 4) x, y, z, radius), ...] (shape_steps).
    shapes: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)


def enabled(scene, view_layer=None) -> bool:
    layer_on = True if view_layer is None else bool(getattr(view_layer, "use_motion_blur", True))
    return bool(scene.render.use_motion_blur) and layer_on


def key_count(ob) -> int:
    """Motion keys of an object: 0 with its Motion Blur off, else 2^steps + 1 (Cycles' object_motion_steps)."""
    settings = getattr(ob, "cycles", None)
    if settings is not None and not getattr(settings, "use_motion_blur", True):
        return 0
    steps = int(getattr(settings, "motion_steps", 1)) if settings is not None else 1
    return (1 << max(1, min(steps, MAX_STEPS))) + 1


def shutter_times(render, frame: float, keys: int) -> np.ndarray:
    """The Blender times (frames, with subframes) of `keys` evenly spaced motion keys."""
    shutter = float(render.motion_blur_shutter)
    centre = frame + {"START": 0.5 * shutter, "END": -0.5 * shutter}.get(render.motion_blur_position, 0.0)
    relative = np.linspace(-1.0, 1.0, keys)
    return centre + relative * 0.5 * shutter


def shutter_table(render) -> np.ndarray:
    """The path-time table of the render's shutter curve (kernels.motion.shutter_table)."""
    mapping = render.motion_blur_shutter_curve
    mapping.update()
    curve = mapping.curves[0]
    values = np.array([mapping.evaluate(curve, i / (CURVE_SAMPLES - 1)) for i in range(CURVE_SAMPLES)], np.float32)
    return kernel_motion.shutter_table(values)


def rolling_shutter(scene) -> float | None:
    """The rolling shutter's duration when Cycles' Rolling Shutter is Top (scene.cycles), else None."""
    cycles = getattr(scene, "cycles", None)
    if cycles is None or getattr(cycles, "rolling_shutter_type", "NONE") != "TOP":
        return None
    return float(cycles.rolling_shutter_duration)


def sample_motion(engine, depsgraph, camera_ob) -> MotionSamples | None:
    """Evaluate the scene at every motion key's time and record matrices; None when motion blur is off.
    The scene is back at its own frame when this returns, whatever happens."""
    scene = depsgraph.scene
    if not enabled(scene, depsgraph.view_layer):
        return None
    frame, subframe = scene.frame_current, scene.frame_subframe
    samples = MotionSamples(shutter_table=shutter_table(scene.render), rolling_shutter=rolling_shutter(scene))
    per_key: dict = {}      # instance key -> key count
    for inst in depsgraph.object_instances:
        if inst.object.type in ("MESH", "CURVES", "POINTCLOUD"):
            count = key_count(inst.object.original)
            if inst.is_instance and inst.parent is not None:
                parent = key_count(inst.parent.original)
                count = 0 if parent == 0 else max(count, parent)
            if count:
                per_key[instance_key(inst)] = count
    camera_keys = key_count(camera_ob.original if hasattr(camera_ob, "original") else camera_ob) \
        if camera_ob is not None else 0
    counts = sorted(set(per_key.values()) | ({camera_keys} if camera_keys else set()))
    if not counts:
        return samples
    largest = counts[-1]
    # Every key count 2^s + 1 divides the largest's grid: evaluate on that grid once.
    times = shutter_times(scene.render, frame + subframe, largest)
    recorded: dict = {}
    camera_matrices = []
    fovs = []
    vertices_first: dict = {}
    deforming: set = set()
    shape_keys: dict = {}   # instance key -> its shape_steps at every time
    render = depsgraph.mode == "RENDER" 
    try:
        for i, t in enumerate(times):
            whole = math.floor(t)
            engine.frame_set(int(whole), float(t - whole))
            read: dict = {}   # this step's shape_steps per data-block
            for inst in depsgraph.object_instances:
                key = instance_key(inst)
                if key in per_key:
                    recorded.setdefault(key, []).append(np.array(inst.matrix_world, np.float64))
                    if i in (0, len(times) - 1) and not inst.is_instance and inst.object.type == "MESH":
                        _track_deformation(inst.object, key, i, vertices_first, deforming)
                    if inst.object.type in ("CURVES", "POINTCLOUD", "MESH") and deform_motion(inst):
                        # Instances of one data-block (geometry nodes' points) or of one haired object (a collection's
                        # fur) read it once a step.
                        shared = inst.object.as_pointer() if inst.object.type == "MESH" else inst.object.data.as_pointer()
                        data = (inst.object.type, shared if inst.is_instance else key)
                        if data not in read:
                            read[data] = shape_steps(inst.object, render)
                        if read[data] is not None:
                            shape_keys.setdefault(key, []).append(read[data])
            if camera_keys:
                camera_matrices.append(_rigid(np.array(camera_ob.evaluated_get(depsgraph).matrix_world)))
            if camera_ob is not None and i in (0, len(times) - 1):
                fovs.append(_fov(camera_ob.evaluated_get(depsgraph)))
    finally:
        engine.frame_set(frame, subframe)
    for key, steps in shape_keys.items():
        if len(steps) == len(times):
            samples.shapes[key] = steps[::(largest - 1) // (per_key[key] - 1)]
    for key, matrices in recorded.items():
        if len(matrices) != len(times):
            continue  # the instance is not there at every key: left static
        stride = (largest - 1) // (per_key[key] - 1)
        keys = np.stack(matrices[::stride])
        if not np.allclose(keys, keys[len(keys) // 2], rtol=0, atol=1e-7):
            samples.objects[key] = keys
    centre = _fov(camera_ob) if camera_ob is not None else None
    if len(fovs) == 2 and centre is not None and None not in fovs and fovs != [centre, centre]:
        samples.camera_fov = (fovs[0], fovs[1])  # Cycles' perspective motion (camera.h: perspective_pre/post)
    if camera_keys:
        stride = (largest - 1) // (camera_keys - 1)
        keys = np.stack(camera_matrices[::stride])
        if not np.allclose(keys, keys[len(keys) // 2], rtol=0, atol=1e-7):
            samples.camera = keys
    samples.warnings.extend(f"Object '{name}': deformation motion blur is not supported (its mesh changes "
                            f"during the shutter); rendered with its transform motion only"
                            for name in sorted(deforming))
    return samples


@dataclass
class VectorSamples:
    """The Vector pass's neighbours in time (Cycles' MOTION_PASS): per instance key and for the camera,
    the world matrices one frame before and one frame after."""
    objects: dict = field(default_factory=dict)   # key -> ((4, 4) before, (4, 4) after)
    camera: tuple = ()                            # ((4, 4) before, (4, 4) after), rigid


def sample_vector_motion(engine, depsgraph, camera_ob) -> VectorSamples | None:
    """Evaluate the scene one frame before and after and record matrices, for the Vector pass (View Layer
    > Passes > Vector); None unless the pass is on and motion blur is off (Cycles offers the pass only
    then). The scene is back at its own frame when this returns."""
    scene = depsgraph.scene
    if not getattr(depsgraph.view_layer, "use_pass_vector", False) or enabled(scene, depsgraph.view_layer):
        return None
    frame, subframe = scene.frame_current, scene.frame_subframe
    out = VectorSamples()
    recorded: dict = {}
    cameras = []
    try:
        for offset in (-1, 1):
            engine.frame_set(frame + offset, subframe)
            for inst in depsgraph.object_instances:
                if inst.object.type == "MESH":
                    recorded.setdefault(instance_key(inst), []).append(np.array(inst.matrix_world, np.float64))
            if camera_ob is not None:
                cameras.append(_rigid(np.array(camera_ob.evaluated_get(depsgraph).matrix_world)))
    finally:
        engine.frame_set(frame, subframe)
    out.objects = {key: (m[0], m[1]) for key, m in recorded.items() if len(m) == 2}
    if len(cameras) == 2:
        out.camera = (cameras[0], cameras[1])
    return out


def vector_fields(samples: VectorSamples | None, geometry, camera_matrix) -> dict:
    """SceneArrays.vector_motion for an exported geometry: per object row, the (3, 4) matrices taking its
    stored world positions to the previous and next frame's; the camera's world matrices then."""
    if samples is None or geometry.instance_keys is None:
        return {}
    rows = len(geometry.instance_keys)
    before = np.zeros((rows, 3, 4), np.float64)
    after = np.zeros((rows, 3, 4), np.float64)
    for row, (key, matrix) in enumerate(zip(geometry.instance_keys, geometry.instance_matrices)):
        inverse = np.linalg.inv(np.asarray(matrix, np.float64))
        pre, post = samples.objects.get(key, (matrix, matrix))
        before[row], after[row] = (pre @ inverse)[:3], (post @ inverse)[:3]
    camera = samples.camera or (camera_matrix, camera_matrix)
    return dict(vector_motion=(before, after, np.asarray(camera[0], np.float64), np.asarray(camera[1], np.float64)))


def _fov(camera_ob) -> float | None:
    """A perspective camera's field of view across its fitted sensor, None for anything else (or a
    degenerate lens)."""
    cam = getattr(camera_ob, "data", None)
    if camera_ob.type != "CAMERA" or cam.type != "PERSP":
        return None
    sensor = cam.sensor_height if cam.sensor_fit == "VERTICAL" else cam.sensor_width
    return perspective_fov(cam.lens, sensor)


def _track_deformation(ob, key, step: int, first: dict, deforming: set) -> None:
    """Compare the evaluated vertices at the first and last key of objects that could deform."""
    if not (ob.modifiers or getattr(ob.data, "shape_keys", None)):
        return
    verts = ob.data.vertices
    co = np.empty(len(verts) * 3, np.float32)
    verts.foreach_get("co", co)
    if step == 0:
        first[key] = co
    elif key in first and (len(first[key]) != len(co) or not np.array_equal(first[key], co)):
        deforming.add(ob.name)


def deform_motion(inst) -> bool:
    """Object Properties > Motion Blur > Deformation (Cycles' use_deform_motion), of the instancer too for an
    instance (Cycles' object_use_deform_motion, intern/cycles/blender/util.h)."""
    owners = [inst.object] + ([inst.parent] if inst.is_instance and inst.parent is not None else [])
    return all(bool(getattr(getattr(ob.original, "cycles", None), "use_deform_motion", True)) for ob in owners)


def shape_steps(ob, render: bool):
    """The local keys of an evaluated Curves or Point Cloud object, or of a mesh object's hair systems, as the
    export reads them (curves.py, points.py; no attributes): (offsets or None for points, (n, 4) keys), or None
    for anything else."""
    quiet: list = []
    if ob.type == "POINTCLOUD":
        return None, read_points(ob.data, (), ob.name, quiet).points
    if ob.type == "CURVES":
        local = read_curves(ob.data, (), ob.name, quiet)
        return local.offsets, local.keys
    if ob.type == "MESH":
        systems = hair_systems(ob, render)
        if systems:
            local = read_particle_hair(ob, systems, render, 1, (), None, ob.name, quiet)
            return local.offsets, local.keys
    return None


def _rigid(m: np.ndarray) -> np.ndarray:
    lengths = np.linalg.norm(m[:3, :3], axis=0)
    m = m.copy()
    m[:3, :3] /= np.where(lengths > 0, lengths, 1.0)
    return m


def scene_motion(samples: MotionSamples | None, geometry) -> dict:
    """SceneArrays fields for the moving objects of an exported geometry (mesh.Geometry)."""
    if samples is None or geometry.instance_keys is None:
        return {}
    row_motion = np.full(len(geometry.instance_keys), -1, np.int32)
    keys, references = [], []
    for row, (key, matrix) in enumerate(zip(geometry.instance_keys, geometry.instance_matrices)):
        if key in samples.objects:
            row_motion[row] = len(keys)
            keys.append(samples.objects[key])
            references.append(np.asarray(matrix, np.float64))
    fields = dict(shutter_table=samples.shutter_table, rolling_shutter=samples.rolling_shutter)
    if keys:
        fields.update(motion=tuple(keys), motion_reference=tuple(references),
                      motion_ids=np.ascontiguousarray(row_motion[geometry.object_ids]))
    return fields
