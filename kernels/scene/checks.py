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


def unusable_rows(values: np.ndarray) -> np.ndarray | None:
    """(n,) bool: the rows of (n, 4) x, y, z, radius Embree cannot take (a value not finite or beyond float32,
    a negative radius), or None when there is none. |x| < 1e30 is False for NaN and infinities too; the whole
    array is tested first, since a per-row test over four columns costs ten times as much."""
    small = np.abs(values) < 1e30
    if small.all() and (values[:, 3] >= 0).all():
        return None
    return ~(small.all(axis=1) & (values[:, 3] >= 0))
