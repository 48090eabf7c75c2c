"""`python -m ember render --ray`: an animation spread over a Ray cluster of several worker processes started
here (a head node and a second node, ray.cluster_utils.Cluster, on the loopback interface), compared bit for
bit with the single-process command line; a worker killed mid-render; sample ranges merged; Ctrl-C; and the
one-line messages (Ray missing, an unreachable cluster, bad --split-samples).

One cluster serves the module (Ray takes seconds to start); the finalizer shuts every node down."""
import os
import re
import signal
import subprocess
import sys
import time

import bpy
import numpy as np
import pytest

from bpy_helpers import diffuse_material, emission_material, mesh_object, new_scene, set_world
from test_cli import ROOT, ember, load_image

# A Ray of this machine alone: the test cluster and the drivers (subprocesses inherit it) stay on the
# loopback interface; Ray reads it at import.
os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
try:
    import ray
    HAVE_RAY = bool(ray.__version__)
except ImportError:
    HAVE_RAY = False
needs_ray = pytest.mark.skipif(not HAVE_RAY, reason="Ray is not installed here: python3 dev.py --blender 5.0 setup "
                                                    "--ray (dev.py test and CI install it on Blender 5.0's Python 3.11; "
                                                    "Ray 2.40 has no Python 3.13 build)")

FRAMES = "1-5"
# About 0.45 s of rendering a frame on one thread: long enough to kill a worker in the middle of one, and for the
# second worker to start before the first has done them all (384 samples took that long before waves of at least
# 65,536 paths; then 0.07 s, and one CI run saw worker 1 render all five frames before worker 2 was ready).
SAMPLES = "3072"
# The renders a signal stops once their first frame is saved: short frames do (far fewer than 40 of them are done
# before the signal arrives), and the first one is saved sooner.
STOPPED_SAMPLES = "256"


def _command(*args):
    code = ("import sys; sys.path.insert(0, %r); from bench.common import import_ember; import_ember(); "
            "import runpy; sys.argv = ['ember'] + sys.argv[1:]; runpy.run_module('ember', run_name='__main__')" % ROOT)
    return [sys.executable, "-c", code, *args]


@pytest.fixture(scope="module")
def animation(tmp_path_factory):
    """A saved .blend: a floor and a moving emissive panel, 24x16, adaptive sampling and denoising off."""
    scene = new_scene(24, 16)
    mesh_object("Floor", [(-2, -2, 0), (2, -2, 0), (2, 2, 0), (-2, 2, 0)], [(0, 1, 2, 3)], diffuse_material("Floor"))
    panel = mesh_object("Panel", [(-0.5, -0.5, 1), (0.5, -0.5, 1), (0.5, 0.5, 1.4), (-0.5, 0.5, 1.4)],
                        [(0, 1, 2, 3)], emission_material("Panel", strength=4.0))
    panel.keyframe_insert("location", frame=1)
    panel.location = (1.0, 0.0, 0.4)
    panel.keyframe_insert("location", frame=5)
    set_world(scene, color=(0.2, 0.25, 0.3))
    scene.render.engine = "EMBER"
    scene.ember.use_denoising = False
    scene.ember.use_adaptive_sampling = False
    path = str(tmp_path_factory.mktemp("blend") / "anim.blend")
    bpy.ops.wm.save_as_mainfile(filepath=path, copy=True)
    return path


@pytest.fixture(scope="module")
def reference(animation, tmp_path_factory):
    """The single-process command line's frames (float EXR), the truth the cluster must match bit for bit."""
    out = tmp_path_factory.mktemp("reference")
    run = ember("render", animation, "--frames", FRAMES, "--samples", SAMPLES, "-o", str(out / "f_#.exr"))
    assert run.returncode == 0, run.stderr
    return {f: load_image(str(out / f"f_{f}.exr")) for f in range(1, 6)}


@pytest.fixture(scope="module")
def cluster(request):
    """A head node (1 CPU) and a second node (2 CPUs): room for two workers and a replacement."""
    if not HAVE_RAY:
        pytest.skip("Ray is not installed here: python3 dev.py --blender 5.0 setup --ray")
    from ray.cluster_utils import Cluster
    common = dict(node_ip_address="127.0.0.1", object_store_memory=100 * 1024 * 1024)
    nodes = Cluster(initialize_head=True, head_node_args=dict(num_cpus=1, include_dashboard=False, **common))
    request.addfinalizer(nodes.shutdown)
    nodes.add_node(num_cpus=2, **common)
    nodes.wait_for_nodes()
    return nodes.address


def _frames_equal_reference(out, reference):
    for frame, expected in reference.items():
        got = load_image(str(out / f"f_{frame}.exr"))
        assert got.shape == expected.shape and np.array_equal(got, expected), f"frame {frame} differs"


@needs_ray
def test_animation_over_the_cluster_equals_one_process(cluster, animation, reference, tmp_path):
    run = ember("render", animation, "--frames", FRAMES, "--samples", SAMPLES, "-o", str(tmp_path / "f_#.exr"),
                "--ray", cluster, "--workers", "2", "--threads", "1")
    assert run.returncode == 0, run.stderr
    _frames_equal_reference(tmp_path, reference)
    assert "Ember | Ray | 5/5 frames" in run.stderr and "worker 2 ready: pid" in run.stderr
    assert sorted(re.findall(r"Ember \| Frame (\d+) \| saved", run.stdout)) == ["1", "2", "3", "4", "5"]
    assert not [p for p in os.listdir(tmp_path) if p.endswith(".partial")]


@needs_ray
def test_a_worker_killed_mid_render_loses_nothing(cluster, animation, reference, tmp_path):
    """The first worker's process is killed as soon as it has a frame: the frame is rendered again by
    another worker (a replacement starts), and every frame is still the single-process one."""
    driver = subprocess.Popen(_command("render", animation, "--frames", FRAMES, "--samples", SAMPLES,
                                       "-o", str(tmp_path / "f_#.exr"), "--ray", cluster, "--workers", "2",
                                       "--threads", "1"),
                              cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        lines = []
        for line in driver.stderr:
            lines.append(line)
            m = re.search(r"worker (\d+) ready: pid (\d+)", line)
            if m:
                time.sleep(0.2)  # it has been handed a frame; it renders for about half a second
                os.kill(int(m.group(2)), signal.SIGKILL)
                break
        out, err = driver.communicate(timeout=120)
    finally:
        driver.kill()
    err = "".join(lines) + err
    assert driver.returncode == 0, err
    assert re.search(r"worker \d+ \(pid \d+ on .*\) lost: .*; frame \d goes to another worker; starting worker 3",
                     err), err
    _frames_equal_reference(tmp_path, reference)


@needs_ray
def test_split_samples_merge_to_the_plain_render(cluster, animation, tmp_path):
    """--split-samples 3: three ranges of frame 2 (6, 5 and 5 samples) rendered as separate tasks and merged by
    sample count equal a plain 16-sample render up to float rounding; the merged file says it holds 16 samples."""
    from ember.engine.merge import exr_strings
    plain, split = str(tmp_path / "plain.exr"), str(tmp_path / "split.exr")
    run = ember("render", animation, "--frames", "2", "--samples", "16", "--sample-offset", "0", "-o", plain)
    assert run.returncode == 0, run.stderr
    run = ember("render", animation, "--frames", "2", "--samples", "16", "--split-samples", "3", "-o", split,
                "--ray", cluster, "--workers", "2", "--threads", "1")
    assert run.returncode == 0, run.stderr
    a, b = load_image(plain), load_image(split)
    assert a.shape == b.shape
    np.testing.assert_allclose(b, a, rtol=1e-5, atol=1e-6)
    fields = exr_strings(split)
    assert fields["ember.samples"] == "16" and fields["ember.denoised"] == "0" and fields["Frame"] == "002"


@needs_ray
def test_split_samples_with_denoise_denoise_the_merged_frame(cluster, animation, tmp_path):
    """--denoise with --split-samples: the ranges come back with their albedo and normal passes, and the
    driver denoises the merged frame as the single-process render denoises its own (with the pattern ranges
    use, a sequence per pixel: the default's blue-noise layout depends on the whole frame's sample count)."""
    from ember.engine.merge import exr_strings
    plain, split = str(tmp_path / "plain.exr"), str(tmp_path / "split.exr")
    run = ember("render", animation, "--frames", "3", "--samples", "16", "--denoise", "--pattern", "sobol-burley",
                "-o", plain)
    assert run.returncode == 0, run.stderr
    run = ember("render", animation, "--frames", "3", "--samples", "16", "--split-samples", "2", "--denoise",
                "-o", split, "--ray", cluster, "--workers", "2", "--threads", "1")
    assert run.returncode == 0, run.stderr
    a, b = load_image(plain), load_image(split)
    assert exr_strings(split)["ember.denoised"] == "1" and exr_strings(plain)["ember.denoised"] == "1"
    np.testing.assert_allclose(b, a, rtol=1e-4, atol=1e-4)  # OIDN of inputs equal to float rounding


@needs_ray
def test_local_ray_renders_the_demo_scene(tmp_path):
    """--ray local:1 starts (and stops) a Ray of its own; without a file, the workers build the demo scene."""
    out = str(tmp_path / "demo.png")
    run = ember("render", "--ray", "local:1", "--samples", "1", "--resolution", "48x27", "--no-denoise", "-o", out)
    assert run.returncode == 0, run.stderr
    assert "Ember | Ray | 1/1 frames" in run.stderr
    assert load_image(out).shape == (27, 48, 4)


@needs_ray
def test_ctrl_c_keeps_the_finished_frames(cluster, animation, tmp_path):
    driver = subprocess.Popen(_command("render", animation, "--frames", "1-40", "--samples", STOPPED_SAMPLES,
                                       "-o", str(tmp_path / "f_##.exr"), "--ray", cluster, "--workers", "2",
                                       "--threads", "1"),
                              cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        for line in driver.stdout:
            if "| saved " in line:
                driver.send_signal(signal.SIGINT)
                break
        out, err = driver.communicate(timeout=60)
    finally:
        driver.kill()
    assert driver.returncode == 130, err
    last = err.strip().splitlines()[-1]
    assert last.startswith("ember: interrupted: ") and "saved" in last and "Traceback" not in err
    files = sorted(os.listdir(tmp_path))
    assert files and len(files) < 40 and all(re.fullmatch(r"f_\d\d\.exr", f) for f in files)


def test_without_ray_one_line(animation, tmp_path):
    """Ray hidden from the command line's process (as if not installed): --ray is one line and exit 1, and
    everything else, the extension's registration and a render included, works without it."""
    code = ("import sys; sys.modules['ray'] = None; sys.path.insert(0, %r); from bench.common import import_ember; "
            "import_ember(); import runpy; sys.argv = ['ember'] + sys.argv[1:]; "
            "runpy.run_module('ember', run_name='__main__')" % ROOT)
    run = subprocess.run([sys.executable, "-c", code, "render", "--ray", "local:2"], capture_output=True, text=True,
                         timeout=120, cwd=ROOT)
    assert run.returncode == 1
    assert run.stderr.strip() == "ember: error: --ray needs Ray: python3 dev.py --blender 5.0 setup --ray"
    run = subprocess.run([sys.executable, "-c", code, "render", animation, "--samples", "1", "-o",
                          str(tmp_path / "f.exr")], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert run.returncode == 0 and (tmp_path / "f.exr").exists(), run.stderr


@pytest.mark.parametrize("args, status, message", [
    (["--ray", "local:2", "--samples", "4", "--split-samples", "0"], 2, "--split-samples must be from 1"),
    (["--ray", "local:2", "--samples", "4", "--split-samples", "5"], 2, "is more than the 4 samples"),
    (["--split-samples", "2"], 2, "--split-samples goes with --ray"),
    (["--ray", "nowhere"], 2, "--ray takes auto, HOST:PORT"),
    pytest.param(["--ray", "127.0.0.1:1"], 1, "cannot reach the Ray cluster at 127.0.0.1:1", marks=needs_ray),
])
def test_bad_ray_input_is_one_line(animation, args, status, message):
    run = ember("render", animation, "-o", "/tmp/ember-never-written.exr", *args, timeout=120)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == status and len(lines) == 1 and message in lines[0], run.stderr
    assert not os.path.exists("/tmp/ember-never-written.exr")


@needs_ray
@pytest.mark.small_disk_size("24k")
def test_a_full_disk_keeps_the_earlier_frames(cluster, animation, small_disk):
    """The driver writes the frames (frame_save.save_render_result): on a disk with no room for a frame, the first
    frame to arrive fails in one line saying which frames were lost, and every earlier file stays."""
    old = {f: f"an earlier frame {f}".encode() for f in range(1, 6)}
    for f, data in old.items():
        (small_disk / f"f_{f}.exr").write_bytes(data)
    run = ember("render", animation, "--frames", FRAMES, "--samples", "1", "--resolution", "64x48",
                "-o", str(small_disk / "f_#.exr"), "--ray", cluster, "--workers", "2", "--threads", "1")
    assert run.returncode == 1, run.stderr
    last = run.stderr.strip().splitlines()[-1]
    assert re.fullmatch(r"ember: error: frame \d: cannot save .*/f_\d\.exr: no space left on device .*; the existing "
                        r"file is kept; no frame was saved; frames 1-5 were not", last), last
    assert "Traceback" not in run.stderr and "| saved " not in run.stdout
    assert {f: (small_disk / f"f_{f}.exr").read_bytes() for f in old} == old
    assert sorted(os.listdir(small_disk)) == [f"f_{f}.exr" for f in old]


def _ray_driver_signalled(cluster_address, animation, out, sig):
    """A driver in its own process group (session); `sig` goes to the whole group once a frame is saved, as
    a farm manager (or Ctrl-C in a terminal) sends it."""
    driver = subprocess.Popen(_command("render", animation, "--frames", "1-40", "--samples", STOPPED_SAMPLES,
                                       "-o", str(out / "f_##.exr"), "--ray", cluster_address, "--threads", "1"),
                              cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              start_new_session=True)
    try:
        for line in driver.stdout:
            if "| saved " in line:
                os.killpg(driver.pid, sig)
                break
        _, err = driver.communicate(timeout=120)
    finally:
        driver.kill()
    return driver, err


def _stopped_cleanly(driver, err, sig, out):
    assert driver.returncode == 128 + sig, err
    assert "Traceback" not in err and "received at time" not in err, err   # nor Ray's stack dump
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"ember: interrupted by {signal.Signals(sig).name}: ") and "saved" in last, err
    files = sorted(os.listdir(out))
    assert files and len(files) < 40 and all(re.fullmatch(r"f_\d\d\.exr", f) for f in files), files


@needs_ray
def test_sigterm_to_the_drivers_process_group(cluster, animation, tmp_path):
    """Before: Ray's SIGTERM handler (a stack dump, exit 1) replaced Ember's."""
    driver, err = _ray_driver_signalled(cluster, animation, tmp_path, signal.SIGTERM)
    _stopped_cleanly(driver, err, signal.SIGTERM, tmp_path)


@needs_ray
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_a_signal_to_the_process_group_of_a_local_ray(animation, tmp_path, sig):
    """--ray local:2 starts Ray's processes in the driver's process group: before, the signal ended them
    under the driver, which aborted with Ray's stack dump. Now they ignore it, the driver stops them, and none
    is left behind."""
    import psutil  # Ray's copy
    driver, err = _ray_driver_signalled("local:2", animation, tmp_path, sig)
    _stopped_cleanly(driver, err, sig, tmp_path)
    left = [p for p in psutil.process_iter() if _session(p.pid) == driver.pid]
    assert not left, [p.cmdline() for p in left]


def _session(pid):
    try:
        return os.getsid(pid)
    except OSError:
        return None
