"""Blender lights -> kernels.Lights, in radiometric units that make Ember as bright as Cycles.

Units, checked against Cycles in bpy 5.0.1 by rendering a white diffuse plane under each light
(tests/test_lights_parity.py keeps them honest):
- strength = colour x energy x 2^exposure (x the blackbody colour when use_temperature is on);
- point and spot: intensity I = strength / (4 pi) W/sr; with a radius the light is a sphere whose
  radiance is I / (pi r^2) when `normalize` is on (strength spread over the sphere's area) and
  strength / pi when it is off;
- sun: irradiance E = strength W/m^2 on a surface facing it, whatever its angle;
- area: radiance strength / (pi A) with `normalize` (A the light's area, object scale included),
  strength / pi without.
"""
from __future__ import annotations

import math

import numpy as np

from ...kernels import LIGHT_KINDS, Lights
from ...kernels.scene.lights import NO_BOUNCE_LIMIT, PORTAL_COLUMNS
from ...kernels.scene.objects import BSDF_RAYS, RAY_CAMERA, RAY_DIFFUSE, RAY_GLOSSY, RAY_SCATTER, RAY_TRANSMIT
from ...kernels.textures import luminance
from .light_groups import GroupTable, group_table, lamp_groups
from .light_shaders import LightShaders
from .light_linking import LinkTable, lamp_masks, link_table

# Blender's blackbody is defined for this range; colours are clamped outside it.
BLACKBODY_RANGE_K = (800.0, 12000.0)
# Radiance (or intensity, for point-like lights) above this is clamped: the kernel works in float32
# (largest 3.4e38) and multiplies radiance by geometry terms on the way, so 1e38 W became inf pixels.
MAX_LIGHT_RADIANCE = 1e20


# A light object's Ray Visibility settings, their labels, Blender's defaults and the ray bit each gives
# Lights.visibility (Camera's, RAY_CAMERA, goes to Lights.camera instead: camera rays meet lamps in a stage of
# their own, so the bounce kinds' bookkeeping stays off while only Camera is changed).
LIGHT_VISIBILITY = (("visible_camera", "Camera", False, RAY_CAMERA), ("visible_diffuse", "Diffuse", True, RAY_DIFFUSE),
                    ("visible_glossy", "Glossy", True, RAY_GLOSSY),
                    ("visible_transmission", "Transmission", True, RAY_TRANSMIT),
                    ("visible_volume_scatter", "Volume Scatter", True, RAY_SCATTER))


def export_lights(depsgraph, warnings: list[str], poll=None, links: LinkTable | None = None,
                  groups: GroupTable | None = None, images=None, layer_attribute=None) -> Lights:
    """Every light instance; poll() is called for each instance (it raises to cancel the export). links: the
    scene's light_linking.LinkTable, groups: the view layer's light_groups.GroupTable (each read from the
    depsgraph when None). images: the export's images.ImageTextures, which the programs of lights whose node
    tree's emission varies read their images from (light_shaders.py; None: such a light's images are not
    kept, see Lights.shaders); layer_attribute: the View Layer attribute lookup (nodes.ProgramBuilder)."""
    if links is None:
        links = link_table(depsgraph)
    if groups is None:
        groups = group_table(depsgraph.view_layer)
    rows, masks, catchers, in_groups, seen, names, portals = [], [], [], [], [], [], []
    shaders = LightShaders(images, layer_attribute)
    for inst in depsgraph.object_instances:
        if poll is not None:
            poll()
        ob = inst.object
        if ob.type != "LIGHT":
            continue
        if is_portal(ob.data):
            portals.append(portal_row(ob.data, np.array(inst.matrix_world, dtype=np.float64)))
            continue
        row = _light_row(ob.data, np.array(inst.matrix_world, dtype=np.float64), ob.name, warnings, shaders)
        if row is not None:
            seen.append(light_visibility(ob))
            names.append(ob.name)
            rows.append(row)
            masks.append(links.memberships(ob))
            catchers.append(light_is_shadow_catcher(inst, ob))
            in_groups.append(groups.of(ob, inst.parent if inst.is_instance else None))
    portal_table = np.array(portals, np.float32).reshape(-1, PORTAL_COLUMNS) if portals else None
    tree = uses_light_tree(depsgraph.scene)
    clamped = clamps_light(depsgraph.scene)
    if not rows:
        return Lights(portals=portal_table, tree=tree, clamped=clamped)
    columns = list(zip(*rows))
    light_sets, shadow_sets = lamp_masks(masks)
    camera = np.array([bool(v & RAY_CAMERA) for v in seen], bool)
    seen = [v & BSDF_RAYS for v in seen]
    visibility = None if all(v == BSDF_RAYS for v in seen) else np.array(seen, np.uint8)
    return Lights(
        kind=np.array(columns[0], np.int32),
        position=np.array(columns[1], np.float32).reshape(-1, 3),
        frame=np.array(columns[2], np.float32).reshape(-1, 3, 3),
        radiance=np.array(columns[3], np.float32).reshape(-1, 3),
        radius=np.array(columns[4], np.float32),
        size=np.array(columns[5], np.float32).reshape(-1, 2),
        spot_cos=np.array(columns[6], np.float32).reshape(-1, 2),
        sun_half_angle=np.array(columns[7], np.float32),
        cast_shadow=np.array(columns[8], bool),
        light_sets=light_sets,
        shadow_sets=shadow_sets,
        shadow_catcher=None if all(catchers) else np.array(catchers, bool),
        light_groups=lamp_groups(in_groups),
        visibility=visibility,
        camera=camera if camera.any() else None,
        spread=np.array(columns[9], np.float32) if min(columns[9]) < math.pi else None,
        sphere=np.array(columns[10], bool) if any(columns[10]) else None,
        shader=np.array(columns[11], np.int32) if max(columns[11]) >= 0 else None,
        shaders=shaders.programs if max(columns[11]) >= 0 else (),
        max_bounces=np.array(columns[12], np.int32) if min(columns[12]) < NO_BOUNCE_LIMIT else None,
        mis=None if all(columns[13]) else np.array(columns[13], bool),
        portals=portal_table,
        tree=tree,
        clamped=clamped,
    )


def uses_light_tree(scene) -> bool:
    """Sampling > Lights > Light Tree, Cycles' own setting (read as Cycles reads it, so that a file set up for Cycles
    renders alike: files from before Blender 3.5 open with it off, and with clamping the way lights are chosen shows
    in the image). Without it, emitters are chosen by Cycles' light distribution (Lights.tree)."""
    return bool(getattr(getattr(scene, "cycles", None), "use_light_tree", True))


def clamps_light(scene) -> bool:
    """Light Paths > Clamping Direct or Indirect above 0 (Lights.clamped): the light tree then shares light samples as
    Cycles' does, since the image depends on it."""
    ember = getattr(scene, "ember", None)
    return any(float(getattr(ember, name, 0.0)) > 0 for name in ("sample_clamp_direct", "sample_clamp_indirect"))


def is_portal(light) -> bool:
    """An area lamp marked Portal (Cycles' own setting): it emits nothing and is not seen; it guides the world's light
    samples (kernels/lights/portals.py)."""
    return light.type == "AREA" and bool(getattr(getattr(light, "cycles", None), "is_portal", False))


def portal_row(light, world_from_light: np.ndarray) -> list[float]:
    """A portal's row of Lights.portals: its centre, its edges (the lamp's x and y axes times Size X and Size Y, as
    Cycles' AreaLight::copy_to_kernel scales them by the object's transform), the direction it faces (its -Z) and
    whether it is round (Disk, Ellipse)."""
    m = np.asarray(world_from_light, np.float64)
    size_u = float(light.size)
    size_v = float(light.size_y) if light.shape in ("RECTANGLE", "ELLIPSE") else size_u
    facing = -m[:3, 2]
    facing = facing / max(float(np.linalg.norm(facing)), 1e-30)
    return [*m[:3, 3], *(m[:3, 0] * size_u), *(m[:3, 1] * size_v), *facing,
            1.0 if light.shape in ("DISK", "ELLIPSE") else 0.0]


def light_is_shadow_catcher(inst, ob) -> bool:
    """Whether shadow catchers receive the light in their own pass (kernels/shadow_catcher.py): the light
    object's Visibility > Shadow Catcher, or its instancer's, which Blender turns on for new lights (Cycles'
    sync_object sets is_shadow_catcher so for lights too; scene/light.cpp excludes the others)."""
    parent = inst.parent if inst.is_instance else None
    return bool(getattr(ob, "is_shadow_catcher", True)) or bool(parent is not None and parent.is_shadow_catcher)


def light_visibility(ob) -> int:
    """The ray bits of a light object's Ray Visibility: the bounces it is seen by, whose light samples may take
    it (Lights.visibility; Cycles' scene/light.cpp SHADER_EXCLUDE_* flags: kernels/lights/ray_visibility.py), and
    RAY_CAMERA where camera rays see it (Lights.camera: kernels/emitters_seen.py)."""
    bits = 0
    for name, _label, default, bit in LIGHT_VISIBILITY:
        if getattr(ob, name, default):
            bits |= bit
    return bits


def light_strength(light) -> np.ndarray:
    """colour x energy x 2^exposure x blackbody colour, (3,) float64."""
    color = np.array(light.color[:3], np.float64)
    if getattr(light, "use_temperature", False):
        color = color * blackbody_rgb(light.temperature)
    return color * float(light.energy) * 2.0 ** float(getattr(light, "exposure", 0.0))


def _light_row(light, world_from_light: np.ndarray, name: str, warnings: list[str], shaders=None):
    settings = getattr(light, "cycles", None)
    if settings is not None and getattr(settings, "is_caustics_light", False):
        warnings.append(f"Light '{name}': Shadow Caustics are not supported, ignored")
    if shaders is None:
        shaders = LightShaders()
    factor, shader = shaders.of(light, name, warnings)
    strength = light_strength(light) * factor
    if not np.all(np.isfinite(strength)):
        warnings.append(f"Light '{name}' has a non-finite power and is skipped")
        return None
    if np.any(strength < 0):
        # Cycles subtracts light for negative power; Ember's light sampling needs power >= 0.
        tree = "" if np.all(factor == 1) else f", its node tree's emission {_triple(factor)}"
        warnings.append(f"Light '{name}' has negative power ({float(light.energy):g} W{tree}): negative lights are "
                        f"not supported, skipped")
        return None
    if np.all(strength <= 0):
        return None
    linear = world_from_light[:3, :3]
    scale = np.linalg.norm(linear, axis=0)
    if not np.all(np.isfinite(world_from_light)) or np.any(scale <= 1e-12):
        warnings.append(f"Light '{name}' has a degenerate transform and is skipped")
        return None
    frame = linear / scale
    position = world_from_light[:3, 3]
    normalize = bool(getattr(light, "normalize", True))
    size = (0.0, 0.0)
    spread = math.pi
    spot = (1.0, 0.0)
    radius = 0.0
    sun_half = 0.0
    sphere = False
    if light.type in ("POINT", "SPOT"):
        kind = LIGHT_KINDS[light.type]
        radius = max(float(light.shadow_soft_size), 0.0)
        # Soft Falloff off makes a sized lamp a sphere (Cycles' blender/light.cpp: is_sphere = !use_soft_falloff;
        # scene/light.cpp: is_sphere && radius != 0), of the same radiance (PointLight::area is 4 pi r^2 either way).
        sphere = radius > 0 and not getattr(light, "use_soft_falloff", True)
        intensity = strength / (4.0 * math.pi)
        if radius > 0:
            radiance = intensity / (math.pi * radius ** 2) if normalize else strength / math.pi
        else:
            radiance = intensity
        if light.type == "SPOT":
            cos_half = math.cos(min(float(light.spot_size), math.pi) / 2.0)
            spot = (cos_half, (1.0 - cos_half) * max(float(light.spot_blend), 0.0))
            if not np.isclose(scale[0], scale[1], rtol=1e-4):
                warnings.append(f"Spot light '{name}': non-uniform scale is ignored (round cone)")
    elif light.type == "SUN":
        kind = LIGHT_KINDS["SUN"]
        radiance = strength
        sun_half = max(float(light.angle), 0.0) / 2.0
    elif light.type == "AREA":
        shape = light.shape
        kind = LIGHT_KINDS["DISK"] if shape in ("DISK", "ELLIPSE") else LIGHT_KINDS["RECT"]
        sx = float(light.size) * scale[0]
        sy = float(light.size_y if shape in ("RECTANGLE", "ELLIPSE") else light.size) * scale[1]
        size = (sx, sy)
        area = sx * sy * (math.pi / 4.0 if kind == LIGHT_KINDS["DISK"] else 1.0)
        if area <= 0:
            return None
        radiance = strength / (math.pi * area) if normalize else strength / math.pi
        spread = min(max(float(getattr(light, "spread", math.pi)), 0.0), math.pi)
        if spread >= math.pi - 1e-4:
            spread = math.pi
    else:
        warnings.append(f"Light '{name}' of type {light.type} is not supported")
        return None
    radiance = np.asarray(radiance, np.float64)
    if radiance.max() > MAX_LIGHT_RADIANCE:
        warnings.append(f"Light '{name}' is too bright for Ember's float32 arithmetic (power {float(light.energy):g} W): "
                        f"clamped to {MAX_LIGHT_RADIANCE:g} W/(sr m^2)")
        radiance = radiance * (MAX_LIGHT_RADIANCE / radiance.max())
    # Max Bounces, Cycles' own setting (light.cycles), as Cycles' sync_light reads it.
    bounces = min(max(int(getattr(settings, "max_bounces", NO_BOUNCE_LIMIT)), 0), NO_BOUNCE_LIMIT)
    mis = bool(getattr(settings, "use_multiple_importance_sampling", True))
    return (kind, position, frame, radiance, radius, size, spot, sun_half, bool(getattr(light, "use_shadow", True)),
            spread, sphere, shader, bounces, mis)


def _triple(c) -> str:
    return "(" + ", ".join(f"{float(v):g}" for v in c) + ")"


# ---------------------------------------------------------------- blackbody colour
def blackbody_rgb(kelvin: float) -> np.ndarray:
    """Linear Rec.709 colour of a black body, normalised to luminance 1 as Blender does.

    Planck's law integrated against the CIE 1931 2-degree colour matching functions (the analytic
    multi-lobe fit of Wyman, Sloan and Shirley 2013), then XYZ -> linear Rec.709 (D65). Agrees with
    Cycles within 1% from 3000 K to 12000 K and 2.5% at 2000 K; redder, the fit drifts further.
    """
    t = min(max(float(kelvin), BLACKBODY_RANGE_K[0]), BLACKBODY_RANGE_K[1])
    wavelength_nm = np.arange(360.0, 831.0, 1.0)
    metres = wavelength_nm * 1e-9
    c1, c2 = 3.741771852e-16, 1.438776877e-2
    spectrum = c1 / (metres ** 5 * np.expm1(c2 / (metres * t)))
    xyz = _cie_1931(wavelength_nm) @ spectrum
    rgb = np.maximum(_XYZ_TO_REC709 @ xyz, 0.0)
    return rgb / float(luminance(rgb))


_XYZ_TO_REC709 = np.array([[3.2404542, -1.5371385, -0.4985314],
                           [-0.9692660, 1.8760108, 0.0415560],
                           [0.0556434, -0.2040259, 1.0572252]])
# Lobes of the CIE 1931 fit: (weight, mean nm, sigma below the mean, sigma above), per X, Y, Z.
_CIE_LOBES = (
    ((1.056, 599.8, 37.9, 31.0), (0.362, 442.0, 16.0, 26.7), (-0.065, 501.1, 20.4, 26.2)),
    ((0.821, 568.8, 46.9, 40.5), (0.286, 530.9, 16.3, 31.1)),
    ((1.217, 437.0, 11.8, 36.0), (0.681, 459.0, 26.0, 13.8)),
)


def _cie_1931(nm: np.ndarray) -> np.ndarray:
    """(3, len(nm)) colour matching functions x, y, z."""
    rows = []
    for lobes in _CIE_LOBES:
        total = np.zeros_like(nm)
        for weight, mean, below, above in lobes:
            sigma = np.where(nm < mean, below, above)
            total += weight * np.exp(-0.5 * ((nm - mean) / sigma) ** 2)
        rows.append(total)
    return np.array(rows)
