"""The transmittance of shadow rays through media that vary, as Cycles 5.x estimates it (kernel/integrator/
shade_volume.h, volume_transmittance and volume_shadow_null_scattering): Misso et al.'s unbiased ray marching
("Unbiased and consistent rendering using biased estimators", 2022) instead of ratio tracking.

Along a segment of length L whose extinction varies within a range sigma_c (here the segment's majorant,
medium.Media.segment_majorant: no minorant is kept), k = clamp(round(sigma_c L), 1, 1024) points, a stratified
offset apart, give the biased estimate T_k = exp(-L / k x the sum of sigma_t). An order n is drawn from the
geometric distribution p(n) = r (1 - r)^n, r = 0.9, cut off at 4 (the last order takes the rest of the mass);
N = 2^n. Order 0 returns T_k alone. Otherwise N k points are taken: T_k is the mean over the N interleaved sets
of k, and the debiasing term (T_{Nk} - T_{Nk/2}) / p(n) is added, T_{Nk/2} the mean of the even and the odd
points' estimates: the telescoping sum's expectation is the transmittance (to the cut-off order's resolution).
Every segment costs about 1.1 k shader evaluations, all of a batch's at once, and its estimate is nearly
noise-free where ratio tracking's is a product of random factors.
"""
from __future__ import annotations

import numpy as np

from ..rng import keyed_uniforms as uniforms
from ..vec import F32

RATIO = 0.9            # r of the geometric distribution of the debiasing order
CUT_OFF = 4            # the highest order (Cycles' cut_off)
MAX_STEPS = 1024       # Cycles' VOLUME_MAX_STEPS: k at most
CHUNK = 1 << 18        # points evaluated per shader call at most
SALT = 307             # rng.keyed_uniforms salt of a segment's numbers


def transmittance(media, stack, origins, dirs, t_end, seeds, sigma_c, salt: int = 0) -> np.ndarray:
    """(3, n) the transmittance of n shadow segments (stack (K, n), origins and unit dirs (n, 3), finite t_end (n,),
    sigma_c (n,) their extinction's range) by the telescoping estimator."""
    n = len(t_end)
    length = np.asarray(t_end, np.float64)
    k = np.clip(np.rint(np.asarray(sigma_c, np.float64) * length), 1, MAX_STEPS).astype(np.int64)
    u_order, u_offset = uniforms(seeds, 0, salt + SALT)
    with np.errstate(divide="ignore"):
        order = np.floor(np.log(u_order.astype(np.float64)) / np.log(1.0 - RATIO))
    order = np.where(sigma_c > 0, np.minimum(order, CUT_OFF), 0).astype(np.int64)
    pmf = np.where(order == CUT_OFF, (1.0 - RATIO) ** order, RATIO * (1.0 - RATIO) ** order)
    sets = np.left_shift(1, order)                # N
    count = sets * k                              # points per segment
    step = length / count
    offset = u_offset.astype(np.float64)
    # Per segment, the optical depth of each of its N interleaved sets (point i is in set i mod N): the even and
    # the odd points' depths are the sums of the even and the odd sets' (N is even where they are used), all
    # points' the sum of all sets'. One bincount over the channels' sets gathers them.
    n_sets = int(sets.sum())
    depth_sets = np.zeros(3 * n_sets)
    first_set = np.concatenate([[0], np.cumsum(sets)[:-1]])
    total = int(count.sum())
    # Points are laid out segment after segment: each point's segment and number along it, without a search.
    rows = np.repeat(np.arange(n), count)
    points = np.arange(total) - np.repeat(np.cumsum(count) - count, count)
    origins = np.asarray(origins)
    dirs = np.asarray(dirs)
    for lo in range(0, total, CHUNK):
        hi = min(total, lo + CHUNK)
        row, point = rows[lo:hi], points[lo:hi]
        t = np.minimum(length[row], (offset[row] + point) * step[row])
        d = dirs[row]
        p = (origins[row] + d * t[:, None]).astype(F32)
        sigma = media.stack_coefficients(stack[:, row], p, d, None, False).sigma_t.astype(np.float64)
        tau = np.nan_to_num(sigma, posinf=0.0) * step[row]
        where = first_set[row] + point % sets[row]
        depth_sets += np.bincount((where[None] + (np.arange(3) * n_sets)[:, None]).ravel(), tau.ravel(), 3 * n_sets)
    depth_sets = depth_sets.reshape(3, n_sets)
    parity = (np.arange(n_sets) - np.repeat(first_set, sets)) & 1
    depth_all = np.add.reduceat(depth_sets, first_set, axis=1)
    depth_odd = np.add.reduceat(depth_sets * parity, first_set, axis=1)
    depth_even = np.add.reduceat(depth_sets * (1 - parity), first_set, axis=1)
    # T_k: each set's k points stand for the whole segment (their depth times N), averaged over the sets.
    scale = np.repeat(sets, sets).astype(np.float64)
    t_sets = np.exp(-depth_sets * scale)
    t_k = np.add.reduceat(t_sets, first_set, axis=1) / sets
    t_half = 0.5 * (np.exp(-2.0 * depth_even) + np.exp(-2.0 * depth_odd))
    t_full = np.exp(-depth_all)
    out = np.where(order > 0, t_k + (t_full - t_half) / pmf, t_k)
    return out.astype(F32)
