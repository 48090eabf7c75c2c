"""The curves and points of an export: which instances show them, each data-block read once (points.py,
curves.py), and where they go: stored once in object space and placed by their instances' transforms when two
or more instances hold many primitives together (kernels.scene.ShapeInstances, Embree's two-level BVH), else
copied into world space as Cycles' apply_transform copies them (the radius times the cube root of the
transform's determinant: intern/cycles/scene/hair.cpp and pointcloud.cpp). Each instance gets an object table
row of its own, after the meshes' rows (hair of a mesh object too, as Cycles makes it an object of its own).

The scene's Curves settings pick the shape (scene.cycles_curves: Rounded Ribbons, 3D Curves, Linear 3D Curves;
Subdivisions), curves of poly type are linear whatever it is (intern/cycles/blender/curves.cpp, sync_hair);
View Layer > Filter > Curves off renders no curves (Cycles' use_hair).

Motion blur, as Cycles keeps moving curves and points (intern/cycles/scene/object.cpp apply_static_transforms,
bvh/embree.cpp add_instance, add_curves, add_points): an instance whose transform moves over the shutter
(motion.MotionSamples.objects) stays in object space, placed by an instance with motion steps
(kernels.scene.ShapeInstances.motion, slerped as Cycles' object motion); its deformation (its keys at each motion
step, MotionSamples.shapes) becomes its prototype's time steps (kernels.scene.Curves.motion, Points.motion). One that
only deforms is copied into world space at each of its steps, as Cycles applies a still object's transform to its
motion keys too. Moving and deforming instances are never shared with still ones. A deformation counts where any
key moves (for curves its radius too), as Cycles' export_hair_curves_motion and export_pointcloud_motion decide
(intern/cycles/blender/curves.cpp, pointcloud.cpp); a Curves object's curve whose keys change in number is
read along itself (resample_curves), as Cycles does; curves or points that change in number give no deformation
blur (a warning names the object).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...kernels.geometry import uniform_scales
from ...kernels.scene import Curves, Points, ShapeInstances, object_rows
from .curves import LocalCurves, hair_systems, read_curves, read_particle_hair
from .instances import INSTANCE_MIN_TRIANGLES
from .points import LocalPoints, read_points

# scene.cycles_curves.shape -> kernels.scene.CURVE_SHAPES
CYCLES_SHAPES = {"RIBBONS": "RIBBON", "THICK": "ROUND", "THICK_LINEAR": "LINEAR"}
# Curves and points placed by two or more instances are instanced once they hold this many primitives (segments,
# points) together, as meshes are (engine/export/instances.py).
INSTANCE_MIN_PRIMITIVES = INSTANCE_MIN_TRIANGLES


@dataclass
class _Group:
    """The instances of one data-block with one set of material rows, per instance what the object table and
    its parallel lists need."""
    matrices: list = field(default_factory=list)
    inputs: list = field(default_factory=list)        # instances.object_inputs + the instance's random
    keys: list = field(default_factory=list)
    assets: list = field(default_factory=list)
    visibility: list = field(default_factory=list)
    slots: list = field(default_factory=list)
    properties: list = field(default_factory=list)
    motion: list = field(default_factory=list)        # per instance ShapeExport._motion: how it moves, or None


@dataclass
class ShapeRows:
    """What assemble() gives the Geometry: the kernel's records and the object rows they use (after the meshes'),
    with per row what the Geometry keeps per row."""
    curves: tuple = ()
    points: Points | None = None
    instances: ShapeInstances | None = None
    objects: np.ndarray | None = None
    keys: list = field(default_factory=list)
    matrices: list = field(default_factory=list)
    assets: list = field(default_factory=list)
    visibility: list = field(default_factory=list)
    slots: list = field(default_factory=list)
    properties: list = field(default_factory=list)


class ShapeExport:
    """Curves and points met by export_geometry's walk over the instances (add_*), assembled at its end."""

    def __init__(self, depsgraph, warnings: list[str], moving=frozenset(), motion=None):
        settings = getattr(depsgraph.scene_eval, "cycles_curves", None)
        self.shape = CYCLES_SHAPES.get(getattr(settings, "shape", "RIBBONS"), "RIBBON")
        self.subdivisions = int(getattr(settings, "subdivisions", 2))
        self.render = depsgraph.mode == "RENDER"
        self.use_hair = bool(getattr(depsgraph.view_layer, "use_strand", True))
        self.warnings = warnings
        self.moving = moving
        self.transforms = motion.objects if motion is not None else {}   # instance key -> (S, 4, 4)
        self.steps = motion.shapes if motion is not None else {}         # instance key -> its keys per step
        # Half the shutter in seconds: how far a `velocity` attribute moves keys each way (None: no motion blur).
        r = depsgraph.scene_eval.render
        self.velocity_time = None if motion is None else 0.5 * float(r.motion_blur_shutter) / (r.fps / r.fps_base)
        self._velocity: dict = {}        # data key -> (n, 3) float32 velocity attribute, or None
        self._local: dict = {}           # data key -> LocalCurves or LocalPoints
        self._groups: dict = {}          # (data key, material rows) -> _Group
        self._warned: set = set()

    @property
    def empty(self) -> bool:
        return not self._groups

    def has_hair(self, ob) -> bool:
        return self.use_hair and bool(hair_systems(ob, self.render))

    def add_data(self, ob, rows: tuple, names: tuple, place: dict) -> bool:
        """A Point Cloud or Curves instance (ob evaluated, rows its material rows, names the attributes they read,
        place its object row data: add's keywords). False when it holds nothing to render."""
        kind = ob.type
        if kind == "CURVES" and not self.use_hair:
            return False
        key = (kind, ob.data.as_pointer())
        if key not in self._local:
            self._local[key] = read_points(ob.data, names, ob.name, self.warnings) if kind == "POINTCLOUD" else \
                read_curves(ob.data, names, ob.name, self.warnings)
            self._velocity[key] = read_velocity(ob.data, self._local[key]) if self.velocity_time else None
        return self._add(key, rows, ob, place)

    def add_hair(self, ob, rows: tuple, names: tuple, place: dict) -> bool:
        """The hair particle systems of a mesh instance, as curves of their own object row."""
        key = ("HAIR", ob.as_pointer())
        if key not in self._local:
            self._local[key] = read_particle_hair(ob, hair_systems(ob, self.render), self.render, len(rows), names,
                                                  ob.data, ob.name, self.warnings)
        return self._add(key, rows, ob, place)

    def _add(self, key, rows: tuple, ob, place: dict) -> bool:
        local = self._local[key]
        if not local.count:
            return False
        group = self._groups.setdefault((key, rows), _Group())
        group.motion.append(self._motion(key, local, place, ob))
        group.matrices.append(place["matrix"])
        group.inputs.append(place["inputs"])
        group.keys.append(place["key"])
        group.assets.append(place["asset"])
        group.visibility.append(place["visibility"])
        group.slots.append(place["slots"])
        group.properties.append(place["properties"])
        return True

    def _motion(self, key, local, place: dict, ob) -> tuple | None:
        """(transform, deformation) of an instance that moves, else None: its (S, 4, 4) world_from_object over the
        shutter or None, and its (S', n, 4) float32 local keys over the shutter or None (its own steps)."""
        matrices = self.transforms.get(place["key"])
        velocity = self._velocity.get(key)
        if velocity is not None and _motion_settings(ob):
            # Cycles' attr_create_motion_from_velocity: three steps, the keys half the shutter's seconds before
            # and after the frame along their velocity (whatever the shutter's position), the radius unchanged;
            # a geometry moved so is not read at the subframes (BlenderSync::sync_motion skips it).
            values = local.points if isinstance(local, LocalPoints) else local.keys
            steps = []
            for sign in (-1.0, 0.0, 1.0):
                moved = values.copy()
                moved[:, :3] = values[:, :3] + velocity * np.float32(sign * self.velocity_time)
                steps.append(moved)
        else:
            steps = self._deformation(key[0], local, place["key"], ob)
        if matrices is None and steps is None:
            return None
        return matrices, None if steps is None else np.ascontiguousarray(np.stack(steps), np.float32)

    def _deformation(self, kind: str, local, key, ob) -> list | None:
        """The instance's local keys at its motion steps when they differ from the frame's, else None."""
        steps = self.steps.get(key)
        if steps is None:
            return None
        points = isinstance(local, LocalPoints)
        values = local.points if points else local.keys
        if kind == "CURVES" and all(len(o) == len(local.offsets) for o, _ in steps):
            # Curves keep their number but some change their keys' number: Cycles' export_hair_curves_motion
            # reads those along the step's curve (interpolate_curve_points), which is motion whatever it gives.
            changed = [not np.array_equal(o, local.offsets) for o, _ in steps]
            steps = [(local.offsets, resample_curves(local.offsets, o, k)) if c else (o, k)
                     for (o, k), c in zip(steps, changed)]
            if any(changed):
                return [k for _, k in steps]
        same = all(len(k) == len(values) and (points or np.array_equal(o, local.offsets)) for o, k in steps)
        if not same:
            if ob.name not in self._warned:
                self._warned.add(ob.name)
                what = "points" if points else "curves"
                self.warnings.append(f"Object '{ob.name}': its {what} change in number during the shutter; "
                                     f"rendered without deformation motion blur")
            return None
        columns = slice(0, 3) if points else slice(0, 4)   # Cycles' points move by their positions alone
        if kind == "HAIR":
            # Read back through the object's own transform at each step: Cycles' ExportCurveSegmentsMotion takes a
            # key (position and radius) as moved beyond 1e-5 only (intern/cycles/blender/curves.cpp).
            moved = any((np.sum((k - values) ** 2, axis=1) > 1e-5 * 1e-5).any() for _, k in steps)
        else:
            moved = any(not np.array_equal(k[:, columns], values[:, columns]) for _, k in steps)
        return [k for _, k in steps] if moved else None

    def assemble(self, first_row: int) -> ShapeRows:
        """The kernel's records of everything added; object rows numbered from first_row."""
        out = ShapeRows()
        plain: dict[str, list] = {}        # shape ("POINTS" for points) -> [(record in world space), ...]
        prototypes, which, placements, instance_rows = [], [], [], []
        motions, motion_ids = [], []     # moving instances' (S, 4, 4) keys; per instance its entry or -1
        tables = []
        row = first_row
        for (key, rows), group in self._groups.items():
            local = self._local[key]
            table = np.array(rows, np.int32)
            matrices = np.stack(group.matrices)
            k = len(matrices)
            size = local.segment_count if isinstance(local, LocalCurves) else local.count
            tables.append(object_rows(matrices, *(np.array(column) for column in zip(*group.inputs))))
            ids = np.arange(row, row + k, dtype=np.int32)
            if k >= 2 and k * size >= INSTANCE_MIN_PRIMITIVES and all(m is None for m in group.motion):
                prototypes.append(self._record(local, table, None, None))
                which.extend([len(prototypes) - 1] * k)
                placements.append(matrices)
                instance_rows.extend(ids)
                motion_ids.extend([-1] * k)
                row += k
                self._rows(out, group)
                continue
            shared = None   # the group's prototype for its moving, undeformed instances
            for matrix, obj, moves in zip(matrices, ids, group.motion):
                transform, steps = moves if moves is not None else (None, None)
                if transform is None and steps is None and not uniform_scales(matrix[None])[0]:
                    # Cycles applies no transform that is not a uniform scale to curves and points: it keeps
                    # them in object space under an instance (scene/object.cpp apply_static_transforms), whose
                    # transform then stretches their tubes, ribbons and spheres (a lawn's grass blades on a plane
                    # scaled 80 x 100 x 1 are 80-100 times as wide, not the cube root of that).
                    if shared is None:
                        prototypes.append(self._record(local, table, None, None))
                        shared = len(prototypes) - 1
                    which.append(shared)
                    placements.append(matrix[None])
                    instance_rows.append(obj)
                    motion_ids.append(-1)
                    continue
                if transform is None:   # still, or deforming in place: copied into world space at each step
                    record = self._record(local, table, matrix, obj, None if steps is None else
                                          np.stack([_placed(keys, matrix) for keys in steps]))
                    plain.setdefault("POINTS" if isinstance(record, Points) else record.shape, []).append(record)
                    continue
                # Moving: an instance with motion steps, as Cycles keeps a moving object's geometry in object space
                # (intern/cycles/scene/object.cpp apply_static_transforms; bvh/embree.cpp add_instance), its
                # deformation as the prototype's own time steps.
                if steps is None:
                    if shared is None:
                        prototypes.append(self._record(local, table, None, None))
                        shared = len(prototypes) - 1
                    which.append(shared)
                else:
                    prototypes.append(self._record(local, table, None, None, steps))
                    which.append(len(prototypes) - 1)
                placements.append(matrix[None])
                instance_rows.append(obj)
                motion_ids.append(len(motions))
                motions.append(np.asarray(transform, np.float64))
            row += k
            self._rows(out, group)
        out.objects = np.concatenate(tables) if tables else None
        out.curves = tuple(_join_curves(records) for shape, records in plain.items() if shape != "POINTS")
        out.points = _join_points(plain["POINTS"]) if "POINTS" in plain else None
        if prototypes:
            out.instances = ShapeInstances(tuple(prototypes), np.array(which, np.int32),
                                           np.concatenate(placements).astype(np.float64),
                                           np.array(instance_rows, np.int32), tuple(motions),
                                           np.array(motion_ids, np.int32) if motions else None)
        return out

    @staticmethod
    def _rows(out: ShapeRows, group: _Group) -> None:
        """A group's per-row lists onto the ShapeRows'."""
        out.keys += group.keys
        out.matrices += group.matrices
        out.assets += group.assets
        out.visibility += group.visibility
        out.slots += group.slots
        out.properties += group.properties

    def _record(self, local, table: np.ndarray, matrix, obj, motion=None):
        """A kernel record of local data: in object space (matrix None: a prototype) or moved into world space,
        on object row obj; motion: its keys over the shutter in the same space, or None."""
        if isinstance(local, LocalPoints):
            values = _placed(local.points, matrix)
            n = local.count
            return Points(values, np.full(n, table[0], np.int32),
                          None if obj is None else np.full(n, obj, np.int32),
                          tuple((name, np.ascontiguousarray(v, np.float32)) for name, v in local.attributes.items()),
                          motion)
        c = local.count
        materials = table[np.clip(local.slots, 0, len(table) - 1)].astype(np.int32)
        return Curves("LINEAR" if local.linear else self.shape, _placed(local.keys, matrix), local.offsets,
                      materials, None if obj is None else np.full(c, obj, np.int32),
                      tuple((name, np.ascontiguousarray(v, np.float32)) for name, v in local.attributes.items()),
                      self.subdivisions, motion)


def _motion_settings(ob) -> bool:
    """Object Properties > Motion Blur and its Deformation both on (Cycles' need_motion and use_deform_motion)."""
    settings = getattr(ob.original, "cycles", None)
    return settings is None or (bool(getattr(settings, "use_motion_blur", True))
                                and bool(getattr(settings, "use_deform_motion", True)))


def read_velocity(data, local) -> np.ndarray | None:
    """(n, 3) float32 the `velocity` attribute (a vector per point, units per second) of a Curves or Point Cloud
    data-block whose keys are all kept, else None."""
    attr = data.attributes.get("velocity")
    n = len(data.points)
    if attr is None or attr.domain != "POINT" or attr.data_type != "FLOAT_VECTOR" or not n:
        return None
    if (local.count if isinstance(local, LocalPoints) else len(local.keys)) != n:
        return None   # curves of a single point were left out: the rows no longer match
    values = np.empty(3 * n, np.float32)
    attr.data.foreach_get("vector", values)
    return values.reshape(n, 3)


def resample_curves(offsets: np.ndarray, step_offsets: np.ndarray, step_keys: np.ndarray) -> np.ndarray:
    """(K, 4) float32 keys for curves of `offsets` read from the same curves at a motion step, where some have
    another number of keys: a curve of n keys takes its i-th at i / (n - 1) of the way along the step's curve of
    m keys, mixed linearly between the two around (Cycles' interpolate_curve_points, in float32 as it); a curve
    whose count is unchanged is copied as it is."""
    n = np.diff(offsets).astype(np.int64)
    m = np.diff(step_offsets).astype(np.int64)
    curve = np.repeat(np.arange(len(n)), n)
    i = np.arange(offsets[-1], dtype=np.int64) - np.repeat(offsets[:-1].astype(np.int64), n)
    step_size = (np.float32(1) / np.maximum(n - 1, 1).astype(np.float32))[curve]
    along = (i.astype(np.float32) * step_size) * (m - 1)[curve].astype(np.float32)
    a = np.clip(along.astype(np.int64), 0, m[curve] - 1)
    b = np.minimum(a + 1, m[curve] - 1)
    f = (along - a).astype(np.float32)[:, None]
    start = step_offsets[:-1].astype(np.int64)[curve]
    out = (step_keys[start + a] + f * (step_keys[start + b] - step_keys[start + a])).astype(np.float32)
    same = (n == m)[curve]
    out[same] = step_keys[start[same] + i[same]]
    return out


def _placed(values: np.ndarray, matrix) -> np.ndarray:
    """(n, 4) x, y, z, radius moved into world space by a (4, 4) matrix (None: as they are): Cycles'
    apply_transform, the radius scaled by the cube root of |det|."""
    if matrix is None:
        return np.ascontiguousarray(values, np.float32)
    m = np.asarray(matrix, np.float64)
    out = np.empty(values.shape, np.float32)
    # Row by row in float64, not a (n, 3) @ (3, 3) product: BLAS's threads make that 3-7x slower on two busy
    # cores (0.3-1.1 s at 1M points against 0.1 s), for the same values.
    x, y, z = (values[:, i].astype(np.float64) for i in range(3))
    with np.errstate(over="ignore", invalid="ignore"):
        for i in range(3):
            out[:, i] = x * m[i, 0] + y * m[i, 1] + z * m[i, 2] + m[i, 3]
        out[:, 3] = values[:, 3] * np.float32(abs(np.linalg.det(m[:3, :3])) ** (1.0 / 3.0))
    return out


def _attribute_union(records, rows_of, count_of) -> tuple:
    """The attributes of records joined end to end: each name present anywhere, zero where a record lacks it,
    per key where any record has it per key (a per-curve value repeated on its keys)."""
    names: dict[str, tuple] = {}
    for r in records:
        for name, v in r.attributes:
            width, per_key = names.get(name, (0, False))
            names[name] = (max(width, v.shape[1]), per_key or (rows_of(r) != count_of(r) and len(v) == rows_of(r)))
    out = []
    for name, (width, per_key) in sorted(names.items()):
        parts = []
        for r in records:
            values = dict(r.attributes).get(name)
            n = rows_of(r) if per_key else count_of(r)
            block = np.zeros((n, width), np.float32)
            if values is not None:
                if per_key and len(values) != rows_of(r):   # per curve: onto each of its keys
                    values = np.repeat(values, np.diff(r.offsets), axis=0)
                block[:, :values.shape[1]] = values
            parts.append(block)
        out.append((name, np.concatenate(parts)))
    return tuple(out)


def _join_curves(records: list) -> Curves:
    if len(records) == 1:
        return records[0]
    keys = np.concatenate([r.keys for r in records])
    starts = np.cumsum([0] + [len(r.keys) for r in records])
    offsets = np.concatenate([records[0].offsets[:1]] + [r.offsets[1:] + s for r, s in zip(records, starts)])
    return Curves(records[0].shape, keys, offsets.astype(np.int32),
                  np.concatenate([r.material_ids for r in records]),
                  np.concatenate([r.object_ids for r in records]),
                  _attribute_union(records, lambda r: len(r.keys), lambda r: r.count), records[0].subdivisions,
                  _joined_motion([(r.keys, r.motion) for r in records]))


def _join_points(records: list) -> Points:
    if len(records) == 1:
        return records[0]
    return Points(np.concatenate([r.points for r in records]), np.concatenate([r.material_ids for r in records]),
                  np.concatenate([r.object_ids for r in records]),
                  _attribute_union(records, lambda r: r.count, lambda r: r.count),
                  _joined_motion([(r.points, r.motion) for r in records]))


def _joined_motion(parts: list) -> np.ndarray | None:
    """The motion keys of records joined end to end, None when none moves: every record on the most steps any
    has, a still one its keys at each, one of fewer steps mixed linearly onto them (the kernel's interpolation
    between its own steps, so its motion is unchanged: step counts 2^s + 1 nest)."""
    counts = [len(m) for _, m in parts if m is not None]
    if not counts:
        return None
    steps = max(counts)
    time = np.linspace(0.0, 1.0, steps)
    out = []
    for keys, motion in parts:
        if motion is None:
            out.append(np.broadcast_to(keys, (steps,) + keys.shape))
            continue
        position = time * (len(motion) - 1)
        lo = np.minimum(position.astype(np.int64), len(motion) - 2)
        f = (position - lo).astype(np.float32)[:, None, None]
        out.append((1 - f) * motion[lo] + f * motion[lo + 1])
    return np.ascontiguousarray(np.concatenate(out, axis=1), np.float32)
