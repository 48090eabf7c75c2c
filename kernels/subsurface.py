"""Subsurface scattering beneath a surface: Cycles 5.x's random walk (`kernel/integrator/subsurface.h`,
`subsurface_random_walk.h`), batched over a wave's walking paths (one ray query per step for all of them) while
many go on, the last few handed to kernels/subsurface_tail.py; enter() hands Christensen-Burley's paths to
kernels/subsurface_disk.py instead.

A path whose closure pick chose a BSSRDF (kernels/bsdf/bssrdf.py: its entry direction and sample weight) walks
inside the mesh of the object it entered: free flights in a homogeneous medium whose coefficients come from the
closure's albedo and radius (the van de Hulst inversion of d'Eon's Hitchhiker's guide for Random Walk and for
negative anisotropy, the Chiang-Kutz-Burley polynomial fit otherwise), Henyey-Greenstein scattering, with
Cycles' MIS of classic and Dwivedi-guided sampling (forward and, where the first ray found the far side,
backward) and of the three colour channels, the similarity relation past step 9, and at most 256 steps. Rays
meet only the object walked in (Cycles' scene_intersect_local). Where a step leaves the surface the path exits:
the integrator shades that point with a white Lambert closure on its normal facing out
(subsurface_shader_data_setup), without emission, holdout, data passes or roulette, and the entry counted no
bounce (the exit's diffuse bounce counts).

Each walk step draws its numbers from rng.keyed_uniforms keyed by the path's ray (paths.ray_keys) and the step
(subsurface_medium.step_numbers, a chunk of steps at once). Why the walk runs in two ways: docs/architecture.md,
Subsurface scattering.
"""
from __future__ import annotations

import numpy as np

from . import subsurface_disk, subsurface_tail
from .bsdf import bssrdf, lobes
from .bsdf.closures import ClosureBuilder
from .interaction import spawn_offset
from .local_hits import LocalRays
from .paths import ray_keys
from .subsurface_medium import (ALPHA, BITANGENT, CLASSIC_COS, CLASSIC_X, CLASSIC_Y, DIFFUSION_LENGTH, DIRECTION,
                                FLIGHT, G, GUIDED_COS, GUIDED_FRACTION, GUIDED_X, GUIDED_Y, HAVE_OPPOSITE,
                                ISOTROPIC_PDF, MAX_BOUNCES, NEG_N, NORMAL, OPPOSITE, P0, PHASE_LOG, POSITION, SIGMA_S,
                                SIGMA_S_STAR, SIGMA_T, SIGMA_T_STAR, SIMILAR_GUIDED_FRACTION, SIMILARITY_LEVEL,
                                TANGENT, THROUGHPUT, THROUGHPUT_EPSILON, U_BACKWARD, U_CHANNEL, U_GUIDED, Exits,
                                WalkTable, first_numbers, hg_pdf, local_hits, step_numbers)
from .vec import F32, INV_2PI, dot_xyz

# Walks stepped together in NumPy until no more than this many are left; the rest go on one by one in Python
# floats (kernels/subsurface_tail.py). See docs/architecture.md, Subsurface scattering.
TAIL_WALKS = 32
# Numbers drawn ahead per chunk of steps, walks x steps (at most MAX_CHUNK_STEPS steps).
NUMBERS_PER_CHUNK = 4096
MAX_CHUNK_STEPS = 16


# ---------------------------------------------------------------- the walk
def walk(accel, object_rows, p0, d0, n0, ng0, obj, albedo, radius, g, van_de_hulst, throughput, keys,
         ray_epsilon=0.0, times=None, park=False):
    """Random walks from the entry points p0 (3, n) along d0 (3, n) into the surface of normal n0 (shading, facing
    the viewer) and geometric normal ng0. obj: (n,) object rows of the walks (None: the scene is one object);
    object_rows(prim) gives a hit's. albedo, radius (3, n) (the closure's, method-scaled), g (n,), van_de_hulst
    (n,) bool; throughput (3, n) the path's, closure weight included; keys the paths' ray keys.

    Returns (rows, prim, u, v, t, direction, throughput): the walks that left the surface, the triangle and
    barycentrics of their exit, the last flight's length and direction (3, m), the throughput there (3, m).
    park: only the first step; returns those exits and (c, s, rows, keys) of the walks that go on (WalkPool.add)."""
    p0 = np.asarray(p0, np.float64)
    table = WalkTable(p0, d0, np.asarray(n0, np.float64), albedo, radius, g, van_de_hulst, throughput)
    live = table.walking
    exits = Exits()

    def trace(origin, d, t_max, rows):
        return local_hits(accel, object_rows, origin, d, t_max, None if obj is None else obj[rows], times, rows)

    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        c, s = table.constants[:, live], table.state[:, live]
        keys = (keys[0][live], keys[1][live])
        # The first flight leaves the entry point below its surface (Embree has no self-hit exclusion).
        eps = spawn_offset(ray_epsilon, *(x.astype(F32) for x in c[P0])).astype(np.float64)
        start = c[P0] - np.asarray(ng0, np.float64)[:, live] * eps
        keep = _first_step(c, s, live, keys, start, trace, exits)
        c, s, live, keys = c[:, keep], s[:, keep], live[keep], (keys[0][keep], keys[1][keep])
        if park:
            return exits.gather(), (c, s, live, keys)
        _steps(c, s, live, keys, 1, trace, exits)
    return exits.gather()


class WalkPool:
    """Random walks parked between the integrator's steps, beside the states of their paths: each step of a wave
    adds the walks its paths began (their first flight taken, whose exits wait here too), and advance() steps all
    of them together, so that a NumPy step moves the walks of many bounces at once and the long tail of a batch
    of walks (a few walks taking a hundred steps or more) is paid once per wave instead of once per bounce.
    docs/architecture.md, Subsurface scattering."""

    # A round (one per integrator step) steps the walks while more than this many go on, then parks them again.
    PARK_WALKS = 256

    def __init__(self, accel, object_rows):
        """accel, object_rows: the walks' queries' (walk's arguments)."""
        self.accel, self.object_rows = accel, object_rows
        self.c = self.s = self.keys = self.bounce = self.obj = self.state = None
        self.waiting = []   # exits not yet handed out: (PathState, prim, u, v, t, direction)

    @classmethod
    def of(cls, tables):
        return cls(tables.accel, _object_rows(tables))

    def __len__(self):
        """The walks parked and the exits waiting."""
        return self._walking() + sum(len(w[1]) for w in self.waiting)

    def _walking(self):
        return 0 if self.bounce is None else len(self.bounce)

    def add(self, state, obj, found, going):
        """The walks of the paths `state` (on the objects obj, None: one object) after their first flight: found,
        the exits it made (walk's), and going, walk's (c, s, rows, keys) of those that go on."""
        self._wait(state, found)
        c, s, live, keys = going
        if not len(live):
            return
        obj = None if obj is None else obj[live]
        state = state.rows(live)
        bounce = np.ones(len(live), np.int64)
        if not self._walking():
            self.c, self.s, self.keys, self.bounce, self.obj, self.state = c, s, keys, bounce, obj, state
            return
        self.c, self.s = np.concatenate([self.c, c], axis=1), np.concatenate([self.s, s], axis=1)
        self.keys = (np.concatenate([self.keys[0], keys[0]]), np.concatenate([self.keys[1], keys[1]]))
        self.bounce = np.concatenate([self.bounce, bounce])
        self.obj = None if obj is None else np.concatenate([self.obj, obj])
        self.state = type(state).concat(self.state, state)

    def advance(self, drain: bool):
        """Steps the parked walks while more than PARK_WALKS go on, or (drain) until every walk has left or faded.
        Returns the exits waiting and those of this round: (the states of their paths, with the throughput there;
        prim, u, v, t, direction), or None when there are none."""
        if self._walking():
            self._round(drain)
        waiting, self.waiting = self.waiting, []
        if not waiting:
            return None
        if len(waiting) == 1:
            return waiting[0]
        state = waiting[0][0]
        for w in waiting[1:]:
            state = type(state).concat(state, w[0])
        return (state,) + tuple(np.concatenate([w[i] for w in waiting], axis=-1) for i in range(1, 6))

    def _round(self, drain):
        obj, state = self.obj, self.state
        accel, object_rows = self.accel, self.object_rows

        def trace(origin, d, t_max, rows):
            return local_hits(accel, object_rows, origin, d, t_max, None if obj is None else obj[rows], state.time,
                              rows)
        exits = Exits()
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            left = _steps(self.c, self.s, np.arange(self._walking()), self.keys, self.bounce, trace, exits,
                          None if drain else self.PARK_WALKS)
        if left is None or not len(left[2]):
            self.c = self.s = self.keys = self.bounce = self.obj = self.state = None
        else:
            self.c, self.s, live, self.keys, self.bounce = left
            self.obj = None if obj is None else obj[live]
            self.state = state.rows(live)
        self._wait(state, exits.gather())

    def _wait(self, state, found):
        """Exits (Exits.gather's, rows of the paths `state`) held until advance() hands them out."""
        rows, prim, u, v, t, direction, throughput = found
        if len(rows):
            out = state.rows(rows)
            out.throughput = throughput
            self.waiting.append((out, prim, u, v, t, direction))


def _triangles_only(object_rows, triangle_count: int):
    """object_rows with no object for curves and points: a walk steps over them. Cycles' local intersection
    ignores curves (kernel_embree_filter_occluded_local_func), and a walk inside a sphere never meets its inside
    (culled)."""
    def rows(prim):
        out = object_rows(prim)
        shape = prim >= triangle_count
        return np.where(shape, np.int32(-1), out) if out is not None and shape.any() else out
    return rows


def _steps(c, s, live, keys, bounce, trace, exits, park=None):
    """The walks live (their columns c, s of WalkTable's constants and state, their keys) from step `bounce` (an
    int, or (m,) each walk's next step) on: in NumPy while more than TAIL_WALKS go on, then in Python
    (subsurface_tail). Their numbers are drawn a chunk of steps ahead (step_numbers), NUMBERS_PER_CHUNK at most.
    park: NumPy steps only while more than this many walks go on, and no Python tail: returns (c, s, live, keys,
    bounce) of the walks still going, to be taken on later (WalkPool); None: all to the end (returns None). Every
    step is below MAX_BOUNCES: a walk is dropped as it reaches it."""
    bounce = np.broadcast_to(np.asarray(bounce, np.int64), live.shape)
    fewest = TAIL_WALKS if park is None else max(park, TAIL_WALKS)
    while len(live) > fewest:
        count = min(max(1, NUMBERS_PER_CHUNK // len(live)), MAX_CHUNK_STEPS)
        numbers = step_numbers(keys, bounce, count, c[G], c[DIFFUSION_LENGTH], c[PHASE_LOG])
        col = None
        for j in range(count):
            keep = _step(c, s, live, numbers[j] if col is None else numbers[j][:, col], bounce, trace, exits)
            bounce = bounce + 1
            keep &= bounce < MAX_BOUNCES
            if not keep.all():
                live, c, s, bounce = live[keep], c[:, keep], s[:, keep], bounce[keep]
                col = np.flatnonzero(keep) if col is None else col[keep]
            if len(live) <= fewest:
                break
        if col is not None:
            keys = (keys[0][col], keys[1][col])
    if park is not None:
        return c, s, live, keys, bounce
    if len(live):
        subsurface_tail.finish(c, s, live, keys, bounce, trace, exits)
    return None


def _channel(thr, alpha, sigma_t, u):
    """volume_sample_channel: the channel pdfs (3, m) by the throughput-weighted albedo (uniform where it is
    zero) and the sigma_t (m,) of the channel u picks."""
    w = np.abs(thr * alpha)
    total = w[0] + w[1] + w[2]
    pdf = w / total
    zero = ~(total > 0)
    if zero.any():
        pdf[:, zero] = 1.0 / 3.0
    return pdf, np.where(u < pdf[0], sigma_t[0], np.where(u < pdf[0] + pdf[1], sigma_t[1], sigma_t[2]))


def _throughput(thr, ch_pdf, pdf, tr, sigma_s, hit):
    """The throughput after a flight: transmittance (and sigma_s where it scattered) over the pdf, MIS over the
    three channels (the balance heuristic); zero where no channel could have sampled it."""
    p = ch_pdf * pdf
    denom = p[0] + p[1] + p[2]
    out = np.where(hit, tr, sigma_s * tr) * thr / denom
    zero = ~(denom > 0)
    if zero.any():
        out[:, zero] = 0.0
    return out


def _going(thr, hit):
    """The walks that go on: not out, throughput not negligible (the largest channel, NaN if any is), finite."""
    finite = np.isfinite(thr)
    return ~hit & (np.maximum(np.maximum(thr[0], thr[1]), thr[2]) >= THROUGHPUT_EPSILON) & finite[0] & finite[1] & \
        finite[2]


def _frame(d):
    """sampling.orthonormal_basis about the directions d (3, m), as (tangent, bitangent), each (3, m)."""
    dx, dy, dz = d
    sign = np.where(dz >= 0, 1.0, -1.0)
    a = -1.0 / (sign + dz)
    tangent, bitangent = np.empty_like(d), np.empty_like(d)
    np.multiply(dx, dy, out=bitangent[0])
    bitangent[0] *= a
    np.multiply(sign, bitangent[0], out=tangent[1])
    np.multiply(sign, dx, out=tangent[2])
    np.multiply(tangent[2], dx, out=tangent[0])
    tangent[0] *= a
    tangent[0] += 1.0
    np.negative(tangent[2], out=tangent[2])
    np.multiply(dy, dy, out=bitangent[1])
    bitangent[1] *= a
    bitangent[1] += sign
    np.negative(dy, out=bitangent[2])
    return tangent, bitangent


def _first_step(c, s, live, keys, start, trace, exits):
    """Step 0 along the entry direction, by classic distance sampling; its ray reaches 10 mean free paths at
    least, to find the far side for the backward guide. Updates c, s in place; returns the walks that go on."""
    u_ch, flight = first_numbers(keys)
    st = c[SIGMA_T]
    thr, d = s[THROUGHPUT], s[DIRECTION]
    ch_pdf, sample_st = _channel(thr, c[ALPHA], st, u_ch)
    t = flight / sample_st
    prim, th, hu, hv = trace(start, d, np.maximum(t, 10.0 / st.min(axis=0)), live)
    hit = prim >= 0
    c[HAVE_OPPOSITE] = hit
    c[OPPOSITE] = np.where(hit, dot_xyz(start + th * d - c[P0], c[NEG_N]), 0.0)
    hit &= th < t
    t = np.where(hit, th, t)
    s[POSITION] += t * d
    tr = np.exp(-st * t)
    thr = s[THROUGHPUT] = _throughput(thr, ch_pdf, np.where(hit, tr, st * tr), tr, c[SIGMA_S], hit)
    if hit.any():
        e = np.flatnonzero(hit)
        exits.add(live[e], 0, prim[e], hu[e], hv[e], th[e], d[:, e], thr[:, e])
    return _going(thr, hit)


def _step(c, s, live, numbers, bounce, trace, exits):
    """One step of the walks live (bounce (m,) each walk's step, > 0): a direction by Henyey-Greenstein or
    Dwivedi's guide (forward, or backward toward the far side), a distance stretched by the guide, the flight, and
    the throughput with MIS over {classic, guided, backward guided} x {r, g, b}. numbers (NUMBER_ROWS, m) the
    step's. Updates c, s in place; returns the walks that go on."""
    similar = bounce > SIMILARITY_LEVEL   # (m,): walks at different steps may step together (WalkPool)
    mixed = similar.any() and not similar.all()
    if mixed:   # what each walk's step takes, as the step alone would
        st = np.where(similar, c[SIGMA_T_STAR], c[SIGMA_T])
        ss = np.where(similar, c[SIGMA_S_STAR], c[SIGMA_S])
        gf = np.where(similar, SIMILAR_GUIDED_FRACTION, c[GUIDED_FRACTION])
    else:
        similar = bool(similar.any())
        st = c[SIGMA_T_STAR] if similar else c[SIGMA_T]
        ss = c[SIGMA_S_STAR] if similar else c[SIGMA_S]
        gf = SIMILAR_GUIDED_FRACTION if similar else c[GUIDED_FRACTION]
    pos, d, thr = s[POSITION], s[DIRECTION], s[THROUGHPUT]
    dl, phase_log = c[DIFFUSION_LENGTH], c[PHASE_LOG]
    ch_pdf, sample_st = _channel(thr, c[ALPHA], st, numbers[U_CHANNEL])
    guided = numbers[U_GUIDED] < gf
    opposite = c[HAVE_OPPOSITE] > 0
    any_opposite = opposite.any()
    if any_opposite:
        # np.clip(x, 0, opposite) but for the sign of a zero, which nothing downstream sees
        x = np.minimum(np.maximum(dot_xyz(pos - c[P0], c[NEG_N]), 0.0), c[OPPOSITE])
        back_frac = np.where(opposite, 1.0 / (1.0 + np.exp((c[OPPOSITE] - 2 * x) / dl)), 0.0)
        backward = numbers[U_BACKWARD] < back_frac
        cos_g = np.where(backward, -numbers[GUIDED_COS], numbers[GUIDED_COS])
    else:
        backward = np.zeros(len(live), bool)
        cos_g = numbers[GUIDED_COS]
    # Both candidate directions, in the frames sampling.local_to_world builds: guided about N, classic about
    # the flight.
    d_g = numbers[GUIDED_X] * c[TANGENT] + numbers[GUIDED_Y] * c[BITANGENT] + cos_g * c[NORMAL]
    tangent, bitangent = _frame(d)
    d_c = numbers[CLASSIC_X] * tangent + numbers[CLASSIC_Y] * bitangent + numbers[CLASSIC_COS] * d
    new_d = np.where(guided, d_g, d_c)
    new_d /= np.sqrt(dot_xyz(new_d, new_d))
    if mixed:
        hg = np.where(similar, ISOTROPIC_PDF, hg_pdf(dot_xyz(d, new_d), c[G]))
    else:
        hg = ISOTROPIC_PDF if similar else hg_pdf(dot_xyz(d, new_d), c[G])
    cos_theta = np.where(guided, cos_g, dot_xyz(new_d, c[NORMAL]))
    fwd_f = INV_2PI / ((dl - cos_theta) * phase_log) / hg
    bwd_f = INV_2PI / ((dl + cos_theta) * phase_log) / hg
    q = cos_theta / dl
    fwd_s, bwd_s = 1.0 - q, 1.0 + q
    sample_st = sample_st * np.where(guided, np.where(backward, bwd_s, fwd_s), 1.0)
    t = numbers[FLIGHT] / sample_st
    prim, th, hu, hv = trace(pos, new_d, t, live)
    hit = prim >= 0
    t = np.where(hit, th, t)
    pos += t * new_d
    d[...] = new_d
    # subsurface_random_walk_pdf of the flight for the classic, forward and backward guided sigma_t, at once.
    sigma = np.empty((3,) + st.shape)
    sigma[0] = st
    np.multiply(fwd_s, st, out=sigma[1])
    np.multiply(bwd_s, st, out=sigma[2])
    tr = np.exp(-sigma * t)
    pdfs = np.where(hit, tr, sigma * tr)
    tr = tr[0]
    guided_pdf = pdfs[1] * fwd_f
    if any_opposite:
        guided_pdf = np.where(opposite, guided_pdf * (1 - back_frac) + pdfs[2] * bwd_f * back_frac, guided_pdf)
    pdf = pdfs[0] * (1 - gf) + guided_pdf * gf
    thr = s[THROUGHPUT] = _throughput(thr, ch_pdf, pdf, tr, ss, hit)
    if hit.any():
        e = np.flatnonzero(hit)
        exits.add(live[e], bounce[e], prim[e], hu[e], hv[e], th[e], new_d[:, e], thr[:, e])
    return _going(thr, hit)


# ---------------------------------------------------------------- what the integrator calls
def enter(tables, state, hit, closures, bs, rows, split=True, pool=None):
    """The paths `state` (those of the hits rows that picked a BSSRDF, already weighted by its sample) go beneath
    their surfaces: a random walk, or Christensen-Burley's disk probes (kernels/subsurface_disk.py). Returns
    (rows of `state` that came out, prim, u, v, t, direction the exit is seen against (3, m), throughput (3, m));
    the caller makes the exit hits. pool: a WalkPool the walks go on in after their first step (their later exits
    come from its advance()), None: the walks go to their end here."""
    burley = closures.dist[bs.row[rows]] == bssrdf.BURLEY
    if not burley.any():
        return _walks(tables, state, hit, closures, bs, rows, pool)
    disks = np.flatnonzero(burley)
    found = _disks(tables, state.rows(disks), hit, closures, bs, rows[disks], split)
    walks = np.flatnonzero(~burley)
    if not len(walks):
        return found
    walked = _walks(tables, state.rows(walks), hit, closures, bs, rows[walks], pool)
    return tuple(np.concatenate([a, b], axis=-1) for a, b in zip((disks[found[0]],) + found[1:],
                                                                  (walks[walked[0]],) + walked[1:]))


def _disks(tables, state, hit, closures, bs, rows, split):
    """Christensen-Burley's disk probes of the paths `state` (of the hits rows)."""
    local = LocalRays(tables.accel, tables.triangles, tables.ray_epsilon)
    p = np.stack([np.take(c, rows) for c in hit.p], axis=1)
    ng = np.stack([np.take(c, rows) for c in hit.ng], axis=1)
    return subsurface_disk.disk(local, p, ng, np.take(hit.backfacing, rows), local.object_rows(np.take(hit.prim, rows)),
                                np.take(closures.c0, bs.row[rows], axis=1), state.throughput,
                                np.take(bs.subsurface_u, rows, axis=1), ray_keys(state, np.arange(len(state))), split,
                                state.time)


def _object_rows(tables):
    """The object row of a hit's primitive for the walks' queries (None: the scene is one object)."""
    object_rows = tables.triangles.object_rows
    if tables.shapes is not None:
        object_rows = _triangles_only(object_rows, tables.shapes.triangle_count)
    return object_rows


def _walks(tables, state, hit, closures, bs, rows, pool=None):
    """The random walks of the paths `state` (of the hits rows); pool: see enter()."""
    picked = bs.row[rows]
    g = closures.offset[picked].astype(np.float64)
    method = closures.dist[picked]
    # Cycles' state keeps anisotropy + 2 for the legacy models (Skin): van de Hulst only for Random Walk, or g < 0.
    van = (method == bssrdf.RANDOM_WALK) | (g < 0)
    p0 = np.stack([np.take(c, rows) for c in hit.p]).astype(np.float64)
    d0 = np.stack([np.take(c, rows) for c in bs.wi])
    n0 = np.stack([np.take(c, rows) for c in hit.ns])
    ng0 = np.stack([np.take(c, rows) for c in hit.ng]).astype(np.float64)
    obj = tables.triangles.object_rows(np.take(hit.prim, rows))
    found = walk(tables.accel, _object_rows(tables), p0, d0, n0, ng0, obj, np.take(closures.c1, picked, axis=1),
                 np.take(closures.c0, picked, axis=1), g, van, state.throughput,
                 ray_keys(state, np.arange(len(state))), tables.ray_epsilon, state.time, park=pool is not None)
    if pool is None:
        return found
    pool.add(state, obj, *found)
    return Exits().gather()


def exit_closures(hit):
    """subsurface_shader_data_setup: a Lambert closure of weight 1 on the exit's shading normal (facing out)."""
    n = len(hit)
    wo = tuple(-c for c in hit.d)
    b = ClosureBuilder(n, hit.ns, wo)
    b.add(lobes.LAMBERT, np.arange(n), np.ones((3, n), F32))
    return b.finish()
