"""Cryptomatte as Blender sees it: the pass names Cycles registers, the names that are hashed, and the
render metadata (the manifest) Blender's compositor reads to pick mattes by name.

Facts kept here (Blender 5.0: Cycles' blender/addon/engine.py list_render_passes, blender/session.cpp
stamp_view_layer_metadata, blender/object.cpp; blenkernel/intern/cryptomatte.cc):
- passes "CryptoObject00", "CryptoObject01", ... (Material, Asset likewise), one per 2 levels, 4 channels
  "rgba" (lowercase, so that OpenEXR's DWA compression keeps them lossless), kind COLOR;
- the Cryptomatte layer "<view layer>.CryptoObject" names the metadata: "cryptomatte/<key>/name|hash|
  conversion|manifest", key = the first 7 hex digits of the layer name's MurmurHash3;
- object ids hash the object's name (an instance: the instanced object's), material ids the material's,
  asset ids the name of the object's top-most parent (itself without a parent).

No bpy here: the functions read view layers and objects through their attributes only.
"""
from __future__ import annotations

from ..kernels.cryptomatte import DEFAULT_LEVELS, hash_name_u32, layer_count

KINDS = ("object", "material", "asset")           # Blender's use_pass_cryptomatte_<kind>, in Cycles' order
_TYPE_NAME = {"object": "CryptoObject", "material": "CryptoMaterial", "asset": "CryptoAsset"}
CHAN_ID = "rgba"
HASH = "MurmurHash3_32"
CONVERSION = "uint32_to_float32"


def enabled_kinds(view_layer) -> tuple:
    """The kinds whose Cryptomatte toggle is on, in Cycles' pass order."""
    return tuple(k for k in KINDS if getattr(view_layer, f"use_pass_cryptomatte_{k}", False))


def levels(view_layer) -> int:
    """The view layer's Cryptomatte Levels (ids kept per pixel)."""
    return int(getattr(view_layer, "pass_cryptomatte_depth", DEFAULT_LEVELS))


def pass_names(kind: str, depth: int = DEFAULT_LEVELS) -> list[str]:
    """What RenderEngine.register_pass gets: "CryptoObject00", "CryptoObject01", ..."""
    return [f"{_TYPE_NAME[kind]}{i:02d}" for i in range(layer_count(depth))]


def layer_name(view_layer_name: str, kind: str) -> str:
    """The Cryptomatte layer: "ViewLayer.CryptoObject" (the metadata's name, the compositor's Layer)."""
    return f"{view_layer_name}.{_TYPE_NAME[kind]}"


def layer_names(view_layer_name: str, kind: str, depth: int = DEFAULT_LEVELS) -> list[str]:
    """The passes as the render result and a multilayer EXR name them: "ViewLayer.CryptoObject00", ..."""
    return [f"{view_layer_name}.{name}" for name in pass_names(kind, depth)]


def asset_name(obj) -> str:
    """The asset an object belongs to: its top-most parent's name, its own without a parent."""
    while obj.parent is not None:
        obj = obj.parent
    return obj.name


def _quoted(name: str) -> str:
    # As Blender's own manifest writer (std::quoted): only the quote and the backslash are escaped. Cycles
    # escapes nothing, which breaks the JSON of a name holding a quote.
    return '"' + name.replace("\\", "\\\\").replace('"', '\\"') + '"'


def manifest(names) -> str:
    """JSON {name: 8 hex digits of its uint32 hash}, names in first-seen order, each once, compact as
    Cycles writes it: {"Cube":"a8fce865","Plane":"..."}."""
    entries = (f'{_quoted(n)}:"{hash_name_u32(n):08x}"' for n in dict.fromkeys(names))
    return "{" + ",".join(entries) + "}"


def metadata_prefix(layer: str) -> str:
    """"cryptomatte/<key>/" of a Cryptomatte layer name; key: the first 7 of the 8 hex digits of its hash."""
    key = f"{hash_name_u32(layer):08x}"[:7]
    return f"cryptomatte/{key}/"


def metadata(view_layer_name: str, kind: str, names) -> dict[str, str]:
    """The render metadata Cycles stamps for one kind (RenderResult.stamp_data_add_field(key, value))."""
    layer = layer_name(view_layer_name, kind)
    prefix = metadata_prefix(layer)
    return {prefix + "name": layer, prefix + "hash": HASH, prefix + "conversion": CONVERSION,
            prefix + "manifest": manifest(names)}
