"""Emissive triangles: a point uniform in the solid angle a triangle subtends from points near it (bounded
variance next to a light), else uniform in its area; the pdf of a BSDF ray's hit, and each scene triangle's row
in the emissive table.
"""
from __future__ import annotations

import numpy as np

from ..vec import cross_xyz, dot_xyz, normalize_floored_xyz
from .common import area_to_solid_angle, direction

# An emissive triangle is sampled by the solid angle it subtends from points nearer its plane than its
# longest edge, and by area from farther points, where the two pdfs hardly differ and area sampling costs
# a fifth: the comparison Cycles' comment describes (kernel/light/triangle.h). Cycles' code divides the
# distance by twice the triangle's area as well (N unnormalised), so its reach depends on the triangle's
# size; this rule does not depend on the scene's scale. Below this solid angle a triangle is sampled by area
# whatever the distance: tiny spherical triangles lose float precision.
SPHERICAL_MIN_SR = 1e-3
# Columns of the emissive-triangle table (LightSampler.tri_table): corner 0, two edges, unit normal, area, mean
# radiance.
TP0, TE1, TE2, TN, TAREA, TLE = 0, 3, 6, 9, 12, 13
TRI_COLUMNS = 16


def sample(sampler, out, idx, slot, px, py, pz, u1, u2):
    """A point on an emissive triangle: uniform in the solid angle it subtends from points near it
    (bounded variance next to a light; _spherical_choice), else uniform in its area."""
    g = np.take(sampler.tri_table, slot, axis=0).T
    spherical, omega, corners = spherical_choice(sampler, g, slot, px, py, pz)
    n = len(slot)
    wx, wy, wz, dist, pdf, b1, b2 = (np.empty(n, np.float32) for _ in range(7))
    far = np.flatnonzero(~spherical)
    if len(far):
        ga = g[:, far]
        su = np.sqrt(u1[far])
        b1[far] = a1 = np.float32(1.0) - su
        b2[far] = a2 = u2[far] * su
        qx = ga[TP0] + a1 * ga[TE1] + a2 * ga[TE2]
        qy = ga[TP0 + 1] + a1 * ga[TE1 + 1] + a2 * ga[TE2 + 1]
        qz = ga[TP0 + 2] + a1 * ga[TE1 + 2] + a2 * ga[TE2 + 2]
        fx, fy, fz, fd = direction(px[far], py[far], pz[far], qx, qy, qz)
        wx[far], wy[far], wz[far], dist[far] = fx, fy, fz, fd
        cos_l = np.abs(fx * ga[TN] + fy * ga[TN + 1] + fz * ga[TN + 2])
        pdf[far] = area_to_solid_angle(ga[TAREA], fd, cos_l)
    sph = np.flatnonzero(spherical)
    if len(sph):
        a, b, c = corners
        sx, sy, sz = _sample_spherical_triangle(a, b, c, omega, u1[sph], u2[sph])
        nx, ny, nz = g[TN, sph], g[TN + 1, sph], g[TN + 2, sph]
        denom = sx * nx + sy * ny + sz * nz
        rx, ry, rz = (g[TP0 + k, sph] - (px, py, pz)[k][sph] for k in range(3))
        # A direction grazing the triangle's plane (possible only by rounding) finds no point on it.
        valid = np.abs(denom) > np.float32(1e-7)
        t = (rx * nx + ry * ny + rz * nz) / np.where(valid, denom, np.float32(1.0))
        valid &= t > 0
        wx[sph], wy[sph], wz[sph] = sx, sy, sz
        dist[sph] = np.where(valid, t, np.float32(0.0))
        pdf[sph] = np.where(valid, np.float32(1.0) / omega, np.float32(0.0))
        if sampler.tri_textured:  # barycentrics of the point hit, for the texture lookup
            b1[sph], b2[sph] = _barycentrics((sx * t - rx, sy * t - ry, sz * t - rz),
                                             g[TE1:TE1 + 3, sph], g[TE2:TE2 + 3, sph])
    if sampler.tri_half is not None:   # one-sided emitters: no sample from the other side (Cycles' SD_MIS_FRONT/BACK)
        pdf[~on_sampled_side(sampler.tri_half, slot, g, px, py, pz)] = np.float32(0.0)
    if sampler.tri_textured:
        radiance = sampler.triangle_emission(np.take(sampler.tri_ids, slot), b1, b2, (wx, wy, wz), dist)
    else:
        radiance = g[TLE:TLE + 3]
    out.set(idx, wx, wy, wz, dist, radiance, pdf)


def one_sided(scene, shaders, materials, plain_ids, instanced_ids):
    """Emission Sampling Front or Back per emissive triangle: (sides (E,) int8: 1 front, -1 back, 0 both; half
    (E,) float32: the same in terms of the table's normal TN, the sign of dot(TN, p - corner) of the points
    that sample it, turned where the triangle's object mirrors it, whose front is opposite its winding), or
    (None, None) when every emitter is sampled from both sides."""
    code = np.array([{"FRONT": 1, "BACK": -1}.get(shader.emission_sides, 0) for shader in shaders], np.int8)
    if not code.any() or not len(materials):
        return None, None
    sides = code[materials]
    if not sides.any():
        return None, None
    front = np.ones(len(materials), np.float32)
    mirrored = scene.mirrored_triangles()
    if mirrored is not None:
        front[:len(plain_ids)][np.take(mirrored, plain_ids)] = -1.0
    if len(instanced_ids):
        inst = scene.instances
        k = np.searchsorted(inst.bases(len(scene.positions)), instanced_ids, side="right") - 1
        front[len(plain_ids):][np.linalg.det(inst.world_from_object[k][:, :3, :3]) < 0] = -1.0
    return sides, (sides * front).astype(np.float32)


def on_sampled_side(half, slot, g, px, py, pz) -> np.ndarray:
    """(n,) bool: points p on the side of their triangle (slot, table rows g) that light samples go to."""
    h = (px - g[TP0]) * g[TN] + (py - g[TP0 + 1]) * g[TN + 1] + (pz - g[TP0 + 2]) * g[TN + 2]
    s = np.take(half, slot)
    return (s == 0) | (s * h > 0)


def spherical_choice(sampler, g, slot, px, py, pz):
    """Which points sample their triangle (slot, its table rows g) by solid angle: those nearer its
    plane than its longest edge where it subtends more than SPHERICAL_MIN_SR.
    Returns (spherical (n,) bool, and for the spherical points only, in order: the solid angle and
    the unit vectors toward the three corners, each a tuple of x, y, z arrays)."""
    ax, ay, az = g[TP0] - px, g[TP0 + 1] - py, g[TP0 + 2] - pz
    h = ax * g[TN] + ay * g[TN + 1] + az * g[TN + 2]
    near = np.flatnonzero(h * h < np.take(sampler.tri_reach2, slot))
    spherical = np.zeros(len(h), bool)
    if not len(near):
        return spherical, np.zeros(0, np.float32), None
    ax, ay, az = ax[near], ay[near], az[near]
    e1, e2 = (tuple(g[k, near] for k in range(r, r + 3)) for r in (TE1, TE2))
    a = normalize_floored_xyz((ax, ay, az))
    b = normalize_floored_xyz((ax + e1[0], ay + e1[1], az + e1[2]))
    c = normalize_floored_xyz((ax + e2[0], ay + e2[1], az + e2[2]))
    omega = solid_angle(a, b, c)
    keep = omega > SPHERICAL_MIN_SR
    spherical[near[keep]] = True
    if not keep.all():
        omega = omega[keep]
        a, b, c = (tuple(comp[keep] for comp in v) for v in (a, b, c))
    return spherical, omega, (a, b, c)


def pdf_hit(sampler, tri, dist, cos_l, ox, oy, oz, receiver=None, facing=None, backfacing=None) -> np.ndarray:
    """pdf (solid angle, with selection) with which NEE from the ray origin o would have sampled
    this point of emissive triangle tri (zero for triangles that do not emit, and for the side of a one-sided
    emitter that is not sampled: backfacing, whether the rays hit the triangles' back); receiver: the light sets
    of the points the rays left (Light Linking), or None."""
    if not len(sampler.tri_ids):
        return np.zeros(len(tri), np.float32)
    slot = slots(sampler, tri)
    ok = slot >= 0
    s = np.maximum(slot, 0)
    pmf = sampler.selection_pmf(sampler.light_count + s, ox, oy, oz, receiver, facing)
    g = np.take(sampler.tri_table, s, axis=0).T
    spherical, omega, _ = spherical_choice(sampler, g, s, ox, oy, oz)
    pdf = area_to_solid_angle(g[TAREA], dist, np.abs(cos_l))
    pdf[spherical] = np.float32(1.0) / omega
    if sampler.tri_sides is not None and backfacing is not None:
        sides = np.take(sampler.tri_sides, s)
        ok &= (sides == 0) | ((sides > 0) != np.asarray(backfacing, bool))
    return np.where(ok, pmf * pdf, np.float32(0.0))


def slots(sampler, tri: np.ndarray) -> np.ndarray:
    """Each scene triangle's position in the emissive list, -1 for triangles that do not emit."""
    if not sampler.has_instances:
        return np.take(sampler.tri_slot, tri)
    plain = tri < sampler.plain_count
    slot = np.full(len(tri), -1, np.int32)
    if sampler.plain_count:
        slot = np.where(plain, np.take(sampler.tri_slot, np.where(plain, tri, 0)), slot)
    if sampler.instanced_emitters:
        found = np.minimum(np.searchsorted(sampler.tri_ids, tri), len(sampler.tri_ids) - 1)
        slot = np.where(~plain & (np.take(sampler.tri_ids, found) == tri), found, slot)
    return slot.astype(np.int32, copy=False)


def solid_angle(a, b, c):
    """Solid angle of the spherical triangle with unit corners a, b, c (Van Oosterom and Strackee)."""
    triple = np.abs(dot_xyz(a, cross_xyz(b, c)))
    return np.float32(2.0) * np.arctan2(triple, np.float32(1.0) + dot_xyz(a, b) + dot_xyz(b, c) + dot_xyz(c, a))


def _sample_spherical_triangle(a, b, c, omega, u1, u2):
    """Unit directions uniform over the spherical triangle a, b, c (Arvo 1995), per component."""
    n_ab = normalize_floored_xyz(cross_xyz(a, b))
    n_ac = normalize_floored_xyz(cross_xyz(a, c))
    cos_alpha = np.clip(dot_xyz(n_ab, n_ac), np.float32(-1.0), np.float32(1.0))
    sin_alpha = np.sqrt(np.maximum(np.float32(1.0) - cos_alpha * cos_alpha, np.float32(0.0)))
    alpha = np.arccos(cos_alpha)
    cos_c = dot_xyz(a, b)
    area = u1 * omega
    s, t = np.sin(area - alpha), np.cos(area - alpha)
    u = t - cos_alpha
    v = s + sin_alpha * cos_c
    with np.errstate(divide="ignore", invalid="ignore"):
        q = ((v * t - u * s) * cos_alpha - v) / ((v * s + u * t) * sin_alpha)
    q = np.clip(np.nan_to_num(q, nan=1.0), np.float32(-1.0), np.float32(1.0))
    ca = dot_xyz(c, a)
    perp = normalize_floored_xyz((c[0] - ca * a[0], c[1] - ca * a[1], c[2] - ca * a[2]))
    sq = np.sqrt(np.maximum(np.float32(1.0) - q * q, np.float32(0.0)))
    c_hat = (q * a[0] + sq * perp[0], q * a[1] + sq * perp[1], q * a[2] + sq * perp[2])
    cb = dot_xyz(c_hat, b)
    z = np.float32(1.0) - u2 * (np.float32(1.0) - cb)
    perp = normalize_floored_xyz((c_hat[0] - cb * b[0], c_hat[1] - cb * b[1], c_hat[2] - cb * b[2]))
    sz = np.sqrt(np.maximum(np.float32(1.0) - z * z, np.float32(0.0)))
    return z * b[0] + sz * perp[0], z * b[1] + sz * perp[1], z * b[2] + sz * perp[2]


def _barycentrics(d, e1, e2):
    """(b1, b2) of the point p0 + d on the triangle with edges e1, e2 (each x, y, z)."""
    d11, d12, d22 = dot_xyz(e1, e1), dot_xyz(e1, e2), dot_xyz(e2, e2)
    d1, d2 = dot_xyz(d, e1), dot_xyz(d, e2)
    det = d11 * d22 - d12 * d12
    det = np.where(det != 0, det, np.float32(1e-30))
    return (d22 * d1 - d12 * d2) / det, (d11 * d2 - d12 * d1) / det
