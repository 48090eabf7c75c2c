"""The Radial Tiling node (kernels/shading/radial_tiling.py) against Cycles' own values, and end to end.

Cycles and Ember are probed pixel-exactly (tests/node_probe.py): a face attribute per pixel carries the point
and another its Sides and Roundness (read through Separate XYZ, exact), so one render holds every case. The
POINTS points mix whole and fractional Sides (Cycles takes other formulas for each), Roundness 0 and 1 (its
shortcuts) and between, values it clamps, points on the axes (signed zeros too), at the origin and far out.
Three probes, each rendered by Cycles and Ember at 1 sample: Segment Coordinates with Normalize off and on,
and Segment ID, Width and Rotation through a Combine XYZ.

What is claimed:
- Bit for bit: with glibc's own tanf, atanf and atan2f in place of Ember's, the kernel equals this Blender's
  Cycles exactly (5.0's and 5.3's kernels fuse different multiply-adds: both are modelled). Skipped where
  Cycles' CPU kernel is not the AVX2 one or the C library is not glibc.
- With Ember's own functions (rounded from float64, while glibc's atan2f is an ulp off in ~15% of arguments):
  within what a last-bit change of those functions makes. The node subtracts nearly equal angles (a hit's
  angle less its wedge's start; pi less floor(Sides) pi / Sides), so a last-bit change of an angle becomes
  tens of ulps of the result near the origin and hundreds far out or beside a wedge boundary. The tolerance
  per value is measured, not chosen: 2 x (the largest change when every tanf, atanf and atan2f result moves
  one ulp up or down, over ENVELOPE_TRIALS random patterns) + 1 ulp of max(|v|, 1); the factor 2 covers
  patterns not tried (over 12k probed points of 5.0 and 5.3 the largest ratio of difference to envelope was
  1.01). Most values are bit-identical all the same.
- Ember's render is the kernel's values exactly (the export reads the node, its options and this Blender's
  rounding). Where a component is NaN (Sides 2 with rounded corners: the circle's centre is at infinity)
  Cycles' film zeroes that component and Ember's drops the path: those pixels are checked apart.
- A node whose inputs are all constants (a 2D Vector's default, Sides from a Value node) is evaluated by
  Blender before Cycles sees it, rounded its own way; Ember folds it at export the same way: bit for bit with
  glibc's functions, within the envelope with Ember's.
"""
from __future__ import annotations

import bpy
import numpy as np
import pytest

from ember.kernels.shading import radial_tiling as rt
from tests.bpy_helpers import export_current
from tests.node_probe import AVX2_KERNEL, glibc_libm, probe_scene, render_probe

F32 = np.float32
EPS = np.finfo(F32).eps
VERSION = bpy.app.version
POINTS = 64 * 40
ENVELOPE_TRIALS = 8
SIDES = np.array([3, 5.5, 12, 2, 1.0, 2.3, 20.9, 100.5, 3.0001, 64], F32)
ROUNDNESS = np.array([0, 0.4, 1, 0.05, 0.95, 1e-4, 0.9999, -0.3, 1.4], F32)
GLIBC = glibc_libm(("tanf", 1), ("atanf", 1), ("atan2f", 2))


def probe_inputs(seed=7):
    """(points (K, 3), Sides (K,), Roundness (K,)): most points within 2 of the origin, a quarter far out,
    some on the axes and at the origin."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-2, 2, (POINTS, 2))
    far = rng.random(POINTS) < 0.25
    xy[far] *= rng.choice([30.0, 300.0], (int(far.sum()), 1))
    xy[:24, 1] = 0.0
    xy[24:48, 0] = 0.0
    xy[48:56] = 0.0
    xy[56:64, 1] = -0.0
    points = np.zeros((POINTS, 3), F32)
    points[:, :2] = xy
    return points, rng.choice(SIDES, POINTS), rng.choice(ROUNDNESS, POINTS)


def build(output, normalize):
    """A probe graph: the node (per-hit Vector, Sides and Roundness; or `node`, already set up) and the output
    shown: "coordinates", or "others" (Segment ID, Width, Rotation as x, y, z)."""
    def graph(tree, sockets, node=None):
        if node is None:
            node = tree.nodes.new("ShaderNodeRadialTiling")
            node.normalize = normalize
            tree.links.new(sockets["probe"], node.inputs["Vector"])
            split = tree.nodes.new("ShaderNodeSeparateXYZ")
            tree.links.new(sockets["probe2"], split.inputs[0])
            tree.links.new(split.outputs[0], node.inputs["Sides"])
            tree.links.new(split.outputs[1], node.inputs["Roundness"])
        if output == "coordinates":
            return node.outputs["Segment Coordinates"]
        join = tree.nodes.new("ShaderNodeCombineXYZ")
        for i, name in enumerate(("Segment ID", "Segment Width", "Segment Rotation")):
            tree.links.new(node.outputs[name], join.inputs[i])
        return join.outputs[0]
    return graph


def kernel(points, sides, roundness, output, normalize, constant=False):
    """The kernel's values as the probe shows them: (K, 3)."""
    out = rt.radial_tiling(points, sides, roundness, normalize=normalize, cycles_version=VERSION, constant=constant)
    if output == "coordinates":
        return out["Segment Coordinates"]
    return np.stack([out["Segment ID"], out["Segment Width"], out["Segment Rotation"]], axis=1)


CASES = [("coordinates", False), ("coordinates", True), ("others", False)]


@pytest.fixture(scope="module")
def probes():
    """case -> (Cycles' image, Ember's image, Ember's export warnings), at probe_inputs()."""
    points, sides, roundness = probe_inputs()
    extra = np.zeros((POINTS, 3), F32)
    extra[:, 0], extra[:, 1] = sides, roundness
    out = {}
    for case in CASES:
        scene, count = probe_scene(build(*case), {"probe": points, "probe2": extra})
        warnings = export_current().warnings
        out[case] = render_probe(scene, count, "CYCLES"), render_probe(scene, count, "EMBER"), warnings
    return out


def _vectorised(fn):
    ufunc = np.frompyfunc(lambda *a: fn(*(float(v) for v in a)), len(fn.argtypes), 1)
    return lambda *args: np.asarray(ufunc(*args), F32)


def _finite(values):
    """Cycles' film: each non-finite component read as 0 (ensure_finite)."""
    return np.where(np.isfinite(values), values, F32(0))


def _nudged(fn, rng):
    """fn with each result moved one ulp up or down at random."""
    def nudged(*args):
        value = fn(*args)
        return np.nextafter(value, rng.choice(np.array([-np.inf, np.inf], F32), np.shape(value))).astype(F32)
    return nudged


def envelope(points, sides, roundness, output, normalize, constant=False):
    """How far each value moves when every tanf, atanf and atan2f result moves one ulp (random directions),
    the largest over ENVELOPE_TRIALS patterns."""
    base = _finite(kernel(points, sides, roundness, output, normalize, constant))
    spread = np.zeros_like(base)
    for trial in range(ENVELOPE_TRIALS):
        rng = np.random.default_rng(trial)
        with pytest.MonkeyPatch.context() as patch:
            for name in ("tanf", "atanf", "atan2f"):
                patch.setattr(rt, name, _nudged(getattr(rt, name), rng))
            moved = _finite(kernel(points, sides, roundness, output, normalize, constant))
        spread = np.maximum(spread, np.abs(moved - base))
    return spread


# ---- against Cycles ------------------------------------------------------------------------------

@pytest.mark.skipif(not (AVX2_KERNEL and GLIBC), reason="Cycles' AVX2 kernel and glibc's libm are the reference")
@pytest.mark.parametrize("case", CASES, ids=lambda c: f"{c[0]}-{'normalized' if c[1] else 'plain'}")
def test_kernel_equals_cycles_bit_for_bit_with_glibcs_functions(probes, case, monkeypatch):
    for name in ("tanf", "atanf", "atan2f"):
        monkeypatch.setattr(rt, name, _vectorised(getattr(GLIBC, name)))
    points, sides, roundness = probe_inputs()
    cycles = probes[case][0]
    np.testing.assert_array_equal(_finite(kernel(points, sides, roundness, *case)), cycles)


@pytest.mark.parametrize("case", CASES, ids=lambda c: f"{c[0]}-{'normalized' if c[1] else 'plain'}")
def test_kernel_matches_cycles_within_a_last_bit_of_its_functions(probes, case):
    """The kernel as Ember runs it (test_ember_renders_the_kernels_values: the render is these values)."""
    points, sides, roundness = probe_inputs()
    cycles = probes[case][0]
    ours = _finite(kernel(points, sides, roundness, *case))
    tolerance = 2 * envelope(points, sides, roundness, *case) + EPS * np.maximum(np.abs(cycles), 1)
    excess = np.abs(ours - cycles) - tolerance
    assert (excess <= 0).all(), (points[np.argmax(excess.max(axis=1))], excess.max())
    assert np.mean(ours == cycles) > 0.5       # most values are bit-identical all the same


# ---- end to end ------------------------------------------------------------------------------------

@pytest.mark.parametrize("case", CASES, ids=lambda c: f"{c[0]}-{'normalized' if c[1] else 'plain'}")
def test_ember_renders_the_kernels_values(probes, case):
    points, sides, roundness = probe_inputs()
    cycles, ember, warnings = probes[case]
    assert not [w for w in warnings if "Radial Tiling" in w], warnings
    ours = kernel(points, sides, roundness, *case)
    finite = np.isfinite(ours).all(axis=1)
    np.testing.assert_array_equal(ember[finite], ours[finite])
    # a NaN component: Cycles' film zeroes it (and keeps the others), Ember's drops the path (docs/materials.md)
    assert (ember[~finite] == 0).all()
    assert (cycles[~np.isfinite(ours)] == 0).all()


# A node whose inputs are all constants (the Vector's default a 2D vector, Sides from a Value node): Blender
# evaluates it and Cycles renders that value; Ember folds it at export, rounded as Blender does. The probe shows
# the outputs' absolute values (exact): a negative constant Emission colour is refused by Ember's scene check.
CONSTANT_CASES = [((0.61, -1.3), 5.5, 0.4, True), ((-0.7, 0.2), 2.3, 1.0, False), ((150.0, -0.0), 12.0, 0.05, True),
                  ((0.3, -1.1), 20.9, 1.0, True)]


def constant_graph(output, point, sides, roundness, normalize):
    def graph(tree, sockets):
        node = tree.nodes.new("ShaderNodeRadialTiling")
        node.normalize = normalize
        node.inputs["Vector"].default_value = point
        node.inputs["Roundness"].default_value = roundness
        value = tree.nodes.new("ShaderNodeValue")
        value.outputs[0].default_value = sides
        tree.links.new(value.outputs[0], node.inputs["Sides"])
        absolute = tree.nodes.new("ShaderNodeVectorMath")
        absolute.operation = "ABSOLUTE"
        tree.links.new(build(output, normalize)(tree, sockets, node), absolute.inputs[0])
        return absolute.outputs[0]
    return graph


@pytest.fixture(scope="module")
def constant_probes():
    """(case, output) -> (Cycles' value, Ember's image) for CONSTANT_CASES."""
    out = {}
    for case in CONSTANT_CASES:
        for output in ("coordinates", "others"):
            scene, count = probe_scene(constant_graph(output, *case), {"probe": np.zeros((16, 3))})
            out[case, output] = render_probe(scene, count, "CYCLES")[0], render_probe(scene, count, "EMBER")
    return out


def test_constant_nodes_fold_as_blender_evaluates_them(constant_probes):
    for (case, output), (cycles, ember) in constant_probes.items():
        point, sides, roundness, normalize = case
        at = np.array([[*point, 0.0]], F32)
        ours = np.abs(kernel(at, sides, roundness, output, normalize, constant=True))
        np.testing.assert_array_equal(ember, np.repeat(ours, len(ember), axis=0))
        spread = envelope(at, sides, roundness, output, normalize, constant=True)[0]
        assert (np.abs(cycles - ours[0]) <= 2 * spread + EPS * np.maximum(np.abs(cycles), 1)).all(), (case, cycles)
        if AVX2_KERNEL and GLIBC:
            with pytest.MonkeyPatch.context() as patch:
                for name in ("tanf", "atanf", "atan2f"):
                    patch.setattr(rt, name, _vectorised(getattr(GLIBC, name)))
                exact = np.abs(kernel(at, sides, roundness, output, normalize, constant=True)[0])
                np.testing.assert_array_equal(exact, cycles, err_msg=str(case))


# ---- the kernel's closed forms ---------------------------------------------------------------------

def test_segment_id_is_the_angle_in_sides_ths_of_a_turn():
    angles = np.radians(np.array([0, 10, 59, 61, 100, 179, 181, 299, 359], np.float64))
    p = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], 1).astype(F32) * 2
    for sides in (6.0, 5.5):
        expected = np.floor(sides * np.degrees(angles) / 360)
        np.testing.assert_array_equal(rt.radial_tiling(p, sides, 0.3, outputs=("Segment ID",))["Segment ID"], expected)
    # y = -0: y < 0 is false and atan2(-0, -1) = -pi, so Cycles' formula gives -Sides / 2
    assert rt.radial_tiling(np.array([[-1, -0.0, 0]], F32), 6.0)["Segment ID"][0] == -3


def test_regular_polygon_coordinates():
    """Sides 6, sharp: the hexagon's edge (distance 1 from the origin along each bisector) is at y = 0, x is the
    distance from the bisector along the edge; width tan(30 deg), rotation the bisector's angle."""
    bisector, offset = np.pi / 6 + 2 * np.pi / 6, np.radians(12)     # the second wedge, 12 deg past its bisector
    angle = bisector + offset
    p = np.array([[np.cos(angle), np.sin(angle), 0]], np.float64) / np.cos(offset)   # on the edge
    out = rt.radial_tiling(p.astype(F32), 6.0, 0.0)
    np.testing.assert_allclose(out["Segment Coordinates"][0], [np.tan(offset), 0, 0], atol=1e-6)
    np.testing.assert_allclose(out["Segment Width"][0], np.tan(np.pi / 6), rtol=1e-6)
    np.testing.assert_allclose(out["Segment Rotation"][0], bisector, rtol=1e-6)
    normalized = rt.radial_tiling(p.astype(F32), 6.0, 0.0, normalize=True)["Segment Coordinates"][0]
    np.testing.assert_allclose(normalized, [0.5 + 0.5 * np.tan(offset) / np.tan(np.pi / 6), 1, 0], atol=1e-6)


def test_circular_coordinates_and_clamped_inputs():
    """Roundness 1 (clamped from 2), whole Sides: y is the distance from the origin less 1, x the angle from
    the bisector; Sides below 2 are 2; the origin's x is 0."""
    p = np.array([[0, 2.5, 0], [0, 0, 0]], F32)          # on the first bisector of Sides 2 at 90 deg
    out = rt.radial_tiling(p, 1.0, 2.0)
    np.testing.assert_allclose(out["Segment Coordinates"][0], [0, 1.5, 0], atol=1e-6)
    np.testing.assert_allclose(out["Segment Width"], np.pi / 2, rtol=1e-6)
    assert out["Segment Coordinates"][1, 0] == 0
    turned = rt.radial_tiling(np.array([[np.cos(2.0), np.sin(2.0), 0]], F32), 2.0, 1.0, normalize=True)
    np.testing.assert_allclose(turned["Segment Coordinates"][0, :2], [0.5 + 0.5 * (2.0 - np.pi / 2) / (np.pi / 2), 1],
                               rtol=1e-6)
    assert set(rt.radial_tiling(p, 5.0, 0.0, outputs=("Segment Width",))) == {"Segment Width"}
