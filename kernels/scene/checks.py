"""The validation vocabulary of the scene's parts: a failed check raises ValueError naming the field, in the
words the tests and the engine's messages read."""
from __future__ import annotations

import numpy as np


def require(ok, name: str, message: str) -> None:
    if not ok:
        raise ValueError(f"{name}: {message}")


def require_finite(a: np.ndarray, name: str) -> None:
    require(np.all(np.isfinite(a)), name, "contains NaN or infinite values")


def check_array(a, name: str, shape: tuple, dtype, finite: bool = True) -> None:
    require(isinstance(a, np.ndarray), name, f"must be a numpy array, got {type(a).__name__}")
    require(a.dtype == dtype, name, f"must be {np.dtype(dtype).name}, got {a.dtype.name}")
    require(a.ndim == len(shape) and all(s == -1 or s == d for s, d in zip(shape, a.shape)), name,
            f"must have shape {_shape_str(shape)}, got {a.shape}")
    if finite:
        require_finite(a, name)


def _shape_str(shape: tuple) -> str:
    return "(" + ", ".join("N" if s == -1 else str(s) for s in shape) + ")"


# Embree's RTC_MAX_TIME_STEP_COUNT: the most motion steps a curve or point geometry may have.
MAX_TIME_STEPS = 129


def check_motion(motion, name: str, n: int) -> None:
    """A curve or point record's motion: None, or (S, n, 4) float32 keys at S in [2, MAX_TIME_STEPS] times."""
    if motion is None:
        return
    check_array(motion, name, (-1, n, 4), np.float32, finite=False)
    require(2 <= len(motion) <= MAX_TIME_STEPS, name, f"needs 2 to {MAX_TIME_STEPS} steps, got {len(motion)}")


def usable_keys(keys: np.ndarray) -> np.ndarray:
    """(..., n) bool: which (..., n, 4) x, y, z, radius rows Embree can take (finite, within float32, radius >= 0).
    |x| < 1e30 is False for NaN and infinities too; the whole array is tested first, since a test per row over
    four columns costs ten times as much (0.14 s at 1M points) and rows are seldom unusable."""
    small = np.abs(keys) < 1e30
    radius = keys[..., 3] >= 0
    if small.all() and radius.all():
        return radius
    return small.all(axis=-1) & radius
