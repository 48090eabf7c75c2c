"""What world focus sampling (environment.Environment.focus) asks of the closure mixture: each hit's main
glossy lobe, the direction about which it gathers light and how wide it is."""
from __future__ import annotations

import numpy as np

from ..vec import F32, ONE
from . import fresnel
from .lobes import ASHIKHMIN_SHIRLEY, GLASS, REFLECTION, REFRACTION

# glossy_axes: the lobes that gather light about one direction (a mirror's or a refraction's, blurred by
# roughness) are reflection, refraction, glass and Ashikhmin-Shirley.
MAX_AXIS_RADIUS = F32(1.0)    # radians: a lobe wider than this gathers from too much of the sphere to focus on
MIN_AXIS_RADIUS = F32(0.02)
MIN_AXIS_SHARE = F32(0.2)     # a lobe with less of its hit's sampling weight is not worth focusing on
AXIS_TILT = F32(2.0)          # microfacet normals within atan(2 alpha) of the macro normal: 80% of GGX's


def glossy_axes(cs):
    """Each hit's main glossy lobe: (hits, (dx, dy, dz), radius, share) for the hits that have one, where d is
    the world direction about which the lobe gathers light, radius (radians) holds most of it and share is
    its part of the hit's sampling weight (at least MIN_AXIS_SHARE); a rough microfacet lobe narrower than
    MAX_AXIS_RADIUS qualifies. d is the mirror direction about the closure's normal, or the refracted one
    (glass: the branch that Fresnel favours at the macro normal, with its probability in the share). The
    radius is how far d moves when the microfacet normal tilts by atan(2 alpha): twice the tilt for
    reflection, |1 - cos_i / (eta cos_t)| times it for refraction (Snell's law differentiated)."""
    lobe = cs.lobe
    cand = ((lobe == REFLECTION) | (lobe == REFRACTION) | (lobe == GLASS) | (lobe == ASHIKHMIN_SHIRLEY)) & \
        ~cs.delta & (cs.sw >= MIN_AXIS_SHARE * np.take(cs.total_sw, cs.hit))
    rows = np.flatnonzero(cand)
    empty = np.zeros(0, F32)
    if not len(rows):
        return np.zeros(0, np.int64), (empty, empty, empty), empty, empty
    h = cs.hit[rows]
    nx, ny, nz = np.take(cs.normal, rows, axis=1)
    wx, wy, wz = (np.take(a, h) for a in cs.wo_world)
    cos = wx * nx + wy * ny + wz * nz
    flip = np.where(cos < 0, F32(-1.0), ONE)
    nx, ny, nz, c = nx * flip, ny * flip, nz * flip, np.abs(cos)
    lobe = lobe[rows]
    tilt = np.arctan(AXIS_TILT * np.maximum(cs.ax[rows], cs.ay[rows]))
    branch = np.ones(len(rows), F32)
    k, scale, spread = F32(2.0) * c, np.ones(len(rows), F32), np.full(len(rows), F32(2.0))
    dielectric = np.flatnonzero((lobe == REFRACTION) | (lobe == GLASS))
    if len(dielectric):
        eta = cs.eta[rows[dielectric]]
        cd = c[dielectric]
        f, cos_t = fresnel.dielectric(cd, eta)
        glass = lobe[dielectric] == GLASS
        refract = (~glass | (f < F32(0.5))) & (cos_t > 0)
        branch[dielectric] = np.where(glass, np.where(refract, ONE - f, f), (cos_t > 0).astype(F32))
        inv_eta = ONE / eta
        k[dielectric] = np.where(refract, inv_eta * cd - cos_t, k[dielectric])
        scale[dielectric] = np.where(refract, inv_eta, ONE)
        with np.errstate(divide="ignore", invalid="ignore"):
            spread[dielectric] = np.where(refract, np.abs(ONE - cd / (eta * cos_t)), F32(2.0))
    radius = np.maximum(spread * tilt, MIN_AXIS_RADIUS)
    share = np.where(np.isfinite(radius) & (radius <= MAX_AXIS_RADIUS),
                     cs.sw[rows] * branch / np.take(cs.total_sw, h), F32(0.0))
    if len(h) > 1 and not np.all(h[1:] != h[:-1]):
        # Several candidates at a hit (rows are in hit order): keep the heaviest, the last in (hit, share) order.
        order = np.lexsort((share, h))
        hs = h[order]
        best = order[np.append(hs[1:] != hs[:-1], True)]
    else:
        best = np.arange(len(h))
    dx, dy, dz = (k * n - scale * w for n, w in ((nx, wx), (ny, wy), (nz, wz)))
    norm = np.sqrt(dx * dx + dy * dy + dz * dz)
    best = best[(share[best] >= MIN_AXIS_SHARE) & (norm[best] > 0)]   # > 0 is False for a NaN normal too
    norm = norm[best]
    return h[best], (dx[best] / norm, dy[best] / norm, dz[best] / norm), radius[best], share[best]
