"""The Sky Texture node as Cycles 5.0 renders it (`kernel/svm/sky.h`, `scene/shader_nodes.cpp`, and the
sky models of `third_party/sky` / Blender's `intern/sky`).

Blender 5.0 offers four sky types; MULTIPLE_SCATTERING is the default:

- MULTIPLE_SCATTERING (Fernando Garcia Linan's spectral atmosphere, 4 wavelengths, a fitted multiple
  scattering term) and SINGLE_SCATTERING (the former "Nishita" model, 21 wavelengths): at export a
  512 x 256 XYZ table of the sky (azimuth x elevation, more rows near the horizon) and the colour of the
  sun disc's lowest and highest points are computed (kernels.shading.sky_scattering); per hit the table
  is read bilinearly and the sun disc (limb darkened) is added.
- PREETHAM and HOSEK_WILKIE: closed-form Perez-style functions of the angle to the zenith and to the sun,
  from nine coefficients per XYZ channel computed at export. Hosek and Wilkie's are interpolated from their
  fitted data set ("An Analytic Model for Full Spectral Sky-Dome Radiance", SIGGRAPH 2012; data/hosek_xyz.npz,
  the authors' BSD-3-Clause data, its notice inside; tools/extract_hosek_data.py) as Cycles does it
  (`third_party/sky/source/sky_hosek.cpp`, in double precision), and evaluated per hit in float32
  (`svm/sky.h` sky_radiance_hosek).

`precompute_sky(**settings)` does the export-time part (pure NumPy, no bpy: the settings are the node's
properties as plain values, with Blender's identifiers); `sky_texture(vector, ...)` evaluates per hit.
The result is XYZ converted to the scene's linear Rec.709 with the matrix Cycles derives from Blender's
colour configuration, negative values clamped to 0.

Float32 throughout, in Cycles' order of operations, with the C library's float functions as Cycles
calls them (kernels.shading.libm).
"""
from __future__ import annotations

import functools
import os
from dataclasses import dataclass

import numpy as np

from ..vec import F32, F64, HALF, HALF_PI, INV_2PI, ONE, PI, TWO_PI, ZERO, length_rows
from . import sky_scattering as sc
from .libm import cosf, expf, libm, sinf

TWO_OVER_PI = F32(0.6366197723675813)  # M_2_PI_F

SKY_TYPES = ("SINGLE_SCATTERING", "MULTIPLE_SCATTERING", "PREETHAM", "HOSEK_WILKIE")


# ---- XYZ -> scene linear ----------------------------------------------------------------------------

def _xyz_to_rec709() -> np.ndarray:
    """Cycles' film XYZ -> RGB matrix for Blender 5.0's OCIO config (`ShaderManager::init_xyz_transforms`).

    The config's aces_interchange role gives scene linear -> ACES2065-1 (OCIO: Rec.709's XYZ D65 matrix
    and the built-in AP0 -> XYZ D65 Bradford matrix, both in double); Cycles composes its inverse with the
    inverse of its own 6-digit copy of that Bradford matrix. The result is within 1.3e-6 of the config's
    XYZ -> Rec.709 matrix.
    """
    def xyz(x, y):
        return np.array([x / y, 1.0, (1.0 - x - y) / y])

    bradford = np.array([[0.8951, 0.2664, -0.1614], [-0.7502, 1.7135, 0.0367], [0.0389, -0.0685, 1.0296]])
    aces_white, d65 = (0.32168, 0.33767), (0.3127, 0.3290)
    primaries = np.stack([xyz(0.7347, 0.2653), xyz(0.0, 1.0), xyz(0.0001, -0.0770)], axis=1)
    ap0_to_xyz = primaries * np.linalg.solve(primaries, xyz(*aces_white))
    cone = bradford @ xyz(*d65) / (bradford @ xyz(*aces_white))
    ap0_to_xyz_d65 = np.linalg.inv(bradford) @ (cone[:, None] * bradford) @ ap0_to_xyz
    xyz_d65_to_rec709 = np.array([[3.2409699, -1.5373832, -0.4986108],
                                  [-0.9692436, 1.8759675, 0.0415551],
                                  [0.0556301, -0.2039770, 1.0569715]])
    cycles_ap0_to_xyz = np.array([[0.938280, -0.004451, 0.016628],
                                  [0.337369, 0.729522, -0.066890],
                                  [0.001174, -0.003711, 1.091595]], F32).astype(F64)
    return (xyz_d65_to_rec709 @ ap0_to_xyz_d65 @ np.linalg.inv(cycles_ap0_to_xyz)).astype(F32)


XYZ_TO_RGB = _xyz_to_rec709()


def xyz_to_rgb_clamped(xyz: np.ndarray) -> np.ndarray:
    """(N, 3) XYZ -> (N, 3) scene linear RGB, negatives clamped (Cycles' xyz_to_rgb_clamped)."""
    m = XYZ_TO_RGB
    x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    rgb = np.stack([m[i, 0] * x + m[i, 1] * y + m[i, 2] * z for i in range(3)], axis=1)
    return np.maximum(rgb, ZERO)


# ---- the sun --------------------------------------------------------------------------------------

def _wrap_sun(elevation: float, rotation: float):
    """Cycles' SkyTextureNode::simplify_settings: elevation into [-pi/2, pi/2] (turning the sun around
    past the zenith), rotation into [0, 2pi), then mirrored to 2pi - rotation."""
    e, r = np.float32(elevation), np.float32(rotation)
    e = np.fmod(e, TWO_PI)
    if abs(e) >= PI:
        e = e - np.copysign(F32(2.0), e) * PI
    if e >= HALF_PI or e <= -HALF_PI:
        e = np.copysign(PI, e) - e
        r = r + PI
    r = np.fmod(r, TWO_PI)
    if r < ZERO:
        r = r + TWO_PI
    return F32(e), F32(TWO_PI - r)


# ---- Preetham (shader_nodes.cpp sky_texture_precompute_preetham) -------------------------------------

def _perez(lam, cos_theta, gamma, cos_gamma):
    """Perez's sky luminance distribution at zenith angle theta and sun angle gamma."""
    return (ONE + lam[0] * expf(lam[1] / cos_theta)) * \
        (ONE + lam[2] * expf(lam[3] * gamma) + lam[4] * cos_gamma * cos_gamma)


def _preetham(sun_direction, turbidity):
    d = np.asarray(sun_direction, F32)
    d = d / np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    theta = libm(np.arccos, d[2])
    phi = F32(np.arctan2(F64(d[0]), F64(d[1])))     # sky_spherical_coordinates: atan2(x, y)
    t = F32(turbidity)
    th2 = theta * theta
    th3 = th2 * theta
    t2 = t * t
    chi = (F32(4.0 / 9.0) - t / F32(120.0)) * (PI - F32(2.0) * theta)
    zenith_y = ((F32(4.0453) * t - F32(4.9710)) * libm(np.tan, chi) - F32(0.2155) * t + F32(2.4192)) \
        * F32(0.06)
    zenith_x = ((F32(0.00166) * th3 - F32(0.00375) * th2 + F32(0.00209) * theta) * t2
                + (F32(-0.02903) * th3 + F32(0.06377) * th2 - F32(0.03202) * theta + F32(0.00394)) * t
                + (F32(0.11693) * th3 - F32(0.21196) * th2 + F32(0.06052) * theta + F32(0.25886)))
    zenith_yy = ((F32(0.00275) * th3 - F32(0.00610) * th2 + F32(0.00317) * theta) * t2
                 + (F32(-0.04214) * th3 + F32(0.08970) * th2 - F32(0.04153) * theta + F32(0.00516)) * t
                 + (F32(0.15346) * th3 - F32(0.26756) * th2 + F32(0.06670) * theta + F32(0.26688)))
    # Perez coefficients a..e per channel (Y, x, y) as slope and intercept in the turbidity.
    coeffs = np.array([
        [0.1787, -1.4630, -0.3554, 0.4275, -0.0227, 5.3251, 0.1206, -2.5771, -0.0670, 0.3703],
        [-0.0193, -0.2592, -0.0665, 0.0008, -0.0004, 0.2125, -0.0641, -0.8989, -0.0033, 0.0452],
        [-0.0167, -0.2608, -0.0950, 0.0092, -0.0079, 0.2102, -0.0441, -1.6537, -0.0109, 0.0529]], F32)
    config = np.zeros((3, 9), F32)
    config[:, :5] = coeffs[:, 0::2] * t + coeffs[:, 1::2]
    radiance = np.array([zenith_y, zenith_x, zenith_yy], F32)
    radiance = np.array([radiance[i] / _perez(config[i], ONE, theta, cosf(theta)) for i in range(3)], F32)
    return theta, phi, radiance, config


# ---- Hosek / Wilkie (shader_nodes.cpp sky_texture_precompute_hosek, sky_hosek.cpp) --------------------

HOSEK_PATH = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "hosek_xyz.npz")


@functools.lru_cache(maxsize=1)
def _hosek_data() -> tuple[np.ndarray, np.ndarray]:
    """(distribution (3, 2, 10, 6, 9), radiance (3, 2, 10, 6)) float64: per XYZ channel, ground albedo 0 and 1,
    turbidity 1..10, the solar elevation's six Bezier control points (and the nine coefficients)."""
    with np.load(HOSEK_PATH) as data:
        return data["xyz"], data["radiance"]


def _hosek_cook(table: np.ndarray, turbidity: float, albedo: float, elevation: float) -> np.ndarray:
    """ArHosekSkyModel_CookConfiguration / _CookRadianceConfiguration of one channel's table (2, 10, 6, ...):
    a quintic Bezier in the cube root of the elevation over pi/2, blended linearly between the two albedos and
    the two turbidities around `turbidity` (the upper one dropped at 10), in double precision."""
    whole = int(turbidity)
    rest = turbidity - whole
    t = (elevation / (np.pi / 2.0)) ** (1.0 / 3.0)
    bezier = np.array([(1.0 - t) ** 5, 5.0 * (1.0 - t) ** 4 * t, 10.0 * (1.0 - t) ** 3 * t ** 2,
                       10.0 * (1.0 - t) ** 2 * t ** 3, 5.0 * (1.0 - t) * t ** 4, t ** 5])

    def at(albedo_row: int, turbidity_row: int) -> np.ndarray:
        return np.tensordot(bezier, table[albedo_row, turbidity_row - 1], axes=(0, 0))

    out = (1.0 - albedo) * (1.0 - rest) * at(0, whole) + albedo * (1.0 - rest) * at(1, whole)
    if whole == 10:
        return out
    return out + (1.0 - albedo) * rest * at(0, whole + 1) + albedo * rest * at(1, whole + 1)


def _hosek(sun_direction, turbidity, ground_albedo):
    d = np.asarray(sun_direction, F32)
    d = d / np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
    theta = min(max(libm(np.arccos, d[2]), ZERO), HALF_PI)      # the sun clamped to the horizon
    phi = F32(np.arctan2(F64(d[0]), F64(d[1])))                 # sky_spherical_coordinates: atan2(x, y)
    turbidity = float(min(max(F32(turbidity), ZERO), F32(10.0)))
    elevation = float(HALF_PI - theta)
    distribution, radiance = _hosek_data()
    config = np.array([_hosek_cook(distribution[c], turbidity, float(ground_albedo), elevation) for c in range(3)])
    radiance = np.array([_hosek_cook(radiance[c], turbidity, float(ground_albedo), elevation) for c in range(3)])
    return F32(theta), phi, radiance.astype(F32), config.astype(F32)


def _hosek_radiance(c: np.ndarray, theta, gamma) -> np.ndarray:
    """sky_radiance_internal: the model's distribution with coefficients c (9,) at zenith angle theta and sun
    angle gamma."""
    cos_theta, cos_gamma = cosf(theta), cosf(gamma)
    exp_m = expf(c[4] * gamma)
    ray_m = cos_gamma * cos_gamma
    mie_m = (ONE + ray_m) / libm(lambda v: np.power(v, 1.5), ONE + c[8] * c[8] - F32(2.0) * c[8] * cos_gamma)
    zenith = np.sqrt(cos_theta)
    return (ONE + c[0] * expf(c[1] / (cos_theta + F32(0.01)))) * \
        (c[2] + c[3] * exp_m + c[5] * ray_m + c[6] * mie_m + c[7] * zenith)


def _hosek_eval(direction: np.ndarray, sky: Sky) -> np.ndarray:
    theta, gamma = _sun_angles(direction, sky)
    xyz = np.stack([_hosek_radiance(sky.config[i], theta, gamma) * sky.radiance[i] for i in range(3)], axis=1)
    return xyz_to_rgb_clamped(xyz.astype(F32, copy=False)) * F32(2.0 * np.pi / 683.0)


# ---- the node -------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Sky:
    """The Sky node's export-time data, what Cycles' compiler writes into the SVM program."""
    sky_type: str
    table: np.ndarray | None = None          # (3, sc.TABLE_HEIGHT, sc.TABLE_WIDTH) X, Y, Z; row 0 lowest elevation
    sun_bottom: np.ndarray | None = None      # (3,) XYZ at the sun disc's lowest point
    sun_top: np.ndarray | None = None         # (3,) XYZ at its highest point
    sun_elevation: np.float32 = ZERO
    sun_rotation: np.float32 = ZERO           # as Cycles stores it: 2pi - the wrapped rotation
    angular_diameter: np.float32 = F32(-1.0)  # the sun disc's, negative when it is off
    sun_intensity: np.float32 = ONE
    horizon: np.float32 = ZERO                # lowest elevation above the ground (negative)
    sun_theta: np.float32 = ZERO              # Preetham / Hosek: the sun's zenith angle and azimuth
    sun_phi: np.float32 = ZERO
    radiance: np.ndarray | None = None        # (3,) zenith x, y, Y (Preetham) or X, Y, Z (Hosek)
    config: np.ndarray | None = None          # (3, 9) distribution coefficients per channel


def precompute_sky(sky_type: str = "MULTIPLE_SCATTERING", sun_disc: bool = True,
                   sun_size: float = 0.009512044, sun_intensity: float = 1.0,
                   sun_elevation: float = 0.2617994, sun_rotation: float = 0.0, altitude: float = 100.0,
                   air_density: float = 1.0, aerosol_density: float = 1.0, ozone_density: float = 1.0,
                   sun_direction=(0.0, 0.0, 1.0), turbidity: float = 2.2, ground_albedo: float = 0.3) -> Sky:
    """The node's settings (Blender's property names and defaults) -> its export-time data (about half a
    second for the scattering types, which ray-march 65536 directions through the atmosphere)."""
    if sky_type == "PREETHAM":
        theta, phi, radiance, config = _preetham(sun_direction, turbidity)
        return Sky(sky_type, sun_theta=theta, sun_phi=phi, radiance=radiance, config=config)
    if sky_type == "HOSEK_WILKIE":
        theta, phi, radiance, config = _hosek(sun_direction, turbidity, ground_albedo)
        return Sky(sky_type, sun_theta=theta, sun_phi=phi, radiance=radiance, config=config)
    if sky_type not in SKY_TYPES:
        raise ValueError(f"unknown sky_type {sky_type!r}")
    elevation, rotation = _wrap_sun(sun_elevation, sun_rotation)
    diameter = max(F32(sun_size), F32(0.0005))           # Cycles clamps it for precision
    if sky_type == "MULTIPLE_SCATTERING":
        bottom, top = sc.multiple_scattering_sun(elevation, diameter, altitude, air_density, aerosol_density,
                                                 ozone_density)
        table = sc.multiple_scattering_table(elevation, altitude, air_density, aerosol_density, ozone_density)
    else:
        bottom, top = sc.single_scattering_sun(elevation, diameter, altitude, air_density, aerosol_density)
        table = sc.single_scattering_table(elevation, altitude, air_density, aerosol_density, ozone_density)
    table = np.ascontiguousarray(np.moveaxis(table, -1, 0))
    return Sky(sky_type, table=table, sun_bottom=bottom, sun_top=top, sun_elevation=elevation,
               sun_rotation=rotation, angular_diameter=diameter if sun_disc else F32(-1.0),
               sun_intensity=F32(sun_intensity), horizon=-sc.earth_intersection_angle(altitude))


@functools.lru_cache(maxsize=8)
def _cached_sky(*settings) -> Sky:
    return precompute_sky(*settings)


def _bilinear_extend(table: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Cycles' CPU linear image lookup with EXTEND in a (C, H, W) table at (x, y) in [0, 1]: (N, C)."""
    channels, h, w = table.shape

    def split(c, size):
        c = c * F32(size) - HALF                       # texel centres at (i + 1/2) / size
        i = c.astype(np.int32) - (c < ZERO)
        return c - i.astype(F32), i

    tx, ix = split(x, w)
    ty, iy = split(y, h)
    ix0, ix1 = np.clip(ix, 0, w - 1), np.clip(ix + 1, 0, w - 1)
    row0, row1 = np.clip(iy, 0, h - 1) * w, np.clip(iy + 1, 0, h - 1) * w
    weights = ((ONE - ty) * (ONE - tx), (ONE - ty) * tx, ty * (ONE - tx), ty * tx)
    texels = (row0 + ix0, row0 + ix1, row1 + ix0, row1 + ix1)
    out = np.empty((len(x), channels), F32)
    for c in range(channels):
        channel = table[c].reshape(-1)
        a, b, cc, d = (np.take(channel, t) for t in texels)
        out[:, c] = ((weights[0] * a + weights[1] * b) + weights[2] * cc) + weights[3] * d
    return out


def _spherical(direction: np.ndarray):
    """direction_to_spherical: (theta from +Z, phi = atan2(y, x))."""
    theta = libm(np.arccos, np.clip(direction[:, 2], -ONE, ONE))
    phi = libm(lambda v: np.arctan2(v, direction[:, 0].astype(F64)), direction[:, 1])
    return theta, phi


def _nishita(direction: np.ndarray, sky: Sky) -> np.ndarray:
    theta, phi = _spherical(direction)
    st, sp = sky.sun_elevation - HALF_PI, sky.sun_rotation - HALF_PI
    sun = np.array([sinf(st) * cosf(sp), sinf(st) * sinf(sp), cosf(st)], F32).reshape(1, 3)
    sun_angle = F32(2.0) * libm(lambda a: np.arctan2(a, length_rows(direction + sun).astype(F64)),
                                 length_rows(direction - sun))
    half = sky.angular_diameter * HALF
    elevation = HALF_PI - theta
    xyz = np.zeros((len(direction), 3), F32)
    if sky.angular_diameter >= ZERO:
        disc = (sun_angle < half) & (elevation > sky.horizon)
        if disc.any():
            e, a = elevation[disc], sun_angle[disc]
            y = (e - sky.sun_elevation) / sky.angular_diameter + HALF
            limb = ONE - F32(0.6) * (ONE - np.sqrt(ONE - np.square(a / half)))
            colour = sky.sun_bottom + y[:, None] * (sky.sun_top - sky.sun_bottom)
            xyz[disc] = colour * sky.sun_intensity * limb[:, None]
    u = (-phi - HALF_PI + sky.sun_rotation) * INV_2PI
    u = u - np.floor(u)
    v = np.copysign(np.sqrt(np.abs(elevation) * TWO_OVER_PI), elevation) * HALF + HALF
    xyz = xyz + _bilinear_extend(sky.table, u, v)
    return xyz_to_rgb_clamped(xyz)


def _sun_angles(direction: np.ndarray, sky: Sky):
    """(theta, gamma): each direction's angle to the zenith, clamped just above the horizon, and to the sun
    (sky_angle_between), as Preetham's and Hosek's evaluations take them."""
    theta, phi = _spherical(direction)
    phi = -phi + HALF_PI
    cos_psi = (sinf(theta) * sinf(sky.sun_theta) * cosf(sky.sun_phi - phi)
               + cosf(theta) * cosf(sky.sun_theta))
    gamma = libm(np.arccos, np.clip(cos_psi, -ONE, ONE))
    return np.minimum(theta, HALF_PI - F32(0.001)), gamma


def _preetham_eval(direction: np.ndarray, sky: Sky) -> np.ndarray:
    theta, gamma = _sun_angles(direction, sky)
    cos_theta, cos_gamma = cosf(theta), cosf(gamma)
    x = sky.radiance[1] * _perez(sky.config[1], cos_theta, gamma, cos_gamma)
    y = sky.radiance[2] * _perez(sky.config[2], cos_theta, gamma, cos_gamma)
    big_y = sky.radiance[0] * _perez(sky.config[0], cos_theta, gamma, cos_gamma)
    with np.errstate(divide="ignore", invalid="ignore"):
        big_x = np.where(y != ZERO, (x / y) * big_y, ZERO)
        big_z = np.where((y != ZERO) & (big_y != ZERO), (ONE - x - y) / y * big_y, ZERO)
    return xyz_to_rgb_clamped(np.stack([big_x, big_y, big_z], axis=1).astype(F32, copy=False))


def sky_texture(vector, *, sky_type: str = "MULTIPLE_SCATTERING", sun_disc: bool = True,
                sun_size: float = 0.009512044, sun_intensity: float = 1.0, sun_elevation: float = 0.2617994,
                sun_rotation: float = 0.0, altitude: float = 100.0, air_density: float = 1.0,
                aerosol_density: float = 1.0, ozone_density: float = 1.0, sun_direction=(0.0, 0.0, 1.0),
                turbidity: float = 2.2, ground_albedo: float = 0.3, precomputed: Sky | None = None) -> dict:
    """Sky Texture at directions `vector` (N, 3): {"Color": (N, 3)}.

    `precomputed` is `precompute_sky(...)` of the same settings, made once at export; without it the
    precomputation runs here, cached on the settings. The direction need not be unit length (Cycles does
    not normalize it either). Blender disables the Vector socket of the two scattering types while the
    sun disc is on: Cycles then ignores any link and uses the default (the ray direction in a world).
    """
    sky = precomputed
    if sky is None:
        sky = _cached_sky(sky_type, bool(sun_disc), float(sun_size), float(sun_intensity),
                          float(sun_elevation), float(sun_rotation), float(altitude), float(air_density),
                          float(aerosol_density), float(ozone_density),
                          tuple(float(c) for c in np.ravel(sun_direction)), float(turbidity),
                          float(ground_albedo))
    direction = np.asarray(vector, F32).reshape(-1, 3)
    if sky.sky_type == "PREETHAM":
        return {"Color": _preetham_eval(direction, sky)}
    if sky.sky_type == "HOSEK_WILKIE":
        return {"Color": _hosek_eval(direction, sky)}
    return {"Color": _nishita(direction, sky)}
