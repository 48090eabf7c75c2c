"""Every lobe family in one visible table, LOBES: the functions that evaluate and sample it in the closure table
(closures.ClosureSet looks them up here; nothing registers itself on import), the branch a two-branch singular
lobe did not take (smooth glass: the integrator asks the closure set, which asks here), and what the lobe
reads from the closure table's parameter columns. What each lobe is (diffuse, glossy, singular...) is
lobes.CLASSES.

The contract of the functions (the package docstring has the lobes'):
    eval(cs, rows, wo, wi) -> (f |cos| (3, n), pdf (n,)), directions in the closures' local frames;
    sample(cs, rows, wo, u1, u2, uc) -> (wi, weight = f |cos| / pdf (3, n), pdf (n,), transmit (n,) bool);
    other_branch(cs, hits, rows, transmitted) -> see microfacet_closures.singular_glass_other_branch.
cs is the ClosureSet, rows its closure rows of this lobe, wo (3 tuple of (n,)) toward the viewer.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from ..vec import F32
from . import bssrdf, diffuse, frames, hair, hair_chiang, hair_huang, sheen, toon, velvet
from . import microfacet_closures as mfc
from .lobes import (ASHIKHMIN_SHIRLEY, BSSRDF, GLASS, HAIR_CHIANG, HAIR_HUANG, HAIR_REFLECTION, HAIR_TRANSMISSION,
                    LAMBERT, OREN_NAYAR, PORTAL, REFLECTION, REFRACTION, SHEEN, TOON_DIFFUSE, TOON_GLOSSY, TRANSLUCENT,
                    TRANSPARENT, VELVET)


@dataclass(frozen=True)
class Lobe:
    """One lobe family's entry. eval None: a singular lobe, which nothing but its own sample finds; sample None:
    a lobe the closure table samples itself (a Ray Portal: its direction is the closure's own column)."""
    name: str
    eval: Callable | None
    sample: Callable | None
    other_branch: Callable | None = None
    columns: dict = field(default_factory=dict)   # parameter column (closures.ClosureBuilder.add) -> meaning


# ---------------------------------------------------------------- the families in the closure table
def _lambert_eval(cs, rows, wo, wi):
    return diffuse.lambert_eval(wo, wi)


def _lambert_sample(cs, rows, wo, u1, u2, uc):
    wi, weight, pdf = diffuse.lambert_sample(wo, u1, u2)
    return wi, weight, pdf, False


def _oren_nayar_eval(cs, rows, wo, wi):
    return diffuse.oren_nayar_eval(wo, wi, cs.rough[rows], np.take(cs.c0, rows, axis=1))


def _oren_nayar_sample(cs, rows, wo, u1, u2, uc):
    wi, weight, pdf = diffuse.oren_nayar_sample(wo, cs.rough[rows], np.take(cs.c0, rows, axis=1), u1, u2)
    return wi, weight, pdf, False


def _translucent_eval(cs, rows, wo, wi):
    return diffuse.translucent_eval(wo, wi)


def _translucent_sample(cs, rows, wo, u1, u2, uc):
    wi, weight, pdf = diffuse.translucent_sample(wo, u1, u2)
    return wi, weight, pdf, True


def _sheen_eval(cs, rows, wo, wi):
    return sheen.sheen_eval(wo, wi, cs.rough[rows])


def _sheen_sample(cs, rows, wo, u1, u2, uc):
    wi, weight, pdf = sheen.sheen_sample(wo, cs.rough[rows], u1, u2)
    return wi, weight, pdf, False


def _velvet_eval(cs, rows, wo, wi):
    return velvet.velvet_eval(wo, wi, cs.rough[rows])


def _velvet_sample(cs, rows, wo, u1, u2, uc):
    wi, weight, pdf = velvet.velvet_sample(wo, cs.rough[rows], u1, u2)
    return wi, weight, pdf, False


def _toon_diffuse_eval(cs, rows, wo, wi):
    return toon.diffuse_toon_eval(wo, wi, cs.size[rows], cs.smooth[rows])


def _toon_diffuse_sample(cs, rows, wo, u1, u2, uc):
    wi, weight, pdf = toon.diffuse_toon_sample(wo, cs.size[rows], cs.smooth[rows], u1, u2)
    return wi, weight, pdf, False


def _toon_glossy_eval(cs, rows, wo, wi):
    return toon.glossy_toon_eval(wo, wi, cs.size[rows], cs.smooth[rows])


def _toon_glossy_sample(cs, rows, wo, u1, u2, uc):
    wi, weight, pdf = toon.glossy_toon_sample(wo, cs.size[rows], cs.smooth[rows], u1, u2)
    return wi, weight, pdf, False


def _hair_args(cs, rows):
    """A hair closure's tangent in its local frame, and its roughnesses and offset."""
    tangent = frames.to_local(tuple(np.take(c, rows, axis=1) for c in cs.frame),
                        tuple(np.take(c, rows) for c in cs.hair_t))
    return tangent, cs.r1[rows], cs.r2[rows], cs.offset[rows]


def _hair_reflection_eval(cs, rows, wo, wi):
    return hair.hair_reflection_eval(wo, wi, *_hair_args(cs, rows))


def _hair_reflection_sample(cs, rows, wo, u1, u2, uc):
    wi, weight, pdf = hair.hair_reflection_sample(wo, *_hair_args(cs, rows), u1, u2)
    return wi, weight, pdf, False


def _hair_transmission_eval(cs, rows, wo, wi):
    return hair.hair_transmission_eval(wo, wi, *_hair_args(cs, rows))


def _hair_transmission_sample(cs, rows, wo, u1, u2, uc):
    wi, weight, pdf = hair.hair_transmission_sample(wo, *_hair_args(cs, rows), u1, u2)
    return wi, weight, pdf, True


def _chiang_args(cs, rows):
    """A Chiang hair closure's offset, variances, scale, tilt, IOR and absorption (hair_chiang)."""
    return (cs.hair_h[rows], cs.hair_v[rows], cs.hair_s[rows], cs.hair_m0[rows], cs.offset[rows], cs.eta[rows],
            np.take(cs.c0, rows, axis=1))


def _chiang_eval(cs, rows, wo, wi):
    return hair_chiang.chiang_eval(wo, wi, *_chiang_args(cs, rows))


def _chiang_sample(cs, rows, wo, u1, u2, uc):
    return hair_chiang.chiang_sample(wo, *_chiang_args(cs, rows), u1, u2, uc)


def huang_params(cs, rows, wo) -> hair_huang.HuangParams:
    """A Huang hair closure's parameters (hair_huang.HuangParams) with its viewer direction wo (closure frame)."""
    return hair_huang.HuangParams(cs.rough[rows], cs.offset[rows], cs.eta[rows], cs.aspect[rows],
                                  np.take(cs.c0, rows, axis=1), np.take(cs.c1, rows, axis=1), cs.hair_h[rows],
                                  cs.coverage[rows], hair_huang.to_cycles(wo))


def _huang_eval(cs, rows, wo, wi):
    return hair_huang.huang_eval(huang_params(cs, rows, wo), wo, wi)


def _huang_sample(cs, rows, wo, u1, u2, uc):
    return hair_huang.huang_sample(huang_params(cs, rows, wo), u1, u2, uc)


def _transparent_sample(cs, rows, wo, u1, u2, uc):
    wi = (-wo[0], -wo[1], -wo[2])
    n = len(rows)
    return wi, np.ones(n, F32), np.ones(n, F32), True


def _bssrdf_sample(cs, rows, wo, u1, u2, uc):
    """The direction a subsurface walk starts along (bssrdf.entry_sample); weight 1, pdf inf (the mixture's
    delta rule gives it Cycles' bssrdf sample weight); pdf 0 where the viewer is below the closure's normal."""
    wi, ok = bssrdf.entry_sample(wo, cs.ax[rows], cs.eta[rows], cs.dist[rows], u1, u2)
    n = len(rows)
    return wi, np.ones(n, F32), np.where(ok, np.float32(np.inf), np.float32(0.0)), True


_MICROFACET_COLUMNS = {"ax": "alpha x", "ay": "alpha y", "dist": "distribution (GGX, Beckmann)",
                       "eval_scale": "1 / E, multiscatter", "fresnel": "Fresnel mode (microfacet_closures.F_*)",
                       "eta": "far side over the viewer's side", "c0": "F0 or n", "c1": "F82 b, k or reflection tint",
                       "c2": "transmission tint", "film_t": "thin film thickness, nm", "film_ior": "thin film IOR"}
_HAIR_COLUMNS = {"r1": "roughness along the strand", "r2": "roughness around it", "offset": "highlight shift",
                 "hair_t": "unit tangent, world space"}
_TOON_COLUMNS = {"size": "cone angle", "smooth": "smooth angle"}
_CHIANG_COLUMNS = {"hair_h": "offset across the strand", "hair_v": "longitudinal variance", "hair_s": "logistic scale",
                   "hair_m0": "R lobe variance", "offset": "scale tilt (-Offset)", "eta": "IOR", "c0": "absorption"}
_HUANG_COLUMNS = {"hair_h": "offset across the fibre", "rough": "GGX alpha", "offset": "tilt (-Offset)", "eta": "IOR",
                  "aspect": "minor over major axis", "c0": "absorption", "c1": "R, TT, TRT scales",
                  "coverage": "half a pixel over the fibre's radius (1: far field)"}

LOBES = {
    LAMBERT: Lobe("Lambert", _lambert_eval, _lambert_sample),
    OREN_NAYAR: Lobe("Oren-Nayar", _oren_nayar_eval, _oren_nayar_sample, columns={"rough": "sigma", "c0": "albedo"}),
    TRANSLUCENT: Lobe("translucent", _translucent_eval, _translucent_sample),
    SHEEN: Lobe("sheen", _sheen_eval, _sheen_sample, columns={"rough": "roughness"}),
    VELVET: Lobe("Ashikhmin velvet", _velvet_eval, _velvet_sample, columns={"rough": "sigma"}),
    TRANSPARENT: Lobe("transparent", None, _transparent_sample),
    REFLECTION: Lobe("microfacet reflection", mfc.reflection_eval, mfc.reflection_sample, columns=_MICROFACET_COLUMNS),
    REFRACTION: Lobe("microfacet refraction", mfc.refraction_eval, mfc.refraction_sample, columns=_MICROFACET_COLUMNS),
    GLASS: Lobe("microfacet glass", mfc.glass_eval, mfc.glass_sample, mfc.singular_glass_other_branch,
                columns=_MICROFACET_COLUMNS),
    ASHIKHMIN_SHIRLEY: Lobe("Ashikhmin-Shirley", mfc.ashikhmin_shirley_eval, mfc.ashikhmin_shirley_sample,
                            columns={"ax": "alpha x", "ay": "alpha y"}),
    TOON_DIFFUSE: Lobe("toon diffuse", _toon_diffuse_eval, _toon_diffuse_sample, columns=_TOON_COLUMNS),
    TOON_GLOSSY: Lobe("toon glossy", _toon_glossy_eval, _toon_glossy_sample, columns=_TOON_COLUMNS),
    PORTAL: Lobe("Ray Portal", None, None, columns={"origin": "where the ray goes on (NaN: the hit)",
                                                     "direction": "its direction"}),
    HAIR_REFLECTION: Lobe("hair reflection", _hair_reflection_eval, _hair_reflection_sample, columns=_HAIR_COLUMNS),
    HAIR_TRANSMISSION: Lobe("hair transmission", _hair_transmission_eval, _hair_transmission_sample,
                            columns=_HAIR_COLUMNS),
    HAIR_CHIANG: Lobe("Principled Hair (Chiang)", _chiang_eval, _chiang_sample, columns=_CHIANG_COLUMNS),
    HAIR_HUANG: Lobe("Principled Hair (Huang)", _huang_eval, _huang_sample, columns=_HUANG_COLUMNS),
    BSSRDF: Lobe("subsurface (BSSRDF)", None, _bssrdf_sample,
                 columns={"c0": "radius, method-scaled", "c1": "albedo", "ax": "entry GGX alpha", "eta": "IOR",
                          "offset": "anisotropy", "dist": "method (bssrdf.METHODS)"}),
}
