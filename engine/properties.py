"""scene.ember: Ember's render settings, stored in the .blend like Cycles' scene.cycles."""
from __future__ import annotations

import bpy
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, PointerProperty

SAMPLING_MODE_ITEMS = (
    ("NEE_MIS", "Next-Event + MIS", "Production: a shadow ray toward a sampled light at every bounce, combined with "
                                    "BSDF sampling by multiple importance sampling; Russian roulette"),
    ("COSINE", "Cosine", "Cosine-weighted hemisphere sampling of the diffuse BSDF: finds light only by hitting it "
                         "(point, spot and sharp sun lights, which no ray can hit, stay dark)"),
    ("LECTURE", "Lecture", "The lecture's estimator: uniform in (theta, phi), weight pi^2 sin(theta). "
                           "For teaching and as a reference; noisier"),
)
DEFAULT_SAMPLING_MODE = "NEE_MIS"
PIXEL_FILTER_ITEMS = (
    ("BOX", "Box", "Box filter: every sample counts only inside its pixel (one pixel wide, whatever the width)"),
    ("GAUSSIAN", "Gaussian", "Gaussian filter"),
    ("BLACKMAN_HARRIS", "Blackman-Harris", "Blackman-Harris filter, Cycles' default"),
)


class EmberSceneSettings(bpy.types.PropertyGroup):
    samples: IntProperty(
        name="Samples", description="Samples per pixel for final renders", default=64, min=1, max=1 << 24,
        soft_max=4096)
    preview_samples: IntProperty(
        name="Viewport Samples", description="Samples per pixel in the viewport's rendered mode (0 = unlimited)",
        default=32, min=0, max=1 << 24, soft_max=4096)
    max_bounces: IntProperty(
        name="Total", description="Bounces after the first hit, as in Cycles: 0 gives direct light only",
        default=12, min=0, max=1024)
    diffuse_bounces: IntProperty(
        name="Diffuse", description="Diffuse reflections a path may make, as Cycles' Diffuse bounces: past them "
                                    "it takes only the light of what it meets next",
        default=4, min=0, max=1024)
    glossy_bounces: IntProperty(
        name="Glossy", description="Glossy and mirror reflections a path may make, as Cycles' Glossy bounces",
        default=4, min=0, max=1024)
    transmission_bounces: IntProperty(
        name="Transmission", description="Passages through surfaces (refraction, translucency) a path may make, "
                                         "as Cycles' Transmission bounces",
        default=12, min=0, max=1024)
    volume_bounces: IntProperty(
        name="Volume", description="Scattering events in volumes a path may take after its first, as Cycles' "
                                   "Volume bounces (0: single scattering in volumes)",
        default=0, min=0, max=1024)
    volume_biased: BoolProperty(
        name="Biased",
        description="Ray-march volumes that vary, in steps of their own size (as Cycles' Biased option): less noise "
                    "per sample, at the cost of some bias that shrinks with the steps. Off: null scattering, "
                    "unbiased (Cycles' default)",
        default=False)
    volume_step_rate: FloatProperty(
        name="Step Rate Render",
        description="Scale the biased ray marcher's steps in final renders (each volume's own step: its voxel size, "
                    "or a tenth of its object's size, times its material's Step Rate), as Cycles' Step Rate: "
                    "higher is faster and coarser",
        default=1.0, min=0.01, max=100.0, soft_min=0.1)
    volume_preview_step_rate: FloatProperty(
        name="Viewport",
        description="The same for the viewport's rendered mode",
        default=1.0, min=0.01, max=100.0, soft_min=0.1)
    volume_max_steps: IntProperty(
        name="Max Steps",
        description="Most steps the biased ray marcher takes through a volume: longer segments take longer steps "
                    "(as Cycles' Max Steps)",
        default=1024, min=2, max=65536)
    transparent_max_bounces: IntProperty(
        name="Transparent Bounces",
        description="Transparent surfaces (alpha, Transparent BSDF) a path may pass straight through, as in "
                    "Cycles; they do not count as bounces",
        default=8, min=0, max=1024)
    sample_clamp_direct: FloatProperty(
        name="Clamp Direct",
        description="Scale down samples of light reaching the first hit or the camera whose summed RGB exceeds "
                    "this (0 = off), as Cycles' Clamp Direct: less noise from rare bright paths, at some bias",
        default=0.0, min=0.0)
    sample_clamp_indirect: FloatProperty(
        name="Clamp Indirect",
        description="The same for light after more bounces (0 = off). Cycles' default, 10, keeps fireflies of "
                    "caustics and small bright reflections down, at some bias",
        default=10.0, min=0.0)
    blur_glossy: FloatProperty(
        name="Filter Glossy",
        description="Blur glossy reflections after blurry bounces, as Cycles' Filter Glossy (0 = off): fewer "
                    "fireflies from caustics, at some loss of sharpness in what reflections show",
        default=1.0, min=0.0, soft_max=10.0)
    caustics_reflective: BoolProperty(
        name="Reflective Caustics",
        description="Light reaching diffuse surfaces through glossy reflections, as Cycles' Reflective Caustics: "
                    "off, rays leaving a diffuse surface find no glossy reflection, which removes such caustics "
                    "and their noise, at the cost of that light",
        default=True)
    caustics_refractive: BoolProperty(
        name="Refractive Caustics",
        description="Light reaching diffuse surfaces through refraction (glass), as Cycles' Refractive Caustics: "
                    "off, rays leaving a diffuse surface find no refraction, which removes such caustics and "
                    "their noise, at the cost of that light",
        default=True)
    sampling_mode: EnumProperty(
        name="Sampling", description="How the next direction of a path is chosen",
        items=SAMPLING_MODE_ITEMS, default=DEFAULT_SAMPLING_MODE)
    use_adaptive_sampling: BoolProperty(
        name="Noise Threshold",
        description="Stop sampling pixels whose noise is under the threshold, as Cycles' adaptive sampling "
                    "(on by default there too)",
        default=True)
    adaptive_threshold: FloatProperty(
        name="Noise Threshold", description="Noise level at which a pixel stops taking samples (Cycles' "
                                            "default 0.01; lower is cleaner and slower)",
        default=0.01, min=0.0001, max=1.0, precision=4, step=0.1)
    adaptive_min_samples: IntProperty(
        name="Min Samples", description="Samples every pixel takes before it may stop (0 = automatic, as "
                                        "Cycles: 64 at threshold 0.01)",
        default=0, min=0, max=4096)
    pixel_filter_type: EnumProperty(
        name="Pixel Filter", description="Pixel filter type, as Cycles' (importance-sampled: each sample counts "
                                         "in one pixel with weight 1)",
        items=PIXEL_FILTER_ITEMS, default="BLACKMAN_HARRIS")
    filter_width: FloatProperty(
        name="Width", description="Pixel filter width, in pixels (Cycles' default 1.5)",
        default=1.5, min=0.01, max=10.0, soft_max=3.0, subtype="PIXEL")
    use_denoising: BoolProperty(
        name="Denoise", description="Denoise the final render with OpenImageDenoise (the library Blender ships), "
                                    "as Cycles does by default",
        default=True)
    use_preview_denoising: BoolProperty(
        name="Denoise Viewport", description="Denoise the viewport's previews (off by default, as in Cycles)",
        default=False)
    denoising_input_passes: EnumProperty(
        name="Passes", description="Passes the denoiser reads besides the noisy image",
        items=(("RGB", "None", "The noisy image alone"),
               ("RGB_ALBEDO", "Albedo", "The image and the albedo of what the camera sees"),
               ("RGB_ALBEDO_NORMAL", "Albedo and Normal", "The image, albedo and normal (Cycles' default)")),
        default="RGB_ALBEDO_NORMAL")
    denoising_prefilter: EnumProperty(
        name="Prefilter", description="How the albedo and normal passes are cleaned before denoising",
        items=(("NONE", "None", "No prefiltering: for albedo and normal passes without noise"),
               ("FAST", "Fast", "Denoise the image and its albedo and normal passes together (least extra time)"),
               ("ACCURATE", "Accurate", "Denoise the albedo and normal passes first, then the image (Cycles' "
                                        "default; more time)")),
        default="ACCURATE")
    denoising_quality: EnumProperty(
        name="Quality", description="OpenImageDenoise's quality: higher is slower",
        items=(("HIGH", "High", ""), ("BALANCED", "Balanced", ""), ("FAST", "Fast", "")),
        default="HIGH")
    sample_offset: IntProperty(
        name="Sample Offset", description="Skip this many samples of each pixel's sequence: render a range of "
                                          "the samples (Cycles' Sample Offset), to merge ranges rendered on "
                                          "several machines (python -m ember merge; ranges rendered with the "
                                          "Sobol-Burley pattern merge into exactly the whole)",
        default=0, min=0, max=1 << 24)
    sampling_pattern: EnumProperty(
        name="Pattern", description="How the first bounce's random numbers are laid out over the pixels "
                                    "(Cycles' Sampling Pattern)",
        items=(("AUTOMATIC", "Automatic",
                "One Owen-scrambled Sobol sequence shared by the pixels, so that neighbouring pixels' noise is "
                "blue noise, which denoises best (Cycles' default for final renders); a sequence per pixel "
                "where the layout does not fit (sample ranges, unlimited samples)"),
               ("SOBOL_BURLEY", "Sobol-Burley",
                "An Owen-scrambled Sobol sequence of each pixel's own: sample ranges rendered apart then merge "
                "into exactly the whole")),
        default="AUTOMATIC")
    seed: IntProperty(
        name="Seed", description="Seed of the random numbers: another seed gives another noise pattern",
        default=0, min=0)
    use_animated_seed: BoolProperty(
        name="Animated Seed", description="Add the frame number to the seed, so the noise changes every frame",
        default=False)
    time_limit: FloatProperty(
        name="Time Limit", description="Stop a final render after this long, whatever the samples (0 = no limit)",
        default=0.0, min=0.0, subtype="TIME_ABSOLUTE", unit="TIME_ABSOLUTE")


def register():
    bpy.utils.register_class(EmberSceneSettings)
    bpy.types.Scene.ember = PointerProperty(type=EmberSceneSettings, name="Ember", description="Ember render settings")


def unregister():
    del bpy.types.Scene.ember
    bpy.utils.unregister_class(EmberSceneSettings)
