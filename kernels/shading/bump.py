"""The Bump node (Cycles' svm_node_set_bump, kernel/svm/displace.h) and the bump a material's Displacement output
makes under the Bump and "Displacement and Bump" methods (ShaderGraph::bump_from_displacement,
scene/shader_graph.cpp), over the hits of a node program's run.

The Height is evaluated at the hit and at two offsets: Filter Width times the ray's spread along
make_orthonormals(Ng) (Cycles' differential_from_compact), each a step across the triangle (HitInputs.shifted,
which carries UVs and attributes along). N' = normalize(w |det| N - D sign(det) grad), blended with N by Strength.
On back faces Cycles negates dPdu and dPdv (shader_setup_from_ray), so the attributes' differentials (UVs,
Generated, colours) run against the step while the position (Object, Camera coordinates) follows it: so here.

Under "Displacement and Bump" (the op's option `undisplaced`) Cycles evaluates that bump as if the surface had not
moved (svm_node_enter_bump_eval, kernel/svm/bump.h, reading ATTR_STD_POSITION_UNDISPLACED and
ATTR_STD_NORMAL_UNDISPLACED, which scene/shader.cpp asks meshes for under this method only): the height at the
undisplaced position with the undisplaced normal (the per-corner attributes UNDISPLACED_POSITION and
UNDISPLACED_NORMAL, object space, that the export stores for such meshes); its offsets the same steps from there
(Cycles' dPdx(sd) stays the displaced triangle's); the gradient's frame the undisplaced triangle's image of the
ray's spread (the full differential enter_bump_eval saves); the normal computed in object space
(bump_in_object_space for this method) and taken back to world space.
"""
from __future__ import annotations

import numpy as np

from ..programs import Ref
from ..vec import F32
from .input_ops import UNDISPLACED_NORMAL, UNDISPLACED_POSITION, to_object, to_world
from .program import constant, make_orthonormals


def bump_node(run, op) -> dict:
    """The Bump op at run.hits (run: program.ProgramRun). Options: invert, undisplaced."""
    hits, n = run.hits, run.hits.n
    inputs = dict(op.inputs)
    get = {k: (run.value(v) if isinstance(v, Ref) else constant(v)) for k, v in inputs.items() if k != "Height"}
    height = inputs.get("Height")
    undisplaced = undisplaced_hits(hits) if op.option("undisplaced", False) and isinstance(height, Ref) else None
    base = hits if undisplaced is None else undisplaced[0]
    normal_in = base.N if "Normal" not in get else np.broadcast_to(np.asarray(get["Normal"], F32), (n, 3))
    if not isinstance(height, Ref):
        return {"Normal": np.ascontiguousarray(normal_in, F32)}
    width = np.broadcast_to(np.asarray(get["Filter Width"], F32), (n,))
    scale = np.broadcast_to(np.asarray(get["Distance"], F32), (n,))
    if op.option("invert", False):
        scale = -scale
    strength = np.maximum(np.broadcast_to(np.asarray(get["Strength"], F32), (n,)), F32(0.0))
    a, b = make_orthonormals(hits.Ng)
    dp = hits.dp[:, None]
    dpdx, dpdy = a * dp, b * dp
    e1, e2 = hits.hit.edges(hits.idx)
    steps = [barycentric_step(e1, e2, d * width[:, None]) for d in (dpdx, dpdy)]
    back = hits.backfacing
    if undisplaced is None:
        h_c = run.value(height)
        h_x, h_y = np.split(run.elsewhere(hits.shifted(steps, e1, e2, back)).value(height), 2)
    else:
        _, u1, u2 = undisplaced
        still = np.zeros(n, F32)
        h_c, h_x, h_y = np.split(run.elsewhere(base.shifted([(still, still)] + steps, e1, e2, back)).value(height), 3)
        # The saved differential is the position attribute's: reversed on back faces, as the attributes' are.
        sign = np.where(back, F32(-1.0), F32(1.0))[:, None]
        dpdx, dpdy = ((sign * (s1[:, None] * u1 + s2[:, None] * u2)).astype(F32)
                      for s1, s2 in (barycentric_step(e1, e2, d) for d in (dpdx, dpdy)))
        normal_in = to_object(hits, normal_in, "NORMAL")
        dpdx, dpdy = to_object(hits, dpdx, "VECTOR"), to_object(hits, dpdy, "VECTOR")
    rx = np.cross(dpdy, normal_in)
    ry = np.cross(normal_in, dpdx)
    det = np.einsum("ij,ij->i", dpdx, rx)
    grad = (h_x - h_c)[:, None] * rx + (h_y - h_c)[:, None] * ry
    out = (width * np.abs(det))[:, None] * normal_in - (scale * np.sign(det))[:, None] * grad
    length = np.sqrt(np.einsum("ij,ij->i", out, out))
    zero = ~(length > 0)
    out = out / np.where(zero, F32(1.0), length)[:, None]
    blended = strength[:, None] * out + (F32(1.0) - strength)[:, None] * normal_in
    blended = blended / np.maximum(np.sqrt(np.einsum("ij,ij->i", blended, blended)), F32(1e-30))[:, None]
    normal = np.where(zero[:, None], normal_in, blended).astype(F32)
    return {"Normal": normal if undisplaced is None else to_world(hits, normal, "NORMAL")}


def undisplaced_hits(hits):
    """(the hits at their undisplaced position and normal (HitInputs.moved), the undisplaced triangles' world
    edges p1 - p0 and p2 - p0 (n, 3) each), or None where the scene stores no undisplaced mesh. The normal is the
    interpolated UNDISPLACED_NORMAL in world space, facing the viewer as the shading normal does (Cycles'
    primitive_normal_set_undisplaced); the shading normal where that is zero."""
    corners = hits.scene.attribute(UNDISPLACED_POSITION, hits.prim)      # (n, 3, 4) object space
    normal = hits.attribute(UNDISPLACED_NORMAL)
    if corners is None or normal is None:
        return None
    corners = corners[:, :, :3]
    b1, b2 = hits.barycentrics()
    w0 = F32(1.0) - b1 - b2
    p = to_world(hits, (corners[:, 0] * w0[:, None] + corners[:, 1] * b1[:, None]
                        + corners[:, 2] * b2[:, None]).astype(F32), "POINT")
    u1 = to_world(hits, (corners[:, 1] - corners[:, 0]).astype(F32), "VECTOR")
    u2 = to_world(hits, (corners[:, 2] - corners[:, 0]).astype(F32), "VECTOR")
    given = np.einsum("ij,ij->i", normal, normal) > 0
    n = to_world(hits, np.where(given[:, None], normal, hits.N).astype(F32), "NORMAL")
    n = np.where(hits.backfacing[:, None], -n, n)
    n = np.where(given[:, None], n, hits.N).astype(F32)
    return hits.moved(p, n), u1, u2


def barycentric_step(e1: np.ndarray, e2: np.ndarray, d: np.ndarray):
    """(db1, db2) with db1 e1 + db2 e2 the projection of the world step d (n, 3) onto the triangle."""
    g11 = np.einsum("ij,ij->i", e1, e1)
    g12 = np.einsum("ij,ij->i", e1, e2)
    g22 = np.einsum("ij,ij->i", e2, e2)
    r1 = np.einsum("ij,ij->i", e1, d)
    r2 = np.einsum("ij,ij->i", e2, d)
    det = g11 * g22 - g12 * g12
    inv = np.where(det > 0, F32(1.0) / np.where(det > 0, det, F32(1.0)), F32(0.0))
    return ((g22 * r1 - g12 * r2) * inv).astype(F32), ((g11 * r2 - g12 * r1) * inv).astype(F32)
