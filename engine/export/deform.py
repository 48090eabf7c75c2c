"""Deformation motion blur of meshes: the triangles of a mesh object that deforms over the shutter get their corners
and normals at each motion step (SceneArrays.deform_ids, deform_positions, deform_normals), which the kernel makes
Embree's time steps (kernels.embree, kernels.accel) and reads at each hit's time (kernels.geometry.deform), as
Cycles' motion triangles (intern/cycles/blender/mesh.cpp sync_mesh_motion: ATTR_STD_MOTION_VERTEX_POSITION and
_NORMAL; intern/cycles/bvh/embree.cpp: a triangle geometry with time steps; kernel/geom/motion_triangle.h).

The steps are read by motion.sample_motion (mesh_steps at each step's subframe and at the frame). As Cycles: a mesh
whose steps all equal its frame has no motion; a step whose vertex count differs from the frame's takes the frame's
vertices (sync_mesh_motion: "Topology differs"), so a mesh that changes its vertex count at every step renders
without deformation blur (a warning names it). The steps are in object space; they go to world space by the
object's matrix at the frame, the one its stored triangles were made with (for a moving object its
motion_reference, kernels.moving.Moving brings them back to object space). Meshes the export changes after reading
them (true displacement, adaptive subdivision) keep their transform motion only, with a warning naming them.
"""
from __future__ import annotations

import numpy as np

from ...kernels.geometry.instances import normal_matrices


def deform_fields(samples, geometry, warnings: list) -> dict:
    """SceneArrays' deform_ids, deform_positions and deform_normals for an exported geometry (export_geometry's
    Geometry), from motion.MotionSamples; {} when no mesh deforms."""
    if samples is None or not samples.meshes or geometry.instance_keys is None or geometry.object_ids is None:
        return {}
    rows = {key: row for row, key in enumerate(geometry.instance_keys)}
    object_ids = geometry.object_ids
    parts = []   # (triangle numbers, (S, n, 3, 3) corners, (S, n, 3, 3) normals) in the stored space
    for key, steps in samples.meshes.items():
        row = rows.get(key)
        if row is None:
            continue
        name = key[0] if isinstance(key, tuple) else str(key)
        count, corners, normals = samples.meshes_frame[key]
        ids = np.flatnonzero(object_ids == row)
        if not len(ids):
            continue
        matrix = np.asarray(geometry.instance_matrices[row], np.float64)
        stored = np.asarray(geometry.positions[ids], np.float64).reshape(-1, 3)
        if len(ids) * 3 != len(corners) or not _same(stored, _placed(corners, matrix)):
            warnings.append(f"Object '{name}': deformation motion blur is not supported with true displacement or "
                            f"adaptive subdivision; rendered with its transform motion only")
            continue
        kept = [(c, n) if (k == count and c is not None and len(c) == len(corners)) else None for k, c, n in steps]
        if all(k is None for k in kept):
            warnings.append(f"Object '{name}': its mesh changes its vertex count during the shutter; rendered "
                            f"without deformation motion blur (as Cycles)")
            continue
        if any(k is None for k in kept):
            warnings.append(f"Object '{name}': its mesh changes its vertex count at some motion steps; those take "
                            f"the frame's vertices (as Cycles)")
        kept = [(corners, normals) if k is None else k for k in kept]
        if all(np.array_equal(c, corners) for c, _ in kept):
            continue   # no deformation: Cycles drops the motion attribute
        normal = normal_matrices(matrix[None, :3, :3])[0].astype(np.float64)
        positions = np.stack([_placed(c, matrix) for c, _ in kept]).reshape(len(kept), -1, 3, 3)
        turned = np.stack([np.asarray(n, np.float64) @ normal.T for _, n in kept]).reshape(len(kept), -1, 3, 3)
        if not (np.isfinite(positions).all() and np.isfinite(turned).all()):
            continue
        parts.append((ids, positions.astype(np.float32), turned.astype(np.float32)))
    if not parts:
        return {}
    steps = max(len(p) for _, p, _ in parts)
    deform_ids = np.full(len(object_ids), -1, np.int32)
    first = 0
    positions, normals = [], []
    for ids, p, n in parts:
        deform_ids[ids] = np.arange(first, first + len(ids), dtype=np.int32)
        first += len(ids)
        positions.append(_resampled(p, steps))
        normals.append(_resampled(n, steps))
    return dict(deform_ids=deform_ids, deform_positions=np.ascontiguousarray(np.concatenate(positions, axis=1)),
                deform_normals=np.ascontiguousarray(np.concatenate(normals, axis=1)))


def vector_deform_fields(samples, geometry, warnings: list) -> dict:
    """SceneArrays' vector_deform_ids and vector_deform for an exported geometry, from motion.VectorSamples: the
    deforming triangles' world-space corners at the previous and next frame, each step's object-space corners moved
    by the object's matrix at that frame (Cycles' motion pass: kernel/geom/primitive.h
    primitive_motion_data_without_camera reads ATTR_STD_MOTION_VERTEX_POSITION at the hit's barycentrics and
    applies the object's motion-pass transforms, scene/object.cpp: its matrices at frame -1 and +1 when the mesh
    has vertex motion); {} when no mesh deforms."""
    if samples is None or not samples.meshes or geometry.instance_keys is None or geometry.object_ids is None:
        return {}
    rows = {key: row for row, key in enumerate(geometry.instance_keys)}
    deform_ids = np.full(len(geometry.object_ids), -1, np.int32)
    parts, first = [], 0
    for key, (before, after) in samples.meshes.items():
        row = rows.get(key)
        if row is None:
            continue
        ids = np.flatnonzero(geometry.object_ids == row)
        corners = samples.meshes_frame[key]
        matrix = np.asarray(geometry.instance_matrices[row], np.float64)
        if not len(ids):
            continue
        if len(ids) * 3 != len(corners) or not _same(np.asarray(geometry.positions[ids], np.float64).reshape(-1, 3),
                                                     _placed(corners, matrix)):
            name = key[0] if isinstance(key, tuple) else str(key)
            warnings.append(f"Object '{name}': the Vector pass does not follow its deformation with true "
                            f"displacement or adaptive subdivision; its vectors follow its transform only")
            continue
        pre, post = samples.objects.get(key, (matrix, matrix))
        steps = np.stack([_placed(before, np.asarray(pre, np.float64)),
                          _placed(after, np.asarray(post, np.float64))]).reshape(2, -1, 3, 3)
        if not np.isfinite(steps).all():
            continue
        deform_ids[ids] = np.arange(first, first + len(ids), dtype=np.int32)
        first += len(ids)
        parts.append(steps.astype(np.float32))
    if not parts:
        return {}
    return dict(vector_deform_ids=deform_ids,
                vector_deform=np.ascontiguousarray(np.concatenate(parts, axis=1)))


def _placed(corners: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """(n, 3) float64 object-space points in world space by a (4, 4) matrix."""
    return np.asarray(corners, np.float64) @ matrix[:3, :3].T + matrix[:3, 3]


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    """The stored float32 corners are the frame's read moved by the matrix, within float32 rounding."""
    scale = max(float(np.abs(b).max()) if b.size else 0.0, 1e-30)
    return a.shape == b.shape and bool(np.allclose(a, b, rtol=0, atol=scale * 1e-5))


def _resampled(steps: np.ndarray, count: int) -> np.ndarray:
    """(count, ...) float32 steps over the shutter mixed linearly from (S, ...) steps (the kernel's interpolation,
    so the motion is unchanged: step counts 2^s + 1 nest)."""
    if len(steps) == count:
        return steps
    position = np.linspace(0.0, 1.0, count) * (len(steps) - 1)
    lo = np.minimum(position.astype(np.int64), len(steps) - 2)
    f = (position - lo).astype(np.float32).reshape((-1,) + (1,) * (steps.ndim - 1))
    return ((1 - f) * steps[lo] + f * steps[lo + 1]).astype(np.float32)
