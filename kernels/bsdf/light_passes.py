"""What the light and colour passes read of the closure mixture: the class Cycles files a closure's light
under (diffuse, glossy, transmission: `kernel/film/light_passes.h`), the mixture evaluated with its diffuse
and glossy parts, and the closures' albedo estimates (Cycles' bsdf_albedo)."""
from __future__ import annotations

import numpy as np

from ..vec import F32, ZERO
from .lobes import DIFFUSE_LOBES, GLASS, GLOSSY_LOBES, TRANSMISSION_LOBES
from .mixture_eval import eval_closures, hit_rows


def pass_classes(cs, idx, wi):
    """(diffuse, glossy) (n,) bool of closures idx toward world directions wi (n,), as Cycles' bsdf_eval_accum
    sorts them for its light passes (anything else is transmission)."""
    lobe = cs.lobe[idx]
    diffuse = np.isin(lobe, DIFFUSE_LOBES)
    glossy = np.isin(lobe, GLOSSY_LOBES)
    if GLASS in cs.kinds:
        n = np.take(cs.normal, idx, axis=1)
        glossy |= (lobe == GLASS) & (wi[0] * n[0] + wi[1] * n[1] + wi[2] * n[2] > 0)
    return diffuse, glossy


def eval_split(cs, hits: np.ndarray, wi):
    """ClosureSet.eval_at with its diffuse and glossy parts: (f (3, n), f_diffuse (3, n), f_glossy (3, n))."""
    if cs.single:
        rows = cs.row_of_hit[hits]
        have = np.flatnonzero(rows >= 0)
        out = [np.zeros((3, len(hits)), F32) for _ in range(3)]
        if len(have):
            w = tuple(c[have] for c in wi)
            f, _ = eval_closures(cs, w, rows[have])
            diffuse, glossy = pass_classes(cs, rows[have], w)
            out[0][:, have], out[1][:, have], out[2][:, have] = f, f * diffuse, f * glossy
        return tuple(out)
    idx, local = hit_rows(cs, hits)
    w = tuple(np.take(c, local) for c in wi)
    f_c, _ = eval_closures(cs, w, idx)
    diffuse, glossy = pass_classes(cs, idx, w)
    return tuple(np.stack([np.bincount(local, part[k], minlength=len(hits)) for k in range(3)]).astype(F32)
                 for part in (f_c, f_c * diffuse, f_c * glossy))


def weight_albedo(weight, sw) -> np.ndarray:
    """(3, C) the weight times the sample weight over the weight's mean: the albedo of a closure whose
    colour is all in its weight (its sample weight is the mean weight times the lobe's estimated albedo)."""
    weight = np.asarray(weight, F32)
    mean = weight.mean(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return (weight * np.where(mean > 0, np.asarray(sw, F32) / mean, 0.0)).astype(F32)


def closure_albedos(cs) -> np.ndarray:
    """(3, C) each closure's albedo estimate, Cycles' bsdf_albedo (reflection and transmission): the one
    the closure gave (a metal's Fresnel colour, glass's tints), else its weight times its sample weight
    over its mean weight."""
    if cs.albedo is not None:
        return (cs.albedo[0] + cs.albedo[1]).astype(F32)
    return weight_albedo(cs.weight, cs.sw)


def class_albedo(cs, n_hits: int):
    """(diffuse, glossy, transmission) (3, n) colours of the hits' closures (Cycles' surface_shader_diffuse,
    _glossy, _transmission): each closure's albedo (closure_albedos) summed in its class; glass gives its
    reflection to glossy and its transmission to transmission, as Cycles' bsdf_albedo(reflection,
    transmission) splits them."""
    out = [np.zeros((3, n_hits), F32) for _ in range(3)]
    if not len(cs):
        return tuple(out)
    lobe = cs.lobe
    reflect, transmit = cs.albedo if cs.albedo is not None else (weight_albedo(cs.weight, cs.sw), ZERO)
    total = reflect + transmit
    glass = lobe == GLASS
    parts = (total * np.isin(lobe, DIFFUSE_LOBES),
             total * np.isin(lobe, GLOSSY_LOBES) + reflect * glass,
             total * np.isin(lobe, TRANSMISSION_LOBES) + transmit * glass)
    for o, part in zip(out, parts):
        for k in range(3):
            o[k] = np.bincount(cs.hit, part[k], minlength=n_hits)
    return tuple(out)
