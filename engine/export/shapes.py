"""The curves and points of an export: which instances show them, each data-block read once (points.py,
curves.py), and where they go: stored once in object space and placed by their instances' transforms when two
or more instances hold many primitives together (kernels.scene.ShapeInstances, Embree's two-level BVH), else
copied into world space as Cycles' apply_transform copies them (the radius times the cube root of the
transform's determinant: intern/cycles/scene/hair.cpp and pointcloud.cpp). Each instance gets an object table
row of its own, after the meshes' rows (hair of a mesh object too, as Cycles makes it an object of its own).

The scene's Curves settings pick the shape (scene.cycles_curves: Rounded Ribbons, 3D Curves, Linear 3D Curves;
Subdivisions), curves of poly type are linear whatever it is (intern/cycles/blender/curves.cpp, sync_hair);
View Layer > Filter > Curves off renders no curves (Cycles' use_hair).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

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

    def __init__(self, depsgraph, warnings: list[str], moving=frozenset()):
        settings = getattr(depsgraph.scene_eval, "cycles_curves", None)
        self.shape = CYCLES_SHAPES.get(getattr(settings, "shape", "RIBBONS"), "RIBBON")
        self.subdivisions = int(getattr(settings, "subdivisions", 2))
        self.render = depsgraph.mode == "RENDER"
        self.use_hair = bool(getattr(depsgraph.view_layer, "use_strand", True))
        self.warnings = warnings
        self.moving = moving
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
        if place["key"] in self.moving and ob.name not in self._warned:
            self._warned.add(ob.name)
            self.warnings.append(f"Object '{ob.name}': motion blur of curves and points is not supported yet, "
                                 f"they render where they are at the frame")
        group = self._groups.setdefault((key, rows), _Group())
        group.matrices.append(place["matrix"])
        group.inputs.append(place["inputs"])
        group.keys.append(place["key"])
        group.assets.append(place["asset"])
        group.visibility.append(place["visibility"])
        group.slots.append(place["slots"])
        group.properties.append(place["properties"])
        return True

    def assemble(self, first_row: int) -> ShapeRows:
        """The kernel's records of everything added; object rows numbered from first_row."""
        out = ShapeRows()
        plain: dict[str, list] = {}        # shape ("POINTS" for points) -> [(record in world space), ...]
        prototypes, which, placements, instance_rows = [], [], [], []
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
            if k >= 2 and k * size >= INSTANCE_MIN_PRIMITIVES and not any(x in self.moving for x in group.keys):
                prototypes.append(self._record(local, table, None, None))
                which.extend([len(prototypes) - 1] * k)
                placements.append(matrices)
                instance_rows.extend(ids)
            else:
                for matrix, obj in zip(matrices, ids):
                    record = self._record(local, table, matrix, obj)
                    plain.setdefault("POINTS" if isinstance(record, Points) else record.shape, []).append(record)
            row += k
            out.keys += group.keys
            out.matrices += group.matrices
            out.assets += group.assets
            out.visibility += group.visibility
            out.slots += group.slots
            out.properties += group.properties
        out.objects = np.concatenate(tables) if tables else None
        out.curves = tuple(_join_curves(records) for shape, records in plain.items() if shape != "POINTS")
        out.points = _join_points(plain["POINTS"]) if "POINTS" in plain else None
        if prototypes:
            out.instances = ShapeInstances(tuple(prototypes), np.array(which, np.int32),
                                           np.concatenate(placements).astype(np.float64),
                                           np.array(instance_rows, np.int32))
        return out

    def _record(self, local, table: np.ndarray, matrix, obj):
        """A kernel record of local data: in object space (matrix None: a prototype) or moved into world space,
        on object row obj."""
        if isinstance(local, LocalPoints):
            values = _placed(local.points, matrix)
            n = local.count
            return Points(values, np.full(n, table[0], np.int32),
                          None if obj is None else np.full(n, obj, np.int32),
                          tuple((name, np.ascontiguousarray(v, np.float32)) for name, v in local.attributes.items()))
        c = local.count
        materials = table[np.clip(local.slots, 0, len(table) - 1)].astype(np.int32)
        return Curves("LINEAR" if local.linear else self.shape, _placed(local.keys, matrix), local.offsets,
                      materials, None if obj is None else np.full(c, obj, np.int32),
                      tuple((name, np.ascontiguousarray(v, np.float32)) for name, v in local.attributes.items()),
                      self.subdivisions)


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
                  _attribute_union(records, lambda r: len(r.keys), lambda r: r.count), records[0].subdivisions)


def _join_points(records: list) -> Points:
    if len(records) == 1:
        return records[0]
    return Points(np.concatenate([r.points for r in records]), np.concatenate([r.material_ids for r in records]),
                  np.concatenate([r.object_ids for r in records]),
                  _attribute_union(records, lambda r: r.count, lambda r: r.count))
