"""Render passes, declared in one place: what Blender's View Layer > Passes toggles ask for, the names and
channels Cycles 5.0 gives them (read from Cycles' own multilayer output: "Object Index", "Diffuse Direct", ...) (so the compositor treats an Ember render as a Cycles one), and the kernel
pass behind each (kernels.passes).

Denoising data (Ember's View Layer > Passes > Denoising Data, as Cycles' "Denoising Data") adds Denoising
Normal, Denoising Albedo and, when the render is denoised, the Noisy Image (and the Noisy Shadow Catcher with
the Shadow Catcher pass).

View Layer > Light Groups adds a "Combined_<name>" pass per group (RGB), as Cycles registers them
(intern/cycles/blender/addon/engine.py list_render_passes); they are never denoised (Cycles' PassMode::NOISY).
"""
from __future__ import annotations

from dataclasses import dataclass

import bpy
from bpy.props import BoolProperty, PointerProperty

from . import cryptomatte
from ..kernels.passes import group_pass


@dataclass(frozen=True)
class Pass:
    toggle: str        # ViewLayer property that turns it on ("" : driven by denoising)
    name: str          # Blender's pass name (Cycles')
    channels: int
    chan_id: str
    kind: str          # 'COLOR', 'VECTOR' or 'VALUE'
    kernel: str        # kernels.passes name, or "" for image passes


DATA_PASSES = (
    Pass("use_pass_z", "Depth", 1, "Z", "VALUE", "depth"),
    Pass("use_pass_position", "Position", 3, "XYZ", "VECTOR", "position"),
    Pass("use_pass_normal", "Normal", 3, "XYZ", "VECTOR", "normal"),
    Pass("use_pass_uv", "UV", 3, "UVA", "VECTOR", "uv"),
    Pass("use_pass_object_index", "Object Index", 1, "X", "VALUE", "object_index"),
    Pass("use_pass_material_index", "Material Index", 1, "X", "VALUE", "material_index"),
    Pass("use_pass_mist", "Mist", 1, "Z", "VALUE", "mist"),
    Pass("use_pass_emit", "Emission", 3, "RGB", "COLOR", "emission"),
    Pass("use_pass_environment", "Environment", 3, "RGB", "COLOR", "environment"),
    Pass("use_pass_ambient_occlusion", "Ambient Occlusion", 3, "RGB", "COLOR", "ao"),
    Pass("ember.use_pass_noise", "Noise", 3, "RGB", "COLOR", "noise"),
    Pass("use_pass_vector", "Vector", 4, "XYZW", "VECTOR", "vector"),
    Pass("use_pass_diffuse_direct", "Diffuse Direct", 3, "RGB", "COLOR", "diffuse_direct"),
    Pass("use_pass_diffuse_indirect", "Diffuse Indirect", 3, "RGB", "COLOR", "diffuse_indirect"),
    Pass("use_pass_diffuse_color", "Diffuse Color", 3, "RGB", "COLOR", "diffuse_color"),
    Pass("use_pass_glossy_direct", "Glossy Direct", 3, "RGB", "COLOR", "glossy_direct"),
    Pass("use_pass_glossy_indirect", "Glossy Indirect", 3, "RGB", "COLOR", "glossy_indirect"),
    Pass("use_pass_glossy_color", "Glossy Color", 3, "RGB", "COLOR", "glossy_color"),
    Pass("use_pass_transmission_direct", "Transmission Direct", 3, "RGB", "COLOR", "transmission_direct"),
    Pass("use_pass_transmission_indirect", "Transmission Indirect", 3, "RGB", "COLOR", "transmission_indirect"),
    Pass("use_pass_transmission_color", "Transmission Color", 3, "RGB", "COLOR", "transmission_color"),
    # A file set up for Cycles' Volume passes (View Layer > Passes with Cycles) gets them from Ember too.
    Pass("ember.use_pass_volume_direct|cycles.use_pass_volume_direct", "Volume Direct", 3, "RGB", "COLOR",
         "volume_direct"),
    Pass("ember.use_pass_volume_indirect|cycles.use_pass_volume_indirect", "Volume Indirect", 3, "RGB", "COLOR",
         "volume_indirect"),
    # On, Combined shows the synthetic objects alone over transparent shadow catchers (no shadows: Cycles' matte)
    # and this pass the factor their shadows and reflections put on the footage (kernels/shadow_catcher.py).
    Pass("ember.use_pass_shadow_catcher|cycles.use_pass_shadow_catcher", "Shadow Catcher", 3, "RGB", "COLOR",
         "shadow_catcher"),
)
DENOISING_ALBEDO = Pass("", "Denoising Albedo", 3, "RGB", "COLOR", "denoising_albedo")
DENOISING_NORMAL = Pass("", "Denoising Normal", 3, "XYZ", "VECTOR", "denoising_normal")
DENOISING_DEPTH = Pass("", "Denoising Depth", 1, "Z", "VALUE", "denoising_depth")
NOISY_IMAGE = Pass("", "Noisy Image", 4, "RGBA", "COLOR", "")
# The Shadow Catcher pass before denoising (Cycles' "Noisy Shadow Catcher", RGB).
NOISY_SHADOW_CATCHER = Pass("", "Noisy Shadow Catcher", 3, "RGB", "COLOR", "shadow_catcher")


def _toggle(view_layer, path: str) -> bool:
    """A pass's toggle (a property path from the view layer; "a|b": either of two, Ember's own and Cycles')."""
    if "|" in path:
        return any(_toggle(view_layer, p) for p in path.split("|"))
    owner = view_layer
    *parents, name = path.split(".")
    for parent in parents:
        owner = getattr(owner, parent, None)
    return bool(getattr(owner, name, False))


def mist_settings(scene) -> tuple:
    """(start, depth, falloff exponent) of the world's Mist Pass panel, as Cycles reads them."""
    world = scene.world
    if world is None:
        return (5.0, 25.0, 2.0)
    mist = world.mist_settings
    return (float(mist.start), float(mist.depth),
            {"QUADRATIC": 2.0, "LINEAR": 1.0, "INVERSE_QUADRATIC": 0.5}.get(mist.falloff, 2.0))


def store_denoising_data(view_layer) -> bool:
    settings = getattr(view_layer, "ember", None)
    return bool(settings is not None and settings.denoising_store_passes)


def crypto_passes(view_layer) -> list[Pass]:
    """The Cryptomatte layers' passes ("CryptoObject00", ...), 4 channels each; kernel "crypto:<kind>:<layer>"."""
    out = []
    for kind in cryptomatte.enabled_kinds(view_layer):
        for i, name in enumerate(cryptomatte.pass_names(kind, cryptomatte.levels(view_layer))):
            out.append(Pass("", name, 4, cryptomatte.CHAN_ID, "COLOR", f"crypto:{kind}:{i}"))
    return out


def _vector_allowed(scene, view_layer) -> bool:
    """Cycles offers the Vector pass only without motion blur."""
    from .export.motion import enabled
    return not enabled(scene, view_layer)


def aov_passes(view_layer) -> list[Pass]:
    """View Layer > Shader AOV: one pass per valid AOV, as Cycles registers them (colour: RGBA, alpha 1)."""
    out = []
    for aov in getattr(view_layer, "aovs", ()):
        if not aov.is_valid:
            continue
        if aov.type == "VALUE":
            out.append(Pass("", aov.name, 1, "X", "VALUE", f"aov:{aov.name}:value"))
        else:
            out.append(Pass("", aov.name, 4, "RGBA", "COLOR", f"aov:{aov.name}:color"))
    return out


def light_group_passes(view_layer) -> list[Pass]:
    """View Layer > Light Groups: one "Combined_<name>" pass per group, in the list's order (the group's number,
    engine/export/light_groups.py)."""
    return [Pass("", f"Combined_{group.name}", 3, "RGB", "COLOR", group_pass(k))
            for k, group in enumerate(getattr(view_layer, "lightgroups", ()))]


def enabled_passes(scene, view_layer) -> list[Pass]:
    """The passes of a view layer besides Combined, in Blender's order."""
    out = [p for p in DATA_PASSES if _toggle(view_layer, p.toggle)
           and (p.kernel != "vector" or _vector_allowed(scene, view_layer))] + crypto_passes(view_layer) + \
        aov_passes(view_layer) + light_group_passes(view_layer)
    if store_denoising_data(view_layer):
        out += [DENOISING_NORMAL, DENOISING_ALBEDO, DENOISING_DEPTH]
        if scene.ember.use_denoising:
            out.append(NOISY_IMAGE)
            if any(p.kernel == "shadow_catcher" for p in out):
                out.append(NOISY_SHADOW_CATCHER)
    return out


# Cycles' own pass toggles (view_layer.cycles) that Ember writes no pass for: (toggle, the panel's name).
UNWRITTEN_CYCLES_PASSES = (("pass_debug_sample_count", "Sample Count"), ("pass_render_time", "Render Time"),
                           ("use_pass_volume_scatter", "Volume Scatter"), ("use_pass_volume_transmit", "Volume Transmit"),
                           ("use_pass_volume_majorant", "Volume Majorant"))


def unwritten_passes_warning(view_layer) -> str | None:
    """One line naming the passes the view layer turns on (Cycles' own toggles) that Ember does not write, or None."""
    settings = getattr(view_layer, "cycles", None)
    names = [name for toggle, name in UNWRITTEN_CYCLES_PASSES if getattr(settings, toggle, False)]
    if not names:
        return None
    return f"View Layer '{view_layer.name}': the {', '.join(names)} pass{'es are' if len(names) > 1 else ' is'} " \
           f"not supported (Cycles' own), not written"


def kernel_passes(scene, view_layer, denoise_inputs: str | None) -> tuple:
    """kernels.passes names to record: the enabled data passes, and what the denoiser reads."""
    names = [p.kernel for p in enabled_passes(scene, view_layer) if p.kernel and not p.kernel.startswith("crypto:")]
    if "vector" in names:
        names.append("vector_weight")
    # Direct and indirect light are read divided by their class's colour: record it too (volumes have none).
    names += [n.split("_")[0] + "_color" for n in names
              if n.endswith(("_direct", "_indirect")) and not n.startswith("volume_")]
    if denoise_inputs in ("RGB_ALBEDO", "RGB_ALBEDO_NORMAL"):
        names.append("denoising_albedo")
    if denoise_inputs == "RGB_ALBEDO_NORMAL":
        names.append("denoising_normal")
    return tuple(dict.fromkeys(names))


def register_passes(engine, scene, view_layer) -> None:
    """RenderEngine.update_render_passes: tell Blender (the compositor, the file output) what Ember writes."""
    engine.register_pass(scene, view_layer, "Combined", 4, "RGBA", "COLOR")
    for p in enabled_passes(scene, view_layer):
        engine.register_pass(scene, view_layer, p.name, p.channels, p.chan_id, p.kind)


class EmberViewLayerSettings(bpy.types.PropertyGroup):
    use_pass_noise: BoolProperty(
        name="Noise", description="The variance of each pixel's mean (Ember's own pass): where the image is "
                                  "still noisy and by how much",
        default=False)
    use_pass_volume_direct: BoolProperty(
        name="Volume Direct", description="Light scattered once in volumes toward the camera: what paths whose "
                                          "first scattering is in a medium find there (Cycles' Volume Direct)",
        default=False)
    use_pass_volume_indirect: BoolProperty(
        name="Volume Indirect", description="The rest of the light of paths whose first scattering is in a "
                                            "medium (Cycles' Volume Indirect)",
        default=False)
    use_pass_shadow_catcher: BoolProperty(
        name="Shadow Catcher", description="The shadows and reflections that objects cast on shadow catchers, as "
                                           "a factor to multiply the footage by; Combined then shows the objects "
                                           "alone, without them (Cycles' Shadow Catcher pass)",
        default=False)
    denoising_store_passes: BoolProperty(
        name="Denoising Data",
        description="Store the denoiser's inputs as passes (Denoising Normal, Denoising Albedo) and the image "
                    "before denoising (Noisy Image), as Cycles' Denoising Data",
        default=False)


def register():
    bpy.utils.register_class(EmberViewLayerSettings)
    bpy.types.ViewLayer.ember = PointerProperty(type=EmberViewLayerSettings, name="Ember")


def unregister():
    del bpy.types.ViewLayer.ember
    bpy.utils.unregister_class(EmberViewLayerSettings)
