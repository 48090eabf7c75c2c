"""Triangles, curves and points in one numbering: the scene's primitives as ray hits report them.

Triangles keep the numbers they have without curves and points: the T plain ones, then the instanced ones
(kernels.scene.Instances). The curve segments follow, then the points (ShapeLayout): each part (a world-space
record, or one instance of a prototype) a range of its own. PrimitiveTable answers for all of them what the
triangle table answers for triangles (materials, object rows, attributes, rows for UVs and edges), so that
shading, lights and passes see any hit alike; the renderer uses it in place of the TriangleTable only when the
scene has curves or points, so a scene of triangles alone pays nothing for them.

Rays leaving a curve or a point skip that whole curve or point, as Cycles' rays skip the primitive they leave
(kernel_embree_is_self_intersection, intern/cycles/kernel/device/cpu/bvh.h, where a curve's segments are one
primitive): a ray through a hair passes its far side, a shadow ray from a ribbon does not meet the ribbon
turned toward it. Each such primitive has a key (self_keys); skip_hits traces a ray again from just past a hit
on its own key (kernels.visibility.skip_hits).
"""
from __future__ import annotations

import dataclasses

import numpy as np

from .. import embree, motion
from ..scene import Curves, Points, SceneArrays
from ..vec import F32
from . import curves as curve_geometry
from . import points as point_geometry
from .instances import uniform_scales
from .triangles import N0, N1, N2, NG, P0, E1, UV0, UV1, UV2

CURVE, POINT = 1, 2


class ShapeLayout:
    """Where the curves and points of a scene sit in its primitive numbering, and their Embree buffers.

    records : the world-space curve records, the world-space points, then the prototypes of
        SceneArrays.shape_instances (kernels.scene.Curves or Points).
    Parts, in numbering order (the plain curves, the curve instances, the plain points, the point instances),
    as (P,) arrays: part_base (int64, the first number), part_record, part_instance (-1 for world space),
    part_kind (CURVE, POINT), part_culled (bool: spheres and linear curves, whose inside is not hit), part_key
    (int64, the first self key: curves, then points).
    plain_base : per world-space record (records[:plain_count]) its first number; instance_base : per shape
    instance its first number."""

    def __init__(self, scene: SceneArrays, triangle_count: int):
        self.triangle_count = int(triangle_count)
        plain = list(scene.curves) + ([scene.points] if scene.points is not None else [])
        self.instances = scene.shape_instances
        protos = list(self.instances.prototypes) if self.instances is not None else []
        # Per shape instance its motion decomposed as Cycles decomposes object motion (kernels.motion), or None.
        inst = self.instances
        decomposed = [motion.decompose(keys) for keys in inst.motion] if inst is not None else []
        self.instance_motion = [] if inst is None else [
            None if inst.motion_ids is None or inst.motion_ids[k] < 0 else decomposed[inst.motion_ids[k]]
            for k in range(inst.count)]
        self.records = plain + protos
        self.plain_count = len(plain)
        parts = [(j, -1) for j, r in enumerate(plain) if isinstance(r, Curves)]
        which = self.instances.prototype if self.instances is not None else np.zeros(0, np.int32)
        parts += [(self.plain_count + int(p), k) for k, p in enumerate(which) if isinstance(protos[p], Curves)]
        parts += [(j, -1) for j, r in enumerate(plain) if isinstance(r, Points)]
        parts += [(self.plain_count + int(p), k) for k, p in enumerate(which) if isinstance(protos[p], Points)]
        records = self.records
        self.part_record = np.array([r for r, _ in parts], np.int32)
        self.part_instance = np.array([k for _, k in parts], np.int32)
        self.part_kind = np.array([CURVE if isinstance(records[r], Curves) else POINT for r, _ in parts], np.int8)
        # Spheres and linear curves are seen from outside only in Cycles: its Embree is built with back faces of
        # curves and spheres culled, which its round linear and sphere intersectors honour (its swept Catmull-Rom
        # tubes report a far wall all the same, as ribbons face every ray).
        self.part_culled = np.array([not isinstance(records[r], Curves) or records[r].shape == "LINEAR"
                                     for r, _ in parts], bool)
        sizes = np.array([records[r].segment_count if isinstance(records[r], Curves) else records[r].count
                          for r, _ in parts], np.int64)
        keys = np.array([records[r].count for r, _ in parts], np.int64)
        self.part_base = self.triangle_count + np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64) \
            if len(parts) else np.zeros(0, np.int64)
        self.part_key = np.concatenate([[0], np.cumsum(keys)[:-1]]).astype(np.int64) if len(parts) \
            else np.zeros(0, np.int64)
        self.total = self.triangle_count + int(sizes.sum())
        self.plain_base = np.zeros(self.plain_count, np.int64)
        self.instance_base = np.zeros(0 if self.instances is None else self.instances.count, np.int64)
        for i, (r, k) in enumerate(parts):
            if k < 0:
                self.plain_base[r] = self.part_base[i]
            else:
                self.instance_base[k] = self.part_base[i]

    def embree_shapes(self) -> list:
        """An embree.Shape per record, in the order of records (each curve record's buffers made here)."""
        out = []
        for record in self.records:
            if isinstance(record, Curves):
                vertices, indices = curve_geometry.embree_buffers(record)
                steps = None if record.motion is None else np.stack(
                    [curve_geometry.embree_buffers(r)[0] for r in step_records(record)])
                out.append(embree.Shape(embree.CURVE_GEOMETRY[record.shape], vertices, indices,
                                        curve_geometry.tessellation_rate(record.subdivisions), steps))
            else:
                out.append(embree.Shape(embree.SPHERE_POINT, point_geometry.embree_vertices(record),
                                        steps=record.motion))
        return out

    @property
    def moves(self) -> bool:
        """Some record has motion keys or some instance moves: rays need their times."""
        return any(r.motion is not None for r in self.records) or any(m is not None for m in self.instance_motion)

    def locate(self, prim: np.ndarray):
        """(part, local number within its record) of curve and point numbers prim (all >= triangle_count)."""
        part = np.searchsorted(self.part_base, prim, side="right") - 1
        return part, prim - np.take(self.part_base, part)


class PrimitiveTable:
    """The triangle table's interface (kernels.geometry.TriangleTable) over triangles, curves and points: what
    the integrator, shading and passes ask of a hit's primitive number."""

    def __init__(self, triangles, scene: SceneArrays, layout: ShapeLayout | None = None):
        self.triangles = triangles
        self.triangle_count = len(scene.positions) + scene.instanced_triangle_count
        self.layout = ShapeLayout(scene, self.triangle_count) if layout is None else layout
        inst = self.layout.instances
        self._matrices = None if inst is None else np.ascontiguousarray(inst.world_from_object[:, :3, :4], F32)
        self._instance_objects = None if inst is None else inst.object_ids
        self.attribute_names = {name for r in self.layout.records for name, _ in r.attributes}
        self._twins = None

    # ---- exact copies (Blender's jittered hair puts some strands on top of one another)
    @property
    def has_twins(self) -> bool:
        """Whether some curve or point has an exact copy in its record (twin_prims)."""
        if self._twins is None:
            self._twins = [element_twins(r) for r in self.layout.records]
        return any(t is not None for t in self._twins)

    def twin_prims(self, prim: np.ndarray) -> np.ndarray:
        """(n,) the number of the same segment (or point) of the next exact copy of each primitive's curve (or
        point), -1 where it has none."""
        out = np.full(len(prim), -1, np.int64)
        if not self.has_twins:
            return out
        part, local = self.layout.locate(prim)
        record = np.take(self.layout.part_record, part)
        for r in np.unique(record):
            twins = self._twins[int(r)]
            if twins is None:
                continue
            sel = np.flatnonzero(record == r)
            rec = self.layout.records[int(r)]
            loc = np.take(local, sel)
            element = self._element(rec, loc)
            twin = np.take(twins, element)
            has = twin >= 0
            if isinstance(rec, Curves):
                starts = rec.segment_offsets()
                moved = loc - np.take(starts, element) + np.take(starts, np.maximum(twin, 0))
            else:
                moved = np.maximum(twin, 0)
            base = np.take(self.layout.part_base, np.take(part, sel))
            out[sel[has]] = (base + moved)[has]
        return out

    # ---- the triangle table's own, for triangles
    @property
    def plain_count(self) -> int:
        return self.triangles.plain_count

    @property
    def material_ids(self) -> np.ndarray:
        return self.triangles.material_ids

    @property
    def rows(self):
        return self.triangles.rows

    @property
    def rows_built(self) -> bool:
        return self.triangles.rows_built

    @property
    def building(self) -> bool:
        return self.triangles.building

    @property
    def instanced(self) -> bool:
        return self.triangles.instanced

    def build_rows(self) -> None:
        self.triangles.build_rows()

    def wait_rows(self) -> None:
        self.triangles.wait_rows()

    def place(self, instances, objects=None) -> None:
        self.triangles.place(instances, objects)

    def shape_materials(self) -> np.ndarray:
        """(M',) int32 every material row the curves and points use (the renderer's wave size asks)."""
        used = [np.unique(r.material_ids) for r in self.layout.records]
        return np.unique(np.concatenate(used)).astype(np.int32) if used else np.zeros(0, np.int32)

    # ---- per primitive number
    def _split(self, prim: np.ndarray):
        shape = np.flatnonzero(prim >= self.triangle_count)
        return shape, (None if not len(shape) else np.flatnonzero(prim < self.triangle_count))

    def _groups(self, prim: np.ndarray):
        """(hit indices, record, local numbers, instance numbers (-1 plain)) per record among prim (all shapes)."""
        part, local = self.layout.locate(prim)
        record = np.take(self.layout.part_record, part)
        instance = np.take(self.layout.part_instance, part)
        for r in np.unique(record):
            sel = np.flatnonzero(record == r)
            yield sel, self.layout.records[int(r)], np.take(local, sel), np.take(instance, sel)

    def _element(self, record, local: np.ndarray) -> np.ndarray:
        """The curve of each segment, or the point itself."""
        return curve_geometry.segment_curves(record, local) if isinstance(record, Curves) else local

    def materials(self, prim: np.ndarray) -> np.ndarray:
        shape, tri = self._split(prim)
        if not len(shape):
            return self.triangles.materials(prim)
        out = np.empty(len(prim), np.int32)
        if len(tri):
            out[tri] = self.triangles.materials(np.take(prim, tri))
        for sel, record, local, _ in self._groups(np.take(prim, shape)):
            out[shape[sel]] = np.take(record.material_ids, self._element(record, local))
        return out

    def object_rows(self, prim: np.ndarray) -> np.ndarray | None:
        shape, tri = self._split(prim)
        if not len(shape):
            return self.triangles.object_rows(prim)
        out = np.zeros(len(prim), np.int32)
        if len(tri):
            rows = self.triangles.object_rows(np.take(prim, tri))
            if rows is not None:
                out[tri] = rows
        for sel, record, local, instance in self._groups(np.take(prim, shape)):
            if record.object_ids is not None:
                out[shape[sel]] = np.take(record.object_ids, self._element(record, local))
            else:
                out[shape[sel]] = np.take(self._instance_objects, instance)
        return out

    def self_keys(self, prim: np.ndarray) -> np.ndarray:
        """(n,) int64 the curve or point each hit is on (what a ray leaving it skips), -1 for triangles."""
        out = np.full(len(prim), -1, np.int64)
        shape, _ = self._split(prim)
        if len(shape):
            part, local = self.layout.locate(np.take(prim, shape))
            kind = np.take(self.layout.part_kind, part)
            element = local.copy()
            curves = np.flatnonzero(kind == CURVE)
            for sel, record, loc, _ in self._groups(np.take(prim, shape[curves])):
                element[curves[sel]] = curve_geometry.segment_curves(record, loc)
            out[shape] = np.take(self.layout.part_key, part) + element
        return out

    def attribute(self, name: str, prim: np.ndarray) -> np.ndarray | None:
        """(n, 3, C) values at the primitive's 'corners', to be weighted by the hit's barycentrics: a triangle's
        own; on a curve segment its keys (f0, f1, f0) with barycentrics (u, 0), or the curve's value thrice; on a
        point its value thrice. Zero where a primitive lacks the attribute; None when none has it."""
        shape, tri = self._split(prim)
        tri_values = self.triangles.attribute(name, prim if not len(shape) else np.take(prim, tri))
        if not len(shape):
            return tri_values
        if name not in self.attribute_names and tri_values is None:
            return None
        parts = []
        for sel, record, local, _ in self._groups(np.take(prim, shape)):
            values = dict(record.attributes).get(name)
            if values is not None:
                parts.append((sel, record, local, values))
        if tri_values is None and not parts:
            return None
        width = max(([tri_values.shape[2]] if tri_values is not None else []) + [v.shape[1] for *_, v in parts])
        out = np.zeros((len(prim), 3, width), F32)
        if tri_values is not None:
            out[tri, :, :tri_values.shape[2]] = tri_values
        for sel, record, local, values in parts:
            out[shape[sel], :, :values.shape[1]] = _corners(record, local, values)
        return out

    def gather(self, prim: np.ndarray) -> np.ndarray:
        return self.rows_of(prim).T

    def rows_of(self, prim: np.ndarray) -> np.ndarray:
        """(n, 27) rows of the triangle table; for a curve segment or a point a row that stands for it where rows
        are read outside SurfaceHit's own geometry: its first key (or centre) as the corner, the segment as the
        first edge (bump steps follow u), a placeholder normal, its render UV at every corner."""
        shape, tri = self._split(prim)
        if not len(shape):
            return self.triangles.rows_of(prim)
        out = np.zeros((len(prim), 27), F32)
        if len(tri):
            out[tri] = self.triangles.rows_of(np.take(prim, tri))
        for col in (NG + 2, N0 + 2, N1 + 2, N2 + 2):
            out[shape, col] = 1.0
        uv = self.attribute("uv", np.take(prim, shape)) if "uv" in self.attribute_names else None
        if uv is not None:
            for col, corner in ((UV0, 0), (UV1, 1), (UV2, 2)):
                out[shape, col:col + 2] = uv[:, corner, :2]
        for sel, record, local, instance in self._groups(np.take(prim, shape)):
            matrices = self._instance_matrices(instance)
            rows = shape[sel]
            if isinstance(record, Curves):
                points = curve_geometry.placed(curve_geometry.control_points(
                    record, local, curve_geometry.segment_curves(record, local)), matrices)
                out[rows, P0:P0 + 3] = points[:, 1, :3]
                out[rows, E1:E1 + 3] = points[:, 2, :3] - points[:, 1, :3]
            else:
                out[rows, P0:P0 + 3] = point_geometry.centres(record, local, matrices)
        return out

    def tangent_frame(self, prim: np.ndarray, b1: np.ndarray, b2: np.ndarray):
        """The triangle table's, with zero tangents ("none": normal maps leave the normal as it is) on curves
        and points."""
        shape, tri = self._split(prim)
        if not len(shape):
            return self.triangles.tangent_frame(prim, b1, b2)
        frame = self.triangles.tangent_frame(np.take(prim, tri), np.take(b1, tri), np.take(b2, tri))
        if frame is None:
            return None
        n = len(prim)
        tangent, normal = [np.zeros(n, F32) for _ in range(3)], [np.zeros(n, F32) for _ in range(3)]
        sign = np.ones(n, F32)
        for k in range(3):
            tangent[k][tri], normal[k][tri] = frame[0][k], frame[2][k]
        sign[tri] = frame[1]
        return tuple(tangent), sign, tuple(normal)

    # ---- hits
    def _instance_matrices(self, instance: np.ndarray, times: np.ndarray | None = None) -> np.ndarray | None:
        """(n, 3, 4) world_from_object of each hit's instance (identity for -1), None when none is placed; a
        moving instance's at each hit's time (times (n,), or its frame matrix without them), interpolated as
        Cycles interpolates object motion (kernels.motion.interpolate: Cycles' object_fetch_transform_motion)."""
        if self._matrices is None or (instance < 0).all():
            return None
        m = np.take(self._matrices, np.maximum(instance, 0), axis=0)
        m[instance < 0] = np.eye(3, 4, dtype=F32)
        if times is not None:
            moving = self.layout.instance_motion
            for k in np.unique(instance[instance >= 0]):
                if moving[k] is not None:
                    sel = np.flatnonzero(instance == k)
                    m[sel] = motion.interpolate(moving[k], np.take(times, sel).astype(np.float64)).astype(F32)
        return m

    def shape_hits(self, prim: np.ndarray, u: np.ndarray, v: np.ndarray, origins: np.ndarray, dirs: np.ndarray,
                   t: np.ndarray, times: np.ndarray | None = None) -> "ShapeHits":
        """What hits on curves and points yield (prim all >= triangle_count; Embree's u, v; the rays' (n, 3)
        origins and directions, (n,) distances; (n,) the rays' shutter times, for records with motion keys, or
        None): ShapeHits."""
        n = len(prim)
        out = ShapeHits(n)
        for sel, record, local, instance in self._groups(prim):
            matrices = self._instance_matrices(instance, None if times is None else np.take(times, sel))
            o, d, tt = origins[sel], dirs[sel], t[sel]
            hit_times = None if times is None or record.motion is None else np.take(times, sel)
            if isinstance(record, Curves):
                curve = curve_geometry.segment_curves(record, local)
                own = at_times(record, hit_times, lambda r: curve_geometry.control_points(r, local, curve))
                points = curve_geometry.placed(own, matrices)
                shape = np.full(len(sel), curve_geometry.SHAPE_IDS[record.shape], np.int8)
                uu, across = np.take(u, sel).astype(F32), np.take(v, sel).astype(F32)
                p, ng, ns, dpdu, vv = curve_geometry.hit_geometry(points, shape, uu, across, o, d, tt)
                stretched = None if matrices is None else np.flatnonzero(~uniform_scales(matrices))
                if stretched is not None and len(stretched):
                    # Cycles sets a curve's normals up in object space where its object's transform is not a
                    # uniform scale (curve_shader_setup, SD_OBJECT_TRANSFORM_APPLIED unset), then turns them into
                    # world space by the inverse transpose; in world space they would differ.
                    k = stretched
                    p[k], ng[k], ns[k], dpdu[k], vv[k] = curve_geometry.object_space_hits(
                        own[k], matrices[k], shape[k], uu[k], across[k], o[k], d[k], tt[k])
                out.curve[sel] = True
                out.ribbon[sel] = record.shape == "RIBBON"
                out.b1[sel] = uu
                out.dpdu[sel] = dpdu
                out.v[sel] = vv
                # Curves Info's Thickness reads the stored radius (the object's on instances, as Cycles).
                out.radius[sel] = curve_geometry.radius_along(
                    at_times(record, hit_times, lambda r: curve_geometry.control_points(r, local, curve)), uu)
                # Huang's near field reads the frame's keys whatever the time (svm/closure.h fetches curve_keys,
                # never the motion steps).
                out.key_radius[sel] = out.radius[sel] if hit_times is None else curve_geometry.radius_along(
                    curve_geometry.control_points(record, local, curve), uu)
            else:
                centre = at_times(record, hit_times, lambda r: point_geometry.centres(r, local, matrices))
                p, ng = point_geometry.hit_geometry(centre, o, d, tt)
                ns = ng
                out.centre[sel] = centre
                # Point Info's Radius is the frame's, through the instance's transform at the hit's time (Cycles'
                # point_radius reads no motion step, intern/cycles/kernel/geom/point.h); Thickness above is at the
                # hit's time (curve_thickness reads the motion keys).
                out.radius[sel] = point_geometry.radii(record, local, matrices)
            out.p[sel], out.ng[sel], out.ns[sel] = p, ng, ns
        return out


class ShapeHits:
    """What n hits on curves and points yield, (n, 3) or (n,) float32: p, ng (not yet toward the viewer), ns,
    dpdu (zero on points), v (across a ribbon, else 0), b1 (u along a curve segment, 0 on points: the weight of
    corner 1 in PrimitiveTable.attribute's corners), curve, ribbon (bool), centre (a point's), radius (a point's
    Point Info Radius, a curve's radius at u at the hit's time), key_radius (a curve's radius at u from the frame's
    keys, radius where the curve does not move), kind (int8: 0 triangle, CURVE, POINT; SurfaceHit sets it)."""
    __slots__ = ("p", "ng", "ns", "dpdu", "v", "b1", "curve", "ribbon", "centre", "radius", "key_radius", "kind")

    def __init__(self, n: int):
        self.p, self.ng, self.ns = (np.zeros((n, 3), F32) for _ in range(3))
        self.dpdu, self.centre = np.zeros((n, 3), F32), np.zeros((n, 3), F32)
        self.v, self.b1, self.radius = np.zeros(n, F32), np.zeros(n, F32), np.zeros(n, F32)
        self.key_radius = np.zeros(n, F32)
        self.curve, self.ribbon = np.zeros(n, bool), np.zeros(n, bool)
        self.kind = np.zeros(n, np.int8)


def step_records(record) -> list:
    """A record with motion keys as one record per time step (its keys or points those of the step)."""
    if isinstance(record, Curves):
        return [dataclasses.replace(record, keys=keys, motion=None) for keys in record.motion]
    return [dataclasses.replace(record, points=points, motion=None) for points in record.motion]


def at_times(record, times: np.ndarray | None, read):
    """read(record) where the record is still (times None or no motion keys), else read at each hit's time: the
    two neighbouring steps' values mixed linearly, as Embree interpolates time steps and as Cycles' motion_keys
    and point motion read them (step = min(floor(t (S - 1)), S - 2), intern/cycles/scene/hair.cpp)."""
    if times is None or record.motion is None:
        return read(record)
    count = len(record.motion)
    position = np.asarray(times, np.float32) * F32(count - 1)
    step = np.clip(position.astype(np.int64), 0, count - 2)
    f = (position - step.astype(F32)).astype(F32)
    steps = step_records(record)
    out = None
    for s in np.unique(step):
        a, b = read(steps[s]), read(steps[s + 1])
        if out is None:
            out = np.empty(a.shape, F32)
        sel = np.flatnonzero(step == s)
        w = f[sel].reshape((-1,) + (1,) * (a.ndim - 1))
        out[sel] = ((F32(1) - w) * a[sel] + w * b[sel]).astype(F32)
    return out


def _corners(record, local: np.ndarray, values: np.ndarray) -> np.ndarray:
    """(n, 3, C) an attribute's values at the three 'corners' of curve segments or points (PrimitiveTable.attribute)."""
    if isinstance(record, Curves):
        curve = curve_geometry.segment_curves(record, local)
        if record.per_key(values):
            k0 = local + curve
            f0, f1 = np.take(values, k0, axis=0), np.take(values, k0 + 1, axis=0)
            return np.stack([f0, f1, f0], axis=1)
        value = np.take(values, curve, axis=0)
    else:
        value = np.take(values, local, axis=0)
    return np.repeat(value[:, None, :], 3, axis=1)



def element_twins(record) -> np.ndarray | None:
    """(C,) int64 per curve (or point) of a record the next one in a group of exact copies (same keys, radii
    included, in the same order; same centre and radius), cyclically; -1 for one without copies. None when the
    record has no copies at all."""
    if isinstance(record, Curves):
        n = record.count
        if n < 2:
            return None
        bits = np.ascontiguousarray(record.keys).view(np.uint32).astype(np.uint64)
        per_key = (bits[:, 0] * np.uint64(0x9E3779B97F4A7C15)) ^ (bits[:, 1] * np.uint64(0xC2B2AE3D27D4EB4F)) ^ \
            (bits[:, 2] * np.uint64(0x165667B19E3779F9)) ^ (bits[:, 3] * np.uint64(0x27D4EB2F165667C5))
        sizes = np.diff(record.offsets).astype(np.int64)
        place = np.arange(len(bits), dtype=np.int64) - np.repeat(record.offsets[:-1].astype(np.int64), sizes)
        per_key = per_key ^ (place.astype(np.uint64) * np.uint64(0x85EBCA77C2B2AE63))
        with np.errstate(over="ignore"):
            print_ = np.add.reduceat(per_key, record.offsets[:-1].astype(np.int64)) + sizes.astype(np.uint64)
    else:
        n = record.count
        if n < 2:
            return None
        print_ = np.ascontiguousarray(record.points).view(np.uint64).reshape(n, 2)
        print_ = print_[:, 0] * np.uint64(0x9E3779B97F4A7C15) ^ print_[:, 1]
    # Most records have no copies: a plain sort tells, 8x quicker than the stable argsort that orders the groups.
    ranked = np.sort(print_)
    if not (ranked[1:] == ranked[:-1]).any():
        return None
    order = np.argsort(print_, kind="stable")
    ranked = print_[order]
    same = np.flatnonzero(ranked[1:] == ranked[:-1])
    if not len(same):
        return None
    twins = np.full(n, -1, np.int64)
    start = np.concatenate([[True], ranked[1:] != ranked[:-1]])
    group = np.cumsum(start) - 1
    first = np.flatnonzero(start)
    size = np.diff(np.concatenate([first, [n]]))
    members = np.flatnonzero(size[group] >= 2)
    for g in np.unique(group[members]):      # groups of copies are few: checked exactly, one by one
        ids = order[first[g]:first[g] + size[g]]
        exact = [i for i in ids if _same_element(record, ids[0], i)]
        if len(exact) >= 2:
            twins[exact] = np.roll(exact, -1)
    return twins if (twins >= 0).any() else None


def _same_element(record, a: int, b: int) -> bool:
    if isinstance(record, Curves):
        ka = record.keys[record.offsets[a]:record.offsets[a + 1]]
        kb = record.keys[record.offsets[b]:record.offsets[b + 1]]
        return len(ka) == len(kb) and bool(np.array_equal(ka, kb))
    return bool(np.array_equal(record.points[a], record.points[b]))
