"""The kernel's numeric vocabulary (more of it moves here as modules are tidied): matrix products of small
matrices with long arrays of vectors.

Why not `@`: NumPy hands a matrix product of float arrays to the BLAS it is linked with. OpenBLAS (NumPy's
wheels) splits a product over many vectors across its own threads, which then spin for a while after each
call on every core: beside a render's other process or thread they took a third of a core (a textured
scene's waves ran 1.5x as long beside such a process). With three or four terms to sum, a sum of products
costs about what the BLAS call did, on the calling thread alone.
"""
from __future__ import annotations

import numpy as np


def matmul(a, b) -> np.ndarray:
    """a @ b for 1-D and 2-D operands whose shared dimension is short (3 or 4: vectors and their matrices),
    as a sum of products over it, in the dtype a @ b would have."""
    a, b = np.asarray(a), np.asarray(b)
    dtype = np.result_type(a, b)
    a, b = a.astype(dtype, copy=False), b.astype(dtype, copy=False)
    if not 1 <= a.ndim <= 2 or not 1 <= b.ndim <= 2 or a.shape[-1] != b.shape[0]:
        raise ValueError(f"matmul: shapes {a.shape} and {b.shape} do not chain")
    if a.ndim == 2 and b.ndim == 2 and a.shape[0] > b.shape[1]:
        # Rows of vectors times a matrix: the transposed product, term by term along the long axis (a
        # broadcast over the short one would be strided), handed back as its transpose (a view).
        return _sum_of_products(b.T, a.T).T
    return _sum_of_products(a, b)


def _sum_of_products(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    out = None
    for k in range(b.shape[0]):
        left = a[:, k, None] if a.ndim == 2 and b.ndim == 2 else a[..., k]
        term = left * b[k]
        out = term if out is None else out + term
    return out
