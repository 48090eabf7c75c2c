"""The colour channel a path's distance sampling follows, as Cycles weighs the channels
(kernel/integrator/shade_volume.h volume_sample_channel_pdf): in proportion to the path's weight times the
medium's single-scattering albedo, uniform where that is zero everywhere."""
from __future__ import annotations

import numpy as np


def channel_pdf(weight: np.ndarray, sigma_s: np.ndarray, sigma_t: np.ndarray) -> np.ndarray:
    """(3, n) the probability of each channel for paths of weight (3, n) at points of coefficients sigma_s,
    sigma_t (3, n), in their dtype. A channel without extinction counts as albedo 1."""
    albedo = np.where(sigma_t > 0, sigma_s / np.where(sigma_t > 0, sigma_t, 1.0), 1.0)
    lean = np.abs(weight * albedo)
    total = lean.sum(axis=0)
    return np.where(total > 0, lean / np.where(total > 0, total, 1.0), 1.0 / 3.0)
