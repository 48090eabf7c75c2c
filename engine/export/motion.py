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

Meshes deform too (an armature, shape keys, any modifier or geometry nodes animated over the frames), read as
Cycles' sync_mesh_motion reads them (intern/cycles/blender/mesh.cpp): a mesh object with modifiers or shape keys
(Cycles' BKE_object_is_deform_modified) whose Motion Blur and Deformation are on has its triangles' corners and
normals read at each motion step and at the frame (vertex_steps), the steps' vertices on the frame's triangles;
engine/export/deform.py makes them the triangles'
time steps. Not done: lights (Cycles does not blur lamps either). A perspective lens that zooms is recorded at the
shutter's start
and end, as Cycles' perspective motion. The rolling shutter is
Cycles' own setting (scene.cycles: Rolling Shutter type Top, its Duration), read as Cycles reads it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ...kernels import motion as kernel_motion
from .camera import perspective_fov, rigid_transform
from .curves import hair_systems, read_curves, read_particle_hair
from .instances import instance_key
from .mesh import read_mesh, read_values, readable_mesh
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
    # Per instance key of a mesh object that may deform, at each of its motion steps and at the frame (meshes_frame):
    # (vertex count, (T*3, 3) local corners, (T*3, 3) local corner normals), the steps' corners those of the frame's
    # triangles (None where the step's vertices differ in number).
    meshes: dict = field(default_factory=dict)
    meshes_frame: dict = field(default_factory=dict)
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
    mesh_keys: dict = {}    # instance key -> its vertex_steps at every time
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
                    if may_deform(inst) and mesh_velocity(inst.object) is None:
                        mesh_keys.setdefault(key, []).append(vertex_steps(inst.object))
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
                camera_matrices.append(rigid_transform(camera_ob.evaluated_get(depsgraph).matrix_world))
            if camera_ob is not None and i in (0, len(times) - 1):
                fovs.append(_fov(camera_ob.evaluated_get(depsgraph)))
    finally:
        engine.frame_set(frame, subframe)
    # The frame's own meshes, which the export reads: the steps are compared with them. A mesh with a `velocity`
    # attribute moves along it instead: Cycles' attr_create_motion_from_velocity (intern/cycles/blender/mesh.cpp)
    # gives it three steps, its vertices half the shutter's seconds before and after the frame along their
    # velocity (the normals the frame's), and it is not read at the subframes.
    r = scene.render
    half_shutter = 0.5 * float(r.motion_blur_shutter) / (r.fps / r.fps_base)
    for inst in depsgraph.object_instances:
        key = instance_key(inst)
        if key not in per_key or not may_deform(inst, velocity=True):
            continue
        velocity = mesh_velocity(inst.object)
        if velocity is None and key not in mesh_keys:
            continue
        with readable_mesh(inst.object) as mesh:
            local = read_mesh(mesh)
            domain = mesh.normals_domain
            frame_mesh = (len(mesh.vertices), local.positions,
                          np.zeros_like(local.positions) if domain == "FACE" else local.normals)
        samples.meshes_frame[key] = frame_mesh
        if velocity is not None:
            count, corners, normals = frame_mesh
            moved = velocity[local.corners] * np.float32(half_shutter)
            samples.meshes[key] = [(count, corners - moved, normals), frame_mesh, (count, corners + moved, normals)]
        elif len(mesh_keys[key]) == len(times):
            # The frame's triangles at every step: Blender may split a quad along its other diagonal at another
            # step, Cycles keeps the frame's triangles (tri_vindex) and moves their vertices.
            steps = mesh_keys[key][::(largest - 1) // (per_key[key] - 1)]
            samples.meshes[key] = [_frame_corners(step, local, domain, frame_mesh) for step in steps]
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
    return samples


@dataclass
class VectorSamples:
    """The Vector pass's neighbours in time (Cycles' MOTION_PASS): per instance key and for the camera,
    the world matrices one frame before and one frame after."""
    objects: dict = field(default_factory=dict)   # key -> ((4, 4) before, (4, 4) after)
    camera: tuple = ()                            # ((4, 4) before, (4, 4) after), rigid
    # Per instance key of a mesh object that deforms: ((T*3, 3) local corners before, after) on the frame's
    # triangles, and the frame's (T*3, 3) local corners (meshes_frame); export.deform.vector_deform_fields.
    meshes: dict = field(default_factory=dict)
    meshes_frame: dict = field(default_factory=dict)


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
    vertices: dict = {}   # instance key -> its vertex_steps at the previous and next frame
    cameras = []
    try:
        for offset in (-1, 1):
            engine.frame_set(frame + offset, subframe)
            for inst in depsgraph.object_instances:
                if inst.object.type == "MESH":
                    key = instance_key(inst)
                    recorded.setdefault(key, []).append(np.array(inst.matrix_world, np.float64))
                    if _vector_deforms(inst) and mesh_velocity(inst.object) is None:
                        vertices.setdefault(key, []).append(vertex_steps(inst.object))
            if camera_ob is not None:
                cameras.append(rigid_transform(camera_ob.evaluated_get(depsgraph).matrix_world))
    finally:
        engine.frame_set(frame, subframe)
    out.objects = {key: (m[0], m[1]) for key, m in recorded.items() if len(m) == 2}
    # Deforming meshes, as Cycles' motion pass reads them: every mesh object Cycles calls deform-modified gets
    # its vertices at frame -1 and +1 (intern/cycles/blender/object.cpp sync_object_motion_init gives every
    # object 3 motion steps for the pass, whatever its Motion Blur and Deformation switches; mesh.cpp
    # sync_mesh_motion), on the frame's triangles; a step whose vertex count differs takes the frame's vertices.
    # A mesh with a `velocity` attribute moves along it instead, one frame's worth each way
    # (attr_create_motion_from_velocity: half of scene.cpp motion_shutter_time, 2 frames for the pass).
    fps = scene.render.fps / scene.render.fps_base
    for inst in depsgraph.object_instances:
        key = instance_key(inst)
        if inst.object.type != "MESH" or not _vector_deforms(inst):
            continue
        velocity = mesh_velocity(inst.object)
        if velocity is None and len(vertices.get(key, ())) != 2:
            continue
        with readable_mesh(inst.object) as mesh:
            local = read_mesh(mesh)
            count = len(mesh.vertices)
        corners = local.positions
        if velocity is not None:
            moved = velocity[local.corners] * np.float32(1.0 / fps)
            steps = [corners - moved, corners + moved]
        else:
            frame_mesh = (count, corners, np.zeros_like(corners))
            steps = [_frame_corners(step, local, "FACE", frame_mesh)[1] for step in vertices[key]]
            steps = [corners if c is None else c for c in steps]
        if not all(np.array_equal(c, corners) for c in steps):
            out.meshes[key] = (steps[0], steps[1])
            out.meshes_frame[key] = corners
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


def _vector_deforms(inst) -> bool:
    """A mesh object (not an instance) with modifiers, shape keys or a `velocity` attribute: the Vector pass reads
    its deformation (Cycles' BKE_object_is_deform_modified; no Motion Blur or Deformation switch for the pass)."""
    ob = inst.object
    if inst.is_instance or ob.type != "MESH":
        return False
    return bool(ob.modifiers) or getattr(ob.original.data, "shape_keys", None) is not None or \
        mesh_velocity(ob) is not None


def may_deform(inst, velocity: bool = False) -> bool:
    """A mesh object (not an instance) that may deform: modifiers or shape keys (Cycles' BKE_object_is_deform_modified,
    intern/cycles/blender/util.h; velocity: or a `velocity` attribute), its Deformation switch on."""
    ob = inst.object
    if inst.is_instance or ob.type != "MESH" or not deform_motion(inst):
        return False
    return bool(ob.modifiers) or getattr(ob.original.data, "shape_keys", None) is not None or \
        (velocity and mesh_velocity(ob) is not None)


def mesh_velocity(ob) -> np.ndarray | None:
    """(V, 3) float32 the `velocity` attribute of an evaluated mesh object (a vector per vertex, units per second),
    else None."""
    attr = ob.data.attributes.get("velocity")
    n = len(ob.data.vertices)
    if attr is None or attr.domain != "POINT" or attr.data_type != "FLOAT_VECTOR" or not n:
        return None
    values = np.empty(3 * n, np.float32)
    attr.data.foreach_get("vector", values)
    return values.reshape(n, 3)


def vertex_steps(ob) -> tuple:
    """(vertex count, (V, 3) float32 vertices, its normals' domain, (N, 3) float32 normal rows or None) of an evaluated
    mesh object, in object space: Blender's vertex normals for a mesh smooth all over (POINT), its corner normals
    (CORNER), none for flat faces only (FACE)."""
    with readable_mesh(ob) as mesh:
        n = len(mesh.vertices)
        vertices = read_values(mesh.attributes["position"].data, "vector", 3 * n, np.float32).reshape(-1, 3) \
            if n else np.zeros((0, 3), np.float32)
        domain = mesh.normals_domain
        rows = None
        if domain == "POINT":
            rows = read_values(mesh.vertex_normals, "vector", 3 * n, np.float32).reshape(-1, 3)
        elif domain == "CORNER":
            rows = read_values(mesh.corner_normals, "vector", 3 * len(mesh.loops), np.float32).reshape(-1, 3)
        return n, vertices, domain, rows


def _frame_corners(step: tuple, local, domain: str, frame: tuple) -> tuple:
    """A step's vertex_steps on the frame's triangles (local: the frame's LocalMesh): (vertex count, (T*3, 3) corners,
    (T*3, 3) normals); the corners None where the step's vertices (or normal rows) differ in number from the frame's.
    Flat faces (FACE) get zero normals: the kernel then shades each triangle by its geometric normal where it is at
    the ray's time, as Cycles shades a flat motion triangle (its Ng)."""
    count, vertices, step_domain, rows = step
    if count != frame[0]:
        return count, None, None
    corners = np.take(vertices, local.corners, axis=0)
    if domain == "FACE" or step_domain != domain or rows is None:
        return count, corners, np.zeros_like(corners)
    if len(rows) != len(local.normal_rows):
        return count, None, None
    return count, corners, np.take(rows, local.normal_index, axis=0)


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
