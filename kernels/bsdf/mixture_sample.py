"""Sampling the closure mixture (closures.ClosureSet): a direction per hit, and its record, BsdfSample.

Sampling picks one closure in proportion to its sample weight. A delta closure (a mirror, smooth glass,
transparency) gives its own direction with weight weight_j * w_j / P(j) and pdf = inf (nothing else can
find that direction). Otherwise the chosen lobe proposes the direction and the whole mixture is evaluated
there (mixture_eval): weight = f / pdf, one-sample MIS over the lobes (balance heuristic), as Cycles does;
the lobe that sampled enters that sum with its sampler's own value where the two differ (lobes.SELF_EVALUATED:
toon, hair), as Cycles keeps the sampling closure's eval. A Ray Portal is a delta closure whose sample also
moves the ray's start (BsdfSample.origin).
"""
from __future__ import annotations

import numpy as np

from .. import sampling
from ..vec import F32, ONE, ZERO
from . import frames
from .lobes import ANY_SIDE_LOBES, PORTAL, SAMPLED_ALONE, SELF_EVALUATED, SUBSURFACE_LOBES, TRANSPARENT
from .mixture_eval import eval_at, eval_closures, take_each, terminator_shift
from .registry import LOBES


class BsdfSample:
    """Per hit: direction wi (world), throughput weight (3, N), pdf (N,) for MIS (inf for delta),
    delta, transmit (the lobe transmits: Cycles' LABEL_TRANSMIT), transparent (a pass-through: a Transparent
    closure or a Ray Portal, which counts no bounce), portal (a Ray Portal) and any_side (ANY_SIDE_LOBES: no
    side test) masks, and row, the closure table row that was picked (-1: none), whose lobe says diffuse or
    glossy (Light Path). origin: None, or (3, N) float32 where a Ray Portal moves the ray's start (NaN
    elsewhere: the ray leaves from the hit). through: None, or (N,) where the ray leaves below the surface
    when that is not what transmit says (the integrator sets it for any_side samples). subsurface: None, or
    (N,) bool where a BSSRDF was picked: wi is the direction a subsurface walk starts along (kernels.subsurface),
    and subsurface_u (2, N) float32 the two numbers its lobe sample was given (Christensen-Burley's disk, which
    takes no direction, draws its probe with them: stratified where the vertex's numbers are)."""
    __slots__ = ("wi", "weight", "pdf", "delta", "transmit", "transparent", "portal", "any_side", "origin",
                 "through", "row", "subsurface", "subsurface_u")

    def __init__(self, n: int):
        self.wi = (np.zeros(n, F32), np.zeros(n, F32), np.ones(n, F32))
        self.weight = np.zeros((3, n), F32)
        self.pdf = np.zeros(n, F32)
        self.delta = np.zeros(n, bool)
        self.transmit = np.zeros(n, bool)
        self.transparent = np.zeros(n, bool)
        self.portal = np.zeros(n, bool)
        self.any_side = np.zeros(n, bool)
        self.origin = self.through = self.subsurface = self.subsurface_u = None
        self.row = np.full(n, -1, np.int64)


def pick_closures(cs, u: np.ndarray, rescale: bool):
    """One closure per hit in proportion to the sample weights: (row per hit, -1 where none; u rescaled within
    the chosen closure's share, or u when not asked: ClosureSet.choose_rescaled)."""
    if cs.single:
        return np.where(cs.total_sw > 0, cs.row_of_hit, -1), u
    cum = np.cumsum(cs.sw, dtype=np.float64)
    if not len(cum):
        return np.full(cs.n_hits, -1, np.int64), u
    before = np.where(cs.start > 0, cum[np.maximum(cs.start - 1, 0)], 0.0)
    target = before + u.astype(np.float64) * cs.total_sw
    row = np.clip(np.searchsorted(cum, target, side="right"), cs.start, cs.start + cs.count - 1)
    row = np.where((cs.count > 0) & (cs.total_sw > 0), row, -1)
    if not rescale:
        return row, u
    r = np.maximum(row, 0)
    lo = np.where(r > 0, cum[np.maximum(r - 1, 0)], 0.0)
    width = np.take(cs.sw, r).astype(np.float64)
    stretched = np.clip((target - lo) / np.where(width > 0, width, 1.0), 0.0, 1.0 - 2.0 ** -24)
    return row, np.where(row >= 0, stretched, u).astype(np.float32)


def sample(cs, u_lobe, u1, u2, uc, warp=None) -> BsdfSample:
    """Pick a closure per hit by u_lobe and sample the mixture (module docstring); uc is the glass
    lobes' reflect-or-refract number. u_lobe None: the closure is picked by u1, rescaled
    (ClosureSet.choose_rescaled).

    warp(hits, u1, u2) -> (wi world, pdf): the reference estimators' direction sampler (LECTURE and
    COSINE). With it, only delta closures are sampled by their lobe; when a non-delta closure is
    picked the warp proposes the direction and the weight is the non-delta mixture / (pdf x the
    probability of having picked a non-delta closure)."""
    n = cs.n_hits
    out = BsdfSample(n)
    if u_lobe is None:
        row, u1 = pick_closures(cs, u1, rescale=True)
    else:
        row = pick_closures(cs, u_lobe, rescale=False)[0]
    out.row = row
    has = np.flatnonzero(row >= 0)
    if not len(has):
        return out
    rows = row[has]
    if cs.lambert_only and warp is None:
        _sample_lambert(cs, out, has, rows, u1, u2)
        return out
    if warp is not None:
        picked = cs.delta[rows]
        _sample_lobes(cs, out, has[picked], rows[picked], u1, u2, uc)
        _sample_warp(cs, out, has[~picked], warp, u1, u2)
    else:
        _sample_lobes(cs, out, has, rows, u1, u2, uc)
        out.delta[has] = cs.delta[rows] | np.isinf(out.pdf[has])
        # Otherwise: the whole (non-delta) mixture at the sampled direction.
        s = np.flatnonzero(~out.delta & (out.pdf > 0))
        if cs.self_evaluated and len(s):
            s = _keep_alone(cs, out, s, row[s])
        if len(s):
            own = (out.weight[:, s] * out.pdf[s], out.pdf[s].copy()) if cs.self_evaluated else None
            f, pdf = eval_at(cs, s, tuple(c[s] for c in out.wi))
            _sampled_bump(cs, s, row[s], out, f, pdf)
            if own is not None:
                _sampled_self(cs, s, row[s], out, f, pdf, own)
            good = pdf > 0
            sampling.put_columns(out.weight, s, np.where(good, f / np.where(good, pdf, ONE), ZERO))
            out.pdf[s] = pdf
    # Delta: the chosen closure alone, divided by the probability of choosing it.
    d = np.flatnonzero(out.delta & (out.pdf > 0))
    if len(d):
        r = row[d]
        sampling.scale_columns(out.weight, d, np.take(cs.weight, r, axis=1) * (cs.total_sw[d] / cs.sw[r]))
        out.pdf[d] = np.inf
        _shift_reflections(cs, out, d, r)
    sampling.put_columns(out.weight, np.flatnonzero(~(out.pdf > 0)), ZERO)
    return out


def _shift_reflections(cs, out, hits, rows) -> None:
    """The samples at hits of closures rows that reflect take the shadow terminator's shading offset
    (mixture_eval.terminator_shift), as Cycles' bsdf_sample gives it to a sample not labelled transmission."""
    if cs.terminator is None:
        return
    keep = np.flatnonzero(~out.transmit[hits])
    if not len(keep):
        return
    h = hits[keep]
    shift = terminator_shift(cs, rows[keep], tuple(c[h] for c in out.wi))
    if shift is not None:
        sampling.scale_columns(out.weight, h, shift)


def _keep_alone(cs, out, s, rows):
    """Hits s whose only closure (rows) is of a lobes.SAMPLED_ALONE lobe take their sample's value times the
    closure's weight (in out, in place); returns the other hits, whose mixture is still to evaluate."""
    alone = np.isin(cs.lobe[rows], SAMPLED_ALONE)
    if not cs.single:
        alone &= cs.count[s] == 1
    if not alone.any():
        return s
    a = np.flatnonzero(alone)
    sampling.scale_columns(out.weight, s[a], np.take(cs.weight, rows[a], axis=1))
    _shift_reflections(cs, out, s[a], rows[a])
    return s[~alone]


def _sampled_bump(cs, s, rows, out, f, pdf):
    """Cycles weighs the closure that sampled a direction by the term of a sample, not of an
    evaluation: no rejection for non-diffuse ones, no term at all for transmission. Put back into the
    mixture (f, pdf at hits s, in place) what eval_at's evaluation term took from them."""
    bump = cs.bump
    if bump is None:
        return
    fix = np.flatnonzero(bump.bumped[rows] & (~bump.diffuse[rows] | out.transmit[s]))
    if not len(fix):
        return
    r = rows[fix]
    wi = tuple(c[s[fix]] for c in out.wi)
    lost = ONE - bump.term(r, wi, cs.normal, cs.soften)
    f_c, pdf_c = eval_closures(cs, wi, r, bump=False)
    f[:, fix] += f_c * lost
    pdf[fix] += (pdf_c * lost * cs.sw[r] / cs.total_sw[s[fix]]).astype(F32)


def _sampled_self(cs, s, rows, out, f, pdf, own):
    """For closures of SELF_EVALUATED lobes that sampled, put their sampler's (f |cos|, pdf) own (lobe
    values at hits s) in the mixture (f, pdf, in place) in place of eval_at's evaluation of them: Cycles
    keeps the sampling closure's own eval. The bump term is that of a sample (_sampled_bump)."""
    fix = np.flatnonzero(np.isin(cs.lobe[rows], SELF_EVALUATED))
    if not len(fix):
        return
    r, h = rows[fix], s[fix]
    wi = tuple(c[h] for c in out.wi)
    f_c, pdf_c = eval_closures(cs, wi, r, bump=False)
    term = cs.bump.term(r, wi, cs.normal, cs.soften) if cs.bump is not None else None
    term = np.ones(len(r), F32) if term is None else np.where(cs.bump.diffuse[r], term, ONE)
    f_own = own[0][:, fix] * np.take(cs.weight, r, axis=1)
    shift = terminator_shift(cs, r, wi)   # in f_c already: the sampler's own value takes it too
    if shift is not None:
        f_own = f_own * shift
    f[:, fix] += (f_own - f_c) * term
    pdf[fix] += ((own[1][fix] - pdf_c) * (term > 0) * cs.sw[r] / cs.total_sw[h]).astype(F32)


def _sample_lambert(cs, out, hits, rows, u1, u2):
    """Only Lambert closures, all on the shading normal: a cosine sample about it. Every closure of
    the hit has the same pdf, so the mixture's f cos / pdf is the sum of the hit's closure weights
    (one closure's weight when it has one)."""
    # Every hit has its closure, in hit order (a diffuse scene): no gathers or scatters.
    whole = len(hits) == cs.n_hits and cs.single and len(rows) == len(cs.hit) and \
        bool((rows == np.arange(len(rows))).all())
    if whole:
        lx, ly, lz = sampling.sample_cosine_hemisphere(u1, u2)
        n = cs.normal
    else:
        lx, ly, lz = sampling.sample_cosine_hemisphere(u1[hits], u2[hits])
        n = np.take(cs.normal, rows, axis=1)
    world = sampling.local_to_world(lx, ly, lz, n[0], n[1], n[2])
    pdf = sampling.cosine_hemisphere_pdf(lz)
    good = pdf > 0
    if cs.single:
        weight = cs.weight if whole else np.take(cs.weight, rows, axis=1)
    else:  # a Mix or Add of Diffuse BSDFs
        weight = np.stack([np.bincount(cs.hit, cs.weight[k], minlength=cs.n_hits)[hits]
                           for k in range(3)]).astype(F32)
    shift = terminator_shift(cs, np.arange(len(rows)) if whole else rows, world)
    if shift is not None:
        weight = weight * shift
    if whole:
        out.wi = tuple(world)
        out.weight = np.where(good, weight, ZERO)
        out.pdf = pdf
        return
    for axis in range(3):
        out.wi[axis][hits] = world[axis]
    sampling.put_columns(out.weight, hits, np.where(good, weight, ZERO))
    out.pdf[hits] = pdf


def _sample_lobes(cs, out, hits, rows, u1, u2, uc):
    """Each hit's chosen closure samples its own lobe: direction, lobe weight, lobe pdf."""
    lobe = cs.lobe[rows]
    for k in np.unique(lobe):
        sel = np.flatnonzero(lobe == k)
        r, h = rows[sel], hits[sel]
        if k == PORTAL:
            _sample_portals(cs, out, h, r)
            continue
        wi, weight, pdf, transmit = LOBES[k].sample(cs, r, take_each(cs.wo, r), u1[h], u2[h], uc[h])
        world = frames.to_world(tuple(np.take(c, r, axis=1) for c in cs.frame), wi)
        for axis in range(3):
            out.wi[axis][h] = world[axis]
        sampling.put_columns(out.weight, h, weight)
        out.pdf[h] = pdf
        out.transmit[h] = transmit
        out.delta[h] = cs.delta[r] | np.isinf(pdf)
        out.transparent[h] = k == TRANSPARENT
        out.any_side[h] = k in ANY_SIDE_LOBES
        if k in SUBSURFACE_LOBES:
            if out.subsurface is None:
                out.subsurface = np.zeros(len(out.pdf), bool)
                out.subsurface_u = np.zeros((2, len(out.pdf)), F32)
            out.subsurface[h] = True
            out.subsurface_u[0, h], out.subsurface_u[1, h] = u1[h], u2[h]


def _sample_portals(cs, out, hits, rows):
    """Ray Portal closures rows at hits send the ray on from their origin along their direction (world
    space), weight 1 and pdf inf: a pass-through like transparency, Cycles' integrate_surface_ray_portal.
    Which side of the surface that is, the integrator sees (it has the geometric normal)."""
    for axis in range(3):
        out.wi[axis][hits] = cs.direction[axis, rows]
    sampling.put_columns(out.weight, hits, ONE)
    out.pdf[hits] = np.inf
    for mask in (out.delta, out.transparent, out.portal, out.any_side, out.transmit):
        mask[hits] = True
    origin = np.take(cs.origin, rows, axis=1)
    moved = np.flatnonzero(np.isfinite(origin[0]))
    if len(moved):
        if out.origin is None:
            out.origin = np.full((3, len(out.pdf)), np.nan, F32)
        out.origin[:, hits[moved]] = origin[:, moved]


def _sample_warp(cs, out, hits, warp, u1, u2):
    """The reference estimators' warp proposes the directions of hits whose picked closure is not delta;
    the weight is the non-delta mixture / (pdf x the probability of picking a non-delta closure)."""
    if not len(hits):
        return
    wi, pdf = warp(hits, u1[hits], u2[hits])
    f, _ = eval_at(cs, hits, wi)
    if cs.single:
        share = np.ones(len(hits), F32)
    else:
        smooth = np.bincount(cs.hit, cs.sw * ~cs.delta, minlength=cs.n_hits)[hits]
        share = (smooth / cs.total_sw[hits]).astype(F32)
    good = (pdf > 0) & (share > 0)
    denom = np.where(good, pdf * share, ONE)
    for axis in range(3):
        out.wi[axis][hits] = wi[axis]
    sampling.put_columns(out.weight, hits, np.where(good, f / denom, ZERO))
    out.pdf[hits] = np.where(good, pdf, ZERO)
