"""Voronoi and Gabor texture nodes (kernels/shading/voronoi.py, gabor.py) against Cycles' own values.

Cycles is probed pixel-exactly (tests/node_probe.py). To keep the renders few (about ten, ~1 s each), one
render holds many cases: a case is a node configuration and one output socket, evaluated at its own
points; a per-point group id (attribute "sel") picks the case's output through Math Compare (exactly 0
or 1) and Vector Math Scale / Add (x * 1 + 0 is exact), so each pixel shows its own case's raw value.
Per-hit inputs (W, Scale, Detail, ...) come from a per-node attribute "aux<k>" through Separate XYZ
(exact components); see probe_cases for why each node has its own.

Tolerance: float precision. Cycles' CPU kernels are built with -ffp-contract=fast and -freciprocal-math
(FMA, x / y as x * (1 / y)) and call libm's sinf / cosf / expf / powf; NumPy rounds every operation and
has its own SIMD transcendental functions, so values differ by a few ULP (about 80% of all probed values
are bit-identical). Gabor's Phase gets a tolerance scaled by its conditioning (phase_tolerance). Where a
value is a discontinuous function of its input (which cell is nearest, which side of 0.0001 a bisector
test falls, Phase across the branch cut of atan2), a few-ULP difference could pick the other branch;
such points would be counted, not hidden: at most MAX_FLIPS per case. A random point lies within a few
ULP (~1e-6 relative) of a decision boundary with probability ~1e-5, so 0 are expected in a case's 192
points; none occur in the ~48k points of this file.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np
import pytest

from ember.kernels.shading.gabor import NORMALIZATION_2D, NORMALIZATION_3D, gabor_texture
from ember.kernels.shading.voronoi import available_outputs, voronoi_texture
from tests.node_probe import cycles_probe

RTOL, ATOL = 2e-5, 2e-6
MAX_FLIPS = 1
PHASOR_EPS = 1e-6    # absolute float error of a Gabor phasor component (see phase_tolerance)
POINTS = 192         # per case
SAFE_INPUT = 1.0     # a per-hit input no node turns infinite (Exponent, Scale, Detail, ...)


# ---- Batched probes ----------------------------------------------------------------------------------

@dataclass
class Case:
    """One node configuration and one output, at its own points."""
    node: str                                   # "ShaderNodeTexVoronoi" / "ShaderNodeTexGabor"
    options: dict                               # node properties (Blender's enum identifiers)
    output: str
    inputs: dict = field(default_factory=dict)  # socket identifier -> constant
    per_hit: tuple = ()                         # up to two socket identifiers fed per point (aux y, z;
                                                # "Orientation 3D" takes the whole aux vector)
    w: bool = False                             # the W socket is fed per point (aux x)
    points: np.ndarray | None = None            # (K, 3)
    aux: np.ndarray | None = None               # (K, 3): W, per-hit inputs

    @property
    def key(self):
        """Cases that differ only in output share one node."""
        return (self.node, tuple(sorted(self.options.items())), tuple(sorted(self.inputs.items())),
                self.per_hit, self.w)


def _socket(sockets, identifier):
    return next(s for s in sockets if s.identifier == identifier)


def probe_cases(cases) -> list[np.ndarray]:
    """Render all cases in one Cycles probe; return each case's values (K, 3).

    Every node sees every point, and x * 0 is NaN for an infinite x, so no node may see inputs that make
    it infinite: a node with per-hit inputs reads its own attribute, which holds the cases' values at
    their points and SAFE_INPUT (valid for every socket) elsewhere."""
    sizes = [len(c.points) for c in cases]
    count = sum(sizes)
    rows = max(-(-count // 64), 4)          # whole rows, at least 4 (Blender's smallest resolution)
    padded = rows * 64

    def column(values, fill):
        out = np.full((padded, 3), fill, np.float32)
        out[:count] = np.concatenate(values)
        return out

    starts = np.cumsum([0] + sizes)
    attributes = {"probe": column([c.points for c in cases], 0.0),
                  "sel": column([np.full((n, 3), i, np.float32) for i, n in enumerate(sizes)], -1.0)}
    keys = list(dict.fromkeys(c.key for c in cases))
    for k, key in enumerate(keys):
        aux = np.full((padded, 3), SAFE_INPUT, np.float32)
        for i, c in enumerate(cases):
            aux[starts[i]:starts[i + 1], 0] = c.aux[:, 0]           # W: any finite value is safe
            if c.key == key:
                aux[starts[i]:starts[i + 1]] = c.aux
        attributes[f"aux{k}"] = aux

    def build(tree, sockets):
        nodes = tree.nodes

        def separate(name):
            sep = nodes.new("ShaderNodeSeparateXYZ")
            tree.links.new(sockets[name], sep.inputs[0])
            return sep

        group = separate("sel").outputs[0]
        made, total = {}, None
        for i, case in enumerate(cases):
            node = made.get(case.key)
            if node is None:
                node = made[case.key] = nodes.new(case.node)
                for prop, value in case.options.items():
                    setattr(node, prop, value)
                tree.links.new(sockets["probe"], _socket(node.inputs, "Vector"))
                for name, value in case.inputs.items():
                    _socket(node.inputs, name).default_value = value
                if case.w or case.per_hit:
                    aux = separate(f"aux{keys.index(case.key)}")
                    if case.w:
                        tree.links.new(aux.outputs[0], _socket(node.inputs, "W"))
                    for slot, name in enumerate(case.per_hit):
                        source = sockets[f"aux{keys.index(case.key)}"] if name == "Orientation 3D" else \
                            aux.outputs[1 + slot]
                        tree.links.new(source, _socket(node.inputs, name))
            pick = nodes.new("ShaderNodeMath")
            pick.operation = "COMPARE"
            tree.links.new(group, pick.inputs[0])
            pick.inputs[1].default_value = float(i)
            pick.inputs[2].default_value = 0.25
            scaled = nodes.new("ShaderNodeVectorMath")
            scaled.operation = "SCALE"
            tree.links.new(_socket(node.outputs, case.output), scaled.inputs[0])
            tree.links.new(pick.outputs[0], _socket(scaled.inputs, "Scale"))
            if total is None:
                total = scaled.outputs[0]
            else:
                add = nodes.new("ShaderNodeVectorMath")
                add.operation = "ADD"
                tree.links.new(total, add.inputs[0])
                tree.links.new(scaled.outputs[0], add.inputs[1])
                total = add.outputs[0]
        return total

    values = cycles_probe(build, attributes)[:count]
    return np.split(values, starts[1:-1])


def sample_points(seed: int, count: int = POINTS, dims: int = 3, span: float = 4.0) -> np.ndarray:
    """Points for a case: mostly random in [-span, span]^3, some lattice-aligned (multiples of 1/4, with
    scale 4 exact cell corners), some far out (|p| up to 1.2e6: cells up to 6e6 at scale 5, where float32
    steps by 0.5)."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(-span, span, (count, 3))
    p[: count // 8] = np.round(p[: count // 8] * 4) / 4
    far = slice(count // 8, count // 4)
    p[far] = rng.uniform(-2e5, 2e5, p[far].shape) * rng.choice([1.0, 6.0], (count // 8, 1))
    if dims < 3:
        p[:, dims:] = 0.0
    return p.astype(np.float32)


def assert_close(ours, cycles, name, rtol=RTOL, atol=ATOL, max_flips=MAX_FLIPS):
    """Equal to float precision, except at most max_flips points (discontinuities: see module doc)."""
    ours, cycles = np.asarray(ours, np.float32), np.asarray(cycles, np.float32)
    bad = ~np.isclose(ours, cycles, rtol=rtol, atol=atol)
    if bad.ndim > 1:
        bad = bad.any(axis=1)
    assert bad.sum() <= max_flips, (
        f"{name}: {bad.sum()} of {len(bad)} points differ; max |diff| "
        f"{np.max(np.abs(ours - cycles)):.3g}; first: ours {ours[bad][:3]}, cycles {cycles[bad][:3]}")


# ---- Cases -------------------------------------------------------------------------------------------

VORONOI, GABOR = "ShaderNodeTexVoronoi", "ShaderNodeTexGabor"
_SEEDS = itertools.count(1)


def case(node, options, output, inputs=None, per_hit=None, w=False, dims=3, span=4.0):
    """A case with fresh points; per_hit maps socket identifiers to a (lo, hi) range of per-point values."""
    seed = next(_SEEDS)
    rng = np.random.default_rng(seed + 1000)
    per_hit = dict(per_hit or {})
    aux = np.zeros((POINTS, 3), np.float32)
    aux[:, 0] = rng.uniform(-span, span, POINTS)
    aux[POINTS // 8: POINTS // 4, 0] *= 3e5       # far W with the far points
    for slot, (name, (lo, hi)) in enumerate(per_hit.items()):
        if name == "Orientation 3D":       # a vector input: the whole attribute
            aux[:] = rng.uniform(lo, hi, (POINTS, 3))
        else:
            aux[:, 1 + slot] = rng.uniform(lo, hi, POINTS)
    return Case(node, dict(options), output, dict(inputs or {}), tuple(per_hit), w,
                sample_points(seed, dims=dims, span=span), aux)


def voronoi_cases(dims: str, feature: str, metric: str = "EUCLIDEAN", normalize=False, inputs=None,
                  per_hit=None, outputs=None):
    options = {"voronoi_dimensions": dims, "feature": feature, "distance": metric, "normalize": normalize}
    return [case(VORONOI, options, out, inputs, per_hit, w=dims in ("1D", "4D"), dims=int(dims[0]))
            for out in (outputs or available_outputs(dims, feature))]


def combinations(dims: str):
    """Every feature x metric x output there is in these dimensions (1D has no metric: one is enough,
    and a non-Euclidean one checks it is ignored; Distance to Edge and N-Sphere Radius ignore it too)."""
    metrics = ("EUCLIDEAN", "MANHATTAN", "CHEBYCHEV", "MINKOWSKI") if dims != "1D" else ("EUCLIDEAN",)
    out = []
    for feature in ("F1", "F2", "SMOOTH_F1"):
        for metric in metrics:
            # Normalize on for half of them; Minkowski at a non-default exponent.
            out += voronoi_cases(dims, feature, metric, normalize=metric in ("MANHATTAN", "MINKOWSKI"),
                                 inputs={"Exponent": 1.7} if metric == "MINKOWSKI" else None)
    out += voronoi_cases(dims, "F1", "MANHATTAN", outputs=("Distance",)) if dims == "1D" else []
    out += voronoi_cases(dims, "DISTANCE_TO_EDGE")
    out += voronoi_cases(dims, "DISTANCE_TO_EDGE", "MANHATTAN", normalize=True)
    out += voronoi_cases(dims, "N_SPHERE_RADIUS")
    out += voronoi_cases(dims, "N_SPHERE_RADIUS", "CHEBYCHEV", inputs={"Randomness": 0.6})
    return out


def parameter_cases():
    """Randomness 0 / between / per hit, fractal detail (integral, fractional, per hit), per-hit Scale,
    Smoothness and Exponent, lattice-aligned points at Scale 4."""
    fractal = {"Detail": 2.5, "Roughness": 0.6, "Lacunarity": 2.7}
    out = []
    out += voronoi_cases("3D", "F1", inputs={"Randomness": 0.0})
    out += voronoi_cases("2D", "F2", "CHEBYCHEV", inputs={"Randomness": 0.37})
    out += voronoi_cases("2D", "F1", normalize=True, per_hit={"Randomness": (-0.2, 1.2)})
    out += voronoi_cases("3D", "N_SPHERE_RADIUS", per_hit={"Randomness": (0.0, 1.0)})
    out += voronoi_cases("2D", "DISTANCE_TO_EDGE", inputs={"Randomness": 0.0})
    out += voronoi_cases("3D", "DISTANCE_TO_EDGE", normalize=True, per_hit={"Randomness": (0.0, 1.0)})
    out += voronoi_cases("3D", "F1", inputs={"Scale": 4.0})
    out += voronoi_cases("2D", "SMOOTH_F1", inputs={"Scale": 4.0, "Smoothness": 0.3})
    out += voronoi_cases("3D", "SMOOTH_F1", "MANHATTAN", inputs={"Smoothness": 0.0})
    out += voronoi_cases("3D", "F1", inputs={"Scale": 0.0}, outputs=("Distance", "Position"))
    out += voronoi_cases("2D", "F1", normalize=True, inputs={"Detail": 16.0, "Roughness": 0.9})
    out += voronoi_cases("3D", "F1", per_hit={"Scale": (-3.0, 9.0)})
    out += voronoi_cases("4D", "F2", per_hit={"Scale": (0.5, 7.0)})
    out += voronoi_cases("3D", "F1", normalize=True, inputs=fractal)
    out += voronoi_cases("3D", "F1", "MANHATTAN", normalize=False, inputs={"Detail": 2.0, "Lacunarity": 1.6})
    out += voronoi_cases("2D", "F2", "MINKOWSKI", normalize=True, inputs={**fractal, "Exponent": 1.5})
    out += voronoi_cases("1D", "SMOOTH_F1", normalize=True, inputs=fractal)
    out += voronoi_cases("4D", "F1", "CHEBYCHEV", normalize=True, inputs={"Detail": 1.3})
    out += voronoi_cases("2D", "SMOOTH_F1", normalize=True, inputs={"Detail": 1.5},
                         per_hit={"Smoothness": (-0.3, 1.2)})
    out += voronoi_cases("3D", "F1", normalize=True,
                         per_hit={"Detail": (-1.0, 4.0), "Roughness": (-0.2, 1.0)})
    out += voronoi_cases("3D", "F1", "MINKOWSKI", per_hit={"Exponent": (0.3, 4.0)})
    out += voronoi_cases("3D", "F2", normalize=True, inputs={"Detail": 2.5},
                         per_hit={"Lacunarity": (0.5, 3.5), "Roughness": (0.0, 1.0)})
    out += voronoi_cases("3D", "F1", inputs={"Detail": 3.0, "Roughness": 0.0})
    out += voronoi_cases("3D", "DISTANCE_TO_EDGE", normalize=True, inputs={"Detail": 3.3, "Roughness": 0.7})
    out += voronoi_cases("1D", "DISTANCE_TO_EDGE", normalize=True, inputs={"Detail": 2.0, "Lacunarity": 3.0})
    out += voronoi_cases("2D", "DISTANCE_TO_EDGE", normalize=True,
                         per_hit={"Detail": (-1.0, 3.0), "Roughness": (0.0, 1.0)})
    out += voronoi_cases("4D", "DISTANCE_TO_EDGE", normalize=True, inputs={"Detail": 1.5})
    return out


def gabor_cases():
    out = []
    for gabor_type, orient in (("2D", {"Orientation 2D": 0.3}), ("3D", {"Orientation 3D": (0.3, -0.5, 0.8)})):
        options = {"gabor_type": gabor_type}
        for inputs, per_hit in (({}, None),                                   # Blender's defaults
                                ({"Anisotropy": 0.0, "Frequency": 3.7}, None),
                                ({"Anisotropy": 0.4, **orient}, None),
                                ({**orient}, {"Frequency": (-0.5, 5.0), "Anisotropy": (-0.2, 1.2)}),
                                ({"Anisotropy": 0.7}, {"Scale": (0.5, 8.0)}),
                                ({"Anisotropy": 0.8}, {"Orientation 2D": (-4.0, 4.0)} if gabor_type == "2D"
                                 else {"Orientation 3D": (-1.0, 1.0)})):
            for output in ("Value", "Phase", "Intensity"):
                out.append(case(GABOR, options, output, inputs, per_hit, span=3.0))
    return out


def renders(name: str, cases, max_nodes: int = 12) -> dict:
    """Cases split into renders of at most max_nodes distinct nodes (Cycles' SVM stack is 255 floats)."""
    out, chunk, keys = {}, [], set()
    for c in cases:
        if c.key not in keys and len(keys) == max_nodes:
            out[f"{name}{len(out)}"], chunk, keys = chunk, [], set()
        chunk.append(c)
        keys.add(c.key)
    out[f"{name}{len(out)}"] = chunk
    return out


RENDERS = {
    **renders("voronoi-1d-2d-", combinations("1D") + combinations("2D")),
    **renders("voronoi-3d-", combinations("3D")),
    **renders("voronoi-4d-", combinations("4D")),
    **renders("voronoi-parameters-", parameter_cases()),
    **renders("gabor-", gabor_cases()),
}
_probed: dict = {}


def cycles_values(render: str) -> list[np.ndarray]:
    if render not in _probed:
        _probed[render] = probe_cases(RENDERS[render])
    return _probed[render]


# ---- Ours --------------------------------------------------------------------------------------------

_KWARGS = {"W": "w", "Scale": "scale", "Detail": "detail", "Roughness": "roughness",
           "Lacunarity": "lacunarity",
           "Smoothness": "smoothness", "Exponent": "exponent", "Randomness": "randomness",
           "Frequency": "frequency", "Anisotropy": "anisotropy", "Orientation 2D": "orientation_2d",
           "Orientation 3D": "orientation_3d"}


def ours(c: Case) -> np.ndarray:
    kwargs = {_KWARGS[k]: v for k, v in c.inputs.items()}
    for slot, name in enumerate(c.per_hit):
        kwargs[_KWARGS[name]] = c.aux if name == "Orientation 3D" else c.aux[:, 1 + slot]
    if c.w:
        kwargs["w"] = c.aux[:, 0]
    if c.node == VORONOI:
        o = c.options
        result = voronoi_texture(c.points, **kwargs, dimensions=o["voronoi_dimensions"], feature=o["feature"],
                                 distance=o["distance"], normalize=o["normalize"], outputs={c.output})
    else:
        result = gabor_texture(c.points, **kwargs, gabor_type=c.options["gabor_type"], outputs={c.output})
    return result[c.output]


def _case_id(render, i):
    c = RENDERS[render][i]
    o = c.options
    if c.node == VORONOI:
        name = f"{o['voronoi_dimensions']}-{o['feature']}-{o['distance']}{'-norm' if o['normalize'] else ''}"
    else:
        name = f"gabor{o['gabor_type']}"
    extra = "".join(f"-{k}={v}" for k, v in c.inputs.items()) + "".join(f"-{k}=hit" for k in c.per_hit)
    return f"{render}:{i}:{name}{extra}-{c.output}".replace(" ", "")


ALL_CASES = [(r, i) for r in RENDERS for i in range(len(RENDERS[r]))]


@pytest.mark.parametrize("render,index", ALL_CASES, ids=[_case_id(r, i) for r, i in ALL_CASES])
def test_matches_cycles(render, index):
    c = RENDERS[render][index]
    cycles = cycles_values(render)[index]
    mine = ours(c)
    if mine.ndim == 1:
        np.testing.assert_array_equal(cycles[:, 0], cycles[:, 2])      # a float output shows grey
        cycles = cycles[:, 0]
    atol = ATOL
    if c.output == "Phase":
        atol = ATOL + phase_tolerance(c)
    assert_close(mine, cycles, _case_id(render, index), atol=atol)


def phase_tolerance(c: Case) -> np.ndarray:
    """Phase = atan2(imag, real) / 2 pi is ill-conditioned where the phasor z is short: a few-ULP error in
    its components (sums of kernels of magnitude <= 1: PHASOR_EPS absolute) turns the angle by
    PHASOR_EPS / |z|. |z| is Intensity x 6 standard deviations (ours, equal to Cycles' to 1e-7)."""
    kwargs = {_KWARGS[k]: v for k, v in c.inputs.items()}
    kwargs.update({_KWARGS[name]: c.aux if name == "Orientation 3D" else c.aux[:, 1 + slot]
                   for slot, name in enumerate(c.per_hit)})
    gabor_type = c.options["gabor_type"]
    intensity = gabor_texture(c.points, **kwargs, gabor_type=gabor_type, outputs={"Intensity"})["Intensity"]
    length = intensity * (NORMALIZATION_2D if gabor_type == "2D" else NORMALIZATION_3D)
    return PHASOR_EPS / (2 * np.pi * np.maximum(length, 1e-30))


# ---- Closed forms and properties ---------------------------------------------------------------------

def test_randomness_zero_puts_points_on_the_lattice():
    """Randomness 0: every cell's point is its corner, so F1 is the distance to the nearest integer point,
    Position that point / Scale, and every N-Sphere Radius is 1/2."""
    rng = np.random.default_rng(5)
    p = rng.uniform(-3, 3, (4000, 3)).astype(np.float32)
    for dims, d in (("2D", 2), ("3D", 3)):
        out = voronoi_texture(p, scale=4.0, randomness=0.0, dimensions=dims, outputs={"Distance", "Position"})
        q = p[:, :d] * np.float32(4.0)
        nearest = np.floor(q + np.float32(0.5))
        np.testing.assert_allclose(out["Distance"], np.linalg.norm(q - nearest, axis=1), rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(out["Position"][:, :d], nearest / 4.0, rtol=1e-6, atol=1e-6)
        radius = voronoi_texture(p, randomness=0.0, dimensions=dims, feature="N_SPHERE_RADIUS")["Radius"]
        np.testing.assert_array_equal(radius, 0.5)
    w = rng.uniform(-3, 3, 4000).astype(np.float32)
    edge = voronoi_texture(0.0, w, scale=1.0, randomness=0.0, dimensions="1D",
                           feature="DISTANCE_TO_EDGE")["Distance"]
    np.testing.assert_allclose(edge, np.abs(w - np.floor(w) - 0.5), atol=1e-6)


def test_f2_is_never_nearer_than_f1_and_inputs_broadcast():
    rng = np.random.default_rng(6)
    p = rng.uniform(-3, 3, (3000, 3)).astype(np.float32)
    w = rng.uniform(-3, 3, 3000).astype(np.float32)
    for dims in ("1D", "2D", "3D", "4D"):
        for metric in ("EUCLIDEAN", "CHEBYCHEV", "MINKOWSKI"):
            f1, f2 = (voronoi_texture(p, w, dimensions=dims, distance=metric, randomness=0.8,
                                      feature=feature)["Distance"] for feature in ("F1", "F2"))
            assert np.all(f2 >= f1), (dims, metric)
    # Constants broadcast like per-hit arrays holding them.
    one = voronoi_texture(p[0], 0.3, scale=3.0, detail=1.5, dimensions="4D")
    many = voronoi_texture(np.tile(p[:1], (5, 1)), np.full(5, 0.3, np.float32),
                           scale=np.full(5, 3.0, np.float32), detail=1.5, dimensions="4D")
    for name, value in one.items():
        assert value.dtype == np.float32 and len(value) == 1
        np.testing.assert_array_equal(np.broadcast_to(value, many[name].shape), many[name])


def test_gabor_value_lies_within_intensity():
    """Value is the phasor's imaginary part remapped, so |2 Value - 1| <= Intensity; Phase is in [0, 1]."""
    rng = np.random.default_rng(7)
    p = rng.uniform(-3, 3, (3000, 3)).astype(np.float32)
    for gabor_type in ("2D", "3D"):
        out = gabor_texture(p, anisotropy=0.5, gabor_type=gabor_type)
        assert all(v.dtype == np.float32 and v.shape == (3000,) for v in out.values())
        assert np.all(np.abs(2 * out["Value"] - 1) <= out["Intensity"] + 1e-6)
        assert np.all((out["Phase"] >= 0) & (out["Phase"] <= 1))


def test_a_nan_detail_is_no_detail():
    """Cycles clamps Detail to [0, 15] with a clamp that makes NaN 0: Voronoi raised on a per-hit NaN Detail and
    Noise gave NaN; both now give what Detail 0 gives (and inf what 15 gives)."""
    from ember.kernels.shading.noise import noise_texture
    co = np.random.default_rng(5).random((4, 3)).astype(np.float32)
    detail = np.float32([0.0, np.nan, 15.0, np.inf])
    like = np.float32([0.0, 0.0, 15.0, 15.0])
    for texture in (voronoi_texture, noise_texture):
        got, want = texture(co, detail=detail), texture(co, detail=like)
        assert got.keys() == want.keys()
        for name in got:
            assert np.array_equal(np.asarray(got[name]), np.asarray(want[name])), (texture.__name__, name)
