"""The reliability catalog (issue 10): unusual and bad input, as a new user or a pipeline gives it,
through the command line in a subprocess. Prints a table (case, outcome, message) and exits non-zero
when a case does not behave as expected.

    .venv/bin/python bench/reliability.py [--only SUBSTRING]

Each case builds its .blend (if any) in a temporary directory, runs `python -m ember render ...`, and
checks the exit status, that stderr holds no traceback or NumPy warning, that a failure is one line, and
the case's own expectation. About a minute on 2 cores (each run starts bpy).
"""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import textwrap
from dataclasses import dataclass
from typing import Callable

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CLI = ("import sys; sys.path.insert(0, %r); from bench.common import import_ember; import_ember(); "
       "import runpy; sys.argv = ['ember'] + sys.argv[1:]; runpy.run_module('ember', run_name='__main__')" % ROOT)

# A .blend is built by a child bpy process from one of these snippets (run after a base scene: camera,
# floor, grey world, Ember at 2 samples, 32x24).
BASE = textwrap.dedent("""
    import sys, math, bpy
    sys.path.insert(0, %r)
    from bpy_helpers import *
    scene = new_scene(32, 24)
    mesh_object("Floor", [(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)], [(0, 1, 2, 3)], diffuse_material("Floor"))
    set_world(scene, color=(0.3, 0.4, 0.5))
    scene.render.engine = "EMBER"
    scene.ember.samples = 2
""") % os.path.join(ROOT, "tests")


def light(name, kind="POINT", energy=100.0, radius=0.1, location=(0.5, -0.5, 1.5)):
    return (f"d = bpy.data.lights.new({name!r}, {kind!r}); d.energy = {energy!r}; d.shadow_soft_size = {radius!r}\n"
            f"o = bpy.data.objects.new({name!r}, d); o.location = {location!r}; scene.collection.objects.link(o)\n")


@dataclass
class Case:
    name: str
    args: list                      # after "render"; {blend} and {tmp} are filled in
    blend: str | None = None        # bpy code after BASE, or None for no file
    status: int = 0                 # expected exit status
    expect: Callable | None = None  # (run, tmp) -> None or a message saying what is wrong
    interrupt: int = 0              # a signal to send to the process group once the first frame is saved
    file_size_limit: int | None = None  # RLIMIT_FSIZE in bytes: writes past it fail, as on a full disk


def files(*names):
    def check(run, tmp):
        missing = [n for n in names if not os.path.exists(os.path.join(tmp, n))]
        return f"missing {missing}" if missing else None
    return check


def absent(*names):
    def check(run, tmp):
        there = [n for n in names if os.path.exists(os.path.join(tmp, n))]
        return f"should not exist: {there}" if there else None
    return check


def says(text, stream="stdout"):
    def check(run, tmp):
        return None if text in getattr(run, stream) else f"{stream} lacks {text!r}"
    return check


def all_of(*checks):
    def check(run, tmp):
        return next((m for m in (c(run, tmp) for c in checks) if m), None)
    return check


CASES = [
    Case("demo scene, -o", ["-o", "{tmp}/demo.png", "--samples", "1", "--resolution", "64x36"], expect=files("demo.png")),
    Case("missing file", ["{tmp}/nope.blend"], status=1, expect=says("no such file", "stderr")),
    Case("corrupt file", ["{tmp}/corrupt.blend"], status=1, expect=says("cannot open", "stderr")),
    Case("no camera", ["{blend}"], blend="bpy.data.objects.remove(scene.camera)", status=1,
         expect=says("has no camera", "stderr")),
    Case("default output //renders/frame_, --frames 1-2", ["{blend}", "--frames", "1-2"],
         blend="scene.render.filepath = '//renders/frame_'",
         expect=files("renders/frame_0001.png", "renders/frame_0002.png")),
    Case("default output, EXR and ### in the file, -a", ["{blend}", "-a"],
         blend="scene.render.filepath = '//exr/f_###'; scene.render.image_settings.file_format = 'OPEN_EXR'; "
               "scene.frame_start, scene.frame_end = 2, 3",
         expect=files("exr/f_002.exr", "exr/f_003.exr")),
    Case("default output /tmp/ (Blender's default path)", ["{blend}"],
         blend="scene.render.filepath = '{tmp}/'", expect=files("0001.png")),
    Case("default output is a video format", ["{blend}"], blend="scene.render.image_settings.media_type = 'VIDEO'",
         status=1, expect=says("video", "stderr")),
    Case("default output under a file", ["{blend}"], blend="open('{tmp}/file', 'w').close(); "
                                                           "scene.render.filepath = '{tmp}/file/sub/f_'",
         status=1, expect=all_of(says("is a file, not a directory", "stderr"), lambda r, t: "rendered before failing" if "Sample" in r.stdout else None)),
    Case("-o in /proc", ["-o", "/proc/ember/x.png"], status=1, expect=says("cannot create the directory", "stderr")),
    Case("-o with an unknown extension", ["-o", "{tmp}/x.gif"], status=1, expect=says("extensions", "stderr")),
    Case("--seed 2**40", ["--seed", str(2 ** 40)], status=2, expect=says("--seed must be", "stderr")),
    Case("--seed -7", ["--seed", "-7"], status=2, expect=says("--seed must be", "stderr")),
    Case("--resolution 1x1", ["--resolution", "1x1"], status=2, expect=says("--resolution must be", "stderr")),
    Case("--samples 0", ["--samples", "0"], status=2, expect=says("--samples must be", "stderr")),
    Case("--frames 9-3", ["--frames", "9-3"], status=2, expect=says("ends before", "stderr")),
    Case("--time-limit -1", ["--time-limit", "-1"], status=2, expect=says("--time-limit", "stderr")),
    Case("volume-only material", ["{blend}", "-o", "{tmp}/v.png"], blend=textwrap.dedent("""
        m = bpy.data.materials.new('Fog'); t = m.node_tree; t.nodes.clear()
        t.links.new(t.nodes.new('ShaderNodeVolumePrincipled').outputs[0], t.nodes.new('ShaderNodeOutputMaterial').inputs['Volume'])
        mesh_object('Cloud', [(-0.5, 0, 0.2), (0.5, 0, 0.2), (0, 0, 1)], [(0, 1, 2)], m)"""),
         expect=says("volume shaders are not supported")),
    Case("negative light", ["{blend}", "-o", "{tmp}/n.png"], blend=light("Neg", energy=-100.0),
         expect=says("negative power")),
    Case("1e38 W light", ["{blend}", "-o", "{tmp}/h.exr"], blend=light("Blinding", energy=1e38),
         expect=says("too bright")),
    Case("object scaled 1e30", ["{blend}", "-o", "{tmp}/s.png"],
         blend="o = mesh_object('Huge', [(-1, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1, 2)]); o.scale = (1e30,) * 3",
         expect=files("s.png")),
    Case("NaN vertex", ["{blend}", "-o", "{tmp}/nan.png"],
         blend="mesh_object('Broken', [(-1, 0, 0), (1, 0, 0), (float('nan'), 0, 1)], [(0, 1, 2)])",
         expect=files("nan.png")),
    Case("missing image, relative path", ["{blend}", "-o", "{tmp}/i.png"], blend=textwrap.dedent("""
        img = bpy.data.images.new('Missing', 4, 4); img.source = 'FILE'; img.filepath = '//../x.png'
        mesh_object('Poster', [(-1, 1, 0), (1, 1, 0), (0, 1, 1)], [(0, 1, 2)], diffuse_material('P', image=img))"""),
         expect=lambda r, t: None if "//" not in r.stdout and "x.png" in r.stdout else "relative path in the warning"),
    Case("1 km floor and a point lamp", ["{blend}", "-o", "{tmp}/floor.png"],
         blend="mesh_object('Big', [(-500, -500, -0.01), (500, -500, -0.01), (500, 500, -0.01), (-500, 500, -0.01)], "
               "[(0, 1, 2, 3)]); " + light("Lamp").replace("\n", "; "), expect=files("floor.png")),
    Case("time limit at 640x480", ["{blend}", "-o", "{tmp}/t.exr", "--time-limit", "0.001", "--samples", "64",
                                    "--resolution", "640x480"], blend="", expect=files("t.exr")),
    Case("Ctrl-C once frame 1 of 3 is saved", ["{blend}", "-o", "{tmp}/c_#.png", "--frames", "1-3", "--resolution", "320x240"],
         blend="scene.ember.samples = 400; bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=(0, 0, 0.5))",
         status=130, interrupt=signal.SIGINT, expect=all_of(absent("c_3.png"), says("interrupted", "stderr"))),
    Case("SIGTERM to the process group once frame 1 of 3 is saved",
         ["{blend}", "-o", "{tmp}/t_#.png", "--frames", "1-3", "--resolution", "320x240"],
         blend="scene.ember.samples = 400; bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=(0, 0, 0.5))",
         status=143, interrupt=signal.SIGTERM,
         expect=all_of(files("t_1.png"), absent("t_3.png"), says("interrupted by SIGTERM", "stderr"))),
    Case("--threads 1000", ["{blend}", "-o", "{tmp}/t.png", "--threads", "1000"], blend="",
         expect=all_of(files("t.png"), says("--threads 1000 is more than the"))),
    Case("output name of 255 bytes", ["{blend}", "-o", "{tmp}/" + "n" * 251 + ".png"], blend="",
         expect=files("n" * 251 + ".png")),
    Case("output name of 256 bytes", ["{blend}", "-o", "{tmp}/" + "n" * 252 + ".png"], blend="", status=1,
         expect=all_of(says("is 256 bytes", "stderr"), lambda r, t: "rendered before failing" if "Sample" in r.stdout else None)),
    Case("a write fails (60 KB file size limit), --frames 1-3", ["{blend}", "-o", "{tmp}/w_#.exr", "--frames", "1-3",
                                                                 "--resolution", "320x240"],
         blend="", status=1, file_size_limit=60_000,
         expect=all_of(absent("w_1.exr"), says("no frame was saved; frames 1-3 were not", "stderr"))),
]


def run_case(case: Case, tmp: str):
    fill = lambda s: s.replace("{tmp}", tmp).replace("{blend}", os.path.join(tmp, "scene.blend"))
    if case.blend is not None:
        code = BASE + fill(case.blend) + f"\nbpy.ops.wm.save_as_mainfile(filepath={os.path.join(tmp, 'scene.blend')!r})\n"
        subprocess.run([sys.executable, "-c", code], capture_output=True, check=True, cwd=tmp)
    with open(os.path.join(tmp, "corrupt.blend"), "wb") as f:
        f.write(b"BLENDER-v500 this is not a blend file")
    cmd = [sys.executable, "-c", CLI, "render", *map(fill, case.args)]
    if not case.interrupt:
        return subprocess.run(cmd, capture_output=True, text=True, cwd=tmp, timeout=300,
                              preexec_fn=None if case.file_size_limit is None else lambda: _limit(case.file_size_limit))
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp,
                            start_new_session=True)
    head = []
    for line in proc.stdout:
        head.append(line)
        if "saved" in line:
            break
    os.killpg(proc.pid, case.interrupt)   # as a terminal's Ctrl-C or a farm manager sends it: to the group
    out, err = proc.communicate(timeout=60)
    return subprocess.CompletedProcess(cmd, proc.returncode, "".join(head) + out, err)


def _limit(file_size: int) -> None:
    import resource
    resource.setrlimit(resource.RLIMIT_FSIZE, (file_size, resource.RLIM_INFINITY))


def judge(case: Case, run, tmp: str) -> tuple[str, str]:
    err = run.stderr.strip()
    lines = err.splitlines()
    message = lines[-1] if lines else ""
    problems = []
    if run.returncode != case.status:
        problems.append(f"exit {run.returncode}, expected {case.status}")
    if "Traceback" in err or "Warning" in err:
        problems.append("traceback or warning on stderr")
    if case.status and len(lines) != 1:
        problems.append(f"{len(lines)} lines on stderr")
    extra = case.expect(run, tmp) if case.expect else None
    if extra:
        problems.append(extra)
    if not case.status:
        warnings = [ln.split("Warning: ", 1)[1] for ln in run.stdout.splitlines() if "Warning: " in ln]
        message = "; ".join(warnings) or "ok"
    return ("FAIL: " + "; ".join(problems)) if problems else "as expected", message


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", help="run the cases whose name contains this")
    args = ap.parse_args()
    cases = [c for c in CASES if not args.only or args.only in c.name]
    rows = []
    for case in cases:
        with tempfile.TemporaryDirectory() as tmp:
            try:
                outcome, message = judge(case, run_case(case, tmp), tmp)
            except (subprocess.SubprocessError, OSError) as err:
                outcome, message = "FAIL: harness", str(err).splitlines()[0]
        rows.append((case.name, outcome, message))
        print(f"{case.name:48.48} | {outcome:12.12} | {message}", flush=True)
    failed = [r for r in rows if r[1].startswith("FAIL")]
    print(f"\n{len(rows) - len(failed)}/{len(rows)} cases as expected")
    for name, outcome, message in failed:
        print(f"  {name}: {outcome}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
