"""Evaluating the closure mixture (closures.ClosureSet) toward given directions: each closure's lobe in its
local frame, times its weight, with the bump shadowing term (bump.py), summed per hit.

    f(wi)   = sum_j weight_j * f_j(wi) |cos|                (delta lobes contribute nothing)
    pdf(wi) = sum_j sample_weight_j * pdf_j(wi) / sum_j sample_weight_j

Lobes of one kind are evaluated together, by their registry entry.
"""
from __future__ import annotations

import numpy as np

from .. import sampling
from ..vec import F32, INV_PI, ONE, ZERO
from . import frames
from .lobes import MICROFACET_LOBES, SINGULAR_LOBES
from .registry import LOBES


def eval_at(cs, hits: np.ndarray, wi) -> tuple[np.ndarray, np.ndarray]:
    """The mixture of the hits `hits` (ascending, unique) at their world directions wi (n,).
    Returns f |cos| (3, n) and pdf (n,)."""
    if cs.single:
        rows = cs.row_of_hit[hits]
        have = rows >= 0
        if have.all():
            return eval_closures(cs, wi, rows)
        f, pdf = np.zeros((3, len(hits)), F32), np.zeros(len(hits), F32)
        sel = np.flatnonzero(have)
        f[:, sel], pdf[sel] = eval_closures(cs, tuple(c[sel] for c in wi), rows[sel])
        return f, pdf
    idx, local = hit_rows(cs, hits)
    f_c, pdf_c = eval_closures(cs, tuple(np.take(c, local) for c in wi), idx)
    f = np.stack([np.bincount(local, f_c[k], minlength=len(hits)) for k in range(3)]).astype(F32)
    total = cs.total_sw[hits]
    with np.errstate(divide="ignore", invalid="ignore"):
        pdf = np.bincount(local, pdf_c * cs.sw[idx], minlength=len(hits)) / total
    return f, np.where(total > 0, pdf, 0.0).astype(F32)


def average_roughness_squared(cs, hits: np.ndarray, wi) -> np.ndarray:
    """ClosureSet.average_roughness_squared: the closures' roughness squared at hits, weighted by pdf x sample weight
    toward wi."""
    if cs.single:
        rows = cs.row_of_hit[hits]
        have = np.flatnonzero(rows >= 0)
        out = np.zeros(len(hits), F32)
        if len(have):
            _, pdf = eval_closures(cs, tuple(c[have] for c in wi), rows[have])
            out[have] = np.where(pdf > 0, cs.specular_roughness_squared(rows[have]), ZERO)
        return out
    idx, local = hit_rows(cs, hits)
    _, pdf_c = eval_closures(cs, tuple(np.take(c, local) for c in wi), idx)
    weight = pdf_c.astype(np.float64) * cs.sw[idx]
    total = np.bincount(local, weight, minlength=len(hits))
    rough = np.bincount(local, weight * cs.specular_roughness_squared(idx), minlength=len(hits))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(total > 0, rough / total, 0.0).astype(F32)


def eval_closures(cs, wi_world, idx, bump: bool = True):
    """f |cos| (3, n) times the closure weight, and pdf (n,), of closures idx at wi_world (n,); with
    the bump shadowing term of an evaluation unless bump is False, and the shadow terminator's shading offset
    (terminator_shift) always."""
    f, pdf = _eval_unshadowed(cs, wi_world, idx)
    bumped = cs.bump.select(idx, wi_world, cs.normal, cs.soften) if bump and cs.bump is not None else None
    if bumped is not None:  # the term is 1 elsewhere: only the bumped closures change
        sel, term = bumped
        sampling.scale_columns(f, sel, term)
        pdf[sel] = np.where(term > 0, pdf[sel], ZERO)
    shift = terminator_shift(cs, idx, wi_world)
    if shift is not None:
        f = f * shift
    return f, pdf


def terminator_shift(cs, rows, wi_world):
    """(n,) float32 factor on the eval of closures rows toward wi_world, or None when it is 1 everywhere: Cycles'
    shadow terminator Shading Offset (closure/bsdf.h shift_cos_in, from appleseed), which bends a closure's cosine
    toward the light into cos(m theta) for directions on its normal's side, m = 1 / (1 - offset / 2) the hit's
    object's (ClosureSet.terminator), softening the terminator of coarse smooth-shaded meshes. The pdf stays."""
    if cs.terminator is None or not len(rows):
        return None
    m = np.take(cs.terminator, np.take(cs.hit, rows))
    n = cs.normal
    cos = wi_world[0] * n[0, rows] + wi_world[1] * n[1, rows] + wi_world[2] * n[2, rows]
    on = (m > ONE) & (cos >= ZERO)
    if not on.any():
        return None
    c = np.minimum(cos, ONE)
    with np.errstate(divide="ignore", invalid="ignore"):
        value = np.maximum(np.cos(np.arccos(c) * m), ZERO) / c
    return np.where(on, np.nan_to_num(value, nan=0.0, posinf=0.0), ONE).astype(F32)


def hit_rows(cs, hits: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every closure row of the hits `hits` of a set sorted by hit (not single): (rows, the entry of hits
    each belongs to), in hit order."""
    count = cs.count[hits]
    idx = np.repeat(cs.start[hits], count) + _ranges(count)
    local = np.repeat(np.arange(len(hits)), count)
    return idx, local


def take_each(w, idx):
    """Entries idx of each component of a direction tuple w."""
    return tuple(np.take(c, idx) for c in w)


def _eval_unshadowed(cs, wi_world, idx):
    """eval_closures without the bump shadowing term."""
    if cs.lambert_only:
        n = cs.normal
        cos = wi_world[0] * n[0, idx] + wi_world[1] * n[1, idx] + wi_world[2] * n[2, idx]
        pdf = np.maximum(cos, ZERO) * INV_PI
        return np.take(cs.weight, idx, axis=1) * pdf, pdf
    wi = frames.to_local(tuple(np.take(c, idx, axis=1) for c in cs.frame), wi_world)
    if len(cs.kinds) == 1:
        return _eval_lobe(cs, cs.kinds[0], idx, wi)
    f = np.zeros((3, len(idx)), F32)
    pdf = np.zeros(len(idx), F32)
    lobe = cs.lobe[idx]
    for k in cs.kinds:
        sel = np.flatnonzero(lobe == k)
        if len(sel):
            f_k, pdf[sel] = _eval_lobe(cs, k, idx[sel], take_each(wi, sel))
            sampling.put_columns(f, sel, f_k)
    return f, pdf


def _eval_lobe(cs, k, rows, wi):
    if k in SINGULAR_LOBES:
        return np.zeros((3, len(rows)), F32), np.zeros(len(rows), F32)
    value, pdf = LOBES[k].eval(cs, rows, take_each(cs.wo, rows), wi)
    f = value * np.take(cs.weight, rows, axis=1)
    if k in MICROFACET_LOBES:
        live = ~cs.delta[rows]
        f, pdf = np.where(live, f, ZERO), np.where(live, pdf, ZERO)
    return f, pdf


def _ranges(count: np.ndarray) -> np.ndarray:
    """0..count[i]-1 for every i, concatenated."""
    total = int(count.sum())
    if total == 0:
        return np.zeros(0, np.int64)
    offsets = np.repeat(np.cumsum(count) - count, count)
    return np.arange(total) - offsets
