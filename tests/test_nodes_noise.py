"""Hashes, Perlin noise and the Noise, White Noise and Wave texture nodes (kernels.shading.hash, .perlin,
.fractal_noise, .noise) against Cycles itself: tests/node_probe.py renders the node at exact points, one
pixel per point.

The reference is Cycles' x86-64 CPU kernel as Blender 5.0 ships it (the AVX2 variant on a CPU that has
AVX2 and FMA): compiled with -ffp-contract=fast and -freciprocal-math, so its multiply-adds are fused and
its divisions by constants are multiplications. kernels.shading.perlin rounds the same way, so the
comparisons below are bit-exact, except the Wave's sine profile (NumPy is not glibc's sinf: within an
ulp). Bit-exactness is what makes distortion with many octaves agree at all: an ulp in a distorted
coordinate, times lacunarity^15, is a different noise value. On another kernel (SSE4.2, Arm) Cycles
itself rounds differently; there the tests still hold everything to float precision
(rtol 2e-5, atol 2e-6) but skip the bit-exact claim.

Probe inputs: every per-hit value comes through a Separate XYZ of a probe vector (exact), not through
the Attribute node's Fac, which Cycles computes as the average of the three components.
"""
import bpy
import numpy as np
import pytest

from ember.kernels.shading import fractal_noise, perlin
from ember.kernels.shading import hash as H
from ember.kernels.shading import noise as N
from tests.node_probe import AVX2_KERNEL, cycles_probe, sweep

F32 = np.float32
RTOL, ATOL = 2e-5, 2e-6
# The reference is this Blender's Cycles: the kernel rounds as it does (perlin.cycles_rounding).
CYCLES = {"cycles_version": tuple(bpy.app.version)}
# Blender 5.3's compiled fractal loops and Wave round differently from 5.0's (same source; Perlin itself is
# followed bit for bit): Ember keeps 5.0's rounding there, which distortion and octaves amplify.
ROUNDING_5_0_ONLY = pytest.mark.xfail(bpy.app.version[:2] >= (5, 3), strict=True,
                                      reason="Cycles 5.3 rounds fractal noise and Wave differently "
                                             "(docs/blender-versions.md)")


TYPES = ["FBM", "MULTIFRACTAL", "HYBRID_MULTIFRACTAL", "RIDGED_MULTIFRACTAL", "HETERO_TERRAIN"]
DIMS = ["1D", "2D", "3D", "4D"]


def assert_matches(ours, cycles, exact=True):
    """Float precision always; bit for bit where the reference is the kernel noise.py mirrors."""
    ours, cycles = np.asarray(ours, F32), np.asarray(cycles, F32)
    assert ours.shape == cycles.shape
    np.testing.assert_allclose(ours, cycles, rtol=RTOL, atol=ATOL)
    if exact and AVX2_KERNEL:
        np.testing.assert_array_equal(ours, cycles)


# ---- Probe graph helpers ----------------------------------------------------------------------------

def link(tree, socket, node, identifier):
    """Link to the node's input with this identifier if this node's mode uses it (1D has no Vector,
    2D and 3D no W)."""
    sock = next(s for s in node.inputs if s.identifier == identifier)
    if sock.enabled:
        tree.links.new(socket, sock)


def component(tree, sockets, probe, index):
    sep = tree.nodes.new("ShaderNodeSeparateXYZ")
    tree.links.new(sockets[probe], sep.inputs[0])
    return sep.outputs[index]


def texture(kind, options, wired, constants, output):
    """A probe build: node `kind` with `options`, inputs wired from probe components {identifier:
    (probe, component)} or set to constants, showing `output`."""
    def build(tree, sockets):
        node = tree.nodes.new(kind)
        for key, value in options.items():
            setattr(node, key, value)
        for sock in node.inputs:
            if sock.identifier in constants:
                sock.default_value = constants[sock.identifier]
        link(tree, sockets["probe"], node, "Vector")
        for identifier, (probe, index) in wired.items():
            link(tree, component(tree, sockets, probe, index), node, identifier)
        return node.outputs[output]
    return build


def grey(values):
    """A float output as the probe shows it: (K,) -> (K, 3)."""
    return np.repeat(np.asarray(values, F32)[:, None], 3, axis=1)


# ---- Hashes -----------------------------------------------------------------------------------------

def test_lookup3_known_values():
    """util/hash.h compiled as C (uint32 wrap-around) gives these; int32 keys wrap like (uint) casts."""
    keys = np.array([[0, 0, 0, 0], [1, 2, 3, 4], [0xDEADBEEF, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFF]], np.uint32)
    expected = {
        1: [0x9519DC65, 0x4AD7C6A0, 0xF385CA09],
        2: [0xDC3D74F9, 0x1037CB9D, 0x9ED67610],
        3: [0x9C6EEDFB, 0xB8D17A0A, 0x998C84E8],
        4: [0x1C900BCC, 0x0584DEC1, 0x4756A2CB],
    }
    fns = {1: H.hash_uint, 2: H.hash_uint2, 3: H.hash_uint3, 4: H.hash_uint4}
    for words, fn in fns.items():
        got = fn(*keys[:, :words].T)
        assert got.dtype == np.uint32
        np.testing.assert_array_equal(got, np.array(expected[words], np.uint32), err_msg=f"hash_uint{words}")
    np.testing.assert_array_equal(H.hash_uint(np.int32(-1)), H.hash_uint(np.uint32(0xFFFFFFFF)))


def test_pcg_known_values():
    """hash_pcg{2,3,4}d_i on int32 (signed overflow wraps, >> is arithmetic), C reference values."""
    keys = np.array([[0, 0, 0, 0], [1, -2, 3, -4], [2147483647, -2147483648, 12345, -1]], np.int32)
    expected = {
        2: [[0x541F2943, 0x65C3F18C], [0x49EBF9CB, 0x2115895D], [0x2D8B26D7, 0x471E43BF]],
        3: [[0x04FFD7C6, 0x2B258A6B, 0x0C08482C], [0x362E14A4, 0x1B4C0AC6, 0x2F3B79E1],
            [0x08885ACB, 0x22D13BD5, 0x4E666099]],
        4: [[0x4529F829, 0x5B788769, 0x7F76C43B, 0x578248EA], [0x69244556, 0x5EB1F6E2, 0x54CC87A7, 0x660383A3],
            [0x055D1835, 0x1C71DB92, 0x632E69C1, 0x3CEFF592]],
    }
    fns = {2: H.hash_pcg2d_i, 3: H.hash_pcg3d_i, 4: H.hash_pcg4d_i}
    for d, fn in fns.items():
        got = np.stack(fn(keys[:, :d].T), axis=1)
        assert got.dtype == np.int32 and (got >= 0).all()
        np.testing.assert_array_equal(got, np.array(expected[d], np.int32), err_msg=f"pcg{d}d")
    unit = np.stack(H.hash_int3_to_float3(keys[:, :3].T), axis=1)
    np.testing.assert_array_equal(unit, np.stack(H.hash_pcg3d_i(keys[:, :3].T), axis=1).astype(F32) * F32(2.0 ** -31))


def white_noise_points():
    """Sweep, integers, both zeros, large and small magnitudes: the hash sees raw float bits."""
    p = sweep(-50, 50, 768, seed=3)
    p[::7] = np.round(p[::7])
    p[1::9] *= F32(1e5)
    p[2::11] *= F32(1e-20)
    p[3::13, 0] = F32(0.0)
    p[4::13, 0] = F32(-0.0)
    w = sweep(-20, 20, 768, seed=4)
    w[::5] = np.round(w[::5])
    w[1::17, 0] = F32(-0.0)
    return p, w


@pytest.mark.parametrize("dims", DIMS)
def test_white_noise_matches_cycles(dims):
    """The White Noise node is nothing but the float hashes: bit for bit, Value and Color."""
    p, w = white_noise_points()
    wire = {"W": ("probe2", 0)}
    ours = N.white_noise_texture(p, w[:, 0], dimensions=dims)
    for output in ("Value", "Color"):
        build = texture("ShaderNodeTexWhiteNoise", {"noise_dimensions": dims}, wire, {}, output)
        cycles = cycles_probe(build, {"probe": p, "probe2": w})
        expected = ours[output] if output == "Color" else grey(ours[output])
        np.testing.assert_array_equal(expected, cycles, err_msg=f"{dims} {output}")


def test_float_hashes_see_the_sign_of_zero():
    assert H.hash_float_to_float(F32(0.0))[0] != H.hash_float_to_float(F32(-0.0))[0]
    assert H.hash_float3_to_float((0.0, 1.0, 2.0))[0] == H.hash_uint3_to_float(0, 0x3F800000, 0x40000000)[0]


# ---- Perlin -----------------------------------------------------------------------------------------

def reciprocal_sensitive(count):
    """Coordinates where trunc(c / 1e5) != trunc(c * float32(1e-5)): just below multiples of 1e5 around
    1e9. They tell Cycles' compiled fmod (reciprocal multiply, fused c - q 1e5) from a true one."""
    c = (np.arange(8000, 20000) * 1e5).astype(F32)
    found = []
    for _ in range(4):
        c = np.nextafter(c, F32(0))
        found.append(c[np.trunc(c / F32(1e5)) != np.trunc(c * F32(1e-5))])
    return np.concatenate(found)[:count]


def perlin_points():
    """(P, W): a sweep with lattice-aligned coordinates, the 1e5 wrap and the 1e6 half-shift."""
    rng = np.random.default_rng(5)
    p = sweep(-40, 40, 1536, seed=7, dims=3)
    w = sweep(-40, 40, 1536, seed=8, dims=1)
    p[::6] = np.round(p[::6])
    w[::5] = np.round(w[::5])
    big = slice(1024, None)
    p[big] = (rng.uniform(-1, 1, (512, 3)) * 10.0 ** rng.uniform(4.5, 9, (512, 3))).astype(F32)
    w[big, 0] = (rng.uniform(-1, 1, 512) * 10.0 ** rng.uniform(4.5, 9, 512)).astype(F32)
    p[1024::7] = np.round(p[1024::7] / 1e5) * 1e5
    p[1025::11, 0], p[1026::11, 1] = F32(1e6), F32(-1e6)
    p[1027::11, 2] = np.nextafter(F32(1e6), F32(0))
    sensitive = reciprocal_sensitive(96)
    p[1100:1196, 0] = sensitive
    p[1200:1296, 1] = -sensitive
    w[1300:1396, 0] = sensitive
    return p, w


@pytest.mark.parametrize("dims", DIMS)
def test_snoise_is_bit_exact(dims):
    """Signed Perlin noise (Noise node, Detail 0, unnormalised fBM = snoise itself), including the large
    coordinates Cycles wraps by fmod(p, 1e5) and shifts by 1/2 beyond 1e6."""
    p, w = perlin_points()
    build = texture("ShaderNodeTexNoise", {"noise_dimensions": dims, "normalize": False}, {"W": ("probe2", 0)},
                    {"Scale": 1.0, "Detail": 0.0}, "Fac")
    cycles = cycles_probe(build, {"probe": p, "probe2": w})
    coords = N._coords(p, w[:, 0], N.DIMENSIONS[dims], len(p))
    with perlin.cycles_rounding(bpy.app.version):
        ours = perlin.snoise(coords)
    assert_matches(grey(ours), cycles)


def test_perlin_vanishes_on_the_lattice():
    rng = np.random.default_rng(1)
    for d in (1, 2, 3, 4):
        lattice = tuple(rng.integers(-50000, 50000, 256).astype(F32) for _ in range(d))
        np.testing.assert_array_equal(perlin.snoise(lattice), np.zeros(256, F32))


# ---- Noise Texture ----------------------------------------------------------------------------------

K = 1024


def noise_inputs():
    """Per-hit inputs spanning and overshooting their ranges (Detail is clamped to [0, 15], Roughness
    to >= 0), with integer Details and zero Distortions among them."""
    rng = np.random.default_rng(11)
    p = sweep(-3, 3, K, seed=3)
    p[::7] = np.round(p[::7])
    w = sweep(-3, 3, K, seed=4)
    a = np.stack([rng.uniform(-1, 17, K), rng.uniform(-0.2, 1.0, K), rng.uniform(0.5, 6, K)], 1).astype(F32)
    a[::4, 0] = np.round(a[::4, 0])
    b = np.stack([rng.uniform(1.2, 3, K), rng.uniform(0, 1.5, K), rng.uniform(0, 3, K)], 1).astype(F32)
    c = np.stack([rng.uniform(-1, 2, K), np.zeros(K), np.zeros(K)], 1).astype(F32)
    c[::3, 0] = 0.0
    probes = {"probe": p, "probe2": w, "probe3": a, "probe4": b, "probe5": c}
    wired = {"W": ("probe2", 0), "Detail": ("probe3", 0), "Roughness": ("probe3", 1), "Scale": ("probe3", 2),
             "Lacunarity": ("probe4", 0), "Offset": ("probe4", 1), "Gain": ("probe4", 2),
             "Distortion": ("probe5", 0)}
    kwargs = dict(w=w[:, 0], detail=a[:, 0], roughness=a[:, 1], scale=a[:, 2], lacunarity=b[:, 0],
                  offset=b[:, 1], gain=b[:, 2], distortion=c[:, 0])
    return probes, wired, kwargs


NOISE_CASES = [(d, t, True) for d in DIMS for t in TYPES] + [(d, "FBM", False) for d in DIMS]


@ROUNDING_5_0_ONLY
@pytest.mark.parametrize("dims,noise_type,normalize", NOISE_CASES)
def test_noise_texture_per_hit_inputs(dims, noise_type, normalize):
    """Every input per hit (Detail 0..15 with fractions, beyond-range values, Distortion with many
    octaves): the Color output, whose channels are the Fac and two more seeded fractals."""
    probes, wired, kwargs = noise_inputs()
    options = {"noise_dimensions": dims, "noise_type": noise_type, "normalize": normalize}
    cycles = cycles_probe(texture("ShaderNodeTexNoise", options, wired, {}, "Color"), probes)
    ours = N.noise_texture(probes["probe"], dimensions=dims, noise_type=noise_type, normalize=normalize,
                           **kwargs, **CYCLES)
    assert_matches(ours["Color"], cycles)
    np.testing.assert_array_equal(ours["Fac"], ours["Color"][:, 0])


CONSTANT_SETTINGS = [
    {},                                                                  # Blender's defaults
    {"Detail": 3.5, "Roughness": 0.6, "Lacunarity": 2.3, "Offset": 0.8, "Gain": 1.3, "Distortion": 0.7},
    {"Detail": 15.0, "Roughness": 0.9, "Lacunarity": 1.7, "Offset": 1.0, "Gain": 2.0, "Scale": 1.5},
    {"Detail": 0.0, "Scale": 2.0, "Distortion": -1.5},
]


@ROUNDING_5_0_ONLY
@pytest.mark.parametrize("dims", DIMS)
@pytest.mark.parametrize("noise_type", TYPES)
def test_noise_texture_constant_inputs(dims, noise_type):
    """The constant-Detail path (scalar octave bookkeeping), over several settings in one render each.
    W stays per hit, so that 1D still reads a linked input (see the fully constant test below)."""
    probes = {"probe": sweep(-2, 2, 512, seed=9), "probe2": sweep(-2, 2, 512, seed=10)}
    for constants in CONSTANT_SETTINGS:
        options = {"noise_dimensions": dims, "noise_type": noise_type}
        build = texture("ShaderNodeTexNoise", options, {"W": ("probe2", 0)}, constants, "Color")
        cycles = cycles_probe(build, probes)
        kwargs = {key.lower(): value for key, value in constants.items()}
        ours = N.noise_texture(probes["probe"], probes["probe2"][:, 0], dimensions=dims, noise_type=noise_type,
                               **kwargs, **CYCLES)
        assert_matches(ours["Color"], cycles)


def test_noise_texture_fully_constant_node():
    """A 1D Noise node whose inputs are all constants (its Vector is unused) is evaluated before Cycles'
    kernel runs (Blender folds it with its own CPU code: Cycles' NoiseTextureNode has no constant_fold),
    which rounds differently: the same value to float precision, not bit for bit."""
    probes = {"probe": sweep(-2, 2, 64, seed=9)}
    for constants in CONSTANT_SETTINGS:
        constants = dict(constants, W=0.37)
        build = texture("ShaderNodeTexNoise", {"noise_dimensions": "1D"}, {}, constants, "Color")
        cycles = cycles_probe(build, probes)
        kwargs = {key.lower(): value for key, value in constants.items()}
        ours = N.noise_texture(probes["probe"], dimensions="1D", **kwargs, **CYCLES)
        assert_matches(ours["Color"], cycles, exact=False)


@pytest.mark.parametrize("dims", DIMS)
def test_noise_texture_large_coordinates(dims):
    """fBM octaves at 1e5 .. 1e9: every octave goes through the fmod wrap (fmodf in 1D, the compiled
    SIMD fmod in 2D-4D)."""
    p, w = perlin_points()
    build = texture("ShaderNodeTexNoise", {"noise_dimensions": dims}, {"W": ("probe2", 0)},
                    {"Scale": 1.0, "Detail": 3.0}, "Fac")
    cycles = cycles_probe(build, {"probe": p, "probe2": w})
    ours = N.noise_texture(p, w[:, 0], scale=1.0, detail=3.0, dimensions=dims, outputs=("Fac",), **CYCLES)
    assert_matches(grey(ours["Fac"]), cycles)


def test_per_hit_detail_equals_constant_detail():
    """The masked per-hit octave loop gives, hit by hit, what the constant path gives."""
    rng = np.random.default_rng(2)
    p = rng.uniform(-4, 4, (600, 3)).astype(F32)
    details = np.array([0.0, 0.5, 1.0, 2.25, 7.0, 7.75], F32)
    per_hit = np.repeat(details, 100)
    for noise_type in TYPES:
        mixed = N.noise_texture(p, detail=per_hit, noise_type=noise_type, offset=0.7, gain=1.4)["Color"]
        for i, d in enumerate(details):
            rows = slice(100 * i, 100 * (i + 1))
            alone = N.noise_texture(p[rows], detail=d, noise_type=noise_type, offset=0.7, gain=1.4)["Color"]
            np.testing.assert_array_equal(mixed[rows], alone, err_msg=f"{noise_type} detail {d}")


def test_fractal_closed_forms():
    """Roughness 0 leaves one octave: fBM = snoise/2 + 1/2 at any Detail; Multifractal = 1 + snoise."""
    rng = np.random.default_rng(4)
    p = tuple(rng.uniform(-9, 9, 400).astype(F32) for _ in range(3))
    s = perlin.snoise(p)
    np.testing.assert_array_equal(fractal_noise.fbm(p, 4.0, 0.0, 2.0), s * F32(0.5) + F32(0.5))
    np.testing.assert_array_equal(fractal_noise.multi_fractal(p, 0.0, 0.5, 2.0), s + F32(1.0))
    np.testing.assert_array_equal(fractal_noise.fbm(p, 0.0, 0.5, 2.0, normalize=False), s)


def test_node_functions_broadcast_constants():
    """Constant sockets (a (3,) vector, Python floats) broadcast to the hits of the per-hit ones; zero
    hits give empty outputs."""
    w = np.linspace(-2, 2, 50, dtype=F32)
    out = N.noise_texture(np.array([0.3, 0.2, 0.1], F32), w, dimensions="4D")
    assert out["Fac"].shape == (50,) and out["Color"].shape == (50, 3)
    assert out["Fac"].dtype == F32 and out["Color"].dtype == F32
    vectors = np.zeros((50, 3), F32)
    one_d = N.noise_texture(np.zeros(3, F32), w, dimensions="1D")["Fac"]
    np.testing.assert_array_equal(N.noise_texture(vectors, w, dimensions="1D")["Fac"], one_d)
    assert one_d.shape == (50,)
    assert set(N.noise_texture(vectors, outputs=("Fac",))) == {"Fac"}
    assert N.white_noise_texture(vectors, 0.5, dimensions="1D")["Color"].shape == (50, 3)
    wave = N.wave_texture(vectors, phase_offset=w)
    assert wave["Fac"].shape == (50,) and wave["Color"].shape == (50, 3) and wave["Fac"].dtype == F32
    none = np.zeros((0, 3), F32)
    assert N.noise_texture(none, distortion=1.0)["Color"].shape == (0, 3)
    assert N.white_noise_texture(none)["Value"].shape == (0,)
    assert N.wave_texture(none, distortion=1.0)["Fac"].shape == (0,)


# ---- Wave Texture -----------------------------------------------------------------------------------

def wave_inputs():
    rng = np.random.default_rng(12)
    p = sweep(-3, 3, K, seed=5)
    p[::5] = np.round(p[::5] * 4) / 4       # on the quarter lattice, where bands would sit on edges
    a = np.stack([rng.uniform(0.5, 6, K), rng.uniform(-3, 3, K), rng.uniform(0, 6, K)], 1).astype(F32)
    a[::3, 1] = 0.0
    b = np.stack([rng.uniform(0, 4, K), rng.uniform(0, 1, K), rng.uniform(-10, 10, K)], 1).astype(F32)
    probes = {"probe": p, "probe3": a, "probe4": b}
    wired = {"Scale": ("probe3", 0), "Distortion": ("probe3", 1), "Detail": ("probe3", 2),
             "Detail Scale": ("probe4", 0), "Detail Roughness": ("probe4", 1), "Phase Offset": ("probe4", 2)}
    kwargs = dict(scale=a[:, 0], distortion=a[:, 1], detail=a[:, 2], detail_scale=b[:, 0],
                  detail_roughness=b[:, 1], phase_offset=b[:, 2])
    return probes, wired, kwargs


WAVE_CASES = [("BANDS", d, prof) for d in ("X", "Y", "Z", "DIAGONAL") for prof in ("SIN", "SAW", "TRI")] + \
             [("RINGS", d, prof) for d in ("X", "Y", "Z", "SPHERICAL") for prof in ("SIN", "SAW", "TRI")]


def wave_options(wave_type, direction, profile):
    key = "bands_direction" if wave_type == "BANDS" else "rings_direction"
    return {"wave_type": wave_type, key: direction, "wave_profile": profile}


def assert_wave_matches(ours, cycles, profile):
    if profile == "SIN":
        # glibc's sinf and a correctly rounded sine differ by at most an ulp of the sine (<= 2^-24 below
        # 1): half of that after 0.5 + 0.5 sin, plus the rounding of the sum (<= 2^-25).
        assert_matches(ours, cycles, exact=False)
        assert np.abs(ours - cycles).max() <= 2.0 ** -24
    else:
        assert_matches(ours, cycles)


@ROUNDING_5_0_ONLY
@pytest.mark.parametrize("wave_type,direction,profile", WAVE_CASES)
def test_wave_texture_per_hit_inputs(wave_type, direction, profile):
    probes, wired, kwargs = wave_inputs()
    options = wave_options(wave_type, direction, profile)
    cycles = cycles_probe(texture("ShaderNodeTexWave", options, wired, {}, "Color"), probes)
    ours = N.wave_texture(probes["probe"], **options, **kwargs, **CYCLES)
    assert_wave_matches(ours["Color"], cycles, profile)


@ROUNDING_5_0_ONLY
@pytest.mark.parametrize("profile", ["SIN", "SAW", "TRI"])
def test_wave_texture_constant_inputs(profile):
    probes = {"probe": sweep(-2, 2, 512, seed=13)}
    for constants in ({}, {"Distortion": 4.0, "Detail": 3.5, "Detail Scale": 2.0, "Phase Offset": 1.0}):
        options = wave_options("RINGS", "SPHERICAL", profile)
        cycles = cycles_probe(texture("ShaderNodeTexWave", options, {}, constants, "Fac"), probes)
        kwargs = {key.lower().replace(" ", "_"): value for key, value in constants.items()}
        ours = N.wave_texture(probes["probe"], **options, **kwargs, **CYCLES)["Fac"]
        assert_wave_matches(grey(ours), cycles, profile)
