#!/usr/bin/env python3.11
"""Set up Ember's development environment and run it: one command per task, on any platform.

    python3.11 dev.py demo [render options]   # .venv + pinned deps, then render the demo to out/demo.png
    python3.11 dev.py test [pytest options]   # .venv + pinned deps, then run the test suite
    python3.11 dev.py bench                   # .venv + pinned deps, then run the benchmarks
    python3.11 dev.py package                 # .venv + pinned deps, then build the extension zips into dist/
    python3.11 dev.py setup [--ray]           # only the environment (--ray: with Ray, for render --ray)

The environment is a virtual environment in .venv with the versions pinned in requirements*.txt
(requirements-ray.txt only with `setup --ray` and for `test`, whose Ray tests need it),
and a .pth hook that makes this checkout importable as the package `ember` (so `python -m ember`
works from anywhere, without copying files or needing symlinks).
"""
from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import venv

ROOT = os.path.dirname(os.path.abspath(__file__))
VENV = os.path.join(ROOT, ".venv")
REQUIREMENTS = os.path.join(ROOT, "requirements-test.txt")
RAY_REQUIREMENTS = os.path.join(ROOT, "requirements-ray.txt")  # optional: python -m ember render --ray


def venv_python() -> str:
    if os.name == "nt":
        return os.path.join(VENV, "Scripts", "python.exe")
    return os.path.join(VENV, "bin", "python")


def run(*cmd: str) -> None:
    subprocess.run(cmd, check=True)


def requirements_digest(*names: str) -> str:
    h = hashlib.sha256()
    for name in names:
        with open(os.path.join(ROOT, name), "rb") as f:
            h.update(f.read())
    return h.hexdigest()


def site_packages(python: str) -> str:
    return subprocess.run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          check=True, capture_output=True, text=True).stdout.strip()


def install(python: str, what: str, requirements: str, stamp: str, *names: str) -> None:
    """pip install -r `requirements` unless the stamp says these files were installed as they are."""
    stamp = os.path.join(VENV, stamp)
    digest = requirements_digest(*names)
    if not os.path.exists(stamp) or open(stamp).read() != digest:
        print(f"dev.py: installing {what}", flush=True)
        run(python, "-m", "pip", "install", "--disable-pip-version-check", "-q", "-r", requirements)
        with open(stamp, "w") as f:
            f.write(digest)


def setup(ray: bool = False) -> str:
    if sys.version_info[:2] != (3, 11):
        sys.exit(f"dev.py: Ember needs Python 3.11 (bpy 5.0 is built for it); this is {sys.version.split()[0]}")
    if not os.path.exists(venv_python()):
        print("dev.py: creating .venv", flush=True)
        venv.create(VENV, with_pip=True)
    python = venv_python()
    install(python, "pinned dependencies (bpy is a large download the first time)", REQUIREMENTS,
            ".ember-requirements", "requirements.txt", "requirements-test.txt")
    if ray:
        install(python, "Ray (requirements-ray.txt)", RAY_REQUIREMENTS, ".ember-requirements-ray",
                "requirements.txt", "requirements-ray.txt")
    hook = os.path.join(site_packages(python), "ember_checkout.pth")
    # A .pth line that starts with "import" runs at start-up: register this checkout as `ember`.
    line = ("import importlib.util as _u, sys as _s; "
            f"_p = {ROOT!r}; "
            "_spec = _u.spec_from_file_location('ember', _p + '/__init__.py', submodule_search_locations=[_p]); "
            "_m = _u.module_from_spec(_spec); _s.modules.setdefault('ember', _m); "
            "_s.modules['ember'] is _m and _spec.loader.exec_module(_m)\n")
    if not os.path.exists(hook) or open(hook).read() != line:
        with open(hook, "w") as f:
            f.write(line)
    return python


def main(argv: list[str]) -> int:
    task, rest = (argv[0], argv[1:]) if argv else ("help", [])
    if task not in ("setup", "demo", "test", "bench", "package"):
        print(__doc__)
        return 0 if task in ("help", "-h", "--help") else 2
    # The tests include the Ray cluster's; the demo and the rest run without Ray.
    python = setup(ray=task == "test" or (task == "setup" and "--ray" in rest))
    if task == "demo":
        return subprocess.call([python, "-m", "ember", "render", "-o", os.path.join(ROOT, "out", "demo.png"), *rest])
    if task == "test":
        return subprocess.call([python, "-m", "pytest", os.path.join(ROOT, "tests"), *rest], cwd=ROOT)
    if task == "package":
        return subprocess.call([python, os.path.join(ROOT, "tools", "build_extension.py"), *rest], cwd=ROOT)
    if task == "bench":
        status = 0
        for script in ("kernel_cornell.py", "vs_cycles.py"):
            path = os.path.join(ROOT, "bench", script)
            if os.path.exists(path):
                status |= subprocess.call([python, path, *rest], cwd=ROOT)
        return status
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
