"""The phase closures at a medium's scattering points as one mixture, as Cycles samples and evaluates them
(kernel/integrator/volume_shader.h): a closure is picked in proportion to its sample weight (the average
of its spectral weight), its phase function samples the direction; the mixture's value is the sum of the
closures' weights times their phase functions (a spectral weight summing to sigma_s: tracking.py leaves
it for the vertex), its pdf the sample-weighted average of their pdfs."""
from __future__ import annotations

import numpy as np

from ..vec import F32, ONE, ZERO
from . import phase


class PhaseMixture:
    """The phase closures (shading.volume.PhaseClosure, over n points) of the scattering points."""

    def __init__(self, closures, n: int):
        self.n = n
        self.lobes = []   # (phase kind, spectral weight (3, n), parameter columns)
        for c in closures:
            inputs = {key: c.params[name] for key, name in (("anisotropy", "Anisotropy"), ("ior", "IOR"),
                                                            ("backscatter", "Backscatter"), ("alpha", "Alpha"),
                                                            ("diameter", "Diameter")) if name in c.params}
            for kind, share, params in phase.scatter_closures(c.phase, **inputs):
                weight = np.asarray(c.weight, F32) * np.asarray(share, F32)
                self.lobes.append((kind, weight, np.broadcast_to(params, (params.shape[0], n))))
        self.sample_weights = [np.abs(w.mean(axis=0)) for _, w, _ in self.lobes]
        self.total = np.sum(self.sample_weights, axis=0) if self.lobes else np.zeros(n, F32)

    def evaluate(self, d, wo):
        """(f (3, n) spectral value, pdf (n,)) toward wo (3 tuple of (n,)) of rays arriving along d (3 tuple)."""
        f = np.zeros((3, self.n), F32)
        pdf = np.zeros(self.n, F32)
        for (kind, weight, params), sw in zip(self.lobes, self.sample_weights):
            value, p = phase.evaluate(kind, params, _back(d), wo)
            f += weight * value
            pdf += sw * p
        total = self.total
        return f, np.where(total > 0, pdf / np.where(total > 0, total, ONE), ZERO).astype(F32)

    def sample(self, d, u_pick, u1, u2):
        """(wo (3 tuple), f (3, n), pdf (n,)): a direction from the closure picked by u_pick."""
        n = self.n
        wo = [np.zeros(n, F32) for _ in range(3)]
        if not self.lobes:
            return tuple(wo), np.zeros((3, n), F32), np.zeros(n, F32)
        total = np.where(self.total > 0, self.total, ONE)
        cdf = np.cumsum(np.stack(self.sample_weights) / total, axis=0)
        chosen = np.minimum((u_pick[None] >= cdf).sum(axis=0), len(self.lobes) - 1)
        for k, (kind, _, params) in enumerate(self.lobes):
            rows = np.flatnonzero(chosen == k)
            if not len(rows):
                continue
            w, _, _ = phase.sample(kind, params[:, rows], tuple(np.take(-c, rows) for c in d), u1[rows], u2[rows])
            for axis in range(3):
                wo[axis][rows] = w[axis]
        wo = tuple(wo)
        f, pdf = self.evaluate(d, wo)
        return wo, f, pdf


def _back(d):
    """Cycles' wi at a scattering point: toward the previous vertex, -d."""
    return tuple(-c for c in d)
