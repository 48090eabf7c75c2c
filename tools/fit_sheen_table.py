#!/usr/bin/env python3.11
"""Measure Cycles' sheen lobe through bpy and fit our own LTC table (kernels/bsdf/data/sheen_ltc.npz).

    .venv/bin/python tools/fit_sheen_table.py            # measure, fit, write the table, verify
    .venv/bin/python tools/fit_sheen_table.py --verify   # only compare the shipped table with Cycles

Cycles 5.0 evaluates its sheen closure (`bsdf_sheen.h`) as albedo * D_ab(l), D_ab the LTC density of
kernels/bsdf/sheen.py, with (a, b, albedo) read bilinearly from a 32 x 32 table at mu = N.v (grid i/31)
and roughness r clamped to [1e-3, 1] (grid j/31). Its numbers may not be copied, so we measure them:

1. Scene: an orthographic camera looking down -z (the viewer direction is exactly +z), one mesh of
   small flat quads, each tilted so that N.z = mu of one table column, at K azimuths, each with the
   Sheen BSDF (Microfiber, white) at the roughness of one table row. Every quad is built so that its
   projection is the same 3 x 3 pixel square inside its own 4 x 4 block: the two pixels in the middle of
   each direction are fully covered (box filter), so one sample per pixel is exact. Quads cast no
   shadows, so every quad sees the sun.
2. Light: one sun of strength 1 and angle 0 (a delta light), max_bounces 0 (direct light only), so a
   pixel is exactly albedo * D_ab(l_local), with no noise (a white Lambert quad checks the scale: cos/pi).
   S sun directions (a Fibonacci sphere) give S x K light directions per cell, about half above it.
3. Fit per cell: albedo * D_ab(l) = y is, after squaring out, linear and homogeneous in
   (a^2, a b, b^2 + 1, a sqrt(albedo)) (see `initial_guess`), which gives a starting point without a
   search; Levenberg-Marquardt on relative residuals then polishes (a, b, albedo).
4. Cycles never looks up mu = 0 (a quad seen edge-on is invisible) nor r = 0 (it clamps to 1e-3): there
   we measure at mu = 0.5/31 and r = 1e-3, which Cycles reads as a known blend of the boundary cell and
   its neighbour, and solve for the boundary cell. The lookup between them is then Cycles' exactly.
5. Verify: render random off-grid (mu, r) quads and compare the pixels with kernels/bsdf/sheen.py.

Where Cycles drops the closure (albedo < 1e-5) the pixels are 0 and a, b cannot be measured; those
cells get albedo 0 and a, b copied from the nearest measured cell of the same roughness (reported).
"""
from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
from bench.common import import_ember  # noqa: E402

import_ember()
from ember.kernels.bsdf import sheen  # noqa: E402

GRID = sheen.TABLE_SIZE
AZIMUTHS = 3            # quad orientations per cell (K)
SUNS = 40               # sun directions (S)
BLOCK = 4               # pixels per quad block; the quad covers [0.5, 3.5] of it
MU_EDGE = 0.5 / (GRID - 1)          # where column 0 is measured (half way to column 1)
R_EDGE = float(sheen.ROUGHNESS_MIN)  # where row 0 is measured (Cycles' clamp)


# ---------------------------------------------------------------- geometry
def cell_points():
    """mu (GRID,) and r (GRID,) at which column i and row j are measured."""
    mu = np.arange(GRID) / (GRID - 1)
    r = np.arange(GRID) / (GRID - 1)
    mu[0], r[0] = MU_EDGE, R_EDGE
    return mu, r


def fibonacci_sphere(n: int) -> np.ndarray:
    """(n, 3) unit directions spread evenly over the sphere."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    s = np.sqrt(1.0 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)


def build_quads(mu, roughness, phi):
    """Quads with normal N.z = mu at azimuth phi, one per entry of the (F,) inputs.

    Returns a dict: verts (4F + 4, 3) float32 (the Lambert reference quad last), normals (F + 1, 3)
    float64 computed from the float32 vertices (as Cycles computes Ng), block centres (F + 1, 2),
    roughness (F,) and the image size in pixels."""
    mu, roughness, phi = (np.asarray(v, float).ravel() for v in (mu, roughness, phi))
    count = mu.size
    side = int(math.ceil(math.sqrt(count + 1)))
    sin_t = np.sqrt(1.0 - mu * mu)
    n = np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), mu], axis=1)
    n = np.vstack([n, [[0.0, 0.0, 1.0]]])                 # the reference quad, last
    slot = np.arange(count + 1)
    centre = np.stack([slot % side, slot // side], axis=1) * BLOCK + BLOCK / 2
    corners = np.array([[-1.5, -1.5], [1.5, -1.5], [1.5, 1.5], [-1.5, 1.5]])
    xy = centre[:, None, :] + corners[None]
    # The quad lies in the plane through (centre, 0) with normal n; its projection is the square.
    z = -(n[:, None, 0] * (xy[..., 0] - centre[:, None, 0]) + n[:, None, 1] * (xy[..., 1] - centre[:, None, 1])) / n[:, None, 2]
    verts = np.concatenate([xy, z[..., None]], axis=2).astype(np.float32)
    v = verts.astype(np.float64)
    normals = np.cross(v[:, 2] - v[:, 0], v[:, 3] - v[:, 1])  # Newell/diagonals: both triangles' plane
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return {"verts": verts.reshape(-1, 3), "normals": normals, "centre": centre,
            "roughness": roughness, "size": side * BLOCK}


def local_light(normals: np.ndarray, light: np.ndarray) -> np.ndarray:
    """The light direction in Cycles' sheen frame per quad, (F, 3): T along the viewer (+z) projected on
    the tangent plane, B = normalize(N x v), or make_orthonormals(N) when N = v (`mapping.h`)."""
    v = np.array([0.0, 0.0, 1.0])
    b = np.cross(normals, v)
    length = np.linalg.norm(b, axis=1, keepdims=True)
    fallback = length[:, 0] == 0.0
    b = np.where(fallback[:, None], 0.0, b / np.where(length > 0, length, 1.0))
    # make_orthonormals(N) for N = +z: a = (N.z - N.y, N.x - N.z, N.y - N.x) normalised, b = N x a.
    nf = normals[fallback]
    a_fb = np.stack([nf[:, 2] - nf[:, 1], nf[:, 0] - nf[:, 2], nf[:, 1] - nf[:, 0]], axis=1)
    a_fb /= np.linalg.norm(a_fb, axis=1, keepdims=True)
    t = np.cross(b, normals)
    t[fallback] = a_fb
    b[fallback] = np.cross(nf, a_fb)
    return np.stack([t @ light, b @ light, normals @ light], axis=1)


# ---------------------------------------------------------------- Cycles
def build_scene(quads, roughness_values):
    """A fresh scene holding the quads (one mesh), their sheen materials and a sun; returns the sun."""
    import bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    size = quads["size"]
    scene.render.resolution_x = scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    cam_data = bpy.data.cameras.new("Camera")
    cam_data.type = "ORTHO"
    cam_data.ortho_scale = float(size)      # one world unit per pixel
    cam_data.clip_start, cam_data.clip_end = 0.1, 1e5
    cam = bpy.data.objects.new("Camera", cam_data)
    scene.collection.objects.link(cam)
    cam.location = (size / 2, size / 2, 1e4)  # identity rotation: looking down -z, pixel = world unit
    scene.camera = cam

    mesh = bpy.data.meshes.new("Quads")
    verts = quads["verts"]
    faces = np.arange(len(verts)).reshape(-1, 4)
    mesh.from_pydata(verts.tolist(), [], faces.tolist())
    slots = {}
    for r in roughness_values:
        mesh.materials.append(_sheen_material(float(r)))
        slots[float(r)] = len(slots)
    mesh.materials.append(_lambert_material())
    index = [slots[float(r)] for r in quads["roughness"]] + [len(slots)]
    mesh.polygons.foreach_set("material_index", np.asarray(index, np.int32))
    mesh.update()
    obj = bpy.data.objects.new("Quads", mesh)
    obj.visible_shadow = False  # every quad sees the sun whatever its neighbours do
    scene.collection.objects.link(obj)

    sun_data = bpy.data.lights.new("Sun", "SUN")
    sun_data.energy = 1.0
    sun_data.angle = 0.0        # a delta light: exact, noise-free direct lighting
    sun = bpy.data.objects.new("Sun", sun_data)
    sun.rotation_mode = "QUATERNION"
    scene.collection.objects.link(sun)
    scene.world = None

    c = scene.cycles
    c.device, c.samples, c.seed = "CPU", 1, 0
    c.use_adaptive_sampling = c.use_denoising = False
    c.sample_clamp_direct = c.sample_clamp_indirect = 0.0
    c.pixel_filter_type = "BOX"
    c.max_bounces = 0
    c.light_sampling_threshold = 0.0  # else weak light samples are killed at random (roulette)
    scene.view_settings.view_transform = "Standard"
    r = scene.render
    r.engine = "CYCLES"
    r.threads_mode, r.threads = "FIXED", 2
    r.image_settings.file_format, r.image_settings.color_depth = "OPEN_EXR", "32"
    return sun


def _sheen_material(roughness):
    import bpy
    mat = bpy.data.materials.new(f"sheen_{roughness:.6f}")
    tree = mat.node_tree
    tree.nodes.clear()
    node = tree.nodes.new("ShaderNodeBsdfSheen")
    node.distribution = "MICROFIBER"
    node.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    node.inputs["Roughness"].default_value = roughness
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    tree.links.new(node.outputs[0], out.inputs["Surface"])
    return mat


def _lambert_material():
    import bpy
    mat = bpy.data.materials.new("lambert")
    tree = mat.node_tree
    tree.nodes.clear()
    node = tree.nodes.new("ShaderNodeBsdfDiffuse")
    node.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    node.inputs["Roughness"].default_value = 0.0
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    tree.links.new(node.outputs[0], out.inputs["Surface"])
    return mat


def render_quads(sun, quads, light: np.ndarray) -> np.ndarray:
    """Render with the sun shining from `light` (unit, world); returns (F,) pixel values (red channel)
    per quad, the Lambert reference last. Asserts the four covered pixels of every quad agree."""
    import bpy
    from mathutils import Vector
    sun.rotation_quaternion = Vector(light.tolist()).to_track_quat("Z", "Y")  # the sun shines along -z
    scene = bpy.context.scene
    with tempfile.TemporaryDirectory() as tmp:
        scene.render.filepath = os.path.join(tmp, "frame.exr")
        bpy.ops.render.render(write_still=True)
        image = bpy.data.images.load(scene.render.filepath, check_existing=False)
        size = quads["size"]
        pixels = np.empty(size * size * 4, np.float32)
        image.pixels.foreach_get(pixels)
        bpy.data.images.remove(image)
    img = pixels.reshape(size, size, 4)  # row 0 at the bottom: pixel (row y, col x) = world [x, x+1] x [y, y+1]
    lo = (quads["centre"] - 1).astype(int)    # the covered pixels are centre-1 and centre
    rows = lo[:, 1, None, None] + np.array([0, 1])[None, :, None]
    cols = lo[:, 0, None, None] + np.array([0, 1])[None, None, :]
    values = img[rows, cols, 0].reshape(len(lo), 4)
    # The quad's two triangles have float32-rounded normals that differ by ~1e-7, so pixels on either
    # side of the diagonal may differ by a few 1e-6 relative. A larger disagreement marks the sample
    # unusable (NaN): seen where a cell's albedo sits on Cycles' 1e-5 drop threshold (one triangle
    # keeps the closure, the other drops it) and where the sun grazes a quad.
    spread = values.max(axis=1) - values.min(axis=1)
    bad = spread > 1e-5 * values.max(axis=1)
    values[bad] = np.nan
    return values.mean(axis=1)


def measure(quads, roughness_values, suns=SUNS, log=print):
    """Light directions in each quad's sheen frame and Cycles' pixel values: (S, F, 3), (S, F)."""
    sun = build_scene(quads, roughness_values)
    lights = fibonacci_sphere(suns)
    local = np.stack([local_light(quads["normals"], l) for l in lights])
    values = []
    t0 = time.time()
    for s, l in enumerate(lights):
        v = render_quads(sun, quads, l)
        # Lambert reference: a strength-1 sun gives exactly cos/pi.
        expected = max(l[2], 0.0) / math.pi
        assert abs(v[-1] - expected) <= 1e-6, (v[-1], expected)
        values.append(v[:-1])
        if np.isnan(v).any():
            log(f"  sun {s}: {np.isnan(v).sum()} quads whose pixels disagree, dropped")
        log(f"  sun {s + 1}/{suns}  {time.time() - t0:.1f} s")
    return local[:, :-1], np.stack(values)


# ---------------------------------------------------------------- fitting
def _model64(p, x, y, z):
    """albedo * D_ab in float64: sheen.ltc_density's formula, kept apart so that the fit resolves
    the measurement (float32 pixels) instead of its own float32 rounding."""
    a, b, albedo = p
    length_sqr = (a * x + b * z) ** 2 + (a * y) ** 2 + z * z
    return albedo * np.maximum(z, 0.0) * a * a / (math.pi * length_sqr ** 2)


def initial_guess(x, y, z, v):
    """Solve the linearised fit. With q = sqrt(z / (pi v)), albedo D = v reads
    L = q a sqrt(albedo), i.e. a^2 (x^2 + y^2) + 2 a b x z + (b^2 + 1) z^2 - q a sqrt(albedo) = 0:
    homogeneous linear in (a^2, a b, b^2 + 1, a sqrt(albedo)). The null vector of the rows, scaled so
    that (b^2 + 1) - (a b)^2 / a^2 = 1, gives a, b, albedo."""
    q = np.sqrt(z / (math.pi * v))
    rows = np.stack([x * x + y * y, 2 * x * z, z * z, -q], axis=1)
    rows /= np.linalg.norm(rows, axis=1, keepdims=True)
    u = np.linalg.svd(rows)[2][-1]
    scale = 1.0 / (u[2] - u[1] ** 2 / u[0])
    a2, ab, c = scale * u[0], scale * u[1], scale * u[3]
    a = math.sqrt(abs(a2))
    return np.array([a, ab / a, (c / a) ** 2])


def fit_cell(x, y, z, v, iterations=50):
    """Levenberg-Marquardt on relative residuals from the linearised start. Returns (params, rms)."""
    p = initial_guess(x, y, z, v)

    def residual(p):
        return _model64(p, x, y, z) / v - 1.0

    lam = 1e-3
    r = residual(p)
    for _ in range(iterations):
        jac = np.empty((len(v), 3))
        for k in range(3):
            step = 1e-7 * max(abs(p[k]), 1e-3)
            dp = p.copy()
            dp[k] += step
            jac[:, k] = (residual(dp) - r) / step
        jtj, jtr = jac.T @ jac, jac.T @ r
        delta = np.linalg.solve(jtj + lam * np.diag(np.diag(jtj)), -jtr)
        r_new = residual(p + delta)
        if r_new @ r_new < r @ r:
            p, r, lam = p + delta, r_new, lam * 0.3
        else:
            lam *= 10.0
        if np.max(np.abs(delta)) < 1e-12 * max(np.max(np.abs(p)), 1.0):
            break
    return p, float(np.sqrt(np.mean(r * r)))


def fit_table(local, values, log=print):
    """Per measured point (j, i): (a, b, albedo) and the rms relative residual; boundary unmixed."""
    points = np.zeros((3, GRID, GRID))
    rms = np.full((GRID, GRID), np.nan)
    point_of_quad = np.arange(GRID * GRID).repeat(AZIMUTHS)
    x, y, z = (local[..., k] for k in range(3))
    measured = np.zeros((GRID, GRID), bool)
    for p in range(GRID * GRID):
        j, i = divmod(p, GRID)
        sel = point_of_quad == p
        xs, ys, zs, vs = x[:, sel].ravel(), y[:, sel].ravel(), z[:, sel].ravel(), values[:, sel].ravel()
        lit = (zs > 1e-3) & np.isfinite(vs)
        good = lit & (vs > 0)
        if good.sum() < 8:
            log(f"  cell (r {j}, mu {i}): {good.sum()} lit non-zero samples, max {np.max(vs[lit], initial=0):.2e}")
            continue
        params, rms[j, i] = fit_cell(xs[good], ys[good], zs[good], vs[good].astype(np.float64))
        points[:, j, i] = params
        measured[j, i] = True
    table, measured = unmix_boundary(points, measured)
    return table, measured, rms


def unmix_boundary(points, measured):
    """Row 0 was measured at r = 1e-3 and column 0 at mu = 0.5/31; Cycles reads there
    (1 - t) T[boundary] + t T[neighbour] per axis. Solve for T[boundary], where both are measured.
    Returns the table and the mask of known cells."""
    table, known = points.copy(), measured.copy()
    ty = float(np.float32(np.float32(R_EDGE) * np.float32(GRID - 1)))
    tx = float(np.float32(np.float32(MU_EDGE) * np.float32(GRID - 1)))
    table[:, 0, 1:] = (points[:, 0, 1:] - ty * points[:, 1, 1:]) / (1 - ty)
    known[0, 1:] &= measured[1, 1:]
    table[:, 1:, 0] = (points[:, 1:, 0] - tx * points[:, 1:, 1]) / (1 - tx)
    known[1:, 0] &= measured[1:, 1]
    corner_known = ((1 - ty) * tx * table[:, 0, 1] + ty * (1 - tx) * table[:, 1, 0]
                    + ty * tx * table[:, 1, 1])
    table[:, 0, 0] = (points[:, 0, 0] - corner_known) / ((1 - ty) * (1 - tx))
    known[0, 0] &= known[0, 1] & known[1, 0] & known[1, 1]
    return table, known


def fill_dropped(table, known, log=print):
    """Cells Cycles drops (albedo or |a| < 1e-5: black pixels) cannot be measured. They get albedo 0
    and a, b from the nearest known cell (grid distance), so a lookup between them and a measured
    neighbour blends towards a plausible shape; the lobe there is below ~1e-4 of white anyway."""
    kj, ki = np.nonzero(known)
    for j, i in zip(*np.nonzero(~known)):
        k = np.argmin((kj - j) ** 2 + (ki - i) ** 2)
        table[:2, j, i] = table[:2, kj[k], ki[k]]
        table[2, j, i] = 0.0
    log(f"  {np.count_nonzero(~known)} cells dropped by Cycles: albedo 0, a and b from the nearest known cell")
    return table


# ---------------------------------------------------------------- verification
def verify(table, count=256, seed=7, suns=6, log=print):
    """Off-grid (mu, r): Cycles' pixels against sheen.sheen_eval with `table`. Returns the relative
    errors of the lit quads (value above 1e-4 of the largest)."""
    rng = np.random.default_rng(seed)
    mus = rng.uniform(0.02, 1.0, count)
    rs = rng.uniform(0.0, 1.0, count)
    quads = build_quads(mus, rs, rng.uniform(0.0, 2.0 * math.pi, count))
    local, values = measure(quads, rs, suns=suns, log=lambda *_: None)
    mu_q = quads["normals"][:-1, 2]
    wo = tuple(np.broadcast_to(c, (suns, count)).astype(np.float32).ravel()
               for c in (np.sqrt(1 - mu_q ** 2), np.zeros(count), mu_q))
    wi = tuple(local[..., k].astype(np.float32).ravel() for k in range(3))
    f_cos, _ = sheen.sheen_eval(wo, wi, np.tile(quads["roughness"], suns).astype(np.float32), table)
    v = values.ravel()
    lit = np.isfinite(v) & (v > 1e-4 * np.nanmax(v))
    rel = np.abs(f_cos[lit] - v[lit]) / v[lit]
    absolute = np.abs(f_cos - v)[np.isfinite(v)]
    log(f"verify: {lit.sum()} lit samples; relative error median {np.median(rel):.2e}, "
        f"99% {np.quantile(rel, 0.99):.2e}, max {rel.max():.2e}; max absolute {absolute.max():.2e} "
        f"(largest value {np.nanmax(v):.3f})")
    return rel


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--verify", action="store_true", help="only verify the shipped table")
    parser.add_argument("--out", default=sheen.TABLE_PATH)
    args = parser.parse_args(argv)
    if not args.verify:
        mus, rs = cell_points()
        mu_grid, r_grid = np.meshgrid(mus, rs)               # point (j, i) = (r_j, mu_i)
        phi = np.tile(2.0 * math.pi * (np.arange(AZIMUTHS) + 0.25) / AZIMUTHS, GRID * GRID)
        quads = build_quads(mu_grid.ravel().repeat(AZIMUTHS), r_grid.ravel().repeat(AZIMUTHS), phi)
        print(f"measuring {GRID}x{GRID} cells x {AZIMUTHS} azimuths under {SUNS} suns "
              f"({quads['size']}^2 pixels)")
        local, values = measure(quads, rs)
        table, measured, rms = fit_table(local, values)
        print(f"fit: rms relative residual median {np.nanmedian(rms):.2e}, max {np.nanmax(rms):.2e}")
        table = fill_dropped(table, measured)
        # Unmixing the boundary can leave an albedo of -1e-9 where Cycles' is ~0: measurement noise.
        table[2] = np.maximum(table[2], 0.0)
        np.savez_compressed(
            args.out, ltc=table.astype(np.float32),
            mu_grid=(np.arange(GRID) / (GRID - 1)).astype(np.float32),
            roughness_grid=(np.arange(GRID) / (GRID - 1)).astype(np.float32),
            fit_rms=rms.astype(np.float32),
            notes=np.array("ltc[k, j, i]: k = a, b, albedo; j: roughness j/31 (clamped to [1e-3, 1] "
                           "before lookup); i: mu = N.wo = i/31. Bilinear lookup as Cycles' "
                           "lookup_table_read_2D. Measured from Cycles 5.0 by tools/fit_sheen_table.py."))
        print(f"wrote {args.out}")
        sheen.load_table.cache_clear()
    verify(sheen.load_table(args.out))


if __name__ == "__main__":
    main()
