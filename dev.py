#!/usr/bin/env python3
"""Set up Ember's development environments and run them: one command per task, on any platform.

    python3 dev.py test [pytest options]   # the test suite on every tested Blender (5.3, then 5.0)
    python3 dev.py demo [render options]   # render the demo to out/demo.png with the newest Blender
    python3 dev.py bench                   # the benchmarks, newest Blender
    python3 dev.py package                 # build the extension zips into dist/
    python3 dev.py setup [--ray]           # only the environments (--ray: Ray too, for render --ray)
    python3 dev.py lts-smoke               # install the built package into bpy 4.2 and 4.5 LTS and render

Options before the task's own: `--blender 5.0` or `--blender 5.3` picks one Blender (default: test and
setup use all of them, the others the newest this machine can run); `--require-all` (test) fails when a
Blender's Python is missing here instead of skipping that suite.

Each Blender has its own virtual environment, built with the Python that Blender embeds, pinned by its own
requirement files: bpy 5.3.0 on Python 3.13 in .venv313 (requirements-blender5.3.txt, NumPy 2), bpy 5.0.1
on Python 3.11 in .venv (requirements.txt, NumPy 1.26). A .pth hook makes this checkout importable there as
the package `ember`. The Python of each is found on PATH (python3.13, python3.11), in pyenv's versions, or
in $EMBER_PYTHON3_13 / $EMBER_PYTHON3_11. Where one is missing, the command says so on one line and runs
the rest; the summary never counts a suite it did not run as passed.
"""
from __future__ import annotations

import glob
import hashlib
import os
import shutil
import subprocess
import sys
from dataclasses import dataclass

ROOT = os.path.dirname(os.path.abspath(__file__))


@dataclass(frozen=True)
class Target:
    """One tested Blender: the bpy release, the Python it is built for, its environment and pins."""
    blender: str
    bpy: str
    python: str
    venv: str
    requirements: str        # runtime pins
    test_requirements: str   # runtime + pytest
    ray: bool                # Ray 2.40 (requirements-ray.txt) is published for this Python

    @property
    def label(self) -> str:
        return f"Blender {self.blender} (bpy {self.bpy}, Python {self.python})"


# Newest first: the demo, the benchmarks and the package use the first one this machine can run.
TARGETS = (
    Target("5.3", "5.3.0", "3.13", ".venv313", "requirements-blender5.3.txt",
           "requirements-test-blender5.3.txt", ray=False),
    Target("5.0", "5.0.1", "3.11", ".venv", "requirements.txt", "requirements-test.txt", ray=True),
)
RAY_REQUIREMENTS = "requirements-ray.txt"   # optional: python -m ember render --ray (Python 3.11)
LTS_SMOKE = os.path.join("tools", "lts_smoke.py")


def find_python(version: str) -> str | None:
    """An interpreter of this exact minor version: $EMBER_PYTHON3_13, PATH, then pyenv's versions."""
    override = os.environ.get("EMBER_PYTHON" + version.replace(".", "_"))
    candidates = [override] if override else []
    candidates.append(shutil.which(f"python{version}"))
    pyenv = os.environ.get("PYENV_ROOT", os.path.expanduser("~/.pyenv"))
    candidates += sorted(glob.glob(os.path.join(pyenv, "versions", f"{version}.*", "bin", f"python{version}")),
                         reverse=True)
    for path in candidates:
        if path and os.path.exists(path) and python_version(path) == version:
            return path
    return None


def python_version(python: str) -> str | None:
    try:
        done = subprocess.run([python, "-c", "import sys; print('%d.%d' % sys.version_info[:2])"],
                              capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return done.stdout.strip() if done.returncode == 0 else None


def venv_python(target: Target) -> str:
    if os.name == "nt":
        return os.path.join(ROOT, target.venv, "Scripts", "python.exe")
    return os.path.join(ROOT, target.venv, "bin", "python")


def requirements_digest(*names: str) -> str:
    h = hashlib.sha256()
    for name in names:
        with open(os.path.join(ROOT, name), "rb") as f:
            h.update(f.read())
    return h.hexdigest()


def site_packages(python: str) -> str:
    return subprocess.run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          check=True, capture_output=True, text=True).stdout.strip()


def install(target: Target, what: str, requirements: str, stamp: str, *names: str) -> None:
    """pip install -r `requirements` unless the stamp says these files were installed as they are."""
    stamp = os.path.join(ROOT, target.venv, stamp)
    digest = requirements_digest(*names)
    if not os.path.exists(stamp) or open(stamp).read() != digest:
        print(f"dev.py: {target.label}: installing {what}", flush=True)
        subprocess.run([venv_python(target), "-m", "pip", "install", "--disable-pip-version-check", "-q",
                        "-r", os.path.join(ROOT, requirements)], check=True)
        with open(stamp, "w") as f:
            f.write(digest)


def install_checkout_hook(python: str) -> None:
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


def setup(target: Target, base_python: str, ray: bool = False, tests: bool = False) -> str:
    """Create (once) and update the target's environment; return its interpreter."""
    python = venv_python(target)
    if not os.path.exists(python) or python_version(python) != target.python:
        print(f"dev.py: {target.label}: creating {target.venv}", flush=True)
        subprocess.run([base_python, "-m", "venv", "--clear", os.path.join(ROOT, target.venv)], check=True)
    requirements = target.test_requirements if tests else target.requirements
    install(target, "pinned dependencies (bpy is a large download the first time)", requirements,
            ".ember-requirements-test" if tests else ".ember-requirements", *pin_files(requirements))
    if ray and target.ray:
        install(target, f"Ray ({RAY_REQUIREMENTS})", RAY_REQUIREMENTS, ".ember-requirements-ray",
                *pin_files(RAY_REQUIREMENTS))
    install_checkout_hook(python)
    return python


def pin_files(name: str) -> list[str]:
    """A requirement file and the ones it includes with -r, recursively."""
    names = [name]
    with open(os.path.join(ROOT, name)) as f:
        for line in f:
            if line.startswith("-r "):
                names += pin_files(line.split(None, 1)[1].strip())
    return names


def available(targets) -> list[tuple[Target, str]]:
    """(target, base interpreter) for the targets whose Python is here; one line for each that is not."""
    found = []
    for target in targets:
        base = find_python(target.python)
        if base is None:
            print(f"dev.py: no Python {target.python} on this machine: {target.label} is NOT set up or run "
                  f"(install Python {target.python}, or set EMBER_PYTHON{target.python.replace('.', '_')})",
                  flush=True)
        else:
            found.append((target, base))
    return found


def parse(argv: list[str]):
    """(task, chosen targets, require_all, the task's own arguments)."""
    targets, require_all, rest = list(TARGETS), False, []
    i = 0
    while i < len(argv):
        if argv[i] == "--blender" and i + 1 < len(argv):
            chosen = [t for t in TARGETS if t.blender == argv[i + 1]]
            if not chosen:
                sys.exit(f"dev.py: --blender {argv[i + 1]}: tested versions are "
                         f"{', '.join(t.blender for t in TARGETS)}")
            targets, i = chosen, i + 2
        elif argv[i] == "--require-all":
            require_all, i = True, i + 1
        else:
            rest.append(argv[i])
            i += 1
    task = rest.pop(0) if rest else "help"
    return task, targets, require_all, rest


def parallel(pytest_args) -> list[str]:
    """pytest-xdist options: one test process per usable core (at most 4: each holds a Blender), unless the
    arguments choose (-n, --numprocesses, -p no:xdist). A render test keeps one core busy for most of its
    time (NumPy between Embree's queries), so two processes on two cores take about 0.8x the time of one."""
    if any(a in ("-n", "--numprocesses", "no:xdist") or a.startswith(("-n=", "--numprocesses=")) for a in pytest_args):
        return []
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return ["-n", str(max(1, min(cores, 4))), "--dist", "load"]


def run_tests(found, pytest_args, missing: list[Target]) -> int:
    results = []
    for target, base in found:
        python = setup(target, base, ray=True, tests=True)
        print(f"dev.py: {target.label}: running the test suite", flush=True)
        code = subprocess.call([python, "-m", "pytest", os.path.join(ROOT, "tests"), *parallel(pytest_args), *pytest_args],
                               cwd=ROOT)
        results.append((target, code))
    print("dev.py: summary", flush=True)
    for target, code in results:
        verdict = "passed" if code == 0 else f"FAILED (pytest exit {code})"
        print(f"dev.py:   {target.label}: {verdict}", flush=True)
    for target in missing:
        print(f"dev.py:   {target.label}: NOT RUN (no Python {target.python} here)", flush=True)
    return 0 if results and all(code == 0 for _, code in results) else 1


def main(argv: list[str]) -> int:
    task, targets, require_all, rest = parse(argv)
    if task not in ("setup", "demo", "test", "bench", "package", "lts-smoke"):
        print(__doc__)
        return 0 if task in ("help", "-h", "--help") else 2
    found = available(targets)
    missing = [t for t in targets if t not in {f[0] for f in found}]
    if not found:
        print("dev.py: none of the tested Blenders' Pythons is here: nothing was run", flush=True)
        return 1
    if task == "test":
        status = run_tests(found, rest, missing)
        return 1 if require_all and missing else status
    if task == "setup":
        for target, base in found:
            setup(target, base, ray="--ray" in rest)
        return 1 if require_all and missing else 0
    target, base = found[0]       # the newest Blender this machine can run
    python = setup(target, base)
    print(f"dev.py: using {target.label}", flush=True)
    if task == "demo":
        return subprocess.call([python, "-m", "ember", "render", "-o", os.path.join(ROOT, "out", "demo.png"), *rest])
    if task == "package":
        return subprocess.call([python, os.path.join(ROOT, "tools", "build_extension.py"), *rest], cwd=ROOT)
    if task == "lts-smoke":
        return subprocess.call([python, os.path.join(ROOT, LTS_SMOKE), *rest], cwd=ROOT)
    status = 0
    for script in ("kernel_cornell.py", "vs_cycles.py"):
        path = os.path.join(ROOT, "bench", script)
        if os.path.exists(path):
            status |= subprocess.call([python, path, *rest], cwd=ROOT)
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
