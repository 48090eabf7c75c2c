"""Big scenes (issue 14): time to first sample and peak memory, Ember against Cycles, in one run.

    .venv/bin/python bench/big_scenes.py [--triangles 1,3,10] [--instances 1000] [--instance-triangles 100000]

Each measurement runs in a fresh process (bpy, the scene built in code, one render): a mesh of N million
triangles (a bumpy sphere, smooth shaded, one material), and K instances of an M-triangle mesh placed
by geometry nodes (Instance on Points on a grid). Time to first sample is the wall time of a 1-sample
render at 128x128 through bpy.ops.render.render (export, BVH build, the sample, the result written
back), as a user pressing F12 sees it; both engines on the same 2 threads. Peak memory is the process's
peak resident memory during the render call above what it held before it (VmHWM reset through
/proc/self/clear_refs, Linux only). Printed as ratios Ember / Cycles.

--child runs one measurement and prints a RESULT line (tests/test_instancing.py uses it too).
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def bumpy_sphere(triangles: int):
    """(vertices (V, 3) float32, quads (F, 4) int32) of a UV sphere with ripples, about `triangles`
    triangles once its quads are split (rings x segments quads, segments = 2 rings)."""
    import numpy as np
    rings = max(4, int(round((triangles / 4) ** 0.5)))
    segments = 2 * rings
    theta = np.linspace(0.02, np.pi - 0.02, rings + 1)
    phi = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    r = 1.0 + 0.03 * np.sin(9 * t) * np.cos(7 * p)
    verts = np.stack([r * np.sin(t) * np.cos(p), r * np.sin(t) * np.sin(p), r * np.cos(t)], -1).reshape(-1, 3)
    i = np.arange(rings)[:, None] * segments
    j = np.arange(segments)[None, :]
    j1 = (j + 1) % segments
    quads = np.stack([i + j, i + j1, i + segments + j1, i + segments + j], -1).reshape(-1, 4)
    return verts.astype(np.float32), quads.astype(np.int32)


def mesh_from_arrays(name: str, verts, quads):
    import bpy
    import numpy as np
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(verts))
    mesh.vertices.foreach_set("co", verts.ravel())
    mesh.loops.add(quads.size)
    mesh.loops.foreach_set("vertex_index", quads.ravel())
    mesh.polygons.add(len(quads))
    mesh.polygons.foreach_set("loop_start", np.arange(0, quads.size, 4, dtype=np.int32))
    mesh.update()
    mesh.shade_smooth()
    return mesh


def build(kind: str, triangles: int, instances: int, width: int = 128, height: int = 128):
    """The benchmark scene in the current (empty) Blender file: camera, sun, world, and either one mesh
    of `triangles` triangles or `instances` instances of such a mesh on a grid."""
    import math
    import bpy
    sys.path.insert(0, os.path.join(ROOT, "tests"))
    from bpy_helpers import add_camera, diffuse_material, new_scene, set_world
    scene = new_scene(width, height)
    set_world(scene, color=(0.3, 0.35, 0.4))
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.rotation_euler = (0.6, 0.2, 0.4)
    scene.collection.objects.link(sun)
    mesh = mesh_from_arrays("Bumpy", *bumpy_sphere(triangles))
    mesh.materials.append(diffuse_material("Clay", (0.7, 0.5, 0.4)))
    ob = bpy.data.objects.new("Bumpy", mesh)
    if kind == "mesh":
        scene.collection.objects.link(ob)
        add_camera(scene, (0, -3.2, 1.2), (0, 0, 0))
        return scene
    # K instances on a square grid of points, by geometry nodes; the source object itself is not rendered.
    side = math.ceil(instances ** 0.5)
    grid = bpy.data.objects.new("Forest", bpy.data.meshes.new("ForestPoints"))
    scene.collection.objects.link(grid)
    tree = bpy.data.node_groups.new("Forest", "GeometryNodeTree")
    tree.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    tree.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    points = tree.nodes.new("GeometryNodeMeshGrid")
    points.inputs["Size X"].default_value = points.inputs["Size Y"].default_value = 2.5 * (side - 1)
    points.inputs["Vertices X"].default_value = points.inputs["Vertices Y"].default_value = side
    on_points = tree.nodes.new("GeometryNodeInstanceOnPoints")
    info = tree.nodes.new("GeometryNodeObjectInfo")
    info.inputs["Object"].default_value = ob
    info.transform_space = "RELATIVE"
    tree.links.new(points.outputs["Mesh"], on_points.inputs["Points"])
    tree.links.new(info.outputs["Geometry"], on_points.inputs["Instance"])
    tree.links.new(on_points.outputs["Instances"], tree.nodes.new("NodeGroupOutput").inputs[0])
    grid.modifiers.new("Forest", "NODES").node_group = tree
    extent = 1.25 * (side - 1)
    add_camera(scene, (0, -extent - 4, 0.6 * extent + 2), (0, -0.3 * extent, 0))
    scene.camera.data.clip_end = 10 * extent + 100
    return scene


CHILD = r"""
import json, os, sys, time
sys.path.insert(0, %(root)r)
from bench.common import import_ember; import_ember()
from bench.big_scenes import build
import bpy

def rss_kb(field):
    with open("/proc/self/status") as f:
        return int(next(l for l in f if l.startswith(field)).split()[1])

if %(refine)r:
    import ember.kernels.accel
    ember.kernels.accel.REFINE_SECONDS_PER_TRIANGLE = 0.0   # the medium BVH built beside the quick one
scene = build(%(kind)r, %(triangles)d, %(instances)d, %(width)d, %(height)d)
scene.render.engine = %(engine)r
scene.render.threads_mode, scene.render.threads = "FIXED", 2
if %(engine)r == "EMBER":
    scene.ember.samples = %(samples)d
    scene.ember.use_adaptive_sampling = False
    scene.ember.use_denoising = False
else:
    scene.cycles.device = "CPU"
    scene.cycles.samples = %(samples)d
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
bpy.context.view_layer.update()
before = rss_kb("VmRSS")
with open("/proc/self/clear_refs", "w") as f:
    f.write("5")   # reset the peak (VmHWM) to the current size
start = time.perf_counter()
bpy.ops.render.render()
wall = time.perf_counter() - start
print("RESULT " + json.dumps({"wall_s": wall, "rss_before_mb": before / 1024,
                              "peak_growth_mb": (rss_kb("VmHWM") - before) / 1024}))
"""


def _huge_pages() -> str:
    """Whether Ember's build would keep NumPy's huge-page advice on this machine now (kernels.memory): the
    first-sample figures depend on it."""
    import importlib.util
    spec = importlib.util.spec_from_file_location("_ember_memory", os.path.join(ROOT, "kernels", "memory.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return "yes" if module.huge_pages_ready() else "no (small pages while it builds)"


def measure(engine: str, kind: str, triangles: int, instances: int = 0, width: int = 128, height: int = 128,
            samples: int = 1, refine: bool = False) -> dict:
    """refine: Ember builds its medium BVH beside the quick one whatever the render's length (the peak of
    a long render of a big mesh)."""
    code = CHILD % {"root": ROOT, "engine": engine, "kind": kind, "triangles": triangles, "instances": instances,
                    "width": width, "height": height, "samples": samples, "refine": refine}
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    line = next((ln for ln in run.stdout.splitlines() if ln.startswith("RESULT ")), None)
    if line is None:
        raise RuntimeError(f"{engine} {kind} failed: {run.stderr.strip()[-800:]}")
    return json.loads(line[len("RESULT "):])


# The memory budget for a render (docs/performance.md): per triangle (export arrays, shading table, Embree's
# BVH), per pixel (Ember's float64 film and Blender's float32 result), and a fixed part (working set, Blender's
# caches).
BUDGET_BYTES_PER_TRIANGLE = 500
BUDGET_BYTES_PER_PIXEL = 64
BUDGET_FIXED_MB = 300


def budget_mb(triangles: int, pixels: int) -> float:
    return (BUDGET_BYTES_PER_TRIANGLE * triangles + BUDGET_BYTES_PER_PIXEL * pixels) / 2**20 + BUDGET_FIXED_MB


def check_budget() -> int:
    """A 4K frame of a 10M-triangle mesh, 2 samples: Ember's peak memory within the budget (and Cycles').
    Two samples are two passes, so the peak holds what a long render builds after its first sample: the
    shading table and, forced here as a render of more samples would have it, the medium BVH beside the
    quick one (kernels.accel.REFINE_SECONDS_PER_TRIANGLE)."""
    triangles, width, height = 10_000_000, 3840, 2160
    limit = budget_mb(triangles, width * height)
    print(f"budget: {BUDGET_BYTES_PER_TRIANGLE} B/triangle + {BUDGET_BYTES_PER_PIXEL} B/pixel + "
          f"{BUDGET_FIXED_MB} MB = {limit:.0f} MB for 10M triangles at {width}x{height}", flush=True)
    e = measure("EMBER", "mesh", triangles, 0, width, height, samples=2, refine=True)
    c = measure("CYCLES", "mesh", triangles, 0, width, height, samples=2)
    print(f"Ember: {e['peak_growth_mb']:.0f} MB peak over the render ({e['wall_s']:.1f} s); "
          f"Cycles: {c['peak_growth_mb']:.0f} MB ({c['wall_s']:.1f} s); ratio {e['peak_growth_mb'] / c['peak_growth_mb']:.2f}; "
          f"budget {'holds' if e['peak_growth_mb'] <= limit else 'BROKEN'}", flush=True)
    return 0 if e["peak_growth_mb"] <= limit else 1


def instancing_speed(repeats: int = 3) -> tuple[float, float]:
    """Paths/s of 49 instances of a 20k-triangle mesh on a floor (1M triangles flattened), traced as
    instances and as world-space copies, kernel only, 160x120, 16 spp, 2 threads: (instanced, flattened)
    medians of `repeats` interleaved runs."""
    import numpy as np
    sys.path.insert(0, ROOT)
    from bench.common import import_ember
    import_ember()
    from ember.kernels import Camera, Materials, Renderer, RenderSettings, SceneArrays, World
    from ember.kernels.geometry import flatten_instances
    from ember.kernels.scene import Instances, Prototype
    from ember.kernels.shapes import look_at
    v, q = bumpy_sphere(20_000)
    corners = v[np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])]
    t = len(corners)
    proto = Prototype(corners.astype(np.float32),
                      (corners / np.linalg.norm(corners, axis=2, keepdims=True)).astype(np.float32),
                      np.zeros((t, 3, 2), np.float32), np.zeros(t, np.int32))
    mats = np.tile(np.eye(4), (49, 1, 1))
    mats[:, 0, 3] = 2.5 * (np.arange(49) % 7 - 3)
    mats[:, 1, 3] = 2.5 * (np.arange(49) // 7 - 3)
    mats[:, 2, 3] = 1.0
    floor = np.array([[[-20, -20, 0], [20, -20, 0], [20, 20, 0]], [[-20, -20, 0], [20, 20, 0], [-20, 20, 0]]], np.float32)
    scene = SceneArrays(
        positions=floor, normals=np.tile(np.float32([0, 0, 1]), (2, 3, 1)), uvs=np.zeros((2, 3, 2), np.float32),
        material_ids=np.zeros(2, np.int32), materials=Materials.diffuse(np.array([[0.7, 0.6, 0.5]], np.float32)),
        world=World(color=np.array([0.6, 0.7, 0.9], np.float32)),
        camera=Camera(world_from_camera=look_at((0, -14, 9), (0, 0, 0)), width=160, height=120, fov_rad=np.radians(60)),
        instances=Instances((proto,), np.zeros(49, np.int32), mats))
    runs = {"instanced": [], "flat": []}
    for _ in range(repeats):
        for name, s in (("instanced", scene), ("flat", flatten_instances(scene))):
            with Renderer(s, 2) as r:
                r.render(RenderSettings(samples=1))
                runs[name].append(r.render(RenderSettings(samples=16, max_bounces=8)).progress.paths_per_s)
    return float(np.median(runs["instanced"])), float(np.median(runs["flat"]))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--triangles", default="1,3,10", help="mesh sizes in millions of triangles")
    ap.add_argument("--instances", type=int, default=1000)
    ap.add_argument("--instance-triangles", type=int, default=100_000)
    ap.add_argument("--repeats", type=int, default=3, help="runs per engine and scene (medians)")
    ap.add_argument("--budget", action="store_true",
                    help="only the memory budget check: 10M triangles at 3840x2160, against the formula")
    ap.add_argument("--speed", action="store_true",
                    help="only the tracing speed of instances against their flattened copies (kernel only)")
    args = ap.parse_args()
    if args.budget:
        return check_budget()
    if args.speed:
        inst, flat = instancing_speed()
        print(f"49 instances of a 20k-triangle mesh: {inst / 1e6:.3f} M paths/s instanced, {flat / 1e6:.3f} "
              f"flattened: {inst / flat:.2f}x")
        return 0
    cases = [("mesh", int(float(m) * 1e6), 0, f"{m}M-triangle mesh") for m in args.triangles.split(",") if m]
    if args.instances:
        cases.append(("instances", args.instance_triangles, args.instances,
                      f"{args.instances} x {args.instance_triangles // 1000}k instances"))
    print(f"cores: {os.cpu_count()}, both engines on 2 threads; 1 sample at 128x128; medians of {args.repeats} "
          f"interleaved runs; huge pages for Ember's build now: {_huge_pages()}", flush=True)
    print(f"{'scene':>26} | {'Ember s':>7} | {'Cycles s':>8} | {'ratio':>5} | {'Ember MB':>8} | {'Cycles MB':>9} | ratio",
          flush=True)
    for kind, triangles, instances, title in cases:
        runs = {"EMBER": [], "CYCLES": []}
        for _ in range(args.repeats):   # interleaved, medians: the machine's load drifts
            for engine in runs:
                runs[engine].append(measure(engine, kind, triangles, instances))
        e, c = ({key: statistics.median(r[key] for r in runs[engine]) for key in runs[engine][0]}
                for engine in ("EMBER", "CYCLES"))
        print(f"{title:>26} | {e['wall_s']:7.2f} | {c['wall_s']:8.2f} | {e['wall_s'] / c['wall_s']:5.2f} | "
              f"{e['peak_growth_mb']:8.0f} | {c['peak_growth_mb']:9.0f} | "
              f"{e['peak_growth_mb'] / max(c['peak_growth_mb'], 1):.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
