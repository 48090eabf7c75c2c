"""The normals and tangents a closure node is given, as Cycles makes them.

- normal_map: the Normal Map node (`svm_node_normal_map`, kernel/svm/tex_coord.h).
- uv_tangent: the Tangent node's UV Map direction (`svm_node_tangent`, same file).
- valid_specular_normal: `maybe_ensure_valid_specular_reflection` (kernel/closure/bsdf_util.h), the tilt
  of a specular closure's normal toward the geometric normal that keeps its mirror direction above the
  surface ("Bump Map Correction").
- rotate_about: `rotate_around_axis` (util/math_float3.h), the anisotropic rotation.

Vectors are (x, y, z) tuples of (n,) float32 arrays; colours (3, n).
"""
from __future__ import annotations

import numpy as np

from ..vec import F32, HALF, ONE, ZERO, cross_xyz, dot_xyz, normalize_xyz


# The first Blender whose Cycles brings a tangent-space normal map's frame normal to unit length (object_frame).
NORMAL_MAP_OBJECT_FRAME_FROM = (5, 1)


def normal_map(color: np.ndarray, strength: np.ndarray, space: str, ns, backfacing: np.ndarray, frame,
               invert_green: bool = False, object_to_world=None, uneven=None, object_frame: bool = False):
    """The Normal Map node's Normal at n hits.

    color : (3, n) the node's Color, each axis stored as (x + 1) / 2. strength : (n,).
    space : TANGENT, WORLD or BLENDER_WORLD (kernels.scene.NORMAL_MAP_SPACES), or OBJECT or BLENDER_OBJECT (the
        program's Normal Map op: object_to_world, (n, 3) object-space normals -> unit world ones, the hits'
        object's normal transform; None where there is no object, a world's, whose object space is world space).
    ns : the hits' unit shading normal, flipped toward the viewer on back faces (Cycles' sd->N).
    frame : (tangent, sign, normal) of SurfaceHit.tangent_frame, unnormalized and not flipped, or None
        (no tangents: the normal is left as it is, as Cycles does without its tangent attribute).
    invert_green : the DirectX convention (Blender 5.1+): the green axis is negated, in every space.
    uneven : for TANGENT, (rows, world_from_object, object_from_world) of the hits whose objects are scaled
        unevenly ((k,) and (k, 3, 3) each; ShadingData.uneven_linear), or None: there the map is combined in
        object space and turned to world space as a normal, as Cycles evaluates it (svm_node_normal_map; probed
        in 5.0 and 5.3); elsewhere the world-space frame gives the same direction.
    object_frame : TANGENT as the Cycles of Blender 5.1 and later (9d939e158, "normal map wrong renders after
        corner normal changes"): the frame's normal brought to unit length (triangle_smooth_normal_unnormalized_
        object_space normalizes it; the tangent stays as interpolated). False: 5.0's, the interpolated normal as
        it is.
    """
    c = F32(2.0) * (np.asarray(color, F32) - HALF)
    if invert_green:
        c[1] = -c[1]
    strength = np.asarray(strength, F32)
    if space == "TANGENT":
        if frame is None:
            return ns
        t, sign, n = frame
        if object_frame:
            n = normalize_xyz(n)
            frame = (t, sign, n)
        cx, cy = c[0] * strength, c[1] * strength
        cz = ONE + (c[2] - ONE) * np.clip(strength, 0.0, 1.0)
        b = _scale(cross_xyz(n, t), sign)
        out = normalize_xyz(tuple(cx * t[k] + cy * b[k] + cz * n[k] for k in range(3)))
        if uneven is not None and len(uneven[0]):
            out = _in_object_space(out, (cx, cy, cz), frame, uneven)
        out = _flip(out, backfacing)
    else:
        if space in ("BLENDER_WORLD", "BLENDER_OBJECT"):  # Blender's convention: y and z point the other way
            c = np.stack([c[0], -c[1], -c[2]])
        if space in ("OBJECT", "BLENDER_OBJECT") and object_to_world is not None:
            # Cycles' object_normal_transform (normalized), before the back-face flip (svm_node_normal_map).
            c = np.asarray(object_to_world(np.ascontiguousarray(c.T)), F32).T
        out = _flip(normalize_xyz(tuple(c)), backfacing)
        weak = strength != ONE
        if weak.any():
            s = np.maximum(strength, ZERO)
            blended = normalize_xyz(tuple(ns[k] + (out[k] - ns[k]) * s for k in range(3)))
            out = tuple(np.where(weak, blended[k], out[k]) for k in range(3))
    length2 = dot_xyz(out, out)
    bad = ~(np.isfinite(length2) & (length2 > ZERO))
    if bad.any():
        out = tuple(np.where(bad, ns[k], out[k]) for k in range(3))
    return tuple(np.asarray(c, F32) for c in out)


def _in_object_space(out, c, frame, uneven):
    """out with the rows of uneven (rows, M, A) replaced by the map combined in object space: the world frame
    brought back to object space (tangent by A = M^-1, normal by M^T, both to unit length, the bitangent's sign
    unmirrored by det M), N_o = cx T_o + cy B_o + cz N_o, then A^T N_o (a normal's transform), to unit length."""
    rows, m, a = uneven
    t, sign, n = frame
    tw = np.stack([np.take(x, rows) for x in t], axis=1).astype(np.float64)
    nw = np.stack([np.take(x, rows) for x in n], axis=1).astype(np.float64)
    to = np.einsum("kij,kj->ki", a, tw)
    no = np.einsum("kji,kj->ki", m, nw)
    with np.errstate(invalid="ignore", divide="ignore"):
        to /= np.linalg.norm(to, axis=1, keepdims=True)
        no /= np.linalg.norm(no, axis=1, keepdims=True)
        bo = np.cross(no, to) * (np.take(sign, rows) * np.sign(np.linalg.det(m)))[:, None]
        cx, cy, cz = (np.take(x, rows).astype(np.float64)[:, None] for x in c)
        world = np.einsum("kji,kj->ki", a, cx * to + cy * bo + cz * no)
        world /= np.linalg.norm(world, axis=1, keepdims=True)
    out = tuple(np.array(x, F32) for x in out)
    for k in range(3):
        out[k][rows] = world[:, k]
    return out


def uneven_scale(linear: np.ndarray) -> np.ndarray:
    """(K,) bool: which 3x3 matrices (K, 3, 3) are not a rotation (or a mirroring) times one scale, their Gram
    matrix M^T M not a multiple of the identity: a normal map then depends on the space it is combined in."""
    g = np.einsum("kai,kaj->kij", linear, linear)
    s = np.trace(g, axis1=1, axis2=2) / 3.0
    return np.abs(g - s[:, None, None] * np.eye(3)).max(axis=(1, 2)) > 1e-5 * np.abs(s)


def uv_tangent(frame, ns):
    """The Tangent node's UV Map tangent: the interpolated tangent made orthogonal to the shading normal ns,
    N x normalize(T x N). NaN where the tangent is zero or along N (the closure then takes an arbitrary
    tangent); None without tangents."""
    if frame is None:
        return None
    t = frame[0]
    with np.errstate(invalid="ignore", divide="ignore"):
        side = cross_xyz(t, ns)
        length = np.sqrt(dot_xyz(side, side))
        side = tuple(np.where(length > F32(1e-12), c / length, np.float32(np.nan)) for c in side)
    return tuple(np.asarray(c, F32) for c in cross_xyz(ns, side))


def valid_specular_normal(ng, wo, n):
    """Cycles' ensure_valid_specular_reflection: where the mirror of wo about n falls below
    min(0.9 ng.wo, 0.01) over the geometric normal ng, n tilted toward ng just enough to lift it there.
    ng faces the viewer (wo . ng >= 0); all unit vectors."""
    iz = dot_xyz(wo, ng)
    threshold = np.minimum(F32(0.9) * iz, F32(0.01))
    i_n = dot_xyz(wo, n)
    r_z = F32(2.0) * i_n * dot_xyz(n, ng) - iz
    low = np.flatnonzero(r_z < threshold)
    if not len(low):
        return n
    g = tuple(c[low] for c in ng)
    w = tuple(c[low] for c in wo)
    m = tuple(c[low] for c in n)
    iz, t = iz[low], threshold[low]
    # X: n's direction within the tangent plane of ng (n itself if n is along ng).
    d = dot_xyz(m, g)
    x = tuple(m[k] - d * g[k] for k in range(3))
    length = np.sqrt(dot_xyz(x, x))
    ok = length > ZERO
    inv = np.where(ok, ONE / np.where(ok, length, ONE), ZERO)
    x = tuple(np.where(ok, x[k] * inv, m[k]) for k in range(3))
    ix = dot_xyz(w, x)
    a = ix * ix + iz * iz
    b = F32(2.0) * (a + iz * t)
    c = np.square(t + iz)
    root = np.sqrt(np.maximum(b * b - F32(4.0) * a * c, ZERO))
    with np.errstate(invalid="ignore", divide="ignore"):
        nz2 = F32(0.25) * np.where(ix < ZERO, b + root, b - root) / a
    nz2 = np.where(a > ZERO, nz2, ONE)
    nx = np.sqrt(np.maximum(ONE - nz2, ZERO))
    nz = np.sqrt(np.maximum(nz2, ZERO))
    out = [np.array(c, F32, copy=True) for c in n]
    for k in range(3):
        out[k][low] = nx * x[k] + nz * g[k]
    return tuple(out)


def rotate_about(v, axis, angle: np.ndarray):
    """v rotated by angle (radians, (n,)) about the unit axis, right-handed (Rodrigues)."""
    cos, sin = np.cos(angle).astype(F32), np.sin(angle).astype(F32)
    along = dot_xyz(axis, v) * (ONE - cos)
    across = cross_xyz(axis, v)
    return tuple((cos * v[k] + along * axis[k] + sin * across[k]).astype(F32) for k in range(3))


def _scale(v, s):
    return tuple(c * s for c in v)


def _flip(v, backfacing):
    sign = np.where(backfacing, F32(-1.0), ONE)
    return tuple(c * sign for c in v)
