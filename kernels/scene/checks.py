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
