"""Statistics for tests: chi-square against a pdf without SciPy, and standard errors."""
from __future__ import annotations

import math

import numpy as np


def trapezoid(y, x=None, axis: int = -1):
    """The trapezoid rule: NumPy 2 renamed np.trapz to np.trapezoid (np.trapz is gone); NumPy 1.26 has only
    the old name."""
    rule = getattr(np, "trapezoid", None) or np.trapz
    return rule(y, x, axis=axis)


def chi2_upper_quantile(dof: int, z: float = 4.0) -> float:
    """Wilson-Hilferty approximation of the chi-square quantile z standard deviations above the mean
    (z = 4: a false alarm about once in 30,000 runs)."""
    k = float(dof)
    return k * (1.0 - 2.0 / (9.0 * k) + z * math.sqrt(2.0 / (9.0 * k))) ** 3


def chi2_statistic(observed: np.ndarray, expected: np.ndarray, min_expected: float = 5.0):
    """Pearson's statistic over cells, pooling cells whose expectation is below min_expected.
    Returns (statistic, degrees of freedom)."""
    observed = np.asarray(observed, np.float64).ravel()
    expected = np.asarray(expected, np.float64).ravel()
    small = expected < min_expected
    obs = np.append(observed[~small], observed[small].sum())
    exp = np.append(expected[~small], expected[small].sum())
    keep = exp > 0
    obs, exp = obs[keep], exp[keep]
    return float(np.sum((obs - exp) ** 2 / exp)), int(len(exp) - 1)


def assert_chi2(observed, expected, z: float = 4.0) -> None:
    stat, dof = chi2_statistic(observed, expected)
    limit = chi2_upper_quantile(dof, z)
    assert stat < limit, f"chi-square {stat:.1f} exceeds {limit:.1f} (dof {dof})"


def mean_and_stderr(samples: np.ndarray, axis=None):
    samples = np.asarray(samples, np.float64)
    n = samples.size if axis is None else samples.shape[axis]
    return samples.mean(axis=axis), samples.std(axis=axis, ddof=1) / math.sqrt(n)
