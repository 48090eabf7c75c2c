#!/usr/bin/env python3.11
"""Regenerate kernels/bsdf/data/microfacet_tables.npz: Cycles' GGX albedo tables by our own Monte Carlo.

    .venv/bin/python tools/precompute_bsdf_tables.py [--scale 1.0] [--processes 2] [--only ggx_E ...]

The recipe is Cycles 5.0's (`app/cycles_precompute.cpp`), computed with Ember's own lobes: every cell is
the mean, over samples of the lobe's own sampler, of one scalar per sample, with the viewer at
wo = (sqrt(1 - mu^2), 0, mu) and alpha = rough^2; a sample that fails (below the horizon) counts 0; the
mean is clamped to [0, 1]. Grids and coordinates are in kernels/bsdf/tables.py.
    ggx_E, ggx_Eavg        weight of GGX reflection with F = 1; Eavg averages 2 mu E over a random mu
    ggx_glass_(inv_)E(avg) mean weight of GGX glass with exact dielectric Fresnel at eta (1 / eta)
    ggx_gen_schlick_ior_s  s of the remapped Fresnel at the sampled microfacet, read as Cycles does: the
                           Fresnel has f0 = (0, 1, 0), f90 = (1, 1, 0), and the value is weight.x / weight.y
    ggx_gen_schlick_s      the same with (1 - cos_h)^exponent, eta = 1
Samples: randomised quasi-Monte Carlo. Each cell takes K = 8 independent random shifts (Cranley-Patterson)
of one 4D additive-recurrence point set (Roberts' R4 sequence, from the generalised golden ratio); the
spread of the K means gives the standard error, whose maximum per table is stored as stderr_<name>.
Fixed seed: the output is reproducible. About 7 minutes on 2 (shared) cores at --scale 1.
"""
from __future__ import annotations

import argparse
import multiprocessing
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from bench.common import import_ember  # noqa: E402

import_ember()
from ember.kernels.bsdf import fresnel, microfacet, tables  # noqa: E402

SEED = 20251126
REPLICATES = 8
LANES_PER_BATCH = 1 << 19

# Points per cell at --scale 1 (all replicates together). QMC errors are far below sigma / sqrt(n).
SAMPLES = {
    "ggx_E": 1 << 17,
    "ggx_Eavg": 1 << 20,
    "ggx_glass_E": 1 << 17,
    "ggx_glass_inv_E": 1 << 17,
    "ggx_glass_Eavg": 1 << 19,
    "ggx_glass_inv_Eavg": 1 << 19,
    "ggx_gen_schlick_ior_s": 1 << 16,
    "ggx_gen_schlick_s": 1 << 16,
}


# ---------------------------------------------------------------- per-sample estimators
def _viewer(mu):
    mu = mu.astype(np.float32)
    return np.sqrt(np.maximum(np.float32(1.0) - mu * mu, np.float32(0.0))), np.zeros_like(mu), mu


def reflection_albedo(rough, mu, u):
    alpha = rough * rough
    s = microfacet.sample_reflection(_viewer(mu), alpha, alpha, fresnel.unit_reflection(), u[0], u[1])
    return s.weight[0]


def glass_albedo(rough, mu, eta, u):
    """One sample of GGX glass with exact Fresnel, as the sampler that made Cycles' shipped glass tables
    (Cycles 4.0, commit 34125e1d0) had it: like microfacet.sample_glass, except that a refraction
    leaving upward (wi.z > 0, possible only for eta < 1) is kept instead of rejected. Cycles 5.0 rejects
    it but still ships those tables, so we reproduce them. With R + T = 1 the weight is the shadowing
    ratio (1 + L(wo)) / (1 + L(wo) + L(wi)) for either event, 1 for delta events."""
    alpha = rough * rough
    wo = _viewer(mu)
    one = np.float32(1.0)
    singular = microfacet.is_singular(alpha, alpha)
    h = microfacet.sample_visible_normal(wo, alpha, alpha, u[0], u[1])
    h = tuple(np.where(singular, n, c) for n, c in zip((0.0, 0.0, 1.0), h))
    cos_h = np.clip(h[0] * wo[0] + h[1] * wo[1] + h[2] * wo[2], 0.0, 1.0).astype(np.float32)
    f, cos_t = fresnel.dielectric(cos_h, eta)
    refract = u[2] >= f  # P = mean(R) / mean(R + T) = F
    k = cos_h / eta - cos_t
    wi = tuple(np.where(refract, k * hc - oc / eta, 2.0 * cos_h * hc - oc).astype(np.float32)
               for hc, oc in zip(h, wo))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        lo, li = microfacet.ggx_lambda(wo, alpha, alpha), microfacet.ggx_lambda(wi, alpha, alpha)
        shadowing = (one + lo) / (one + lo + li)
    delta = singular | (refract & (np.abs(eta - one) < microfacet.SINGULAR_ETA))
    value = np.where(delta, one, shadowing)
    return np.where(refract | (wi[2] > 0), value, 0.0)


S_PROBE_F0 = np.float32([0.0, 1.0, 0.0])
S_PROBE_F90 = np.float32([1.0, 1.0, 0.0])


def schlick_s(rough, mu, model, u):
    """weight.x / weight.y where the Fresnel is (s, 1, 0): the sample's s, or 0 for a failed sample."""
    alpha = rough * rough
    s = microfacet.sample_reflection(_viewer(mu), alpha, alpha, model, u[0], u[1])
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = s.weight[0] / s.weight[1]
    return np.where(s.weight[1] > 0, np.clip(ratio, 0.0, 1.0), 0.0)


def estimate(name, rough, mu, z, u):
    """One value per lane for the table `name`; rough, mu, z (lanes,) float32 node values, u 4 x (lanes,)."""
    ior = tables.ior_from_coordinate(z)
    if name == "ggx_E":
        return reflection_albedo(rough, mu, u)
    if name == "ggx_Eavg":
        return 2.0 * u[3] * reflection_albedo(rough, u[3], u)
    if name in ("ggx_glass_E", "ggx_glass_inv_E"):
        return glass_albedo(rough, mu, ior if name == "ggx_glass_E" else np.float32(1.0) / ior, u)
    if name in ("ggx_glass_Eavg", "ggx_glass_inv_Eavg"):
        eta = ior if name == "ggx_glass_Eavg" else np.float32(1.0) / ior
        return 2.0 * u[3] * glass_albedo(rough, u[3], eta, u)
    if name == "ggx_gen_schlick_ior_s":
        return schlick_s(rough, mu, fresnel.remapped_reflection(ior, S_PROBE_F0, S_PROBE_F90), u)
    if name == "ggx_gen_schlick_s":
        model = fresnel.generalized_schlick_reflection(1.0, S_PROBE_F0, S_PROBE_F90,
                                                       tables.exponent_from_coordinate(z))
        return schlick_s(rough, mu, model, u)
    raise KeyError(name)


# ---------------------------------------------------------------- grid and points
def cell_nodes(name):
    """Node values (rough, mu, z) of every cell of a table, C order of its shape. Averaged tables
    (Eavg) have no mu axis; the IOR or exponent axis is z."""
    shape = tables.TABLE_SHAPES[name]
    if name == "ggx_E":
        mu, rough = np.meshgrid(tables.nodes(32), tables.nodes(32), indexing="ij")
        z = np.zeros_like(mu)
    elif name == "ggx_Eavg":
        rough = tables.nodes(32)
        mu = z = np.zeros_like(rough)
    elif name.endswith("Eavg"):
        z, rough = np.meshgrid(tables.z_nodes(16), tables.nodes(16), indexing="ij")
        mu = np.zeros_like(z)
    else:
        z, mu, rough = np.meshgrid(tables.z_nodes(16), tables.nodes(16), tables.nodes(16), indexing="ij")
    assert rough.shape == shape
    return rough.ravel(), mu.ravel(), z.ravel()


# Roberts' R4: alpha_j = phi^-(j+1), phi the real root of x^5 = x + 1.
PHI_4 = 1.1673039782614187
R4 = np.array([PHI_4 ** -(j + 1) for j in range(4)])
ALMOST_ONE = np.float32(1.0) - np.float32(2.0 ** -24)


def qmc_points(count, shifts):
    """(len(shifts), 4, count) float32 points in [0, 1): the R4 set under each random shift (4,)."""
    base = np.outer(R4, np.arange(count, dtype=np.float64))
    pts = np.mod(base[None] + shifts[:, :, None], 1.0).astype(np.float32)
    return np.minimum(pts, ALMOST_ONE)


def run_cells(job):
    """Means of K replicates for a batch of cells. job = (name, cell indices, samples per replicate)."""
    name, cells, per_rep = job
    rough_all, mu_all, z_all = cell_nodes(name)
    out = np.empty((len(cells), REPLICATES))
    for row, cell in enumerate(cells):
        rng = np.random.default_rng([SEED, list(tables.TABLE_SHAPES).index(name), int(cell)])
        u = qmc_points(per_rep, rng.random((REPLICATES, 4)))
        u = tuple(u[:, j, :].ravel() for j in range(4))
        lanes = REPLICATES * per_rep
        full = lambda a: np.full(lanes, a[cell], np.float32)  # noqa: E731
        values = estimate(name, full(rough_all), full(mu_all), full(z_all), u).astype(np.float64)
        values = np.where(np.isfinite(values), values, 0.0)
        out[row] = values.reshape(REPLICATES, per_rep).mean(axis=1)
    return cells, out


def compute_table(name, scale, pool):
    samples = max(REPLICATES, int(SAMPLES[name] * scale))
    per_rep = samples // REPLICATES
    n_cells = int(np.prod(tables.TABLE_SHAPES[name]))
    cells_per_job = max(1, LANES_PER_BATCH // samples)
    jobs = [(name, np.arange(i, min(i + cells_per_job, n_cells)), per_rep)
            for i in range(0, n_cells, cells_per_job)]
    reps = np.empty((n_cells, REPLICATES))
    start = time.time()
    for done, (cells, out) in enumerate(pool.imap_unordered(run_cells, jobs), 1):
        reps[cells] = out
        if done % max(1, len(jobs) // 10) == 0 or done == len(jobs):
            print(f"  {name}: {done}/{len(jobs)} batches, {time.time() - start:.0f} s", flush=True)
    means = np.clip(reps.mean(axis=1), 0.0, 1.0)
    stderr = reps.std(axis=1, ddof=1) / np.sqrt(REPLICATES)
    return means.reshape(tables.TABLE_SHAPES[name]).astype(np.float32), float(stderr.max())


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=1.0, help="multiply the sample counts")
    parser.add_argument("--processes", type=int, default=2)
    parser.add_argument("--only", nargs="*", help="recompute these tables, keep the others from the file")
    parser.add_argument("--out", default=tables.DATA_PATH)
    args = parser.parse_args()

    result = {}
    if args.only and os.path.exists(args.out):
        with np.load(args.out) as old:
            result.update({k: old[k] for k in old.files})
    names = args.only or list(tables.TABLE_SHAPES)
    start = time.time()
    with multiprocessing.Pool(args.processes) as pool:
        for name in names:
            data, err = compute_table(name, args.scale, pool)
            result[name], result["stderr_" + name] = data, np.float32(err)
            print(f"{name}: max standard error {err:.2e}", flush=True)
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    np.savez_compressed(args.out, **result)
    print(f"wrote {args.out} in {time.time() - start:.0f} s")


if __name__ == "__main__":
    main()
