"""kernels/vec.py: the constants, the vector helpers of each layout against NumPy's own, and matrix products of
small matrices and long arrays of vectors, without BLAS, equal to `@`
to rounding and in its dtype (NumPy 1.26's value-based casting and NumPy 2's rules alike)."""
from __future__ import annotations

import ast
import pathlib
import re
from fractions import Fraction

import numpy as np
import pytest

from ember.kernels import vec
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


# ---------------------------------------------------------------- constants
def test_constants_are_the_float32_values_of_cycles_literals():
    assert all(c.dtype == np.float32 for c in (vec.ZERO, vec.HALF, vec.ONE, vec.TWO, vec.PI, vec.HALF_PI,
                                                 vec.TWO_PI, vec.INV_PI, vec.INV_2PI, vec.INV_4PI))
    assert (vec.ZERO, vec.HALF, vec.ONE, vec.TWO) == (0.0, 0.5, 1.0, 2.0)
    # Cycles' M_PI_F, M_PI_2_F, M_2PI_F, M_1_PI_F, M_1_2PI_F, M_1_4PI_F, as float32, bit for bit.
    cycles = {"PI": 3.1415926535897932, "HALF_PI": 1.5707963267948966, "TWO_PI": 6.2831853071795864,
              "INV_PI": 0.3183098861837067, "INV_2PI": 0.1591549430918953, "INV_4PI": 0.0795774715459476}
    for name, literal in cycles.items():
        assert getattr(vec, name).view(np.uint32) == np.float32(literal).view(np.uint32), name
    assert (vec.F32, vec.F64, vec.I32, vec.U32) == (np.float32, np.float64, np.int32, np.uint32)


# ---------------------------------------------------------------- components (x, y, z)
def _rows(n, seed, dtype=np.float32):
    """(n, 3) vectors of lengths from 1e-3 to 1e3, with a zero row first."""
    rng = np.random.default_rng(seed)
    v = rng.normal(size=(n, 3)) * 10.0 ** rng.uniform(-3, 3, (n, 1))
    v[0] = 0.0
    return v.astype(dtype)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("stacked", [False, True])
def test_component_helpers_match_numpy(dtype, stacked):
    a, b = _rows(500, 1, dtype), _rows(500, 2, dtype)
    xyz_a, xyz_b = (a.T.copy(), b.T.copy()) if stacked else (tuple(a.T), tuple(b.T))   # (3, N) or a tuple
    rtol = 1e-5 if dtype == np.float32 else 1e-12

    dot = vec.dot_xyz(xyz_a, xyz_b)
    assert dot.shape == (500,) and dot.dtype == dtype
    scale = np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1)
    assert np.all(np.abs(dot - np.sum(a.astype(np.float64) * b, axis=1)) <= rtol * scale)

    cross = vec.cross_xyz(xyz_a, xyz_b)
    assert isinstance(cross, tuple) and all(c.shape == (500,) and c.dtype == dtype for c in cross)
    assert np.all(np.abs(np.stack(cross, axis=1) - np.cross(a.astype(np.float64), b)) <= rtol * scale[:, None])

    length = vec.length_xyz(xyz_a)
    assert length.shape == (500,) and length.dtype == dtype
    np.testing.assert_allclose(length, np.linalg.norm(a.astype(np.float64), axis=1), rtol=rtol)

    expected = a.astype(np.float64) / np.maximum(np.linalg.norm(a.astype(np.float64), axis=1), 1e-300)[:, None]
    for normalize in (vec.normalize_xyz, vec.normalize_floored_xyz):
        unit = normalize(xyz_a)
        assert isinstance(unit, tuple) and all(c.shape == (500,) and c.dtype == dtype for c in unit)
        np.testing.assert_allclose(np.stack(unit, axis=1), expected, rtol=rtol, atol=rtol)
        assert np.all(np.stack(unit, axis=1)[0] == 0.0)          # the zero vector stays zero


def test_component_helpers_broadcast_and_keep_their_order_of_operations():
    rng = np.random.default_rng(3)
    x, y, z = (rng.normal(size=100).astype(np.float32) for _ in range(3))
    up = (np.float32(0.0), np.float32(0.0), np.float32(1.0))           # a constant vector broadcasts
    assert np.array_equal(vec.dot_xyz((x, y, z), up), z)
    assert np.array_equal(vec.dot_xyz((x, y, z), (x, y, z)), x * x + y * y + z * z)     # ((x + y) + z)
    assert np.array_equal(vec.cross_xyz((x, y, z), up)[0], y)


def test_the_two_component_normalizations_differ_only_below_the_floor_and_for_nan():
    short = (np.array([2e-19, np.nan], np.float32), np.zeros(2, np.float32), np.zeros(2, np.float32))
    safe, floored = vec.normalize_xyz(short), vec.normalize_floored_xyz(short)      # |v|^2 = 4e-38 < 1e-37
    np.testing.assert_allclose(safe[0][0], 1.0, rtol=1e-6)
    assert floored[0][0] == np.float32(2e-19) * (np.float32(1.0) / np.sqrt(np.float32(1e-37)))
    assert np.isnan(safe[0][1]) and safe[1][1] == 0.0                   # NaN length: the inverse taken as 0
    assert np.isnan(floored[0][1]) and np.isnan(floored[1][1])


def test_make_orthonormals_is_cycles_frame():
    """make_orthonormals_xyz: (a, b, n) right-handed and orthonormal, the frame shading.program's rows version
    gives (both Cycles' make_orthonormals), the (-1, 1, 1) cross product where n's components are equal."""
    from ember.kernels.shading.program import make_orthonormals
    n = _rows(500, 8)[1:]
    n = (n / np.linalg.norm(n, axis=1, keepdims=True)).astype(np.float32)
    n[0] = np.float32(1 / np.sqrt(3))
    a, b = vec.make_orthonormals_xyz(tuple(n.T))
    assert all(c.dtype == np.float32 for c in (*a, *b))
    rows_a, rows_b = make_orthonormals(n)
    np.testing.assert_allclose(np.stack(a, axis=1), rows_a, atol=1e-6)
    np.testing.assert_allclose(np.stack(b, axis=1), rows_b, atol=1e-6)
    frame = np.stack([np.stack(a, axis=1), np.stack(b, axis=1), n], axis=1).astype(np.float64)    # (N, 3, 3)
    np.testing.assert_allclose(frame @ frame.transpose(0, 2, 1), np.broadcast_to(np.eye(3), frame.shape), atol=1e-6)
    np.testing.assert_allclose(np.linalg.det(frame), 1.0, atol=1e-6)
    expected = np.cross([-1.0, 1.0, 1.0], n[0].astype(np.float64))
    np.testing.assert_allclose(np.array(a)[:, 0], expected / np.linalg.norm(expected), atol=1e-6)


# ---------------------------------------------------------------- rows (..., 3)
@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_row_helpers_match_numpy(dtype):
    a, b = _rows(500, 4, dtype), _rows(500, 5, dtype)
    rtol = 1e-5 if dtype == np.float32 else 1e-12
    scale = np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1)
    for dot in (vec.dot_rows, vec.dot_rows_einsum):
        d = dot(a, b)
        assert d.shape == (500,) and d.dtype == dtype
        assert np.all(np.abs(d - np.einsum("ij,ij->i", a.astype(np.float64), b)) <= rtol * scale)
    assert np.array_equal(vec.dot_rows(a, b), a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2])

    length = vec.length_rows(a)
    assert length.shape == (500,) and length.dtype == dtype
    np.testing.assert_allclose(length, np.linalg.norm(a.astype(np.float64), axis=1), rtol=rtol)

    expected = a.astype(np.float64) / np.maximum(np.linalg.norm(a.astype(np.float64), axis=1), 1e-300)[:, None]
    # normalize_rows takes Cycles' float32 inverse whatever v's dtype.
    for normalize, tolerance in ((vec.normalize_rows, 1e-6), (vec.normalize_rows_einsum, rtol)):
        unit = normalize(a)
        assert unit.shape == (500, 3) and unit.dtype == dtype
        np.testing.assert_allclose(unit, expected, rtol=tolerance, atol=tolerance)
        assert np.all(unit[0] == 0.0)


def test_row_helpers_take_leading_axes_and_constants():
    v = _rows(24, 6).reshape(2, 4, 3, 3)
    assert vec.dot_rows(v, v).shape == (2, 4, 3) and vec.length_rows(v).shape == (2, 4, 3)
    np.testing.assert_allclose(vec.length_rows(v), np.linalg.norm(v, axis=-1), rtol=1e-6)
    constant = np.array([3.0, 0.0, 4.0], np.float32)
    assert vec.length_rows(constant) == 5.0
    np.testing.assert_allclose(vec.normalize_rows(constant), [0.6, 0.0, 0.8], rtol=1e-7)
    assert np.all(vec.normalize_rows(np.zeros((1, 3), np.float32)) == 0.0)
    assert np.array_equal(vec.columns(np.arange(4.0)), np.repeat(np.arange(4.0)[:, None], 3, axis=1))
    assert vec.columns(np.ones(1)).shape == (1, 1)


def _fma64(x: float, y: float, z: float) -> float:
    """x * y + z rounded once to float64 (Python 3.13's math.fma; exact in fractions, then one rounding)."""
    return float(Fraction(x) * Fraction(y) + Fraction(z))


def test_fused_products_round_once():
    """fma and cross_rows_fused against a fused multiply-add rounded once in float64 (_fma64, what math.fma
    gives on Python 3.13), number by number, then to float32: equal but for exact float64 ties, which random
    data does not hit."""
    rng = np.random.default_rng(7)
    a, b, c = (rng.normal(size=(300, 3)).astype(np.float32) for _ in range(3))
    got = vec.fma(a, b, c)
    assert got.shape == (300, 3) and got.dtype == np.float32
    expected = np.array([_fma64(float(x), float(y), float(z)) for x, y, z in
                         zip(a.ravel(), b.ravel(), c.ravel())]).astype(np.float32).reshape(300, 3)
    assert np.array_equal(got, expected)
    # Broadcasting either way, and numbers.
    assert np.array_equal(vec.fma(a[0], np.float32(2.0), c), (a[0] * np.float64(2.0) + c).astype(np.float32))
    assert np.array_equal(vec.fma(a[:, 0], b[:, 0], np.float32(1.0)), vec.fma(a[:, 0], b[:, 0], np.ones(300)))
    assert vec.fma(2.0, 3.0, 1.0) == 7.0 and vec.fma(2.0, 3.0, 1.0).dtype == np.float32

    cross = vec.cross_rows_fused(a, b)
    assert cross.shape == (300, 3) and cross.dtype == np.float32
    np.testing.assert_allclose(cross, np.cross(a.astype(np.float64), b), atol=1e-5)
    fused_x = [_fma64(float(ay), float(bz), -float(np.float32(az) * np.float32(by)))
               for ay, bz, az, by in zip(a[:, 1], b[:, 2], a[:, 2], b[:, 1])]
    assert np.array_equal(cross[:, 0], np.array(fused_x).astype(np.float32))


# ---------------------------------------------------------------- one home
KERNELS = pathlib.Path(vec.__file__).parent
# vec's dtype names and constants, and the names modules gave their own copies before they moved here.
VOCABULARY_CONSTANTS = {"F32", "F64", "I32", "U32", "ZERO", "HALF", "ONE", "TWO", "PI", "HALF_PI", "TWO_PI",
                        "INV_PI", "INV_2PI", "INV_4PI", "INV_TWO_PI", "INV_FOUR_PI"}
# dot, _dot3, cross, length, _len, norm, normalize, _normalized, safe_normalize, fma, dot_rows, ... (not
# normal_map: a name must be one of these words, optionally followed by digits or by _ and more).
VECTOR_HELPER = re.compile(r"_*(safe_)?(dot|cross|normali[sz]ed?|length|len|norm|fma)(\d+|_\w*)?")


def _module_level_definitions(path: pathlib.Path):
    """(line, name, kind) of the names a module binds at its top level: constants and functions."""
    for node in ast.parse(path.read_text(), str(path)).body:
        if isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for target in targets:
                for name in ast.walk(target):
                    if isinstance(name, ast.Name):
                        yield node.lineno, name.id, "constant"
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield node.lineno, node.name, "function"


def test_no_kernel_module_but_vec_defines_the_vocabulary():
    """The float32 constants and the dot / cross / length / normalize helpers live in kernels/vec.py alone:
    a module imports them (`from ..vec import F32, ONE, dot_xyz`) instead of writing its own copy."""
    modules = sorted(p for p in KERNELS.rglob("*.py") if p.name != "vec.py")
    assert len(modules) > 30
    copies = [f"{path.relative_to(KERNELS.parent)}:{line} {name}"
              for path in modules for line, name, kind in _module_level_definitions(path)
              if (kind == "constant" and name.lstrip("_") in VOCABULARY_CONSTANTS)
              or (kind == "function" and VECTOR_HELPER.fullmatch(name))]
    assert not copies, "define these in kernels/vec.py and import them: " + ", ".join(copies)


def test_the_scan_sees_the_definitions_it_forbids(tmp_path):
    source = tmp_path / "sample.py"
    source.write_text("import numpy as np\nF32 = np.float32\nZERO, ONE = F32(0.0), F32(1.0)\n_PI: float = 3.14\n"
                      "def _dot(a, b):\n    pass\ndef normal_map():\n    pass\n")
    found = {(name, kind) for _, name, kind in _module_level_definitions(source)}
    assert {("F32", "constant"), ("ZERO", "constant"), ("ONE", "constant"), ("_PI", "constant")} <= found
    assert [n for n, k in found if k == "function" and VECTOR_HELPER.fullmatch(n)] == ["_dot"]
    for name in ("dot", "_dot3", "cross", "length", "_length2", "_len", "_norm", "normalize", "_normalized",
                 "safe_normalize", "fma", "dot_rows", "normalize_floored_xyz"):
        assert VECTOR_HELPER.fullmatch(name), name
    for name in ("normal_map", "normal_matrices", "_normal_input", "lengths_of", "crossing"):
        assert not VECTOR_HELPER.fullmatch(name), name
