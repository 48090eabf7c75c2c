"""kernels/vec.py: matrix products of small matrices and long arrays of vectors, without BLAS, equal to `@`
to rounding and in its dtype (NumPy 1.26's value-based casting and NumPy 2's rules alike)."""
from __future__ import annotations

import numpy as np
import pytest

from ember.kernels.vec import matmul


@pytest.mark.parametrize("a_shape, b_shape", [((1000, 3), (3, 3)), ((3, 3), (3, 1000)), ((3,), (3, 1000)),
                                              ((1000, 3), (3,)), ((3,), (3,)), ((4, 4), (4,)), ((7, 4), (4, 3)),
                                              ((2, 3), (3, 5))])
@pytest.mark.parametrize("a_type, b_type", [(np.float32, np.float32), (np.float64, np.float32),
                                            (np.float32, np.float64)])
def test_matmul_is_the_matrix_product(a_shape, b_shape, a_type, b_type):
    rng = np.random.default_rng(len(a_shape) * 10 + len(b_shape))
    a = rng.normal(size=a_shape).astype(a_type)
    b = rng.normal(size=b_shape).astype(b_type)
    expected = a @ b
    got = matmul(a, b)
    assert np.shape(got) == expected.shape and np.result_type(got) == expected.dtype
    np.testing.assert_allclose(got, expected, rtol=1e-5 if expected.dtype == np.float32 else 1e-12, atol=1e-6)
    np.testing.assert_allclose(matmul(a.T.copy().T, b), expected, rtol=1e-5, atol=1e-6)   # strided views


def test_matmul_says_when_shapes_do_not_chain():
    with pytest.raises(ValueError, match="do not chain"):
        matmul(np.ones((4, 3)), np.ones((4, 3)))
