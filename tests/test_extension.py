"""Ember as a Blender extension: the manifest, the version it shows, and the built package installed,
rendering and removed the way a user's Blender does it."""
from __future__ import annotations

import importlib.util
import json
import os
import platform
import subprocess
import sys
import tomllib
import zipfile

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BUILD_SCRIPT = os.path.join(ROOT, "tools", "build_extension.py")
CHILD_SCRIPT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "extension_install_child.py")


def manifest() -> dict:
    with open(os.path.join(ROOT, "blender_manifest.toml"), "rb") as f:
        return tomllib.load(f)


def test_version_shown_is_the_manifests():
    from ember.engine.ui import EMBER_RENDER_PT_sampling
    from ember.engine.version import EMBER_VERSION
    assert EMBER_VERSION == manifest()["version"]
    assert hasattr(EMBER_RENDER_PT_sampling, "draw_header_preset")


def test_manifest_bundles_embreex_for_every_platform_and_never_numpy():
    data = manifest()
    wheels = [os.path.basename(w) for w in data["wheels"]]
    assert len(wheels) == 2 * len(data["platforms"]) and all(w.startswith("embreex-") for w in wheels)
    # Blender 4.2 to 5.0 run Python 3.11, 5.1 and later 3.13: each platform bundles both.
    assert sum("-cp311-cp311-" in w for w in wheels) == sum("-cp313-cp313-" in w for w in wheels) == len(
        data["platforms"])
    assert not any("numpy" in w for w in wheels), "Blender ships numpy"
    # The range is the tested one: 4.2 LTS up to 5.3 (the maximum is exclusive).
    assert (data["blender_version_min"], data["blender_version_max"]) == ("4.2.0", "5.4.0")


@pytest.fixture(scope="module")
def linux_package() -> str:
    """Build every platform's zip into dist/ (about a second once wheels/ holds the wheels; downloads
    them from PyPI the first time) and return the Linux one."""
    done = subprocess.run([sys.executable, BUILD_SCRIPT], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    data = manifest()
    path = os.path.join(ROOT, "dist", f"{data['id']}-{data['version']}-linux_x64.zip")
    assert os.path.exists(path), done.stdout
    return path


def test_package_holds_the_add_on_and_no_development_files(linux_package):
    with zipfile.ZipFile(linux_package) as z:
        names = z.namelist()
    for required in ("__init__.py", "blender_manifest.toml", "engine/version.py", "kernels/integrator.py",
                     "kernels/bsdf/data/microfacet_tables.npz", "kernels/bsdf/data/sheen_ltc.npz"):
        assert required in names
    top = {n.split("/")[0] for n in names}
    development = {"tests", "bench", "tools", "docs", ".ci", ".git", ".venv", ".pytest_cache", "out", "dist",
                   "dev.py", "requirements.txt", "requirements-test.txt", ".gitignore"}
    assert not top & development, top & development
    assert not [n for n in names if "__pycache__" in n or n.endswith(".pyc")]
    assert [n for n in names if n.startswith("wheels/")] == [
        w.removeprefix("./") for w in manifest()["wheels"] if "manylinux" in w]


def site_without_embreex(directory: str) -> str:
    """A directory of symbolic links to everything in the site-packages that holds bpy, except embreex
    (and .pth hooks such as the one that makes this checkout importable as `ember`)."""
    site_packages = os.path.dirname(os.path.dirname(importlib.util.find_spec("bpy").origin))
    os.makedirs(directory)
    for name in os.listdir(site_packages):
        if not name.lower().startswith("embreex") and not name.endswith(".pth"):
            os.symlink(os.path.join(site_packages, name), os.path.join(directory, name))
    return directory


@pytest.mark.skipif(not (sys.platform.startswith("linux") and platform.machine() in ("x86_64", "AMD64")),
                    reason="installs the linux-x64 package")
def test_installed_package_renders_with_its_bundled_embreex(linux_package, tmp_path):
    """Install the built zip into a fresh Blender user-resources directory with Blender's own operator,
    render with the installed Ember, then disable and uninstall it.

    The install runs in a child interpreter (tests/extension_install_child.py) started with `-I -S`:
    no site-packages, no .pth hooks, no PYTHONPATH. Its only extra sys.path entry is a directory of
    links to the virtual environment's packages without embreex, so bpy and numpy import as usual but
    embreex can come only from the wheel the package bundles (Blender appends the wheels'
    site-packages to sys.path; with the venv's embreex visible that copy would win). The child checks
    embreex is not importable before the install, and reports the file embreex was imported from.
    """
    resources = tmp_path / "resources"
    work = tmp_path / "work"
    work.mkdir()
    site = site_without_embreex(str(tmp_path / "site"))
    env = {k: v for k, v in os.environ.items() if not k.startswith(("BLENDER_USER_", "BLENDER_SYSTEM_"))}
    env["BLENDER_USER_RESOURCES"] = str(resources)
    done = subprocess.run([sys.executable, "-I", "-S", CHILD_SCRIPT, site, linux_package, str(work)],
                          cwd=str(tmp_path), env=env, capture_output=True, text=True, timeout=300)
    lines = [line for line in done.stdout.splitlines() if line.startswith("RESULT:")]
    assert done.returncode == 0 and lines, done.stdout + done.stderr
    result = json.loads(lines[-1].removeprefix("RESULT:"))
    extensions = os.path.join(str(resources), "extensions")

    assert result["embreex_visible_before_install"] is False, "the child must not see the venv's embreex"
    assert result["enabled"]
    assert result["embreex_file"].startswith(os.path.join(extensions, ".local", "lib")), result["embreex_file"]
    assert result["ember_file"] == os.path.join(extensions, "user_default", "ember", "__init__.py")
    assert result["checkout_ember_loaded"] is False
    assert result["version"] == manifest()["version"]

    # Sky rows see the world colour exactly; plane rows albedo x world (a diffuse plane under a
    # uniform sky), within the noise of 8 samples.
    assert result["finite"] and result["shape"] == [24, 32, 4]
    world, albedo = (0.2, 0.4, 0.8), 0.8
    assert result["sky_rgb"] == pytest.approx(world, rel=1e-4)
    assert result["plane_rgb"] == pytest.approx([albedo * c for c in world], rel=0.05)

    # Worker processes of the installed package: they rendered waves (the finish line), the image is the
    # same, and after the render the worker waited in the pool.
    pids = result["worker_pids"]
    assert result["worker_image_equal"] and len(pids) == 2 and pids[0] == pids[1], \
        done.stdout[-1500:] + done.stderr[-3000:]
    assert "1 worker process" in done.stdout, done.stdout[-1000:] + done.stderr[-2000:]

    assert result["package_dir_existed"]
    assert result["disabled"] and not result["engine_after_disable"] and not result["settings_after_disable"]
    assert not result["package_dir_after_uninstall"]
    assert result["wheel_files_after_uninstall"] == [], "the bundled wheel must go with the package"


FARM_CHILD = os.path.join(os.path.dirname(os.path.abspath(__file__)), "farm_worker_child.py")


@pytest.mark.skipif(not (sys.platform.startswith("linux") and platform.machine() in ("x86_64", "AMD64")),
                    reason="installs the linux-x64 package")
def test_farm_worker_renders_with_the_installed_extension_and_factory_startup_drops_it(linux_package, tmp_path):
    """A render farm's worker (docs/install.md, Render farms): Ember installed once into the worker's user
    resources; then, each in a fresh process, a worker that loads the preferences as `blender -b scene.blend
    -E EMBER -f 1` does renders frame 1 to the .blend's output path with Ember, and one started like
    `--factory-startup` has no Ember (the trap the farm notes warn about): -E EMBER is refused."""
    site = site_without_embreex(str(tmp_path / "site"))
    env = {k: v for k, v in os.environ.items() if not k.startswith(("BLENDER_USER_", "BLENDER_SYSTEM_"))}
    env["BLENDER_USER_RESOURCES"] = str(tmp_path / "resources")

    def child(mode, *extra):
        done = subprocess.run([sys.executable, "-I", "-S", FARM_CHILD, site, mode, str(tmp_path), *extra],
                              cwd=str(tmp_path), env=env, capture_output=True, text=True, timeout=300)
        lines = [line for line in done.stdout.splitlines() if line.startswith("RESULT:")]
        assert done.returncode == 0 and lines, done.stdout + done.stderr
        return dict(json.loads(lines[-1].removeprefix("RESULT:")), log=done.stdout[-2000:] + done.stderr[-2000:])

    assert child("install", linux_package)["enabled"]
    worker = child("worker")
    assert worker["ember_enabled"] and worker["engine"] == "EMBER" and worker["written"], worker["log"]
    assert worker["sky_rgb"] == pytest.approx((0.2, 0.4, 0.8), rel=1e-4)
    factory = child("factory")
    assert not factory["ember_enabled"] and factory["engine"] is None and "EMBER" in factory["error"]
