"""Colour, maths and converter nodes (kernels/shading/math_nodes.py, color_nodes.py, mix_nodes.py,
vector_nodes.py, curve_nodes.py; engine/export/node_tables.py) against Cycles itself, probed
pixel-exactly (tests/node_probe.py), at float precision.

Many node variants share one render: each variant gets its own block of pixels holding the same points,
and a chain of Mix nodes (factor 1 exactly on the variant's block, 0 elsewhere: a (1 - 0) + b 0 = a, exact
for finite values) shows each variant on its block. So every variant's outputs must stay finite on every
point of its render. Float inputs come from a Separate XYZ of a probe vector (exact).
"""
from __future__ import annotations

import bpy
import numpy as np
import pytest

from ember.engine.export import node_tables
from ember.kernels.shading import color_nodes, curve_nodes, math_nodes, mix_nodes, vector_nodes
from tests.node_probe import cycles_probe

F32 = np.float32
RTOL, ATOL = 2e-5, 2e-6
MIN_POINTS = 4 * 64  # Blender renders at least 4 x 4 pixels: keep the probe image 4 rows high or more


# ---------------------------------------------------------------- probing many variants in one render
def probe_variants(builders, **arrays) -> np.ndarray:
    """Render each builder's graph over the same points, in one Cycles render: (K, n, 3) float32.

    builders : callables (tree, sockets) -> the output socket to show. sockets holds each array's Vector
        socket by name and its components as "<name>.x", ".y", ".z" (float sockets, exact).
    arrays : name -> (n, 3) or (n,) points (a 1-D array is the x component).
    """
    k = len(builders)
    n = len(next(iter(arrays.values())))
    total = max(k * n, MIN_POINTS)
    points = {}
    for name, a in arrays.items():
        a = np.asarray(a, F32)
        if a.ndim == 1:
            a = np.stack([a, np.zeros_like(a), np.zeros_like(a)], -1)
        p = np.zeros((total, 3), F32)
        p[:k * n] = np.tile(a, (k, 1))
        points[name] = p
    variant = np.zeros((total, 3), F32)
    variant[:k * n, 0] = np.repeat(np.arange(k), n)
    points["variant"] = variant

    def build(tree, sockets):
        s = dict(sockets)
        for name in arrays:
            sep = tree.nodes.new("ShaderNodeSeparateXYZ")
            tree.links.new(sockets[name], sep.inputs[0])
            for axis, out in zip("xyz", sep.outputs):
                s[f"{name}.{axis}"] = out
        which = tree.nodes.new("ShaderNodeSeparateXYZ")
        tree.links.new(sockets["variant"], which.inputs[0])
        shown = None
        for i, builder in enumerate(builders):
            out = builder(tree, s)
            if shown is None:
                shown = out
                continue
            is_i = node(tree, "ShaderNodeMath", {0: which.outputs[0]}, operation="COMPARE")
            is_i.inputs[1].default_value, is_i.inputs[2].default_value = float(i), 0.0
            pick = node(tree, "ShaderNodeMix", {"Factor": is_i.outputs[0], 4: shown, 5: out},
                        data_type="VECTOR", clamp_factor=False)
            shown = pick.outputs[1]
        return shown

    return cycles_probe(build, points)[:k * n].reshape(k, n, 3)


def node(tree, idname, links=None, **props):
    """A new node with its properties set and {input (index or name): source socket} linked."""
    n = tree.nodes.new(idname)
    for key, value in props.items():
        setattr(n, key, value)
    for key, socket in (links or {}).items():
        tree.links.new(socket, n.inputs[key])
    return n


def inp(n, identifier):
    """A node's input by identifier (names repeat across a node's data types)."""
    return next(s for s in n.inputs if s.identifier == identifier)


def show3(tree, x, y, z):
    """Three float sockets shown as one colour (Combine XYZ)."""
    return node(tree, "ShaderNodeCombineXYZ", {0: x, 1: y, 2: z}).outputs[0]


def check(label, ours, cycles, rtol=RTOL, atol=ATOL, scale=None, points=None, allowed=0):
    """Assert |ours - cycles| <= atol * scale + rtol * |cycles| everywhere but at `allowed` entries.
    scale (broadcast) says how large the terms were that the value came from (a rotated vector's length)."""
    cycles = np.asarray(cycles, F32)
    ours = np.broadcast_to(np.asarray(ours, F32), cycles.shape)
    assert ours.dtype == F32
    tol = atol * (1.0 if scale is None else np.asarray(scale)) + rtol * np.abs(cycles)
    err = np.abs(ours.astype(np.float64) - cycles)
    bad = ~(err <= tol)
    if bad.sum() > allowed:
        rows = np.unique(np.nonzero(bad)[0])[:5]
        detail = "; ".join(f"#{r} ours {ours[r]} cycles {cycles[r]}" +
                           ("" if points is None else f" at {[np.asarray(p)[r] for p in points]}")
                           for r in rows)
        pytest.fail(f"{label}: {bad.sum()} values differ (max err {err.max():.3g}): {detail}")


RNG_SEED = 20250905


def rng(k=0):
    return np.random.default_rng(RNG_SEED + k)


# ---------------------------------------------------------------- Math
def _math_points():
    r = rng(1)
    e = 1.0 + 2.0 ** -12
    parts = [
        np.array([[e, e, -(1.0 + 2.0 ** -11)],      # a b + c: the fused product decides it
                  [3e7 + 2.0, 1.0 / 3.0, -1e7], [2.5, -2.5, 0.0], [-0.5, 1.0, 0.0], [0.5, 2.0, 0.0]]),
        r.uniform(-10, 10, (300, 3)),
        np.stack([r.integers(-5, 6, 100), r.integers(-5, 6, 100), r.uniform(0, 1, 100)], -1),  # lattice
        np.stack([r.uniform(-10, 10, 40), np.zeros(40), r.uniform(-2, 2, 40)], -1),           # b = 0
        np.stack([r.uniform(-5, 5, 30), r.uniform(-5, 5, 30), np.zeros(30)], -1),             # c = 0
    ]
    a = r.uniform(-5, 5, 40)
    parts.append(np.stack([a, a, r.uniform(-1, 1, 40)], -1))                                   # a = b
    sign = r.choice([-1, 1], 60)
    parts.append(np.stack([sign * 10 ** r.uniform(4, 7.5, 60), r.uniform(0.3, 100, 60),          # large
                           r.uniform(-100, 100, 60)], -1))
    parts.append(np.stack([r.uniform(-1e-3, 1e-3, 20), r.uniform(-1e-3, 1e-3, 20), np.full(20, 1e-3)], -1))
    return np.concatenate(parts).astype(F32)


def _power_points():
    """Bases and exponents whose powers, exponentials and hyperbolics stay finite."""
    r = rng(2)
    return np.concatenate([
        np.stack([r.uniform(-8, 8, 200), r.uniform(-5, 5, 200), np.zeros(200)], -1),
        np.stack([r.uniform(-8, 8, 100), r.integers(-5, 6, 100), np.zeros(100)], -1),   # negative ** integer
        np.stack([np.zeros(20), r.uniform(-3, 3, 20), np.zeros(20)], -1),                # 0 ** y, x ** 0
        np.array([[0.0, 0.0, 0.0], [-2.0, 0.0, 0.0], [-2.0, 0.5, 0.0], [-8.0, 1.0 / 3.0, 0.0]]),
    ]).astype(F32)


_FINITE_ONLY_ON_SMALL = ("POWER", "EXPONENT", "SINH", "COSH")


def _math_builder(operation, use_clamp=False):
    def build(tree, s):
        n = node(tree, "ShaderNodeMath", {0: s["p.x"], 1: s["p.y"], 2: s["p.z"]},
                 operation=operation, use_clamp=use_clamp)
        return n.outputs[0]
    return build


@pytest.mark.parametrize("group", ["general", "powers"])
def test_math_every_operation(group):
    ops = [o for o in math_nodes.MATH_OPERATIONS if (o in _FINITE_ONLY_ON_SMALL) == (group == "powers")]
    points = _power_points() if group == "powers" else _math_points()
    variants = [(o, False) for o in ops] + [(o, True) for o in ops[:8]]
    got = probe_variants([_math_builder(o, c) for o, c in variants], p=points)
    a, b, c = points.T
    for (op, use_clamp), cycles in zip(variants, got):
        ours = math_nodes.math(a, b, c, operation=op, use_clamp=use_clamp)["Value"]
        check(f"Math {op} clamp={use_clamp}", ours, cycles[:, 0], points=[points])


def test_math_operation_list_is_blenders():
    import bpy
    n = bpy.data.materials.new("ops").node_tree.nodes.new("ShaderNodeMath")
    assert set(n.bl_rna.properties["operation"].enum_items.keys()) == set(math_nodes.MATH_OPERATIONS)
    n = bpy.data.materials.new("vops").node_tree.nodes.new("ShaderNodeVectorMath")
    assert set(n.bl_rna.properties["operation"].enum_items.keys()) == set(VECTOR_OPS)
    n = bpy.data.materials.new("mix").node_tree.nodes.new("ShaderNodeMix")
    assert set(n.bl_rna.properties["blend_type"].enum_items.keys()) == set(mix_nodes.BLEND_TYPES)


# ---------------------------------------------------------------- Vector Math
VECTOR_OPS = math_nodes.operations_in(bpy.app.version, math_nodes.VECTOR_MATH_OPERATIONS)   # this Blender's
def _vector_points(large=False):
    r = rng(3 + large)
    n = 160
    a = r.normal(0, 4, (n, 3))
    b = r.normal(0, 4, (n, 3))
    c = r.normal(0, 4, (n, 3))
    s = r.uniform(-3, 3, n)
    a[:20] = np.round(a[:20])                      # lattice points
    b[20:30] = 0.0                                 # zero vector: normalise, project, divide, modulo
    b[30:40, 1] = 0.0
    a[40:50] = 0.0
    b[50:60] = a[50:60] * r.uniform(-2, 2, (10, 1))  # parallel: cross product cancels
    s[60:80] = r.uniform(0.5, 2.0, 20)             # refraction IORs, some total internal reflection
    b[60:80] = np.round(b[60:80])                  # integer exponents for negative bases
    c[80:90] = b[80:90]                            # wrap with max == min
    if large:
        a *= 10 ** r.uniform(3, 7, (n, 1))
        b = np.where(np.abs(b) < 0.3, 0.3, b)
    return a.astype(F32), b.astype(F32), c.astype(F32), s.astype(F32)


def _vector_math_builder(operation):
    def build(tree, s):
        n = node(tree, "ShaderNodeVectorMath", {0: s["a"], 1: s["b"], 2: s["c"], 3: s["s.x"]},
                 operation=operation)
        value = operation in ("DOT_PRODUCT", "DISTANCE", "LENGTH")
        return n.outputs["Value" if value else "Vector"]
    return build


_LARGE_VECTOR_OPS = ("ADD", "SUBTRACT", "MULTIPLY", "DIVIDE", "MULTIPLY_ADD", "MODULO", "WRAP", "SNAP",
                     "FRACTION", "FLOOR", "CEIL", "ABSOLUTE", "SIGN", "MINIMUM", "MAXIMUM", "NORMALIZE",
                     "LENGTH", "DISTANCE", "SCALE", "CROSS_PRODUCT")


@pytest.mark.parametrize("large", [False, True], ids=["moderate", "large"])
def test_vector_math_every_operation(large):
    ops = _LARGE_VECTOR_OPS if large else VECTOR_OPS
    a, b, c, s = _vector_points(large)
    got = probe_variants([_vector_math_builder(o) for o in ops], a=a, b=b, c=c, s=s)
    scale = np.maximum(1.0, np.linalg.norm(a, axis=1) * np.maximum(1.0, np.linalg.norm(b, axis=1)))[:, None]
    for op, cycles in zip(ops, got):
        out = math_nodes.vector_math(a, b, c, s, operation=op)
        ours = out["Value"][:, None] if op in ("DOT_PRODUCT", "DISTANCE", "LENGTH") else out["Vector"]
        check(f"Vector Math {op}", ours, cycles, scale=scale, points=[a, b, c, s])


# ---------------------------------------------------------------- Mix
def _colors(k, n=150):
    r = rng(10 + k)
    a = r.uniform(-0.2, 1.4, (n, 3))
    b = r.uniform(-0.2, 1.4, (n, 3))
    f = r.uniform(-0.5, 1.5, n)
    a[:15] = a[:15, :1]                 # greys: no hue, no saturation
    b[15:30] = b[15:30, :1]
    a[30:40] = 0.0
    b[40:50] = 0.0                      # divide by zero
    a[50:60, 0] = 0.5                   # overlay's branch point
    b[60:70] = 1.0                      # dodge by 1
    f[70:80] = np.round(f[70:80] * 2) / 2
    a[80:90] = r.uniform(0, 1, (10, 3))
    b[80:90] = r.uniform(0, 1, (10, 3))
    return a.astype(F32), b.astype(F32), f.astype(F32)


def test_mix_color_every_blend_type():
    a, b, f = _colors(0)
    variants = [(t, False, False) for t in mix_nodes.BLEND_TYPES] + [(t, True, True) for t in mix_nodes.BLEND_TYPES]

    def builder(blend, clamp_factor, clamp_result):
        def build(tree, s):
            n = node(tree, "ShaderNodeMix", {0: s["f.x"], 6: s["a"], 7: s["b"]}, data_type="RGBA",
                     blend_type=blend, clamp_factor=clamp_factor, clamp_result=clamp_result)
            return n.outputs[2]
        return build

    got = probe_variants([builder(*v) for v in variants], a=a, b=b, f=f)
    for (blend, cf, cr), cycles in zip(variants, got):
        ours = mix_nodes.mix(f, a, b, data_type="RGBA", blend_type=blend, clamp_factor=cf, clamp_result=cr)["Result"]
        check(f"Mix {blend} clamp factor={cf} result={cr}", ours, cycles, scale=4.0, points=[a, b, f])


def test_mix_float_vector_and_legacy_mixrgb():
    a, b, f = _colors(1)
    fv = rng(5).uniform(-0.5, 1.5, a.shape).astype(F32)
    variants = []
    for clamp_factor in (False, True):
        variants.append(("FLOAT", "UNIFORM", clamp_factor))
        variants.append(("VECTOR", "UNIFORM", clamp_factor))
        variants.append(("VECTOR", "NON_UNIFORM", clamp_factor))
    legacy = [("MIX", False), ("OVERLAY", True), ("DODGE", False), ("HUE", True), ("LINEAR_LIGHT", True)]

    def builder(data_type, mode, clamp_factor):
        def build(tree, s):
            n = node(tree, "ShaderNodeMix", data_type=data_type, factor_mode=mode, clamp_factor=clamp_factor)
            if data_type == "FLOAT":
                links = {0: s["f.x"], 2: s["a.x"], 3: s["b.y"]}
            elif mode == "NON_UNIFORM":
                links = {1: s["fv"], 4: s["a"], 5: s["b"]}
            else:
                links = {0: s["f.x"], 4: s["a"], 5: s["b"]}
            for key, sock in links.items():
                tree.links.new(sock, n.inputs[key])
            return n.outputs[0 if data_type == "FLOAT" else 1]
        return build

    def legacy_builder(blend, use_clamp):
        def build(tree, s):
            return node(tree, "ShaderNodeMixRGB", {0: s["f.x"], 1: s["a"], 2: s["b"]}, blend_type=blend,
                        use_clamp=use_clamp).outputs[0]
        return build

    got = probe_variants([builder(*v) for v in variants] + [legacy_builder(*v) for v in legacy],
                         a=a, b=b, f=f, fv=fv)
    for (data_type, mode, cf), cycles in zip(variants, got):
        if data_type == "FLOAT":
            ours = mix_nodes.mix(f, a[:, 0], b[:, 1], data_type="FLOAT", clamp_factor=cf)["Result"][:, None]
        else:
            ours = mix_nodes.mix(fv if mode == "NON_UNIFORM" else f, a, b, data_type="VECTOR", factor_mode=mode,
                                 clamp_factor=cf)["Result"]
        check(f"Mix {data_type} {mode} clamp={cf}", ours, cycles, scale=4.0)
    for (blend, use_clamp), cycles in zip(legacy, got[len(variants):]):
        ours = mix_nodes.mix_rgb(f, a, b, blend_type=blend, use_clamp=use_clamp)["Color"]
        check(f"MixRGB {blend} clamp={use_clamp}", ours, cycles, scale=4.0)


# ---------------------------------------------------------------- Map Range, Clamp
def _range_points(n=200):
    r = rng(20)
    value = r.uniform(-2, 3, n)
    f0, f1 = r.uniform(-1, 1, n), r.uniform(0, 2, n)
    t0, t1 = r.uniform(-5, 5, n), r.uniform(-5, 5, n)
    steps = r.integers(-1, 6, n).astype(float)
    f1[:20] = f0[:20]                                # empty input range
    f0[20:40], f1[20:40] = f1[20:40], f0[20:40]      # reversed input range
    value[40:50] = f0[40:50]                         # at the ends
    value[50:60] = f1[50:60]
    steps[60:70] = r.uniform(0.5, 4, 10)             # fractional steps
    p = np.stack([value, f0, f1], -1).astype(F32)
    q = np.stack([t0, t1, steps], -1).astype(F32)
    return p, q


def test_map_range_float_every_interpolation():
    p, q = _range_points()
    variants = [(t, c) for t in ("LINEAR", "STEPPED", "SMOOTHSTEP", "SMOOTHERSTEP") for c in (False, True)]

    def builder(interp, clamp):
        def build(tree, s):
            n = node(tree, "ShaderNodeMapRange", data_type="FLOAT", interpolation_type=interp, clamp=clamp)
            for i, sock in enumerate((s["p.x"], s["p.y"], s["p.z"], s["q.x"], s["q.y"], s["q.z"])):
                tree.links.new(sock, n.inputs[i])
            return n.outputs["Result"]
        return build

    got = probe_variants([builder(*v) for v in variants], p=p, q=q)
    for (interp, clamp), cycles in zip(variants, got):
        ours = math_nodes.map_range(*p.T, *q.T, interpolation_type=interp, clamp=clamp)["Result"]
        check(f"Map Range {interp} clamp={clamp}", ours, cycles[:, 0], scale=10.0, points=[p, q])


def test_map_range_vector_every_interpolation():
    r = rng(21)
    n = 160
    value, f0, f1, t0, t1 = (r.uniform(-2, 3, (n, 3)) for _ in range(5))
    steps = r.integers(-1, 6, (n, 3)).astype(float)
    f1[:20, 0] = f0[:20, 0]
    f0[20:40], f1[20:40] = f1[20:40].copy(), f0[20:40].copy()
    arrays = dict(v=value, f0=f0, f1=f1, t0=t0, t1=t1, st=steps)
    arrays = {k: a.astype(F32) for k, a in arrays.items()}
    variants = [(t, c) for t in ("LINEAR", "STEPPED", "SMOOTHSTEP", "SMOOTHERSTEP") for c in (False, True)]

    def builder(interp, clamp):
        def build(tree, s):
            n = node(tree, "ShaderNodeMapRange", data_type="FLOAT_VECTOR", interpolation_type=interp, clamp=clamp)
            for name, ident in zip(arrays, ("Vector", "From_Min_FLOAT3", "From_Max_FLOAT3", "To_Min_FLOAT3",
                                            "To_Max_FLOAT3", "Steps_FLOAT3")):
                tree.links.new(s[name], inp(n, ident))
            return n.outputs["Vector"]
        return build

    got = probe_variants([builder(*v) for v in variants], **arrays)
    for (interp, clamp), cycles in zip(variants, got):
        ours = math_nodes.map_range(*arrays.values(), data_type="FLOAT_VECTOR", interpolation_type=interp,
                                    clamp=clamp)["Vector"]
        check(f"Vector Map Range {interp} clamp={clamp}", ours, cycles, scale=10.0)


def test_clamp_both_types():
    r = rng(22)
    p = r.uniform(-3, 3, (200, 3)).astype(F32)
    p[:20, 2] = p[:20, 1]
    variants = ["MINMAX", "RANGE"]
    got = probe_variants([lambda tree, s, t=t: node(tree, "ShaderNodeClamp", {0: s["p.x"], 1: s["p.y"], 2: s["p.z"]},
                                                    clamp_type=t).outputs[0] for t in variants], p=p)
    for t, cycles in zip(variants, got):
        check(f"Clamp {t}", math_nodes.clamp(*p.T, clamp_type=t)["Result"], cycles[:, 0])


# ---------------------------------------------------------------- colour converters
def _color_points(n=220):
    r = rng(30)
    c = r.uniform(-0.3, 1.5, (n, 3))
    c[:20] = c[:20, :1]                                     # grey
    c[20:30] = 0.0
    c[30:40] = r.uniform(0, 1, (10, 3)) * [1, 0, 0]          # pure hues
    c[40:50] = [[1.0, 0.5, 0.0]] * 10
    c[50:60, 1] = c[50:60, 0]                               # two channels tie at the max
    h = r.uniform(-1.5, 2.5, n)
    h[60:70] = np.round(h[60:70] * 2) / 2                   # hue wrap at integers and halves
    return c.astype(F32), h.astype(F32)


def test_separate_combine_color_and_xyz():
    c, h = _color_points()
    hsx = np.stack([np.mod(h, 1.0), np.abs(c[:, 1]) % 1.0, c[:, 2]], -1).astype(F32)
    hsx[:30] = c[:30]                                        # hue outside [0, 1], saturation 0
    modes = ("RGB", "HSV", "HSL")

    def sep(mode):
        return lambda tree, s: show3(tree, *node(tree, "ShaderNodeSeparateColor", {0: s["c"]}, mode=mode).outputs)

    def comb(mode):
        return lambda tree, s: node(tree, "ShaderNodeCombineColor", {0: s["k.x"], 1: s["k.y"], 2: s["k.z"]},
                                    mode=mode).outputs[0]

    def xyz(tree, s):
        parts = node(tree, "ShaderNodeSeparateXYZ", {0: s["c"]}).outputs
        return node(tree, "ShaderNodeCombineXYZ", {0: parts[2], 1: parts[0], 2: parts[1]}).outputs[0]

    got = probe_variants([sep(m) for m in modes] + [comb(m) for m in modes] + [xyz], c=c, k=hsx)
    for mode, cycles in zip(modes, got[:3]):
        out = color_nodes.separate_color(c, mode=mode)
        check(f"Separate Color {mode}", np.stack([out["Red"], out["Green"], out["Blue"]], -1), cycles, points=[c])
    for mode, cycles in zip(modes, got[3:6]):
        check(f"Combine Color {mode}", color_nodes.combine_color(*hsx.T, mode=mode)["Color"], cycles, scale=2.0,
              points=[hsx])
    parts = vector_nodes.separate_xyz(c)
    check("Separate/Combine XYZ", vector_nodes.combine_xyz(parts["Z"], parts["X"], parts["Y"])["Vector"], got[6])


def test_color_adjustment_nodes():
    c, h = _color_points()
    r = rng(31)
    n = len(c)
    k = np.stack([h, r.uniform(-0.5, 2.0, n), r.uniform(-0.5, 2.0, n)], -1).astype(F32)   # hue, sat, val
    m = np.stack([r.uniform(-0.5, 1.5, n), r.uniform(-1, 1, n), r.uniform(-1, 1, n)], -1).astype(F32)  # fac, b, c
    g = r.uniform(-2, 3, n).astype(F32)
    g[:10] = 0.0

    builders = [
        lambda tree, s: node(tree, "ShaderNodeHueSaturation", {0: s["k.x"], 1: s["k.y"], 2: s["k.z"], 3: s["m.x"],
                                                               4: s["c"]}).outputs[0],
        lambda tree, s: node(tree, "ShaderNodeBrightContrast", {0: s["c"], 1: s["m.y"], 2: s["m.z"]}).outputs[0],
        lambda tree, s: node(tree, "ShaderNodeGamma", {0: s["c"], 1: s["g.x"]}).outputs[0],
        lambda tree, s: node(tree, "ShaderNodeInvert", {0: s["m.x"], 1: s["c"]}).outputs[0],
        lambda tree, s: node(tree, "ShaderNodeRGBToBW", {0: s["c"]}).outputs[0],
        lambda tree, s: node(tree, "ShaderNodeMath", {0: node(tree, "ShaderNodeCombineColor", {
            0: s["c.x"], 1: s["c.y"], 2: s["c.z"]}).outputs[0], 1: s["m.x"]}, operation="ADD").outputs[0],
        lambda tree, s: node(tree, "ShaderNodeMath", {0: s["k"], 1: s["m.x"]}, operation="ADD").outputs[0],
    ]
    got = probe_variants(builders, c=c, k=k, m=m, g=g)
    check("Hue/Saturation/Value", color_nodes.hue_saturation(*k.T, m[:, 0], c)["Color"], got[0], scale=4.0,
          points=[c, k, m])
    check("Bright/Contrast", color_nodes.bright_contrast(c, m[:, 1], m[:, 2])["Color"], got[1], scale=4.0)
    check("Gamma", color_nodes.gamma(c, g)["Color"], got[2], points=[c, g])
    check("Invert", color_nodes.invert(m[:, 0], c)["Color"], got[3], scale=4.0)
    check("RGB to BW", color_nodes.rgb_to_bw(c)["Val"][:, None], got[4])
    # The links' implicit conversions: a colour into a float input (luminance), a vector (the average).
    check("colour -> float", (color_nodes.color_to_float(c) + m[:, 0])[:, None], got[5], scale=2.0)
    check("vector -> float", (color_nodes.vector_to_float(k) + m[:, 0])[:, None], got[6], scale=2.0)


def test_rgb_to_bw_weights_are_cycles():
    unit = np.eye(3, dtype=F32)
    got = probe_variants([lambda tree, s: node(tree, "ShaderNodeRGBToBW", {0: s["c"]}).outputs[0]], c=unit)
    if bpy.app.version[:2] == (5, 0):
        np.testing.assert_array_equal(got[0, :, 0], color_nodes.RGB_TO_Y)
    else:
        # Cycles 5.3 derives the same weights in float32 a step differently: R and B up to 2 ulp lower
        # (docs/blender-versions.md). Ember keeps 5.0's.
        np.testing.assert_array_max_ulp(got[0, :, 0], color_nodes.RGB_TO_Y, maxulp=2)
    # The same numbers from Blender's colour management (the path node_tables.color_constants takes).
    constants = node_tables.color_constants()
    np.testing.assert_allclose(constants["rgb_to_y"], color_nodes.RGB_TO_Y, rtol=0, atol=3e-7)
    np.testing.assert_allclose(constants["xyz_to_rgb"], color_nodes.XYZ_TO_RGB, rtol=0, atol=3e-7)
    assert constants["rec709_to_rgb"] is None


def test_blackbody_and_wavelength():
    edges = [800, 965, 1167, 1449, 1902, 3315, 6365, 12000]
    t = np.concatenate([np.linspace(0, 15000, 300), edges, np.nextafter(np.array(edges, F32), 0), [-100, 1e6]])
    lam = np.concatenate([np.linspace(300, 850, 300), [375, 377.5, 379.99, 380, 385, 777.5, 779.99, 780, 785],
                          np.arange(380, 781, 5)])
    n = max(len(t), len(lam))
    t = np.resize(t, n).astype(F32)
    lam = np.resize(lam, n).astype(F32)
    got = probe_variants([lambda tree, s: node(tree, "ShaderNodeBlackbody", {0: s["t.x"]}).outputs[0],
                          lambda tree, s: node(tree, "ShaderNodeWavelength", {0: s["t.y"]}).outputs[0]],
                         t=np.stack([t, lam, np.zeros(n)], -1))
    check("Blackbody", color_nodes.blackbody(t)["Color"], got[0], scale=2.0, points=[t])
    check("Wavelength", color_nodes.wavelength(lam)["Color"], got[1], points=[lam])


# ---------------------------------------------------------------- Mapping, Vector Rotate
def _transform_points(n=180):
    r = rng(40)
    v = r.normal(0, 3, (n, 3))
    loc = r.normal(0, 2, (n, 3))
    rot = r.uniform(-7, 7, (n, 3))
    scale = r.uniform(-3, 3, (n, 3))
    axis = r.normal(0, 1, (n, 3))
    angle = r.uniform(-7, 7, n)
    scale[:15, 1] = 0.0                # safe divides
    axis[15:25] = 0.0                  # zero axis: no rotation
    rot[25:35] = np.round(rot[25:35] / (np.pi / 2)) * np.pi / 2
    v[35:45] = 0.0
    return {k: np.asarray(a, F32) for k, a in
            dict(v=v, loc=loc, rot=rot, sc=scale, ax=axis, ang=np.stack([angle] * 3, -1)).items()}


def test_mapping_every_type():
    p = _transform_points()
    types = ("POINT", "TEXTURE", "VECTOR", "NORMAL")
    builders = [lambda tree, s, t=t: node(tree, "ShaderNodeMapping", {0: s["v"], 1: s["loc"], 2: s["rot"], 3: s["sc"]},
                                          vector_type=t).outputs[0] for t in types]
    got = probe_variants(builders, **p)
    size = np.linalg.norm(p["v"], axis=1) * np.abs(p["sc"]).max(1) + np.linalg.norm(p["loc"], axis=1)
    for t, cycles in zip(types, got):
        ours = vector_nodes.mapping(p["v"], p["loc"], p["rot"], p["sc"], vector_type=t)["Vector"]
        scale = np.maximum(1.0, size / np.maximum(np.abs(p["sc"]).min(1), 0.1) if t == "TEXTURE" else size)[:, None]
        check(f"Mapping {t}", ours, cycles, scale=scale, points=[p["v"], p["rot"], p["sc"]])


def test_vector_rotate_every_type():
    p = _transform_points()
    variants = [(t, inv) for t in ("AXIS_ANGLE", "X_AXIS", "Y_AXIS", "Z_AXIS", "EULER_XYZ") for inv in (False, True)]

    def builder(t, inv):
        def build(tree, s):
            n = node(tree, "ShaderNodeVectorRotate", rotation_type=t, invert=inv)
            for ident, name in (("Vector", "v"), ("Center", "loc"), ("Axis", "ax"), ("Angle", "ang.x"),
                                ("Rotation", "rot")):
                tree.links.new(s[name], inp(n, ident))
            return n.outputs[0]
        return build

    got = probe_variants([builder(*v) for v in variants], **p)
    scale = np.maximum(1.0, np.linalg.norm(p["v"], axis=1) + np.linalg.norm(p["loc"], axis=1))[:, None]
    for (t, inv), cycles in zip(variants, got):
        ours = vector_nodes.vector_rotate(p["v"], p["loc"], p["ax"], p["ang"][:, 0], p["rot"], rotation_type=t,
                                          invert=inv)["Vector"]
        check(f"Vector Rotate {t} invert={inv}", ours, cycles, scale=scale, points=[p["v"], p["ax"]])


# ---------------------------------------------------------------- Color Ramp and curves
def _ramp_positions():
    r = rng(50)
    return np.concatenate([np.linspace(-0.25, 1.25, 200), r.uniform(0, 1, 100), np.arange(257) / 256.0,
                           [0.1, 0.35, 0.6, 0.9, np.nextafter(F32(0.35), F32(0)), 0.5 + 0.5 / 256]]).astype(F32)


def _setup_ramp(ramp, interpolation, color_mode="RGB", hue="NEAR"):
    ramp.interpolation = interpolation
    ramp.color_mode = color_mode
    ramp.hue_interpolation = hue
    ramp.elements[0].position, ramp.elements[0].color = 0.1, (0.9, 0.1, 0.05, 1.0)
    ramp.elements[1].position, ramp.elements[1].color = 0.9, (0.05, 0.2, 1.0, 0.25)
    e = ramp.elements.new(0.35)
    e.color = (0.2, 1.0, 0.3, 0.5)
    e = ramp.elements.new(0.6)
    e.color = (1.5, 0.8, -0.2, 1.0)


def test_color_ramp_every_interpolation():
    f = _ramp_positions()
    variants = [(i, "RGB", "NEAR") for i in ("LINEAR", "EASE", "CARDINAL", "B_SPLINE", "CONSTANT")]
    variants += [("LINEAR", "HSV", "FAR"), ("LINEAR", "HSL", "CW")]
    tables = []

    def builder(interpolation, mode, hue, alpha):
        def build(tree, s):
            n = node(tree, "ShaderNodeValToRGB", {0: s["f.x"]})
            _setup_ramp(n.color_ramp, interpolation, mode, hue)
            tables.append(node_tables.color_ramp_table(n.color_ramp))
            return n.outputs["Alpha" if alpha else "Color"]
        return build

    builders = [builder(*v, False) for v in variants] + [builder("B_SPLINE", "RGB", "NEAR", True)]
    got = probe_variants(builders, f=f)
    assert all(t.shape == (257, 4) for t, _ in tables)
    for v, (table, interpolate), cycles in zip(variants, tables, got):
        check(f"Color Ramp {v}", curve_nodes.color_ramp(f, table=table, interpolate=interpolate)["Color"], cycles,
              points=[f])
    table, interpolate = tables[-1]
    check("Color Ramp alpha", curve_nodes.color_ramp(f, table=table, interpolate=interpolate)["Alpha"][:, None],
          got[-1])


def _edit_curve(curve, points, handle="AUTO"):
    """Replace a CurveMap's points by (x, y) pairs."""
    while len(curve.points) > 2:
        curve.points.remove(curve.points[1])
    curve.points[0].location, curve.points[1].location = points[0], points[-1]
    for x, y in points[1:-1]:
        curve.points.new(x, y)
    for p in curve.points:
        p.handle_type = handle


def test_rgb_and_vector_curves():
    r = rng(60)
    c = np.concatenate([r.uniform(-0.5, 1.5, (200, 3)), r.uniform(0, 1, (100, 3))]).astype(F32)
    fac = r.uniform(-0.5, 1.5, len(c)).astype(F32)
    fac[:150] = 1.0
    v = (c * 3 - 1.5).astype(F32)
    tables = []

    def rgb(extend, clip):
        def build(tree, s):
            n = node(tree, "ShaderNodeRGBCurve", {0: s["fac.x"], 1: s["c"]})
            m = n.mapping
            m.extend, m.use_clip = extend, clip
            m.black_level, m.white_level = (0.1, 0.0, 0.2), (0.8, 0.9, 1.0)  # Cycles ignores the levels
            _edit_curve(m.curves[0], [(0.0, 0.1), (0.4, 0.7), (1.0, 0.9)])
            _edit_curve(m.curves[1], [(0.0, 0.0), (0.5, 0.2), (1.0, 1.0)], "VECTOR")
            _edit_curve(m.curves[3], [(0.0, 0.05), (0.3, 0.5), (1.0, 1.0)], "AUTO_CLAMPED")
            if not clip:  # points beyond [0, 1]: the table spans them
                _edit_curve(m.curves[2], [(-0.25, -0.1), (0.5, 0.4), (1.3, 1.6)])
            tables.append(node_tables.rgb_curves_table(m))
            return n.outputs[0]
        return build

    def vector(extend):
        def build(tree, s):
            n = node(tree, "ShaderNodeVectorCurve", {0: s["fac.x"], 1: s["v"]})
            m = n.mapping
            m.extend = extend
            _edit_curve(m.curves[0], [(-1.0, 0.5), (0.0, -0.5), (1.0, 0.8)])
            _edit_curve(m.curves[2], [(-0.8, -1.0), (0.6, 0.2), (1.0, 0.3)], "VECTOR")
            tables.append(node_tables.vector_curves_table(m))
            return n.outputs[0]
        return build

    variants = [("rgb", "EXTRAPOLATED", True), ("rgb", "HORIZONTAL", True), ("rgb", "EXTRAPOLATED", False),
                ("rgb", "HORIZONTAL", False), ("vector", "EXTRAPOLATED", None), ("vector", "HORIZONTAL", None)]
    got = probe_variants([rgb(e, c_) if k == "rgb" else vector(e) for k, e, c_ in variants], c=c, v=v, fac=fac)
    for (kind, extend, clip), (table, lo, hi, extrapolate), cycles in zip(variants, tables, got):
        assert extrapolate == (extend == "EXTRAPOLATED")
        if kind == "rgb":
            ours = curve_nodes.rgb_curves(fac, c, table=table, min_x=lo, max_x=hi, extrapolate=extrapolate)["Color"]
        else:
            ours = curve_nodes.vector_curves(fac, v, table=table, min_x=lo, max_x=hi, extrapolate=extrapolate)["Vector"]
        check(f"{kind} curves extend={extend} clip={clip} range=({lo}, {hi})", ours, cycles, scale=2.0)
    assert tables[2][1:3] == (-0.25, F32(1.3)) and tables[0][1:3] == (0.0, 1.0) and tables[4][1:3] == (-1.0, 1.0)


def test_float_curve():
    r = rng(61)
    x = np.concatenate([np.linspace(-1.5, 2.5, 200), r.uniform(-0.2, 1.2, 100)]).astype(F32)
    fac = np.where(np.arange(len(x)) < 200, 1.0, r.uniform(-0.5, 1.5, len(x))).astype(F32)
    variants = [("EXTRAPOLATED", [(0.0, 0.2), (0.3, 0.9), (1.0, 0.1)]),
                ("HORIZONTAL", [(0.0, 0.2), (0.3, 0.9), (1.0, 0.1)]),
                ("EXTRAPOLATED", [(0.2, 1.0), (0.5, 0.0), (0.8, 0.5)])]
    tables = []

    def builder(extend, points):
        def build(tree, s):
            n = node(tree, "ShaderNodeFloatCurve", {0: s["fac.x"], 1: s["x.x"]})
            n.mapping.extend = extend
            _edit_curve(n.mapping.curves[0], points)
            tables.append(node_tables.float_curve_table(n.mapping))
            return n.outputs[0]
        return build

    got = probe_variants([builder(*v) for v in variants], x=x, fac=fac)
    for (extend, _), (table, lo, hi, extrapolate), cycles in zip(variants, tables, got):
        ours = curve_nodes.float_curve(fac, x, table=table, min_x=lo, max_x=hi, extrapolate=extrapolate)["Value"]
        check(f"Float Curve {extend} range=({lo}, {hi})", ours[:, None], cycles, scale=2.0, points=[x, fac])
    assert tables[2][1:3] == (np.float32(0.2), np.float32(0.8))


# ---------------------------------------------------------------- closed forms and conventions (no render)
def test_constants_broadcast_and_stay_float32():
    for op in math_nodes.MATH_OPERATIONS:
        out = math_nodes.math(0.3, 2.0, 0.5, operation=op)["Value"]
        assert out.dtype == F32 and out.shape == (1,), op
    for op in math_nodes.VECTOR_MATH_OPERATIONS:
        out = math_nodes.vector_math((1.0, -2.0, 0.5), 0.25, 0.0, 2.0, operation=op)
        assert out["Vector"].dtype == F32 and out["Vector"].shape == (1, 3), op
        assert out["Value"].dtype == F32, op
    hits = np.arange(12, dtype=F32).reshape(4, 3)
    for blend in mix_nodes.BLEND_TYPES:
        out = mix_nodes.mix(0.25, hits, (0.5, 0.5, 0.5), data_type="RGBA", blend_type=blend)["Result"]
        assert out.dtype == F32 and out.shape == (4, 3), blend
    assert math_nodes.map_range(np.zeros(5, F32), 0.0, 1.0, 2.0, 3.0)["Result"].shape == (5,)


def test_closed_forms():
    r = rng(70)
    c = r.uniform(0, 1, (1000, 3)).astype(F32)
    np.testing.assert_allclose(color_nodes.hsv_to_rgb(color_nodes.rgb_to_hsv(c)), c, atol=1e-6)
    np.testing.assert_allclose(color_nodes.hsl_to_rgb(color_nodes.rgb_to_hsl(c)), c, atol=1e-6)
    # Default ramp (black -> white, linear) baked and looked up: the identity on [0, 1], clamped outside.
    table = np.repeat(np.arange(257, dtype=F32)[:, None] / 256, 4, 1)
    f = np.linspace(-0.5, 1.5, 101, dtype=F32)
    np.testing.assert_allclose(curve_nodes.color_ramp(f, table=table)["Alpha"], np.clip(f, 0, 1), atol=1e-6)
    # An identity curve table extrapolates to the identity.
    line = np.linspace(0, 1, 257, dtype=F32)
    np.testing.assert_allclose(curve_nodes.float_curve(1.0, f, table=line)["Value"], f, atol=2e-6)
    # Math guards: x / 0 = 0, sqrt and log of negatives 0, negative ** fraction 0, x ** 0 = 1.
    assert math_nodes.math(3.0, 0.0, operation="DIVIDE")["Value"][0] == 0
    assert math_nodes.math(-4.0, operation="SQRT")["Value"][0] == 0
    assert math_nodes.math(-4.0, 2.0, operation="LOGARITHM")["Value"][0] == 0
    assert math_nodes.math(-8.0, 1 / 3, operation="POWER")["Value"][0] == 0
    assert math_nodes.math(-2.0, 3.0, operation="POWER")["Value"][0] == -8
    assert math_nodes.math(0.0, 0.0, operation="POWER")["Value"][0] == 1
    assert math_nodes.math(7.0, -3.0, operation="FLOORED_MODULO")["Value"][0] == -2
    assert math_nodes.math(-7.0, 3.0, operation="MODULO")["Value"][0] == -1
    # Luminance weights sum to one (within the float32 rounding of the config's matrices).
    assert abs(float(color_nodes.RGB_TO_Y.sum()) - 1.0) < 2e-6
