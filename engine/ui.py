"""Ember's panels, and the built-in panels Ember reuses (COMPAT_ENGINES)."""
from __future__ import annotations

import bpy

from .version import EMBER_VERSION

ENGINE = "EMBER"

# Panels written for EEVEE that show exactly what Ember reads: material and world node surfaces,
# the material slots, and light settings. Generic panels (they list BLENDER_RENDER) are added too.
EXTRA_PANELS = (
    "EEVEE_MATERIAL_PT_context_material",
    "EEVEE_MATERIAL_PT_surface",
    "EEVEE_WORLD_PT_surface",
    "DATA_PT_EEVEE_light",
    "DATA_PT_spot",
    "DATA_PT_camera_dof",
    "DATA_PT_camera_dof_aperture",
    "CYCLES_OBJECT_PT_motion_blur",   # per object: Motion Blur on/off, Steps (object.cycles, read by Ember)
    # Render Properties > Bake: Blender's bake settings and Cycles' bake type, which Ember bakes (engine/bake.py).
    "CYCLES_RENDER_PT_bake",
    "CYCLES_RENDER_PT_bake_influence",
    "CYCLES_RENDER_PT_bake_selected_to_active",
    "CYCLES_RENDER_PT_bake_output",
    "CYCLES_RENDER_PT_bake_output_margin",
    "CYCLES_RENDER_PT_curves",        # Render > Curves: Shape, Subdivisions (scene.cycles_curves, read by Ember)
    "CYCLES_OBJECT_PT_lightgroup",    # Object > Shading > Light Group (Object.lightgroup, read by Ember)
    "CYCLES_WORLD_PT_settings",       # World > Settings, the Light Group's parent
    "CYCLES_WORLD_PT_settings_light_group",   # World.lightgroup, read by Ember
    "CYCLES_WORLD_PT_settings_surface",   # World > Settings > Surface: sampling, Map Resolution, Max Bounces
    "CYCLES_WORLD_PT_ray_visibility",     # World > Settings > Ray Visibility (world.cycles_visibility)
    "CYCLES_RENDER_PT_subdivision",   # scene.cycles: dicing rates, Max Subdivisions, dicing camera (adaptive)
)
_added: list = []


def _compat_panels():
    for name in dir(bpy.types):
        cls = getattr(bpy.types, name, None)
        engines = getattr(cls, "COMPAT_ENGINES", None)
        if isinstance(cls, type) and isinstance(engines, set) and issubclass(cls, bpy.types.Panel):
            if "BLENDER_RENDER" in engines or name in EXTRA_PANELS:
                yield cls


def split_layout(layout, decorate: bool | None = False):
    """A panel's layout with each property's label beside it (use_property_split), and no keyframe decorators
    unless `decorate` (None: Blender's default left alone)."""
    layout.use_property_split = True
    if decorate is not None:
        layout.use_property_decorate = decorate
    return layout


class EmberPanel:
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"
    COMPAT_ENGINES = {ENGINE}

    @classmethod
    def poll(cls, context):
        return context.engine in cls.COMPAT_ENGINES and cls.shows(context)

    @classmethod
    def shows(cls, context) -> bool:
        """What the panel needs besides Ember as the engine (the data it draws); a render panel needs nothing."""
        return True


class EMBER_RENDER_PT_sampling(EmberPanel, bpy.types.Panel):
    bl_label = "Sampling"

    def draw_header_preset(self, context):
        # The build that renders, so a user can tell which one made a frame.
        self.layout.label(text=f"Ember {EMBER_VERSION}")

    def draw(self, context):
        layout = split_layout(self.layout)
        ember = context.scene.ember
        col = layout.column(align=True)
        col.prop(ember, "samples", text="Render Samples")
        col.prop(ember, "preview_samples", text="Viewport Samples")
        row = layout.row(heading="Noise Threshold")
        row.prop(ember, "use_adaptive_sampling", text="")
        sub = row.row()
        sub.active = ember.use_adaptive_sampling
        sub.prop(ember, "adaptive_threshold", text="")
        sub = layout.row()
        sub.active = ember.use_adaptive_sampling
        sub.prop(ember, "adaptive_min_samples")
        layout.prop(ember, "time_limit")
        layout.prop(ember, "sampling_mode")
        col = layout.column(align=True)
        col.prop(ember, "seed")
        col.prop(ember, "sample_offset")
        col.prop(ember, "use_animated_seed")
        layout.prop(ember, "sampling_pattern")
        cycles = getattr(context.scene, "cycles", None)
        if cycles is not None:   # Cycles' own settings, read as Cycles reads them (export/lights.uses_light_tree,
            layout.prop(cycles, "use_light_tree")   # session.light_threshold)
            sub = layout.row()
            sub.active = not cycles.use_light_tree   # Cycles applies the threshold only without the tree
            sub.prop(cycles, "light_sampling_threshold", text="Light Threshold")


class EMBER_RENDER_PT_light_paths(EmberPanel, bpy.types.Panel):
    bl_label = "Light Paths"

    def draw(self, context):
        layout = split_layout(self.layout)
        col = layout.column(heading="Max Bounces", align=True)
        col.prop(context.scene.ember, "max_bounces")
        col.prop(context.scene.ember, "diffuse_bounces")
        col.prop(context.scene.ember, "glossy_bounces")
        col.prop(context.scene.ember, "transmission_bounces")
        col.prop(context.scene.ember, "volume_bounces")
        col.prop(context.scene.ember, "transparent_max_bounces", text="Transparent")
        col = layout.column(align=True)
        col.prop(context.scene.ember, "sample_clamp_direct")
        col.prop(context.scene.ember, "sample_clamp_indirect")
        col = layout.column(heading="Caustics", align=True)
        col.prop(context.scene.ember, "blur_glossy")
        col.prop(context.scene.ember, "caustics_reflective", text="Reflective")
        col.prop(context.scene.ember, "caustics_refractive", text="Refractive")
        cycles = getattr(context.scene, "cycles", None)
        if cycles is not None:   # Cycles' own settings, read as Cycles reads them (export/world.py fast_gi)
            col = layout.column(heading="Fast GI", align=True)
            col.prop(cycles, "use_fast_gi", text="Approximation")
            sub = col.column(align=True)
            sub.active = cycles.use_fast_gi
            sub.prop(cycles, "fast_gi_method", text="Method")
            sub.prop(cycles, "ao_bounces", text="Viewport Bounces")
            sub.prop(cycles, "ao_bounces_render", text="Render Bounces")
            world = context.scene.world
            if world is not None:   # the world's AO settings, as Cycles' Fast GI panel shows them
                sub.prop(world.light_settings, "ao_factor", text="AO Factor")
                sub.prop(world.light_settings, "distance", text="AO Distance")


class EMBER_RENDER_PT_simplify_culling(EmberPanel, bpy.types.Panel):
    """Render > Simplify > Culling: Cycles' own scene settings, which Ember reads (export/culling.py); each object's
    switches are in Cycles' Object > Visibility > Culling panel."""
    bl_label = "Culling"
    bl_parent_id = "RENDER_PT_simplify"
    bl_options = {"DEFAULT_CLOSED"}

    @classmethod
    def shows(cls, context):
        return hasattr(context.scene, "cycles")

    def draw(self, context):
        layout = split_layout(self.layout)
        layout.active = context.scene.render.use_simplify
        cycles = context.scene.cycles
        col = layout.column(heading="Camera Culling", align=True)
        col.prop(cycles, "use_camera_cull", text="")
        col.prop(cycles, "camera_cull_margin", text="Margin")
        col = layout.column(heading="Distance Culling", align=True)
        col.prop(cycles, "use_distance_cull", text="")
        col.prop(cycles, "distance_cull_margin", text="Distance")


class EMBER_RENDER_PT_volumes(EmberPanel, bpy.types.Panel):
    bl_label = "Volumes"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = split_layout(self.layout)
        ember = context.scene.ember
        layout.prop(ember, "volume_biased")
        col = layout.column(align=True)
        col.active = ember.volume_biased
        col.prop(ember, "volume_step_rate")
        col.prop(ember, "volume_preview_step_rate")
        col.prop(ember, "volume_max_steps")


class VolumeSettingsPanel(EmberPanel):
    """Settings > Volume of the material or world that bl_context names: Cycles' settings of its medium."""
    bl_label = "Volume"
    bl_options = {"DEFAULT_CLOSED"}

    @classmethod
    def shows(cls, context):
        block = getattr(context, cls.bl_context, None)
        return block is not None and hasattr(block, "cycles")


class EMBER_MATERIAL_PT_volume(VolumeSettingsPanel, bpy.types.Panel):
    """Material > Settings > Volume: Cycles' settings of the material's medium, which Ember reads."""
    bl_context = "material"

    def draw(self, context):
        layout = split_layout(self.layout)
        settings = context.material.cycles
        layout.prop(settings, "volume_interpolation", text="Interpolation")
        layout.prop(settings, "volume_step_rate", text="Step Rate")


class EMBER_WORLD_PT_volume(VolumeSettingsPanel, bpy.types.Panel):
    """World > Settings > Volume: Cycles' step size of the world's medium, which Ember reads."""
    bl_context = "world"

    def draw(self, context):
        layout = split_layout(self.layout)
        layout.prop(context.world.cycles, "volume_step_size", text="Step Size")


class EMBER_RENDER_PT_film(EmberPanel, bpy.types.Panel):
    bl_label = "Film"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = split_layout(self.layout)
        cycles = getattr(context.scene, "cycles", None)
        if cycles is not None:   # Cycles' own setting, read as Cycles reads it (session.film_exposure)
            layout.prop(cycles, "film_exposure", text="Exposure")
        layout.prop(context.scene.render, "film_transparent", text="Transparent")
        if cycles is not None:   # Cycles' own settings, read as Cycles reads them (session.transparent_glass)
            sub = layout.column()
            sub.active = context.scene.render.film_transparent
            sub.prop(cycles, "film_transparent_glass", text="Transparent Glass")
            row = sub.row()
            row.active = context.scene.render.film_transparent and cycles.film_transparent_glass
            row.prop(cycles, "film_transparent_roughness", text="Roughness Threshold")
        col = layout.column()
        col.prop(context.scene.ember, "pixel_filter_type", text="Pixel Filter")
        sub = col.column()
        sub.active = context.scene.ember.pixel_filter_type != "BOX"
        sub.prop(context.scene.ember, "filter_width", text="Width")


class EMBER_RENDER_PT_motion_blur(EmberPanel, bpy.types.Panel):
    """Blender's own motion blur settings, as Cycles shows them (engine/export/motion.py reads them)."""
    bl_label = "Motion Blur"
    bl_options = {"DEFAULT_CLOSED"}

    def draw_header(self, context):
        self.layout.prop(context.scene.render, "use_motion_blur", text="")

    def draw(self, context):
        layout = split_layout(self.layout)
        rd = context.scene.render
        layout.active = rd.use_motion_blur
        col = layout.column()
        col.prop(rd, "motion_blur_position", text="Position")
        col.prop(rd, "motion_blur_shutter")
        cycles = getattr(context.scene, "cycles", None)
        if cycles is not None:  # Cycles' own setting, which Ember reads as Cycles does
            col = layout.column()
            col.prop(cycles, "rolling_shutter_type", text="Rolling Shutter")
            sub = col.column()
            sub.active = cycles.rolling_shutter_type != "NONE"
            sub.prop(cycles, "rolling_shutter_duration")
        layout.template_curve_mapping(rd, "motion_blur_shutter_curve")


class EMBER_RENDER_PT_denoise(EmberPanel, bpy.types.Panel):
    bl_label = "Denoise"
    bl_parent_id = "EMBER_RENDER_PT_sampling"

    def draw(self, context):
        layout = split_layout(self.layout)
        ember = context.scene.ember
        col = layout.column(heading="Render")
        col.prop(ember, "use_denoising", text="Denoise")
        col.prop(ember, "use_preview_denoising", text="Viewport")
        sub = layout.column()
        sub.active = ember.use_denoising or ember.use_preview_denoising
        sub.prop(ember, "denoising_input_passes")
        sub.prop(ember, "denoising_prefilter")
        sub.prop(ember, "denoising_quality")


class EMBER_VIEWLAYER_PT_passes(EmberPanel, bpy.types.Panel):
    """View Layer > Passes: the passes Ember writes, with Blender's own toggles (Cycles' names)."""
    bl_label = "Passes"
    bl_context = "view_layer"

    def draw(self, context):
        layout = split_layout(self.layout)
        view_layer = context.view_layer
        col = layout.column(heading="Include")
        col.prop(view_layer, "use_pass_combined")
        col.prop(view_layer, "use_pass_z")
        col.prop(view_layer, "use_pass_position")
        col.prop(view_layer, "use_pass_normal")
        col.prop(view_layer, "use_pass_uv")
        col.prop(view_layer, "use_pass_object_index")
        col.prop(view_layer, "use_pass_material_index")
        col.prop(view_layer, "use_pass_mist")
        col.prop(view_layer.ember, "use_pass_noise")
        col.prop(view_layer.ember, "denoising_store_passes", text="Denoising Data")
        col = layout.column(heading="Light")
        for kind in ("diffuse", "glossy", "transmission"):
            row = col.row(heading=kind.title(), align=True)
            row.prop(view_layer, f"use_pass_{kind}_direct", text="Direct", toggle=True)
            row.prop(view_layer, f"use_pass_{kind}_indirect", text="Indirect", toggle=True)
            row.prop(view_layer, f"use_pass_{kind}_color", text="Color", toggle=True)
        row = col.row(heading="Volume", align=True)
        row.prop(view_layer.ember, "use_pass_volume_direct", text="Direct", toggle=True)
        row.prop(view_layer.ember, "use_pass_volume_indirect", text="Indirect", toggle=True)
        col.prop(view_layer, "use_pass_emit", text="Emission")
        col.prop(view_layer, "use_pass_environment")
        col.prop(view_layer, "use_pass_ambient_occlusion", text="Ambient Occlusion")
        col.prop(view_layer.ember, "use_pass_shadow_catcher")
        col = layout.column(heading="Cryptomatte")
        col.prop(view_layer, "use_pass_cryptomatte_object", text="Object")
        col.prop(view_layer, "use_pass_cryptomatte_material", text="Material")
        col.prop(view_layer, "use_pass_cryptomatte_asset", text="Asset")
        col.prop(view_layer, "pass_cryptomatte_depth", text="Levels")
        layout.label(text="Shader AOV")
        row = layout.row()
        row.template_list("UI_UL_list", "aovs", view_layer, "aovs", view_layer, "active_aov_index", rows=2)
        col = row.column(align=True)
        col.operator("scene.view_layer_add_aov", icon="ADD", text="")
        col.operator("scene.view_layer_remove_aov", icon="REMOVE", text="")
        aov = view_layer.active_aov
        if aov is not None:
            layout.prop(aov, "name")
            layout.prop(aov, "type", expand=True)


class EMBER_VIEWLAYER_PT_passes_lightgroups(EmberPanel, bpy.types.Panel):
    """View Layer > Passes > Light Groups: the view layer's list, as Cycles shows it (a Combined_<name> pass
    each; emitters join one in Object > Shading > Light Group and World > Settings > Light Group)."""
    bl_label = "Light Groups"
    bl_context = "view_layer"
    bl_parent_id = "EMBER_VIEWLAYER_PT_passes"

    def draw(self, context):
        view_layer = context.view_layer
        row = self.layout.row()
        row.template_list("UI_UL_list", "lightgroups", view_layer, "lightgroups", view_layer,
                          "active_lightgroup_index", rows=3)
        col = row.column(align=True)
        col.operator("scene.view_layer_add_lightgroup", icon="ADD", text="")
        col.operator("scene.view_layer_remove_lightgroup", icon="REMOVE", text="")
        if hasattr(bpy.types, "VIEWLAYER_MT_lightgroup_sync"):   # add the groups objects name, drop unused ones
            col.separator()
            col.menu("VIEWLAYER_MT_lightgroup_sync", icon="DOWNARROW_HLT", text="")


class EMBER_RENDER_PT_performance(EmberPanel, bpy.types.Panel):
    bl_label = "Performance"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = split_layout(self.layout)
        rd = context.scene.render
        col = layout.column(align=True)
        col.prop(rd, "threads_mode")
        sub = col.column(align=True)
        sub.enabled = rd.threads_mode == "FIXED"
        sub.prop(rd, "threads")
        # Cycles' Final Render option: frames of an animation reuse the scene built for the frame before.
        layout.prop(rd, "use_persistent_data", text="Persistent Data")


class EMBER_LIGHT_PT_shadow(EmberPanel, bpy.types.Panel):
    """Light > Cast Shadow, which Ember renders (EEVEE's shadow panel holds settings Ember does not read)."""
    bl_label = "Shadow"
    bl_context = "data"

    @classmethod
    def shows(cls, context):
        return context.light is not None

    def draw(self, context):
        layout = split_layout(self.layout)
        layout.prop(context.light, "use_shadow", text="Cast Shadow")


class EMBER_LIGHT_PT_settings(EmberPanel, bpy.types.Panel):
    """A light's Max Bounces and Multiple Importance, Cycles' own settings (light.cycles), which Ember renders."""
    bl_label = "Settings"
    bl_context = "data"

    @classmethod
    def shows(cls, context):
        return context.light is not None and hasattr(context.light, "cycles")

    def draw(self, context):
        layout = split_layout(self.layout)
        layout.prop(context.light.cycles, "max_bounces")
        layout.prop(context.light.cycles, "use_multiple_importance_sampling", text="Multiple Importance")


class EMBER_LIGHT_PT_beam_shape(EmberPanel, bpy.types.Panel):
    """Light > Beam Shape > Spread of an area light, which Ember renders (Cycles shows it in its own Beam Shape
    panel; EEVEE's panels do not show it)."""
    bl_label = "Beam Shape"
    bl_context = "data"

    @classmethod
    def shows(cls, context):
        return context.light is not None and context.light.type == "AREA"

    def draw(self, context):
        layout = split_layout(self.layout, decorate=None)
        layout.prop(context.light, "spread", text="Spread")


class VisibilityPanel(EmberPanel):
    """A panel under Object > Visibility, for the objects Cycles' Visibility panel shows it for."""
    bl_context = "object"
    bl_parent_id = "OBJECT_PT_visibility"

    @classmethod
    def shows(cls, context):
        return _has_geometry_visibility(context.object)


class EMBER_OBJECT_PT_visibility_mask(VisibilityPanel, bpy.types.Panel):
    """Object > Visibility > Mask: Shadow Catcher and Holdout, which Ember renders as Cycles (Blender's own
    Visibility panel shows them for Cycles only)."""
    bl_label = "Mask"

    def draw(self, context):
        layout = split_layout(self.layout, decorate=None)
        col = layout.column()
        col.prop(context.object, "is_shadow_catcher")
        col.prop(context.object, "is_holdout", toggle=False)


class EMBER_OBJECT_PT_visibility_rays(VisibilityPanel, bpy.types.Panel):
    """Object > Visibility > Ray Visibility, as Cycles' panel of that name (kernels/visibility.py)."""
    bl_label = "Ray Visibility"

    def draw(self, context):
        layout = split_layout(self.layout)
        ob = context.object
        col = layout.column()
        col.prop(ob, "visible_camera", text="Camera", toggle=False)
        col.prop(ob, "visible_diffuse", text="Diffuse")
        col.prop(ob, "visible_glossy", text="Glossy")
        col.prop(ob, "visible_transmission", text="Transmission")
        col.prop(ob, "visible_volume_scatter", text="Volume Scatter")
        if ob.type != "LIGHT":
            col.prop(ob, "visible_shadow", text="Shadow")


def _has_geometry_visibility(ob) -> bool:
    """The objects Cycles' Visibility panel shows masks and ray visibility for (has_geometry_visibility, in
    bl_ui.properties_object from Blender 4.3 on and in Cycles' ui.py before)."""
    return ob is not None and (ob.type in {"MESH", "CURVE", "SURFACE", "FONT", "META", "LIGHT", "VOLUME",
                                           "POINTCLOUD", "CURVES"}
                               or (ob.instance_type == "COLLECTION" and ob.instance_collection is not None))


def subdivision_modifier(ob):
    """The last modifier of ob when it is a Subdivision Surface with the adaptive options (Blender 5.0 on), else
    None: the one adaptive subdivision reads (engine/export/adaptive.py)."""
    modifiers = getattr(ob, "modifiers", None)
    last = modifiers[-1] if modifiers else None
    return last if last is not None and last.type == "SUBSURF" and hasattr(last, "adaptive_space") else None


class EMBER_OBJECT_PT_adaptive_subdivision(EmberPanel, bpy.types.Panel):
    """The adaptive options of the last Subdivision Surface modifier: Blender draws them in the modifier's own
    panel only when Cycles is the render engine (MOD_subsurf.cc)."""
    bl_label = "Adaptive Subdivision"
    bl_context = "object"
    bl_options = {"DEFAULT_CLOSED"}

    @classmethod
    def shows(cls, context):
        return subdivision_modifier(context.object) is not None

    def draw_header(self, context):
        self.layout.prop(subdivision_modifier(context.object), "use_adaptive_subdivision", text="")

    def draw(self, context):
        modifier = subdivision_modifier(context.object)
        layout = split_layout(self.layout)
        layout.active = modifier.use_adaptive_subdivision
        layout.label(text=f"Modifier '{modifier.name}'")
        layout.prop(modifier, "adaptive_space", text="Space")
        cycles = getattr(context.scene, "cycles", None)
        rates = (getattr(cycles, "preview_dicing_rate", 8.0), getattr(cycles, "dicing_rate", 1.0))
        if modifier.adaptive_space == "OBJECT":
            layout.prop(modifier, "adaptive_object_edge_length")
            texts = [f"{rate * modifier.adaptive_object_edge_length:.5g}" for rate in rates]
        else:
            layout.prop(modifier, "adaptive_pixel_size")
            texts = [f"{max(rate * modifier.adaptive_pixel_size, 0.1):.2f} px" for rate in rates]
        col = layout.column(align=True)
        col.label(text=f"Viewport {texts[0]}, Render {texts[1]}")


CLASSES = (EMBER_RENDER_PT_sampling, EMBER_RENDER_PT_denoise, EMBER_RENDER_PT_light_paths,
           EMBER_RENDER_PT_volumes, EMBER_RENDER_PT_simplify_culling, EMBER_RENDER_PT_film, EMBER_RENDER_PT_motion_blur, EMBER_RENDER_PT_performance,
           EMBER_VIEWLAYER_PT_passes, EMBER_VIEWLAYER_PT_passes_lightgroups, EMBER_LIGHT_PT_shadow,
           EMBER_LIGHT_PT_settings, EMBER_LIGHT_PT_beam_shape,
           EMBER_MATERIAL_PT_volume, EMBER_WORLD_PT_volume, EMBER_OBJECT_PT_visibility_mask,
           EMBER_OBJECT_PT_visibility_rays, EMBER_OBJECT_PT_adaptive_subdivision)


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    for panel in _compat_panels():
        if ENGINE not in panel.COMPAT_ENGINES:
            panel.COMPAT_ENGINES.add(ENGINE)
            _added.append(panel)


def unregister():
    for panel in _added:
        panel.COMPAT_ENGINES.discard(ENGINE)
    _added.clear()
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
