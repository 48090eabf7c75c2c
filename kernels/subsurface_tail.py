"""The last few random walks of a batch, stepped one by one in Python floats (kernels/subsurface.py steps them
together in NumPy while there are many).

A batch of walks ends in a long tail: the last few walks of a wave can take a hundred steps or more (Cycles allows
256), and a NumPy step costs about the same for three walks as for three hundred (a hundred calls on tiny
arrays). Here each step of each walk is plain float arithmetic instead, the very operations of the NumPy step in
the same order on the same numbers (subsurface_medium.step_numbers: NumPy takes their logs, sines and cosines for
both), so the results are the same bit for bit where NumPy's exp is the C library's (it is on machines without
AVX-512; on those NumPy's own may differ in the last bit).

Steps are taken ahead: a walk's numbers are keyed by its step (rng.keyed_uniforms), so each walk takes TAIL_CHUNK
steps as if none of its flights met the surface, the flights of all the walks go to Embree in one query, and
each walk keeps its steps up to its first flight that met the surface, whose throughput is then computed as an
exit's. What came after it is thrown away, so the result is the step-by-step walk's.
"""
from __future__ import annotations

import math

import numpy as np

from .subsurface_medium import (DIFFUSION_LENGTH, G, ISOTROPIC_PDF, MAX_BOUNCES, PHASE_LOG, SIMILAR_GUIDED_FRACTION,
                                SIMILARITY_LEVEL, THROUGHPUT_EPSILON, step_numbers)
from .vec import INV_2PI

TAIL_CHUNK = 16             # steps taken ahead per walk and query
_INV_2PI_FLOAT = float(INV_2PI)   # Python float arithmetic is float64, as the NumPy step's
_FOUR_PI = 4 * np.pi


def finish(constants, state, rows, keys, bounce, trace, exits):
    """Steps the walks rows (int64 (m,)) from step `bounce` (an int, or (m,) each walk's next step, below
    MAX_BOUNCES) on until they leave, fade or reach MAX_BOUNCES. constants (CONSTANT_ROWS, m) and state (9, m)
    their columns of subsurface_medium.WalkTable; keys their ray keys; trace(origin (3, k), d (3, k), t_max (k,),
    rows (k,)) -> (prim, t, u, v) the walk's ray query; exits a subsurface_medium.Exits the walks that leave are
    added to."""
    consts = constants.T.tolist()
    states = state.T.tolist()
    steps = np.broadcast_to(np.asarray(bounce, np.int64), (len(rows),)).tolist()
    active = list(range(len(rows)))
    while active:
        idx = np.array(active)
        numbers = step_numbers((keys[0][idx], keys[1][idx]), np.array([steps[w] for w in active]), TAIL_CHUNK,
                               constants[G, idx], constants[DIFFUSION_LENGTH, idx], constants[PHASE_LOG, idx])
        per_walk = numbers.transpose(2, 0, 1).tolist()
        flights, planned = [], []
        for i, w in enumerate(active):
            first = len(flights) // 7
            exp = math.exp
            ahead = per_walk[i][:MAX_BOUNCES - steps[w]]
            try:
                plan = _ahead(consts[w], states[w], ahead, steps[w], flights, exp, math.sqrt)
            except (ArithmeticError, ValueError):
                # A division by zero or an overflow: the same steps with NumPy's scalars, which give inf and nan
                # where Python raises, as the NumPy step does.
                del flights[7 * first:]
                exp = np.exp
                plan = _ahead(np.array(consts[w]), np.array(states[w]), np.array(ahead), steps[w], flights,
                              exp, np.sqrt)
            planned.append((first, exp, len(ahead), *plan))
        flights = np.array(flights, np.float64).reshape(-1, 7)
        owners = np.repeat(rows[idx], [len(p[3]) for p in planned])
        prim, th, hu, hv = trace(flights[:, 0:3].T, flights[:, 3:6].T, flights[:, 6], owners)
        met, th_list = (prim >= 0).tolist(), th.tolist()
        going, out, out_steps, out_thr = [], [], [], []
        for w, (first, exp, taken, finishes, ended, after) in zip(active, planned):
            for j, terms in enumerate(finishes):
                if met[first + j]:
                    out.append(first + j)
                    out_steps.append(steps[w] + j)
                    out_thr.append(_finish(terms, th_list[first + j], True, exp))
                    break
            else:
                steps[w] += taken
                if not ended and steps[w] < MAX_BOUNCES:
                    states[w] = after if exp is math.exp else [float(x) for x in after]
                    going.append(w)
        if out:
            q = np.array(out)
            exits.add(owners[q], np.array(out_steps), prim[q], hu[q], hv[q], th[q], flights[q, 3:6].T,
                      np.array(out_thr, np.float64).reshape(-1, 3).T)
        active = going


def _ahead(const, state, numbers, bounce, flights, exp, sqrt):
    """A walk's next len(numbers) steps from step `bounce`, as if no flight met the surface: kernels/subsurface.py's
    _step, operation for operation. Appends each flight (origin, direction, length: 7 floats) to flights.
    Returns (the terms each step's throughput is computed from (for _finish), whether the walk ended (faded),
    its state after the last step)."""
    # WalkTable's rows, in their order
    (p0x, p0y, p0z, nx, ny, nz, mx, my, mz, tx, ty, tz, bx, by, bz, st0, st1, st2, ss0, ss1, ss2, sts0, sts1, sts2,
     sss0, sss1, sss2, a0, a1, a2, g, one_minus_g2, gf0, dl, phase_log, opposite, opp) = const
    px, py, pz, dx, dy, dz, t0, t1, t2 = state
    anisotropic = abs(g) >= 1e-3
    finishes = []
    for j, (u_ch, flight, u_gs, u_gd, gx, gy, gcos, cx, cy, ccos) in enumerate(numbers):
        if bounce + j > SIMILARITY_LEVEL:
            s0, s1, s2, r0, r1, r2, gf, hg_varies = sts0, sts1, sts2, sss0, sss1, sss2, SIMILAR_GUIDED_FRACTION, False
        else:
            s0, s1, s2, r0, r1, r2, gf, hg_varies = st0, st1, st2, ss0, ss1, ss2, gf0, anisotropic
        # volume_sample_channel
        w0, w1, w2 = abs(t0 * a0), abs(t1 * a1), abs(t2 * a2)
        total = w0 + w1 + w2
        if total > 0:
            c0, c1, c2 = w0 / total, w1 / total, w2 / total
        else:
            c0 = c1 = c2 = 1.0 / 3.0
        sample_st = s0 if u_ch < c0 else (s1 if u_ch < c0 + c1 else s2)
        guided = u_gs < gf
        back_frac = 0.0
        if opposite:
            x = (px - p0x) * mx + (py - p0y) * my + (pz - p0z) * mz
            if not (x != x or x > 0.0):     # np.clip(x, 0, opp), NaN kept
                x = 0.0
            if not (x != x or x < opp):
                x = opp
            try:
                back_frac = 1.0 / (1.0 + exp((opp - 2 * x) / dl))
            except OverflowError:
                back_frac = 0.0
        backward = u_gd < back_frac
        if guided:
            cos_g = -gcos if backward else gcos
            ex, ey, ez = gx * tx + gy * bx + cos_g * nx, gx * ty + gy * by + cos_g * ny, gx * tz + gy * bz + cos_g * nz
        else:
            # sampling.orthonormal_basis about the flight
            sign = 1.0 if dz >= 0 else -1.0
            a = -1.0 / (sign + dz)
            b = dx * dy * a
            ex = cx * (1.0 + sign * dx * dx * a) + cy * b + ccos * dx
            ey = cx * (sign * b) + cy * (sign + dy * dy * a) + ccos * dy
            ez = cx * (-sign * dx) + cy * (-dy) + ccos * dz
        length = sqrt(ex * ex + ey * ey + ez * ez)
        ex, ey, ez = ex / length, ey / length, ez / length
        if hg_varies:
            fac = 1 + g * (g - 2 * (dx * ex + dy * ey + dz * ez))
            hg = one_minus_g2 / (_FOUR_PI * fac * sqrt(max(fac, 0.0)))
        else:
            hg = ISOTROPIC_PDF
        cos_theta = cos_g if guided else ex * nx + ey * ny + ez * nz
        fwd_f = _INV_2PI_FLOAT / ((dl - cos_theta) * phase_log) / hg
        bwd_f = _INV_2PI_FLOAT / ((dl + cos_theta) * phase_log) / hg
        q = cos_theta / dl
        fwd_s, bwd_s = 1.0 - q, 1.0 + q
        if guided:
            sample_st = sample_st * (bwd_s if backward else fwd_s)
        t = flight / sample_st
        flights += (px, py, pz, ex, ey, ez, t)
        finishes.append((s0, s1, s2, r0, r1, r2, fwd_s, bwd_s, fwd_f, bwd_f, back_frac, opposite, gf, c0, c1, c2,
                         t0, t1, t2))
        # _finish(..., hit=False) unrolled (the same operations in the same order): the flight scattered.
        classic_w = 1 - gf
        tr0, tr1, tr2 = exp(-s0 * t), exp(-s1 * t), exp(-s2 * t)
        f0, f1, f2 = fwd_s * s0, fwd_s * s1, fwd_s * s2
        q0, q1, q2 = f0 * exp(-f0 * t) * fwd_f, f1 * exp(-f1 * t) * fwd_f, f2 * exp(-f2 * t) * fwd_f
        if opposite:
            forward_w = 1 - back_frac
            b0, b1, b2 = bwd_s * s0, bwd_s * s1, bwd_s * s2
            q0 = q0 * forward_w + b0 * exp(-b0 * t) * bwd_f * back_frac
            q1 = q1 * forward_w + b1 * exp(-b1 * t) * bwd_f * back_frac
            q2 = q2 * forward_w + b2 * exp(-b2 * t) * bwd_f * back_frac
        denom = c0 * (s0 * tr0 * classic_w + q0 * gf) + c1 * (s1 * tr1 * classic_w + q1 * gf) + \
            c2 * (s2 * tr2 * classic_w + q2 * gf)
        if denom > 0:
            t0, t1, t2 = r0 * tr0 * t0 / denom, r1 * tr1 * t1 / denom, r2 * tr2 * t2 / denom
        else:
            t0 = t1 = t2 = 0.0
        px, py, pz = px + t * ex, py + t * ey, pz + t * ez
        dx, dy, dz = ex, ey, ez
        if not (math.isfinite(t0) and math.isfinite(t1) and math.isfinite(t2)) or max(t0, t1, t2) < THROUGHPUT_EPSILON:
            return finishes, True, None
    return finishes, False, [px, py, pz, dx, dy, dz, t0, t1, t2]


def _finish(terms, t, hit, exp):
    """The throughput after a step's flight of length t that met the surface (hit) or scattered: subsurface.py's
    subsurface_random_walk_pdf for the classic, forward and backward guided sigma_t, mixed as the step mixes them,
    and _throughput, over the step's terms (see _ahead)."""
    s0, s1, s2, r0, r1, r2, fwd_s, bwd_s, fwd_f, bwd_f, back_frac, opposite, gf, c0, c1, c2, t0, t1, t2 = terms
    pdfs, trs = [], []
    for sigma_t in (s0, s1, s2):
        tr = exp(-sigma_t * t)
        sigma = fwd_s * sigma_t
        guided_tr = exp(-sigma * t)
        guided = (guided_tr if hit else sigma * guided_tr) * fwd_f
        if opposite:
            sigma = bwd_s * sigma_t
            back_tr = exp(-sigma * t)
            guided = guided * (1 - back_frac) + (back_tr if hit else sigma * back_tr) * bwd_f * back_frac
        pdfs.append((tr if hit else sigma_t * tr) * (1 - gf) + guided * gf)
        trs.append(tr)
    denom = c0 * pdfs[0] + c1 * pdfs[1] + c2 * pdfs[2]
    if not denom > 0:
        return 0.0, 0.0, 0.0
    tr0, tr1, tr2 = trs
    if hit:
        return tr0 * t0 / denom, tr1 * t1 / denom, tr2 * t2 / denom
    return r0 * tr0 * t0 / denom, r1 * tr1 * t1 / denom, r2 * tr2 * t2 / denom
