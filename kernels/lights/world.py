"""The world as a light: directions from its importance map (environment.Environment), and their pdf.
"""
from __future__ import annotations

import numpy as np



def sample(sampler, out, idx, u1, u2, focus=None):
    wx, wy, wz, pdf = sampler.environment.sample_direction(u1, u2, focus)
    out.set(idx, wx, wy, wz, np.float32(np.inf), sampler.environment.radiance(wx, wy, wz), pdf)
    out.world[idx] = True


def pdf(sampler, dx, dy, dz, focus=None, receiver=None) -> np.ndarray:
    """pdf (solid angle, with selection) with which NEE would have sampled world directions d (focus: as
    given to sample(); receiver: the light sets of the points the rays left, or None)."""
    if not sampler.samples_world():
        return np.zeros(len(dx), np.float32)
    return sampler.distant_pmf(sampler.world_index, len(dx), receiver) * \
        sampler.environment.direction_pdf(dx, dy, dz, focus)
