"""The shader nodes that trace rays, Ambient Occlusion, Bevel and Raycast, as Cycles 5.x computes them
(kernel/svm/ao.h, kernel/svm/bevel.h, kernel/svm/raycast.h), batched over the hits of a material in a wave: one ray query for all the
samples of all hits (up to GROUP_RAYS rays a query; and per surface passed, for rays that look only for their
own object).

Cycles runs these nodes only where a path shades a surface (shaders holding one are flagged SD_HAS_RAYTRACE,
scene/svm.cpp, and shaded by the shade_surface_raytrace kernel, kernel/integrator/intersect_closest.h). Its
other evaluations leave KERNEL_FEATURE_NODE_RAYTRACE out of their node masks (kernel/features.h): in shadow
rays' transparency, lights' emission, the world and volumes AO is 1 and Bevel gives the shading normal.
Here that is HitInputs.tracing() returning None: only the integrator's surface vertex gives its paths' keys.

Random numbers: Cycles draws sample i of n of a node from its Sobol-Burley sequence at index sample * n + i
(path_branched_rng_2D, dimensions PRNG_SURFACE_AO and PRNG_SURFACE_BEVEL): an aligned block, so the n
directions of one evaluation are stratified together. Ember takes points 0..n-1 of an Owen-scrambled Sobol
sequence scrambled per ray (rng.stratified_2d seeded by the path's keys): stratified alike. It matters beyond
noise: AO through a Color Ramp averages a nonlinear function of the n-sample estimate, whose mean depends on
the estimate's variance (with independent numbers a clamped ramp read 2-4% darker than Cycles in penumbrae).
"""
from __future__ import annotations

import numpy as np

from ..geometry import N0, N1, N2, NG
from ..local_hits import LocalRays, own_hits, pick_hits
from ..rng import pcg2d, stratified_2d
from ..sampling import sample_uniform_disk_concentric
from ..vec import F32, ONE, TWO_PI, ZERO, columns, dot_rows, normalize_rows
from ..scene.objects import RAY_SHADOW
from ..visibility import skip_hits
from .program import TracedHits, make_orthonormals

# rng.stratified_2d dimensions of the AO directions and the Bevel disks (apart from samples.py's), and the
# rng.keyed_uniforms salt (apart from the media's) of Bevel's choice of hits beyond local_hits.LOCAL_MAX_HITS.
AO_DIMENSION, BEVEL_DIMENSION, BEVEL_PICK_SALT = 40, 41, 1442
# Cycles skips Bevel on blurry indirect rays: where the path's smallest BSDF pdf so far is below this.
BEVEL_MIN_RAY_PDF = F32(8.0)
# Rays per query of the nodes' samples traced together (raytrace.sample_groups).
GROUP_RAYS = 1 << 18


class ShaderRays(LocalRays):
    """What shader nodes trace with (local_hits.LocalRays: the BVH, the triangles, the offset's scale) and the
    world's AO distance (World.ao_distance: an AO node's unlinked Distance of 0 reads it, Cycles'
    NODE_AO_GLOBAL_RADIUS)."""

    def __init__(self, accel, triangles, epsilon, ao_distance: float = 10.0, visibility=None):
        super().__init__(accel, triangles, epsilon)
        self.ao_distance = float(ao_distance)
        # Objects shadow rays do not see (Ray Visibility > Shadow off), which AO rays pass too, as Cycles traces
        # them with PATH_RAY_VISIBILITY_SHADOW_OPAQUE (svm/ao.h): (K,) bool per object row, or None for none.
        unseen = None if visibility is None else (np.asarray(visibility) & RAY_SHADOW) == 0
        self.shadow_unseen = unseen if unseen is not None and unseen.any() else None

    @property
    def ray_epsilon(self):
        return self.epsilon

    def ao_blocked(self, origins, d, t_max, split, time) -> np.ndarray:
        """(n,) bool: something shadow rays see lies on the rays before t_max."""
        if self.shadow_unseen is None:
            return self.accel.occluded(origins, d, t_max, split, time)
        hits = self.accel.intersect(origins, d, t_max, split, time)
        hits = skip_hits(self, origins, d, t_max, hits,
                         lambda prim, rows: np.take(self.shadow_unseen, self.object_rows(prim)), split, time)
        return hits.prim >= 0


def sample_groups(samples: int, m: int):
    """The node's samples 0..samples-1 of m hits in groups traced together, at most GROUP_RAYS rays a group
    (one sample at least): (first sample, samples in the group, (group * m,) the hit of each ray, sample-major)."""
    per = max(1, min(samples, GROUP_RAYS // max(m, 1)))
    for first in range(0, samples, per):
        group = min(per, samples - first)
        yield first, group, np.tile(np.arange(m), group)


# ---------------------------------------------------------------- Ambient Occlusion (svm/ao.h)
def ambient_occlusion(hits: TracedHits, normal: np.ndarray, distance: np.ndarray, samples: int,
                      inside: bool = False, only_local: bool = False) -> np.ndarray:
    """(n,) float32 the unoccluded share of `samples` rays per hit, as svm_ao: directions cosine-distributed
    about normal (n, 3) (reversed with inside), a uniform disk point lifted to the hemisphere; a ray is
    occluded by any surface within distance (n,) (only_local: of the hit's own object). A hit with
    distance <= 0 or samples < 1 reads 1."""
    n = len(distance)
    out = np.ones(n, F32)
    live = np.flatnonzero(distance > 0)
    if samples < 1 or not len(live):
        return out
    h = hits.take(live)
    m = len(live)
    axis = -normal[live] if inside else normal[live]
    t, b = make_orthonormals(np.ascontiguousarray(axis, F32))
    t_max = np.ascontiguousarray(distance[live], F32)
    scramble = pcg2d(h.keys[0], h.keys[1])[0]
    unoccluded = np.zeros(m, np.int32)
    # Several samples' rays in one query (each ray's outcome is its own, whatever its batch holds).
    for first, group, tile in sample_groups(samples, m):
        u, v = stratified_2d(np.tile(scramble, group), np.repeat(np.arange(first, first + group, dtype=np.uint32), m),
                             0, AO_DIMENSION)
        dx, dy = sample_uniform_disk_concentric(u, v)
        dz = np.sqrt(np.maximum(ONE - dx * dx - dy * dy, ZERO))
        ax = axis[tile]
        d = (t[tile] * columns(dx) + b[tile] * columns(dy) + ax * columns(dz)).astype(F32)
        origins = h.rays.offset_origins(h.p[tile], h.ng[tile], d)
        tm = t_max[tile]
        time = None if h.time is None else h.time.take(tile)
        if only_local:
            blocked = np.zeros(len(tile), bool)
            for rows, _, _, _, _ in own_hits(h.rays, h.objects[tile], origins, d, tm, h.split, time, first_only=True):
                blocked[rows] = True
        else:
            blocked = h.rays.ao_blocked(origins, d, tm, h.split, time)
        unoccluded += (~blocked).reshape(group, m).sum(axis=0, dtype=np.int32)
    out[live] = unoccluded.astype(F32) / F32(samples)
    return out


# ---------------------------------------------------------------- Bevel (svm/bevel.h)
def cubic_root(xi: np.ndarray) -> np.ndarray:
    """x in [0, 1] with 10x^2 - 20x^3 + 15x^4 - 4x^5 = xi: the radius (over R) of the cubic falloff
    10 (R - r)^3 / (pi R^5) on the disk, by Cycles' Newton iteration (from 0.25, at most 10 steps, until
    |f| < 1e-6, each step clamped to [0, 1])."""
    x = np.full(np.shape(xi), F32(0.25), F32)
    going = np.ones(np.shape(xi), bool)
    for _ in range(10):
        x2 = x * x
        x3 = x2 * x
        nx = ONE - x
        f = F32(10.0) * x2 - F32(20.0) * x3 + F32(15.0) * x2 * x2 - F32(4.0) * x2 * x3 - xi
        f_ = F32(20.0) * (x * nx) * (nx * nx)
        going &= ~((np.abs(f) < F32(1e-6)) | (f_ == ZERO))
        if not going.any():
            break
        with np.errstate(divide="ignore", invalid="ignore"):
            x = np.where(going, np.clip(x - f / f_, ZERO, ONE), x).astype(F32)
    return x


def bevel(hits: TracedHits, radius: np.ndarray, samples: int) -> np.ndarray:
    """(n, 3) float32 normals averaged over the hit's object around each hit, as svm_bevel: per sample an axis
    of the frame about Ng (Ng with probability 1/2, either tangent 1/4), a point of the disk across it drawn
    from the cubic falloff of radius (n,), a ray along the axis through the disk's point, 2h long (h the
    falloff sphere's height there); every hit of it on the object (a random LOCAL_MAX_HITS of them, weighted
    up, where there are more) adds its smooth normal weighted by MIS over the three axes (power heuristic)
    and the falloff at its distance over the disk's pdf. The shading normal where radius <= 0, samples < 1,
    after a blurry bounce (min ray pdf below 8), or where nothing was met; flipped on back faces."""
    out = np.array(hits.n, F32, copy=True)
    ok = radius > 0
    if hits.min_ray_pdf is not None:
        ok &= ~(hits.min_ray_pdf < BEVEL_MIN_RAY_PDF)
    live = np.flatnonzero(ok)
    if samples < 1 or not len(live):
        return out
    h = hits.take(live)
    m = len(live)
    r_max = np.ascontiguousarray(radius[live], F32)
    frame_t, frame_b = make_orthonormals(h.ng)
    total = np.zeros((m, 3), np.float64)
    scramble = pcg2d(h.keys[0], h.keys[1])[0]
    quarter, half = F32(0.25), F32(0.5)
    # Several samples' rays in one query, as ray rows sample * m + hit; their hits are put back in the order
    # sample by sample queries would meet them, so the sums add up in the same order.
    for first, group, tile in sample_groups(samples, m):
        sample_of = np.repeat(np.arange(first, first + group, dtype=np.uint32), m)
        u_axis, u_r = stratified_2d(np.tile(scramble, group), sample_of, 0, BEVEL_DIMENSION)
        ng, f_t, f_b, p, r = h.ng[tile], frame_t[tile], frame_b[tile], h.p[tile], r_max[tile]
        along_n, along_t = u_axis < F32(0.5), (u_axis >= F32(0.5)) & (u_axis < F32(0.75))
        along_b = ~(along_n | along_t)
        # The axis drawn becomes disk_n; the one it replaced takes its place in the disk's plane.
        disk_n = np.where(columns(along_n), ng, np.where(columns(along_t), f_t, f_b))
        disk_t = np.where(columns(along_t), ng, f_t)
        disk_b = np.where(columns(along_b), ng, f_b)
        pick = [np.where(c, half, quarter) for c in (along_n, along_t, along_b)]
        u_phi = np.where(along_n, u_axis * F32(2.0), np.where(along_t, (u_axis - half) * F32(4.0),
                                                               (u_axis - F32(0.75)) * F32(4.0)))
        phi = TWO_PI * u_phi
        disk_r = cubic_root(u_r) * r
        height = np.sqrt(np.maximum(r * r - disk_r * disk_r, ZERO))
        disk_p = disk_t * columns(disk_r * np.cos(phi)) + disk_b * columns(disk_r * np.sin(phi))
        origins = (p + disk_n * columns(height) + disk_p).astype(F32)
        d = np.ascontiguousarray(-disk_n, F32)
        found = list(own_hits(h.rays, h.objects[tile], origins, d, F32(2.0) * height, h.split,
                              None if h.time is None else h.time.take(tile)))
        if not found:
            continue
        rows, prim, t, u, v = (np.concatenate(c) for c in zip(*found))
        order = np.argsort(rows // m, kind="stable")
        rows, prim, t, u, v = rows[order], prim[order], t[order], u[order], v[order]
        count = np.bincount(rows, minlength=len(tile))
        keep, scale = pick_hits(rows, count, (np.tile(h.keys[0], group), np.tile(h.keys[1], group)), sample_of,
                                BEVEL_PICK_SALT)
        rows, prim, t, u, v = rows[keep], prim[keep], t[keep], u[keep], v[keep]
        g = h.rays.triangles.rows_of(prim)
        hit_ng = g[:, NG:NG + 3]
        w0 = ONE - u - v
        smooth = normalize_rows(g[:, N0:N0 + 3] * columns(w0) + g[:, N1:N1 + 3] * columns(u)
                                + g[:, N2:N2 + 3] * columns(v))
        normal = np.where(columns(dot_rows(smooth, smooth) > 0), smooth, hit_ng)
        pdf_n, pdf_t, pdf_b = (p_[rows] * np.abs(dot_rows(a[rows], hit_ng))
                               for p_, a in zip(pick, (disk_n, disk_t, disk_b)))
        with np.errstate(divide="ignore", invalid="ignore"):
            w = pdf_n / (pdf_n * pdf_n + pdf_t * pdf_t + pdf_b * pdf_b) * scale[rows]
            hit_p = origins[rows] + d[rows] * columns(t)
            distance = np.sqrt(dot_rows(hit_p - p[rows], hit_p - p[rows]))
            # The falloff at the hit over its pdf on the disk: (R - r)^3 / (R - disk_r)^3, zero beyond R.
            near = np.maximum(r[rows] - distance, ZERO)
            w = w * (near / (r[rows] - disk_r[rows])) ** 3
        w = np.where(np.isfinite(w), w, ZERO)
        np.add.at(total, tile[rows], normal.astype(np.float64) * w[:, None])
    summed = normalize_rows(total.astype(F32))
    met = dot_rows(summed, summed) > 0
    summed = np.where(columns(h.backfacing), -summed, summed)
    out[live] = np.where(columns(met), summed, h.n)
    return out


# ---------------------------------------------------------------- the ops (kernels/shading/ops.py)
def ambient_occlusion_node(hits, inputs, op):
    """The Ambient Occlusion node (svm_node_ao): AO, and Color times AO. Options: samples, inside,
    only_local, world_distance (an unlinked Distance of 0: the world's AO distance). The Normal input (when
    linked) is normalized; the shading normal otherwise. Where nothing is traced (HitInputs.tracing), AO 1."""
    n = hits.n
    color = np.broadcast_to(np.asarray(inputs["Color"], F32), (n, 3))
    traced = hits.tracing() if hasattr(hits, "tracing") else None
    ao = np.ones(n, F32)
    if traced is not None:
        distance = np.broadcast_to(np.asarray(inputs["Distance"], F32), (n,))
        if op.option("world_distance", False):
            distance = np.full(n, F32(traced.rays.ao_distance))
        normal = hits.N
        if "Normal" in inputs:
            given = normalize_rows(np.broadcast_to(np.asarray(inputs["Normal"], F32), (n, 3)))
            normal = np.where(columns(dot_rows(given, given) > 0), given, hits.N)
        ao = ambient_occlusion(traced, normal, distance, int(op.option("samples", 16)),
                               bool(op.option("inside", False)), bool(op.option("only_local", False)))
    return {"AO": ao, "Color": (color * columns(ao)).astype(F32)}


def bevel_node(hits, inputs, op):
    """The Bevel node (svm_node_bevel): the bevelled normal; with its Normal input linked, that normal moved
    by what bevelling changed, normalize(Normal + bevel - N). Option: samples. Where nothing is traced
    (HitInputs.tracing), the shading normal."""
    n = hits.n
    traced = hits.tracing() if hasattr(hits, "tracing") else None
    if traced is None:
        return {"Normal": np.ascontiguousarray(hits.N, F32)}
    radius = np.broadcast_to(np.asarray(inputs["Radius"], F32), (n,))
    out = bevel(traced, radius, int(op.option("samples", 4)))
    if "Normal" in inputs:
        given = np.broadcast_to(np.asarray(inputs["Normal"], F32), (n, 3))
        out = normalize_rows((given + (out - hits.N)).astype(F32))
    return {"Normal": out.astype(F32)}


# ---------------------------------------------------------------- Raycast (svm/raycast.h)
def raycast_node(hits, inputs, op):
    """The Raycast node (Blender 5.3, svm_node_raycast): one ray from Position (the hit's, unlinked) along
    Direction (the shading normal, unlinked) for Length; Is Hit, Self Hit (the hit is on the shading point's
    object), Hit Distance (in units of Direction; Length where nothing is hit), Hit Position and Hit Normal (the
    smooth normal there, facing the ray, as Cycles' shader_setup_from_ray gives it). A ray that starts at the
    shading point leaves its surface (Cycles skips the point's own triangle); only_local: the closest surface of
    the point's own object. Where nothing is traced (HitInputs.tracing: a world, a lamp, shadow rays) or Length
    is not positive: no hit."""
    from ..interaction import SurfaceHit
    n = hits.n
    length = np.broadcast_to(np.asarray(inputs["Length"], F32), (n,)).astype(F32)
    out = {"Is Hit": np.zeros(n, F32), "Self Hit": np.zeros(n, F32), "Hit Distance": length.copy(),
           "Hit Position": np.zeros((n, 3), F32), "Hit Normal": np.zeros((n, 3), F32)}
    traced = hits.tracing() if hasattr(hits, "tracing") else None
    if traced is None:
        return out
    position = np.array(np.broadcast_to(np.asarray(inputs["Position"], F32), (n, 3)), F32) \
        if "Position" in inputs else np.ascontiguousarray(hits.P, F32)
    direction = np.array(np.broadcast_to(np.asarray(inputs["Direction"], F32), (n, 3)), F32) \
        if "Direction" in inputs else np.ascontiguousarray(hits.N, F32)
    scale = np.sqrt(dot_rows(direction, direction))
    live = np.flatnonzero((length > 0) & (scale > 0))
    if not len(live):
        return out
    h = traced.take(live)
    d = (direction[live] / columns(scale[live])).astype(F32)
    start = position[live]
    own = np.all(start == h.p, axis=1)             # at the shading point: off its surface, as Cycles skips it
    origins = np.where(columns(own), h.rays.offset_origins(h.p, h.ng, d), start).astype(F32)
    t_max = (length[live] * scale[live]).astype(F32)
    prim = np.full(len(live), -1, np.int64)
    t = np.zeros(len(live), F32)
    b1, b2 = np.zeros(len(live), F32), np.zeros(len(live), F32)
    if op.option("only_local", False):
        for rows, p_, t_, u_, v_ in own_hits(h.rays, h.objects, origins, d, t_max, h.split, h.time, first_only=True):
            prim[rows], t[rows], b1[rows], b2[rows] = p_, t_, u_, v_
    else:
        met = h.rays.accel.intersect(origins, d, t_max, h.split, h.time)
        found = np.flatnonzero(met.prim >= 0)
        prim[found], t[found] = met.prim[found], met.t[found]
        b1[found], b2[found] = met.u[found], met.v[found]
    found = np.flatnonzero(prim >= 0)
    if not len(found):
        return out
    rows = live[found]
    # In units of Direction, as Cycles' ray.D is Direction as given (from the shading point, whose offset start
    # is a float's width off it).
    distance = (t[found] / scale[rows]).astype(F32)
    hit = SurfaceHit(h.rays.triangles, prim[found], b1[found], b2[found], tuple(d[found].T), False,
                     ray=(origins[found], t[found]))
    out["Is Hit"][rows] = ONE
    out["Self Hit"][rows] = (h.rays.object_rows(prim[found]) == h.objects[found]).astype(F32)
    out["Hit Distance"][rows] = distance
    out["Hit Position"][rows] = position[rows] + direction[rows] * columns(distance)
    out["Hit Normal"][rows] = np.stack(hit.ns, axis=1)
    return out
