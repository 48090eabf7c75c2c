"""Ember's version, read once from blender_manifest.toml: the manifest is the one place it is written,
and it ships in every package, so a render can say which build made it; and the version of the Blender it
runs in, whose Cycles is the reference where Cycles changed (docs/blender-versions.md)."""
from __future__ import annotations

import os
import tomllib

MANIFEST_PATH = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "blender_manifest.toml")


def _read_version() -> str:
    with open(MANIFEST_PATH, "rb") as f:
        return tomllib.load(f)["version"]


EMBER_VERSION = _read_version()


def blender_version() -> tuple:
    """(major, minor, patch) of the running Blender: export passes it to the kernel functions that follow
    a particular Cycles release."""
    import bpy
    return tuple(bpy.app.version)
