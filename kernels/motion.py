"""Transform motion blur and the shutter, as Cycles 5.0 does them.

Each camera path carries one time in [0, 1] over the shutter (Cycles' ray->time, shared by every bounce
and shadow ray of the path). The camera and every moving object hold K >= 2 motion steps, world_from_object
matrices sampled at evenly spaced times over the shutter; at a path's time a matrix is rebuilt from the
two neighbouring steps:

    decompose    matrices (K, 4, 4) -> Decomposed: rotation quaternion, translation, scale/shear per step
                 (Cycles util/transform.cpp: transform_motion_decompose, transform_decompose)
    interpolate  Decomposed, time (N,) -> (N, 3, 4): slerp the rotation (nlerp when nearly parallel), lerp
                 the rest, compose  M = T R S  (util/transform.h: transform_motion_array_interpolate)
    affine_inverse (N, 3, 4) -> (N, 3, 4): object_from_world for the same lanes (transform_inverse)

The shutter: Blender's shutter curve (render.motion_blur_shutter_curve) is turned into Cycles' 256-entry
inverse-CDF table (scene/camera.cpp: shutter_curve_eval, util/math_cdf: util_cdf_inverted), and a path's
time is a linear lookup in that table (kernel/camera/camera.h: camera_sample), optionally mixed with a
rolling shutter that makes time depend on the pixel row.

Quirks of Cycles kept on purpose, for parity (each is pinned by a test):
- a flat shutter curve does not give the identity: the table maps u to 255 (255 u + 0.5) / 256^2, so times
  span [0.0019, 0.9941] and their mean is 0.498, not 0.5;
- shutter_curve_eval reads the curve at index  x * len - 1  (not x * (len - 1)): the curve is stretched by
  about 1 %, and its first sample (x = 0) takes the curve's last value;
- a mirrored (negative determinant) step keeps its shear terms unsigned while the rotation and the scale
  diagonal are negated, so a step that is both mirrored and sheared does not rebuild its own matrix
  (the shear terms come back negated). Cycles renders that shape; so do we.

Arithmetic: Cycles works in float32; decompose and the shutter table are computed in float64 and stored in
the caller's float dtype, interpolate and the lookups run in the dtype they are given.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

SHUTTER_TABLE_SIZE = 256  # Cycles kernel/types.h SHUTTER_TABLE_SIZE
NLERP_COS = 0.9995  # Cycles quat_interpolate: below this angle slerp is ill-conditioned, nlerp instead


class Decomposed(NamedTuple):
    """Motion steps of one transform, decomposed as Cycles stores them (world = T R S object)."""
    rotation: np.ndarray     # (K, 4) quaternion (x, y, z, w); signs matched so neighbours take the short way
    translation: np.ndarray  # (K, 3)
    scale: np.ndarray        # (K, 3, 3) upper triangular: scale on the diagonal, shear above it


# ---------------------------------------------------------------- quaternions

def matrix_to_quaternion(rot: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) quaternions (x, y, z, w), float64.
    Cycles' transform_to_quat: the trace branch when the trace is positive, else the largest diagonal."""
    m = np.asarray(rot, np.float64)
    trace = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]

    # Trace branch (computed on every lane, kept where the trace is positive).
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.sqrt(trace + 1.0)
        h = 0.5 / s
        q_trace = np.stack([(m[..., 2, 1] - m[..., 1, 2]) * h,
                            (m[..., 0, 2] - m[..., 2, 0]) * h,
                            (m[..., 1, 0] - m[..., 0, 1]) * h,
                            s / 2.0], axis=-1)

    # Largest-diagonal branch: i is Cycles' pick (first of equals wins), j and k follow cyclically.
    diag = np.stack([m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]], axis=-1)
    i = np.where(diag[..., 1] > diag[..., 0], 1, 0)
    i = np.where(diag[..., 2] > np.take_along_axis(diag, i[..., None], -1)[..., 0], 2, i)
    j = (i + 1) % 3
    k = (j + 1) % 3

    def at(r, c):
        rows = np.take_along_axis(m, r[..., None, None], -2)[..., 0, :]
        return np.take_along_axis(rows, c[..., None], -1)[..., 0]

    with np.errstate(invalid="ignore"):
        s = np.sqrt(at(i, i) - (at(j, j) + at(k, k)) + 1.0)
    half_inv = np.divide(0.5, s, out=np.zeros_like(s), where=s != 0.0)
    q_diag = np.zeros(m.shape[:-2] + (4,))
    np.put_along_axis(q_diag, i[..., None], (s * 0.5)[..., None], -1)
    np.put_along_axis(q_diag, j[..., None], ((at(j, i) + at(i, j)) * half_inv)[..., None], -1)
    np.put_along_axis(q_diag, k[..., None], ((at(k, i) + at(i, k)) * half_inv)[..., None], -1)
    q_diag[..., 3] = (at(k, j) - at(j, k)) * half_inv

    return np.where((trace > 0.0)[..., None], q_trace, q_diag)


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions (x, y, z, w) -> (..., 3, 3), in q's dtype. Not renormalised, as in Cycles'
    transform_compose."""
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    one, two = q.dtype.type(1), q.dtype.type(2)
    return np.stack([
        np.stack([one - two * (y * y + z * z), two * (x * y - w * z), two * (x * z + w * y)], -1),
        np.stack([two * (x * y + w * z), one - two * (x * x + z * z), two * (y * z - w * x)], -1),
        np.stack([two * (x * z - w * y), two * (y * z + w * x), one - two * (x * x + y * y)], -1),
    ], -2)


def quaternion_interpolate(q1: np.ndarray, q2: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N, 4), (N, 4), (N,) -> (N, 4): Cycles' CPU quat_interpolate. Slerp, or a normalised lerp when
    cos(angle) > 0.9995. No sign check here: decompose already matched the signs of neighbours."""
    dtype = q1.dtype.type
    t = t[:, None]
    cos = np.sum(q1 * q2, axis=-1, keepdims=True)
    lerp = (dtype(1) - t) * q1 + t * q2
    nlerp = lerp / np.linalg.norm(lerp, axis=-1, keepdims=True)
    theta = np.arccos(np.clip(cos, dtype(-1), dtype(1)))
    perp = q2 - q1 * cos
    perp_len = np.linalg.norm(perp, axis=-1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):  # perp is ~0 only on nlerp lanes
        perp = perp / perp_len
    slerp = q1 * np.cos(theta * t) + perp * np.sin(theta * t)
    return np.where(cos > dtype(NLERP_COS), nlerp, slerp)


# ---------------------------------------------------------------- decompose / compose

def decompose(matrices: np.ndarray) -> Decomposed:
    """(K, 4, 4) or (K, 3, 4) world_from_object matrices of K motion steps -> Decomposed in their float
    dtype (float64 for integer input).

    Per step (Cycles transform_decompose): translation from the last column; the 3x3 part is split by
    Gram-Schmidt on its columns into Q (orthonormal) times S (upper triangular: scale, shear); if Q is a
    reflection, Q and S's diagonal are negated (shear left alone, as Cycles does). Then, over the steps
    (transform_motion_decompose): each quaternion is negated if it points away from the previous one, and
    a step whose three scales are all zero borrows its neighbour's rotation (previous, else next)."""
    m = np.asarray(matrices)
    if m.ndim != 3 or m.shape[1] not in (3, 4) or m.shape[2] != 4:
        raise ValueError(f"expected (K, 4, 4) or (K, 3, 4) matrices, got {m.shape}")
    return decompose_many([m])[0]


def decompose_many(keys) -> list:
    """decompose of each of a sequence of (K, 4, 4) or (K, 3, 4) step matrices (K may differ), the steps of all
    of them decomposed at once: a particle system's hundreds of moving instances cost one pass."""
    keys = [np.asarray(k) for k in keys]
    if not keys:
        return []
    dtypes = [k.dtype if k.dtype in (np.float32, np.float64) else np.dtype(np.float64) for k in keys]
    m = np.concatenate([k.astype(np.float64)[:, :3, :4] for k in keys])
    translation = m[:, :, 3].copy()
    c0, c1, c2 = m[:, :, 0].copy(), m[:, :, 1].copy(), m[:, :, 2].copy()

    def unit(c):
        length = np.linalg.norm(c, axis=-1)
        return np.divide(c, length[:, None], out=np.zeros_like(c), where=length[:, None] != 0.0), length

    c0, sx = unit(c0)
    shear_xy = np.sum(c0 * c1, -1)
    c1 = c1 - shear_xy[:, None] * c0
    c1, sy = unit(c1)
    shear_xz = np.sum(c0 * c2, -1)
    c2 = c2 - shear_xz[:, None] * c0
    shear_yz = np.sum(c1 * c2, -1)
    c2 = c2 - shear_yz[:, None] * c1
    c2, sz = unit(c2)

    q_mat = np.stack([c0, c1, c2], axis=-1)
    mirrored = np.sum(np.cross(c0, c1) * c2, -1) < 0.0
    sign = np.where(mirrored, -1.0, 1.0)
    q_mat = q_mat * sign[:, None, None]
    sx, sy, sz = sx * sign, sy * sign, sz * sign

    scale = np.zeros((len(m), 3, 3))
    scale[:, 0, 0], scale[:, 1, 1], scale[:, 2, 2] = sx, sy, sz
    scale[:, 0, 1], scale[:, 0, 2], scale[:, 1, 2] = shear_xy, shear_xz, shear_yz

    rotations = matrix_to_quaternion(q_mat)
    degenerate_all = (sx == 0.0) & (sy == 0.0) & (sz == 0.0)
    out = []
    start = 0
    for k, dtype in zip(keys, dtypes):
        rows = slice(start, start + len(k))
        start += len(k)
        rotation = rotations[rows]
        for step in range(1, len(rotation)):  # sequential: each step is matched to the already-matched previous
            if np.dot(rotation[step - 1], rotation[step]) < 0.0:
                rotation[step] = -rotation[step]
        for step in np.flatnonzero(degenerate_all[rows]):
            if step > 0:
                rotation[step] = rotation[step - 1]
            elif step < len(rotation) - 1:
                rotation[step] = rotation[step + 1]
        out.append(Decomposed(rotation.astype(dtype), translation[rows].astype(dtype), scale[rows].astype(dtype)))
    return out


def compose(rotation: np.ndarray, translation: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """(..., 4), (..., 3), (..., 3, 3) -> (..., 3, 4) matrices [R S | t] (Cycles transform_compose)."""
    linear = quaternion_to_matrix(rotation) @ scale
    return np.concatenate([linear, translation[..., :, None]], axis=-1)


def interpolate(decomposed: Decomposed, time: np.ndarray) -> np.ndarray:
    """World_from_object (N, 3, 4) at each path's time (N,) in [0, 1], in the decomposed dtype.

    Step index  s = min(floor(time (K-1)), K-2),  fraction  f = time (K-1) - s  (Cycles clamps only the
    top; times below 0 are clamped to step 0 here). Rotation: quaternion_interpolate; translation and
    scale/shear: (1 - f) a + f b. A single step (K = 1) is returned as is for every lane."""
    time = np.asarray(time)
    stacked = Decomposed(*(np.asarray(part)[None] for part in decomposed))
    return interpolate_many(stacked, np.zeros(len(time), np.int64), time)


def stack_by_steps(decomposed: list) -> list:
    """The motions of many objects grouped by their step count, for interpolate_many: [(members (O_K,) int64, their
    Decomposed stacked (O_K, K, ...))] per step count K."""
    counts = np.array([len(d.rotation) for d in decomposed], np.int64)
    out = []
    for count in np.unique(counts):
        members = np.flatnonzero(counts == count)
        out.append((members, Decomposed(*(np.stack([decomposed[i][k] for i in members]) for k in range(3)))))
    return out


def interpolate_many(stacked: Decomposed, which: np.ndarray, time: np.ndarray) -> np.ndarray:
    """World_from_object (N, 3, 4) of the objects which (N,) of a stack (stack_by_steps: (O, K, ...) arrays) at
    times (N,), each as interpolate describes, row by row."""
    rotation, translation, scale = stacked
    dtype = rotation.dtype.type
    time = np.asarray(time).astype(dtype, copy=False)
    count = rotation.shape[1]
    if count == 1:
        return compose(rotation[which, 0], translation[which, 0], scale[which, 0])
    max_step = count - 1
    position = time * dtype(max_step)
    step = np.clip(position.astype(np.int64), 0, max_step - 1)
    f = position - step.astype(dtype)
    a, b = step, step + 1
    f1 = f[:, None]
    q = quaternion_interpolate(rotation[which, a], rotation[which, b], f)
    t = (dtype(1) - f1) * translation[which, a] + f1 * translation[which, b]
    s = (dtype(1) - f1[:, :, None]) * scale[which, a] + f1[:, :, None] * scale[which, b]
    return compose(q, t, s)


def affine_inverse(m: np.ndarray) -> np.ndarray:
    """(..., 3, 4) affine matrices -> their inverses (..., 3, 4), same dtype: adjugate over determinant,
    as Cycles' transform_inverse. A singular 3x3 gets 1e-8 added to its diagonal first, and if still
    singular the determinant is taken as FLT_MAX (Cycles' fallback for zero-scale steps)."""
    dtype = m.dtype.type
    x, y, z, w = m[..., :, 0], m[..., :, 1], m[..., :, 2], m[..., :, 3]
    det = np.sum(x * np.cross(y, z), -1)
    singular = det == 0.0
    if np.any(singular):
        x, y, z = x.copy(), y.copy(), z.copy()
        x[singular, 0] += dtype(1e-8)
        y[singular, 1] += dtype(1e-8)
        z[singular, 2] += dtype(1e-8)
        det = np.sum(x * np.cross(y, z), -1)
        det = np.where(det == 0.0, dtype(np.finfo(np.float32).max), det)
    inv_rows = np.stack([np.cross(y, z), np.cross(z, x), np.cross(x, y)], axis=-2) / det[..., None, None]
    inv_t = -np.sum(inv_rows * w[..., None, :], -1)
    return np.concatenate([inv_rows, inv_t[..., None]], axis=-1).astype(dtype, copy=False)


# ---------------------------------------------------------------- shutter

def shutter_curve_eval(x: np.ndarray, curve: np.ndarray) -> np.ndarray:
    """Cycles' shutter_curve_eval, quirks included: the curve's n samples are read at index x n - 1
    (linear between samples); an index below 0 or at the end gives the last sample. Empty curve: 1."""
    curve = np.asarray(curve, np.float64)
    x = np.asarray(x, np.float64)
    n = len(curve)
    if n == 0:
        return np.ones_like(x)
    position = np.clip(x, 0.0, 1.0) * n - 1.0
    index = np.trunc(position).astype(np.int64)  # C's (int) cast truncates toward zero
    frac = position - index
    inside = (index >= 0) & (index < n - 1)  # index -1 compares as a huge size_t in Cycles: falls out
    lo = np.clip(index, 0, n - 1)
    hi = np.clip(index + 1, 0, n - 1)
    return np.where(inside, curve[lo] + frac * (curve[hi] - curve[lo]), curve[n - 1])


def shutter_table(curve: np.ndarray, dtype=np.float32) -> np.ndarray:
    """(SHUTTER_TABLE_SIZE,) inverse CDF of the shutter curve: Cycles' util_cdf_inverted(256, 0, 1, ...).

    curve: the shutter curve sampled over [0, 1] (Blender gives 257 samples at i / 256, see the fact sheet);
    only its shape matters. The CDF is a running sum of |curve| at 255 points x = i / 254, normalised; the
    inverse is read at levels (i + 0.5) / 256 and stored as (cdf index + fraction) / 256."""
    size = SHUTTER_TABLE_SIZE
    x = np.arange(size - 1, dtype=np.float64) / (size - 2)
    density = np.abs(shutter_curve_eval(x, curve))
    cdf = np.concatenate([[0.0], np.cumsum(density)])
    total = cdf[-1]
    cdf = cdf * (0.0 if total == 0.0 else 1.0 / total)
    cdf[-1] = 1.0

    level = (np.arange(size) + 0.5) / size
    index = np.searchsorted(cdf, level, side="right") - 1  # std::upper_bound - 1
    inside = index < len(cdf) - 1
    idx = np.minimum(index, len(cdf) - 2)
    frac = np.where(inside, (level - cdf[idx]) / (cdf[idx + 1] - cdf[idx]), 0.0)
    index = np.where(inside, index, size)
    return ((index + frac) / size).astype(dtype)


def lookup_table(uc: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Cycles' lookup_table_read: linear interpolation in a table spanning [0, 1], uc clamped."""
    table = np.asarray(table)
    dtype = table.dtype.type
    last = len(table) - 1
    x = np.clip(np.asarray(uc).astype(dtype, copy=False), dtype(0), dtype(1)) * dtype(last)
    index = np.minimum(x.astype(np.int64), last)
    f = x - index.astype(dtype)
    return (dtype(1) - f) * table[index] + f * table[np.minimum(index + 1, last)]


def sample_time(uc: np.ndarray, table: np.ndarray, row: np.ndarray | None = None, height: int = 0,
                rolling_duration: float | None = None) -> np.ndarray:
    """Path times (N,) in [0, 1] from uniform numbers uc (N,), as Cycles' camera_sample (motion blur on).

    Without rolling shutter (rolling_duration None): the shutter table lookup. With it (Cycles'
    rolling_shutter_type TOP), row (N,) is the pixel row, 0 at the top of the full frame of `height` rows;
    Cycles counts y from the bottom and takes the row's own time  1 - y / height  = (row + 1) / height,
    then mixes:  (time - 0.5) d + (row time - 0.5)(1 - d) + 0.5  with d = rolling_duration, or the row
    time alone when d = 0. (Motion blur off: Cycles uses time 0.5 for every path; not this function.)"""
    time = lookup_table(uc, table)
    if rolling_duration is None:
        return time
    dtype = time.dtype.type
    y = dtype(height - 1) - np.asarray(row).astype(dtype)
    row_time = dtype(1) - y / dtype(height)
    if rolling_duration == 0.0:
        return row_time
    d = dtype(rolling_duration)
    half = dtype(0.5)
    return (time - half) * d + (row_time - half) * (dtype(1) - d) + half
