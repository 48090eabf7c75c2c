"""Memory and time of large frames (issue 10, item 5): one render per size, each in a fresh process.

    .venv/bin/python bench/memory.py [--sizes 1000,2000,4000] [--samples 1] [--display] [--layered]

For every size: the wall time of the render call, the process's peak resident memory (VmHWM) over the
render, and the peak of Ember's own NumPy memory (tracemalloc; Blender's C allocations are not in it).
Renders that last long enough get a worker process (kernels/workers.py): its peak resident memory
(RUSAGE_CHILDREN, after it exits with the renderer) is printed beside, as the memory the render adds to the
machine. The formula of docs/performance.md (Memory) is checked against the figures:

    Ember's memory = 32 bytes per pixel (the float64 RGBA film; the benchmark turns adaptive sampling off,
                     whose buffers make it 49) + a working set of at most WORKING_SET_MB
    Blender's own  = its render result, 16 bytes per pixel (float32 RGBA), and what it needs to save it

--texture SIZE measures instead an image texture of SIZE x SIZE 8-bit RGB pixels (a PNG generated into a
temporary directory, never committed) on a small frame, with Ember and with Cycles, each in a fresh process:
the peak resident memory the render adds and its wall time, and for Ember the export's time. Ember keeps
such an image as 3 bytes per texel (engine/export/images.py); Cycles as 4 (uchar4).

--display forces the interactive path (rows written every wave, as F12 in the interface does) in
background mode, where Ember would otherwise write every row once at the end. --layered gives the sphere a
Principled BSDF with metal and coat layers: materials that mix lobes get waves twice as large (the automatic
wave size, kernels.schedule.LAYERED_WAVE_SIZE), and the bound on the working set doubles with them.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
FILM_BYTES_PER_PIXEL = 32
WORKING_SET_MB = 192  # bound on the waves in flight (two threads, 131k paths each) and the row chunks; 93-159 measured
LAYERED_WORKING_SET_MB = 384  # the same with waves of 262k paths (materials that mix lobes)

CHILD = r"""
import json, os, resource, sys, time, tracemalloc
sys.path.insert(0, %(root)r); sys.path.insert(0, os.path.join(%(root)r, "tests"))
from bench.common import import_ember; import_ember()
import bpy
from bpy_helpers import diffuse_material, mesh_object, new_scene, set_world
import ember.engine.session as session
if %(display)r:
    session._background = lambda: False
    session.DISPLAY_INTERVAL_S = 0.0

def peak_kb():
    with open("/proc/self/status") as f:
        return int(next(l for l in f if l.startswith("VmHWM")).split()[1])

size = %(size)d
scene = new_scene(size, size)
mesh_object("Floor", [(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)], [(0, 1, 2, 3)], diffuse_material("Floor"))
bpy.ops.mesh.primitive_uv_sphere_add(radius=0.8, location=(0, 0, 0.8))
if %(layered)r:
    mat = bpy.data.materials.new("Layered")
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Metallic"].default_value = 0.5
    bsdf.inputs["Coat Weight"].default_value = 1.0
else:
    mat = diffuse_material("Clay")
bpy.context.active_object.data.materials.append(mat)
set_world(scene, color=(0.3, 0.4, 0.5))
scene.render.engine = "EMBER"
scene.ember.samples = %(samples)d
scene.ember.use_adaptive_sampling = False
scene.ember.pixel_filter_type = "BOX"
scene.ember.use_denoising = False
scene.render.threads_mode, scene.render.threads = "FIXED", 2
before = peak_kb()
tracemalloc.start()
start = time.perf_counter()
bpy.ops.render.render()
wall = time.perf_counter() - start
numpy_peak = tracemalloc.get_traced_memory()[1]
tracemalloc.stop()
from ember.kernels import workers
workers.close_pool()   # the closed renderer left its workers idle: stop them, so that their peak is counted
workers_kb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
print("RESULT " + json.dumps({"size": size, "wall_s": wall, "rss_before_mb": before / 1024,
                              "rss_peak_mb": peak_kb() / 1024, "ember_peak_mb": numpy_peak / 2**20,
                              "worker_peak_mb": workers_kb / 1024}))
"""


TEXTURE_IMAGE = r"""
import sys
import bpy, numpy as np
bpy.utils.expose_bundled_modules()
import OpenImageIO as oiio
size, path = %(size)d, %(path)r
out = oiio.ImageOutput.create(path)
out.open(path, oiio.ImageSpec(size, size, 3, "uint8"))
x = np.arange(size, dtype=np.float32)[None, :]
for y0 in range(0, size, 64):
    y = np.arange(y0, min(size, y0 + 64), dtype=np.float32)[:, None]
    planes = [127 + 120 * np.sin(x / 97.0 + y / 53.0), 127 + 120 * np.cos(y / 71.0) + 0 * x, (x + y) %% 256]
    out.write_scanlines(y0, y0 + len(y), 0, np.ascontiguousarray(np.stack(planes, -1).astype(np.uint8)))
out.close()
"""

TEXTURE_CHILD = r"""
import json, os, sys, time
sys.path.insert(0, %(root)r); sys.path.insert(0, os.path.join(%(root)r, "tests"))
from bench.common import import_ember; import_ember()
import bpy
from bpy_helpers import new_scene, quad_object, set_world

def peak_kb():
    with open("/proc/self/status") as f:
        return int(next(l for l in f if l.startswith("VmHWM")).split()[1])

scene = new_scene(64, 64)
material = bpy.data.materials.new("Textured")
tree = material.node_tree
texture = tree.nodes.new("ShaderNodeTexImage")
texture.image = bpy.data.images.load(%(path)r)
tree.links.new(texture.outputs["Color"], tree.nodes["Principled BSDF"].inputs["Base Color"])
quad_object("Plane", (-2, 0, -1), (4, 0, 0), (0, 0, 4), material)
set_world(scene, color=(1, 1, 1))
scene.render.engine = %(engine)r
if %(engine)r == "CYCLES":
    scene.cycles.device, scene.cycles.samples = "CPU", 1
else:
    scene.ember.samples, scene.ember.use_denoising = 1, False
scene.render.threads_mode, scene.render.threads = "FIXED", 2
export = {}
if %(engine)r == "EMBER":
    import ember.engine.session as session
    original = session.export_scene
    def timed(*args, **kwargs):
        result = original(*args, **kwargs)
        export["s"] = result.seconds
        return result
    session.export_scene = timed
before = peak_kb()
start = time.perf_counter()
bpy.ops.render.render()
print("RESULT " + json.dumps({"wall_s": time.perf_counter() - start, "rss_before_mb": before / 1024,
                              "rss_peak_mb": peak_kb() / 1024, "export_s": export.get("s")}))
"""


def measure_texture(size: int, engine: str, path: str) -> dict:
    code = TEXTURE_CHILD % {"root": ROOT, "path": path, "engine": engine}
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    line = next((ln for ln in run.stdout.splitlines() if ln.startswith("RESULT ")), None)
    if line is None:
        raise RuntimeError(f"{engine} failed: {run.stderr.strip()[-500:]}")
    return json.loads(line[len("RESULT "):])


def texture_main(size: int) -> int:
    import tempfile
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, f"texture_{size}.png")
        subprocess.run([sys.executable, "-c", TEXTURE_IMAGE % {"size": size, "path": path}], check=True)
        print(f"{size}x{size} 8-bit RGB PNG ({os.path.getsize(path) / 2**20:.0f} MB file, "
              f"{3 * size * size / 2**20:.0f} MB of texels)")
        print(f"{'engine':>7} | {'render s':>8} | {'export s':>8} | {'peak RSS MB':>11} | {'RSS growth MB':>13} | "
              f"bytes/texel", flush=True)
        growth = {}
        for engine in ("EMBER", "CYCLES"):
            r = measure_texture(size, engine, path)
            growth[engine] = r["rss_peak_mb"] - r["rss_before_mb"]
            export = f"{r['export_s']:8.2f}" if r["export_s"] is not None else f"{'-':>8}"
            print(f"{engine:>7} | {r['wall_s']:8.2f} | {export} | {r['rss_peak_mb']:11.0f} | "
                  f"{growth[engine]:13.0f} | {growth[engine] * 2**20 / size**2:.1f}", flush=True)
    print(f"\nEmber's peak growth / Cycles': {growth['EMBER'] / growth['CYCLES']:.2f}")
    return 0


def measure(size: int, samples: int, display: bool, layered: bool = False) -> dict:
    code = CHILD % {"root": ROOT, "size": size, "samples": samples, "display": display, "layered": layered}
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    line = next((ln for ln in run.stdout.splitlines() if ln.startswith("RESULT ")), None)
    if line is None:
        raise RuntimeError(f"size {size} failed: {run.stderr.strip()[-500:]}")
    return json.loads(line[len("RESULT "):])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1000,2000,4000")
    ap.add_argument("--samples", type=int, default=1)
    ap.add_argument("--display", action="store_true")
    ap.add_argument("--layered", action="store_true", help="a layered Principled sphere (larger waves)")
    ap.add_argument("--texture", type=int, default=0, help="measure an 8-bit image texture of this size instead")
    args = ap.parse_args()
    if args.texture:
        return texture_main(args.texture)
    bound = LAYERED_WORKING_SET_MB if args.layered else WORKING_SET_MB
    print(f"{'size':>11} | {'render s':>8} | {'peak RSS MB':>11} | {'RSS growth MB':>13} | {'Ember MB':>8} | "
          f"{'film MB':>7} | {'working set MB':>14} | worker process peak RSS MB", flush=True)
    ok = True
    for size in map(int, args.sizes.split(",")):
        r = measure(size, args.samples, args.display, args.layered)
        film = FILM_BYTES_PER_PIXEL * size * size / 2**20
        working = r["ember_peak_mb"] - film
        ok &= working <= bound
        print(f"{size:>5}x{size:<5} | {r['wall_s']:8.2f} | {r['rss_peak_mb']:11.0f} | "
              f"{r['rss_peak_mb'] - r['rss_before_mb']:13.0f} | {r['ember_peak_mb']:8.0f} | {film:7.0f} | "
              f"{working:14.0f} | {r['worker_peak_mb']:.0f}", flush=True)
    print(f"\nformula: Ember = {FILM_BYTES_PER_PIXEL} B/pixel + at most {bound} MB: "
          f"{'holds' if ok else 'BROKEN'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
