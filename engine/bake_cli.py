"""`python -m ember bake`: bake one object of a .blend file into an image file, headless, with Ember.

What Render Properties > Bake does in Blender, from a shell: open the file (engine/batch.py, as `render`
does), give each of the object's materials an Image Texture node holding a new image of the asked size (the
bake's target, made active), select the object (and, for Selected to Active, the objects it takes from) and
run Blender's bake operator with Ember as the engine, then write the image: 8 bits in the image's colour
space for PNG, JPEG and TIFF (sRGB, or the raw values of data passes such as Normal, Position and UV, as
Blender writes a bake into a byte image), 32-bit linear floats for OpenEXR. The file is written as frames are
(engine/frame_save.py: a temporary name, a whole-file check, a rename). The .blend is never saved.

Bad input (an unknown object or bake type, an object that cannot be baked, an unwritable output) gets one
line on stderr and exit status 1 (2 for a malformed command line); what Blender's bake operator refuses (no
UV map, a cage with another topology) is passed on in its words.
"""
from __future__ import annotations

import argparse
import os

import bpy

from . import stop_signals
from .batch import CliError, UsageError, interrupted, open_scene
from .frame_save import SaveError, first_line, save_file
from ..kernels.bake import KINDS

# Blender's bake operator's pass filter names (bpy.ops.object.bake(pass_filter=...)), lower case on the line.
PASS_FILTERS = ("direct", "indirect", "color", "diffuse", "glossy", "transmission", "emit")
# Bake types whose values are data, not colours: written raw (Blender's is_noncolor_pass).
DATA_KINDS = ("POSITION", "NORMAL", "UV")
BAKE_FORMATS = {".png": "PNG", ".exr": "OPEN_EXR", ".tif": "TIFF", ".tiff": "TIFF", ".jpg": "JPEG", ".jpeg": "JPEG"}


def add_parser(sub) -> None:
    bake = sub.add_parser("bake", help="bake an object of a .blend file into an image with Ember",
                          description="Bake OBJECT of FILE.blend (as Render Properties > Bake does) into an image.")
    bake.add_argument("file", help=".blend file")
    bake.add_argument("--type", required=True, type=str.upper, choices=KINDS, metavar="TYPE",
                      help=f"bake type: {', '.join(k.lower() for k in KINDS)}")
    bake.add_argument("--object", help="the object to bake into (default: the file's active object)")
    bake.add_argument("-o", "--output", required=True, help="image path: .png, .exr, .tif or .jpg")
    bake.add_argument("--resolution", default="1024x1024", help="WIDTHxHEIGHT of the image (default 1024x1024)")
    bake.add_argument("--samples", type=int, help="samples per texel (default: the file's Ember samples)")
    bake.add_argument("--max-bounces", type=int, help="bounces after the first hit (0 = direct light only)")
    bake.add_argument("--seed", type=int, help="random seed")
    bake.add_argument("--threads", type=int, help="threads (default or 0: all cores)")
    bake.add_argument("--scene", help="scene name inside the file (default: the active scene)")
    bake.add_argument("--filter", help="comma-separated pass filter for combined, diffuse, glossy and transmission: "
                                       f"{', '.join(PASS_FILTERS)} (default: all)")
    bake.add_argument("--margin", type=int, default=16, help="texels filled around the UV islands (default 16)")
    bake.add_argument("--selected", help="comma-separated objects to bake from onto OBJECT (Selected to Active)")
    bake.add_argument("--cage-extrusion", type=float, default=0.0, help="Selected to Active: how far the rays "
                                                                         "start outside OBJECT")
    bake.add_argument("--max-ray-distance", type=float, default=0.0, help="Selected to Active: how far they reach "
                                                                          "(0: no limit)")
    bake.add_argument("--cage", help="Selected to Active: a cage object to cast the rays from")
    bake.add_argument("--normal-space", choices=("tangent", "object"), default="tangent",
                      help="normal bakes: the space of the normals (default tangent)")
    bake.add_argument("--uv-map", help="the UV map to bake into (default: the active one)")
    bake.add_argument("--denoise", action=argparse.BooleanOptionalAction, default=None,
                      help="denoise combined and shadow bakes, as Cycles does (default: the file's Denoise setting)")
    # What the render options of engine/batch.py read, unused by a bake.
    bake.set_defaults(mode=None, pattern=None, time_limit=None, sample_offset=None)


def check_bake_options(args) -> tuple[str, int, int]:
    """(absolute output path, width, height) of a bake's command line, or UsageError / CliError."""
    size = [part.strip() for part in args.resolution.lower().split("x")]
    if len(size) != 2 or not all(part.isdigit() for part in size):
        raise UsageError(f"--resolution must look like 1024x1024, got {args.resolution!r}")
    width, height = int(size[0]), int(size[1])
    if not (1 <= width <= 65536 and 1 <= height <= 65536):
        raise UsageError(f"--resolution must be from 1x1 to 65536x65536, got {args.resolution}")
    if not 0 <= args.margin <= 64:
        raise UsageError(f"--margin must be from 0 to 64, got {args.margin}")
    if args.cage_extrusion < 0 or args.max_ray_distance < 0:
        raise UsageError("--cage-extrusion and --max-ray-distance must be 0 or more")
    _pass_filter(args.filter)
    output = os.path.abspath(os.path.expanduser(args.output))
    if os.path.splitext(output)[1].lower() not in BAKE_FORMATS:
        raise CliError(f"output {output!r} needs one of the extensions {', '.join(sorted(BAKE_FORMATS))}")
    if not os.path.isfile(args.file):
        raise CliError(f"no such file: {args.file}")
    return output, width, height


def bake_file(args, output: str, width: int, height: int) -> int:
    """Open the file, bake, save the image (the options checked by check_bake_options)."""
    scene = open_scene(argparse.Namespace(**{**vars(args), "resolution": None}), need_camera=False)
    target = _object(scene, args.object)
    sources = [_object(scene, name) for name in (args.selected or "").split(",") if name.strip()]
    file_format = BAKE_FORMATS[os.path.splitext(output)[1].lower()]
    image = _target_image(target, args.type, width, height, file_format == "OPEN_EXR")
    view_layer = bpy.context.view_layer
    for ob in view_layer.objects:
        ob.select_set(False)
    for ob in [target, *sources]:
        ob.select_set(True)
    view_layer.objects.active = target
    options = dict(type=args.type, margin=args.margin, width=width, height=height, target="IMAGE_TEXTURES",
                   save_mode="INTERNAL", use_clear=True, normal_space=args.normal_space.upper(),
                   use_selected_to_active=bool(sources), cage_extrusion=args.cage_extrusion,
                   max_ray_distance=args.max_ray_distance)
    filters = _pass_filter(args.filter)
    if filters is not None:
        options["pass_filter"] = filters
    if args.cage:
        options.update(use_cage=True, cage_object=_object(scene, args.cage).name)
    if args.uv_map:
        options["uv_layer"] = args.uv_map
    try:
        bpy.ops.object.bake(**options)
    except RuntimeError as err:
        raise CliError(f"cannot bake {target.name!r}: {first_line(err)}") from None
    if interrupted():
        print(f"ember: {stop_signals.interrupted_by()} during the bake: nothing saved", flush=True)
        return stop_signals.exit_status()
    try:
        save_file(output, lambda path: _save_image(image, path, file_format), file_format)
    except SaveError as err:
        raise CliError(str(err)) from None
    print(f"Ember | Bake {args.type.lower()} of {target.name} | saved {output}", flush=True)
    return 0


def _pass_filter(text: str | None):
    if text is None:
        return None
    names = [n.strip().lower() for n in text.split(",") if n.strip()]
    unknown = [n for n in names if n not in PASS_FILTERS]
    if unknown or not names:
        raise UsageError(f"--filter: unknown {', '.join(unknown) or 'nothing'}; known: {', '.join(PASS_FILTERS)}")
    return {n.upper() for n in names}


def _object(scene, name: str | None):
    """The scene's object of that name (the active object without one), or CliError."""
    if name is None:
        ob = bpy.context.view_layer.objects.active
        if ob is None:
            raise CliError("the file has no active object: name one with --object")
        return ob
    ob = scene.objects.get(name.strip())
    if ob is None:
        raise CliError(f"no object named {name.strip()!r} in scene {scene.name!r}")
    return ob


def _target_image(ob, kind: str, width: int, height: int, floats: bool):
    """A new image, active in an Image Texture node of each of the object's materials (a new material in an
    empty slot or for an object without any): where Blender's bake operator writes."""
    if ob.type != "MESH":
        raise CliError(f"object {ob.name!r} is a {ob.type.lower()}: Blender bakes into meshes")
    image = bpy.data.images.new(f"Ember bake {ob.name}", width, height, alpha=True, float_buffer=floats)
    if kind in DATA_KINDS:
        image.colorspace_settings.is_data = True
    if not ob.material_slots:
        ob.data.materials.append(None)
    for slot in ob.material_slots:
        if slot.material is None:
            slot.material = bpy.data.materials.new(f"Ember bake {ob.name}")
        tree = slot.material.node_tree
        node = tree.nodes.new("ShaderNodeTexImage")
        node.image = image
        tree.nodes.active = node
    return image


def _save_image(image, path: str, file_format: str) -> None:
    image.filepath_raw = path
    image.file_format = file_format
    if file_format == "OPEN_EXR" and hasattr(image, "use_half_precision"):
        image.use_half_precision = False
    image.save()
