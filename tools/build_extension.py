#!/usr/bin/env python3
"""Build Ember's Blender extension packages: one zip per platform in dist/, embreex bundled.

    .venv313/bin/python tools/build_extension.py         # or: python3 dev.py package
    .venv/bin/python tools/build_extension.py --update-manifest   # after changing the embreex pin

Steps:
1. Download the embreex wheels of every platform in the manifest into ./wheels/ (not in git), one per
   Python that the supported Blenders embed (cp311: Blender 4.2 to 5.0; cp313: 5.1 and later; Blender
   installs the one for its own Python), with `pip download --only-binary=:all: --no-deps
   --python-version X.Y --platform TAG`. A wheel already there is not downloaded again, so a second build
   works offline.
2. Check that the manifest's `wheels` list names exactly those files. The list is pinned in git (the
   version is pinned in requirements.txt), so the manifest in git is the one that is built and validated;
   --update-manifest rewrites the list from the downloaded files instead of failing.
3. `blender_ext.py validate` the source, `build --split-platforms` into dist/, then `validate` every zip
   and check that no development file went into it. blender_ext.py is Blender's own extension tool; it
   ships inside the bpy package and runs with plain Python (bpy is located, not imported).

numpy is never bundled: Blender ships its own.
"""
from __future__ import annotations

import argparse
import fnmatch
import glob
import importlib.util
import os
import re
import subprocess
import sys
import tomllib
import zipfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MANIFEST = os.path.join(ROOT, "blender_manifest.toml")
WHEELS = os.path.join(ROOT, "wheels")
DIST = os.path.join(ROOT, "dist")
# The Pythons of the Blenders the manifest accepts: 3.11 (Blender 4.2 to 5.0) and 3.13 (5.1 to 5.3).
PYTHON_VERSIONS = ("3.11", "3.13")

# Blender platform -> the pip platform tag to download for, and the wheel file name pattern it gives.
# macOS wheels of embreex 4.4 need macOS 13 or newer; Linux ones glibc 2.28 (manylinux_2_28).
PLATFORMS = {
    "linux-x64": ("manylinux_2_28_x86_64", "*-manylinux*_x86_64.whl"),
    "windows-x64": ("win_amd64", "*-win_amd64.whl"),
    "macos-arm64": ("macosx_13_0_arm64", "*-macosx_*_arm64.whl"),
    "macos-x64": ("macosx_13_0_x86_64", "*-macosx_*_x86_64.whl"),
}

# Paths that must never be in a package: development files, whatever the manifest's exclude list says.
FORBIDDEN_PREFIXES = ("tests/", "bench/", "tools/", "docs/", "out/", "dist/", ".ci/", ".venv/", ".git/",
                      ".pytest_cache/")
FORBIDDEN_NAMES = ("dev.py", ".gitignore")
FORBIDDEN_PATTERNS = ("*/__pycache__/*", "__pycache__/*", "*.pyc", "requirements*.txt", "*numpy*")


def embreex_version() -> str:
    """The embreex pin of requirements.txt: the wheels bundled are the version the tests run."""
    with open(os.path.join(ROOT, "requirements.txt")) as f:
        match = re.search(r"^embreex==(\S+)", f.read(), re.MULTILINE)
    if match is None:
        sys.exit("build_extension: no embreex==VERSION pin in requirements.txt")
    return match.group(1)


def load_manifest() -> dict:
    with open(MANIFEST, "rb") as f:
        return tomllib.load(f)


def blender_ext_path() -> str:
    """blender_ext.py inside the installed bpy package (found without importing bpy)."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        sys.exit("build_extension: bpy is not installed; run with a development environment's python "
                 "(python3 dev.py setup)")
    for location in spec.submodule_search_locations:
        found = sorted(glob.glob(os.path.join(location, "*", "scripts", "addons_core", "bl_pkg", "cli",
                                              "blender_ext.py")))
        if found:
            return found[-1]
    sys.exit("build_extension: blender_ext.py not found inside the bpy package")


def wheel_for(platform: str, version: str, python: str) -> str | None:
    """The downloaded embreex wheel for a Blender platform and a Python ("3.13"), or None."""
    tag = "cp" + python.replace(".", "")
    pattern = f"embreex-{version}-{tag}-{tag}{PLATFORMS[platform][1]}"
    names = sorted(n for n in os.listdir(WHEELS) if fnmatch.fnmatch(n, pattern))
    if len(names) > 1:
        sys.exit(f"build_extension: several {tag} wheels in wheels/ for {platform}: {names}; remove the stale ones")
    return names[0] if names else None


def download_wheels(platforms: list[str], version: str) -> dict[str, list[str]]:
    """Download (unless present) one wheel per platform and Python; return {platform: the manifest's
    relative paths of its wheels}."""
    os.makedirs(WHEELS, exist_ok=True)
    paths = {}
    for platform in platforms:
        if platform not in PLATFORMS:
            sys.exit(f"build_extension: no wheel source known for platform {platform!r}; add it to PLATFORMS")
        paths[platform] = []
        for python in PYTHON_VERSIONS:
            if wheel_for(platform, version, python) is None:
                print(f"build_extension: downloading embreex {version} for {platform}, Python {python}", flush=True)
                subprocess.run([sys.executable, "-m", "pip", "download", f"embreex=={version}",
                                "--only-binary=:all:", "--no-deps", "--python-version", python,
                                "--platform", PLATFORMS[platform][0], "-d", WHEELS,
                                "--disable-pip-version-check", "-q"], check=True)
            name = wheel_for(platform, version, python)
            if name is None:
                sys.exit(f"build_extension: pip downloaded no Python {python} wheel for {platform}")
            paths[platform].append(f"./wheels/{name}")
    return paths


def check_manifest_wheels(wheels: list[str], update: bool) -> None:
    listed = load_manifest().get("wheels", [])
    if listed == wheels:
        return
    block = "wheels = [\n" + "".join(f'  "{w}",\n' for w in wheels) + "]"
    if not update:
        sys.exit("build_extension: blender_manifest.toml lists other wheels than the ones downloaded:\n"
                 f"  listed:     {listed}\n  downloaded: {wheels}\n"
                 "Run with --update-manifest (after changing the embreex pin), or put this in the manifest:\n"
                 + block)
    with open(MANIFEST) as f:
        text = f.read()
    text, count = re.subn(r"^wheels = \[.*?^\]", lambda _: block, text, flags=re.MULTILINE | re.DOTALL)
    if count != 1:
        sys.exit("build_extension: cannot find the `wheels = [...]` block in blender_manifest.toml")
    with open(MANIFEST, "w") as f:
        f.write(text)
    print("build_extension: updated the wheels list in blender_manifest.toml", flush=True)


def blender_ext(*args: str) -> None:
    if subprocess.run([sys.executable, blender_ext_path(), *args]).returncode != 0:
        sys.exit(f"build_extension: blender_ext.py {args[0]} failed (its message is above)")


def forbidden(name: str) -> bool:
    return (name.startswith(FORBIDDEN_PREFIXES) or name in FORBIDDEN_NAMES
            or any(fnmatch.fnmatch(name, p) for p in FORBIDDEN_PATTERNS)
            or (name.startswith("wheels/") and not fnmatch.fnmatch(name, "wheels/embreex-*.whl")))


def check_package(path: str, expected_wheels: list[str]) -> list[str]:
    """The zip's file names, after checking it holds the add-on, exactly the expected wheels and no
    development file."""
    with zipfile.ZipFile(path) as z:
        names = z.namelist()
    bad = [n for n in names if forbidden(n)]
    if bad:
        sys.exit(f"build_extension: development files in {os.path.basename(path)}: {bad}")
    wheels = sorted(n for n in names if n.startswith("wheels/"))
    if wheels != sorted(w.removeprefix("./") for w in expected_wheels):
        sys.exit(f"build_extension: {os.path.basename(path)} bundles {wheels}, expected {expected_wheels}")
    for required in ("__init__.py", "blender_manifest.toml", "engine/render_engine.py", "kernels/integrator.py",
                     "kernels/bsdf/data/microfacet_tables.npz", "kernels/bsdf/data/sheen_ltc.npz",
                     "kernels/bsdf/data/thin_film_cmf.npz", "kernels/shading/data/hosek_xyz.npz"):
        if required not in names:
            sys.exit(f"build_extension: {required} missing from {os.path.basename(path)}")
    return names


def package_path(manifest: dict, platform: str) -> str:
    """Where `build --split-platforms` writes a platform's zip."""
    return os.path.join(DIST, f"{manifest['id']}-{manifest['version']}-{platform.replace('-', '_')}.zip")


def build(update_manifest: bool = False, quiet: bool = False) -> dict[str, str]:
    """Download, check, build and validate; return {platform: zip path}."""
    version = embreex_version()
    platforms = list(load_manifest().get("platforms", []))
    if not platforms:
        sys.exit("build_extension: blender_manifest.toml declares no platforms")
    wheels = download_wheels(platforms, version)
    check_manifest_wheels([w for platform in platforms for w in wheels[platform]], update_manifest)
    manifest = load_manifest()
    blender_ext("validate", ROOT)
    os.makedirs(DIST, exist_ok=True)
    blender_ext("build", "--source-dir", ROOT, "--output-dir", DIST, "--split-platforms")
    packages = {}
    for platform in platforms:
        path = package_path(manifest, platform)
        blender_ext("validate", path)
        names = check_package(path, wheels[platform])
        packages[platform] = path
        if not quiet:
            print(f"build_extension: {os.path.relpath(path, ROOT)}: {os.path.getsize(path) / 1e6:.1f} MB, "
                  f"{len(names)} files, bundles {', '.join(os.path.basename(w) for w in wheels[platform])}",
                  flush=True)
    return packages


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--update-manifest", action="store_true",
                        help="rewrite the manifest's wheels list from the downloaded wheels")
    args = parser.parse_args(argv)
    build(update_manifest=args.update_manifest)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
