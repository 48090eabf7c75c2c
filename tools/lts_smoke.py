#!/usr/bin/env python3
"""Install-and-render smoke test of the built package in the LTS Blenders: bpy 4.2 and 4.5 (Python 3.11).

    python3 dev.py lts-smoke                      # or: .venv313/bin/python tools/lts_smoke.py [VERSION ...]

For each bpy release: a virtual environment in .venv-lts/bpy-VERSION (made once with Python 3.11, bpy only:
no embreex, so the package's bundled wheel is the only one there is), then tests/extension_install_child.py
in a fresh interpreter with that environment's packages: it installs dist/ember-*-linux_x64.zip with
Blender's own operator into a temporary user-resources directory, renders a diffuse plane under a uniform
sky with the installed Ember (in the render's own process and with a worker process), disables and
uninstalls it. One line per release, and exit 1 if any failed.

Not part of `dev.py test`: each bpy is a download of about 400 MB and an environment of about 1 GB, more
than the suite should pull in on every run. The suite itself runs on Blender 5.0 and 5.3.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
CHILD = os.path.join(ROOT, "tests", "extension_install_child.py")
LTS_RELEASES = ("4.2.23", "4.5.15")   # the newest bpy of each LTS series on PyPI
PYTHON = "3.11"                       # the Python of Blender 4.2 to 5.0
WORLD_COLOR, ALBEDO = (0.2, 0.4, 0.8), 0.8


def environment(version: str) -> str:
    """The release's environment (created once); returns its site-packages directory."""
    from dev import find_python, site_packages
    venv = os.path.join(ROOT, ".venv-lts", f"bpy-{version}")
    python = os.path.join(venv, "Scripts" if os.name == "nt" else "bin", "python")
    if not os.path.exists(python):
        base = find_python(PYTHON)
        if base is None:
            raise RuntimeError(f"no Python {PYTHON} here (bpy {version} is built for it)")
        subprocess.run([base, "-m", "venv", venv], check=True)
    if subprocess.run([python, "-c", f"import importlib.metadata as m; assert m.version('bpy') == '{version}'"],
                      capture_output=True).returncode != 0:
        print(f"lts_smoke: installing bpy {version} (about 400 MB)", flush=True)
        subprocess.run([python, "-m", "pip", "install", "--disable-pip-version-check", "-q", f"bpy=={version}"],
                       check=True)
    return site_packages(python), python


def smoke(version: str, package: str) -> tuple[bool, str]:
    """Install the package into bpy `version`, render, uninstall: (passed, one line)."""
    site, python = environment(version)
    if os.path.exists(os.path.join(site, "embreex")):
        return False, f"bpy {version}: its environment has an embreex of its own; the bundled one must be used"
    with tempfile.TemporaryDirectory(prefix="ember-lts-") as tmp:
        work = os.path.join(tmp, "work")
        os.makedirs(work)
        env = {k: v for k, v in os.environ.items() if not k.startswith(("BLENDER_USER_", "BLENDER_SYSTEM_"))}
        env["BLENDER_USER_RESOURCES"] = os.path.join(tmp, "resources")
        done = subprocess.run([python, "-I", "-S", CHILD, site, package, work], cwd=tmp, env=env,
                              capture_output=True, text=True, timeout=900)
    lines = [line for line in done.stdout.splitlines() if line.startswith("RESULT:")]
    if done.returncode != 0 or not lines:
        tail = (done.stdout + done.stderr).strip().splitlines()[-12:]
        return False, f"bpy {version}: the install or render failed:\n    " + "\n    ".join(tail)
    result = json.loads(lines[-1].removeprefix("RESULT:"))
    problems = check(result)
    if problems:
        return False, f"bpy {version}: " + "; ".join(problems)
    sky = ", ".join(f"{c:.3f}" for c in result["sky_rgb"])
    return True, (f"bpy {version}: installed, rendered with the bundled embreex ({os.path.basename(os.path.dirname(result['embreex_file']))}), "
                  f"sky ({sky}), worker image equal, uninstalled")


def check(result: dict) -> list[str]:
    """What the render and the install left, against what they must be (as tests/test_extension.py)."""
    problems = []
    close = lambda a, b, rel: all(abs(x - y) <= rel * abs(y) for x, y in zip(a, b))   # noqa: E731
    if not result.get("enabled"):
        problems.append("not enabled after the install")
    if ".local" not in result.get("embreex_file", ""):
        problems.append(f"embreex not from the bundled wheel: {result.get('embreex_file')}")
    if not (result.get("finite") and result.get("shape") == [24, 32, 4]):
        problems.append(f"image not finite or of shape {result.get('shape')}")
    if not close(result.get("sky_rgb", ()), WORLD_COLOR, 1e-4):
        problems.append(f"sky {result.get('sky_rgb')} != {WORLD_COLOR}")
    if not close(result.get("plane_rgb", ()), [ALBEDO * c for c in WORLD_COLOR], 0.05):
        problems.append(f"plane {result.get('plane_rgb')} not albedo x sky")
    if not result.get("worker_image_equal"):
        problems.append("the worker process rendered another image")
    if result.get("package_dir_after_uninstall") or result.get("wheel_files_after_uninstall"):
        problems.append("files left after the uninstall")
    return problems


def main(argv: list[str]) -> int:
    from tools.build_extension import build
    versions = argv or list(LTS_RELEASES)
    package = build(quiet=True)["linux-x64"]
    failed = 0
    for version in versions:
        try:
            passed, line = smoke(version, package)
        except (RuntimeError, subprocess.SubprocessError) as error:
            passed, line = False, f"bpy {version}: {error}"
        failed += not passed
        print(f"lts_smoke: {'passed' if passed else 'FAILED'}: {line}", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    if not (sys.platform.startswith("linux") and shutil.which("uname")):
        sys.exit("lts_smoke: installs the linux-x64 package: run it on Linux x86-64")
    sys.exit(main(sys.argv[1:]))
