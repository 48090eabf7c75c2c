"""The Sky Texture node as Cycles 5.0 renders it (`kernel/svm/sky.h`, `scene/shader_nodes.cpp`, and the
sky models of `third_party/sky` / Blender's `intern/sky`).

Blender 5.0 offers four sky types; MULTIPLE_SCATTERING is the default:

- MULTIPLE_SCATTERING (Fernando Garcia Linan's spectral atmosphere, 4 wavelengths, a fitted multiple
  scattering term) and SINGLE_SCATTERING (the former "Nishita" model, 21 wavelengths): at export a
  512 x 256 XYZ table of the sky (azimuth x elevation, more rows near the horizon) and the colour of the
  sun disc's lowest and highest points are computed; per hit the table is read bilinearly and the sun
  disc (limb darkened) is added.
- PREETHAM and HOSEK_WILKIE: closed-form Perez-style functions of the angle to the zenith and to the sun,
  from nine coefficients per XYZ channel computed at export. Hosek-Wilkie needs the model's fitted data
  set, which Ember does not carry yet: `precompute_sky` raises NotImplementedError for it.

`precompute_sky(**settings)` does the export-time part (pure NumPy, no bpy: the settings are the node's
properties as plain values, with Blender's identifiers); `sky_texture(vector, ...)` evaluates per hit.
The result is XYZ converted to the scene's linear Rec.709 with the matrix Cycles derives from Blender's
colour configuration, negative values clamped to 0.

Float32 throughout, in Cycles' order of operations, with the C library's float functions as Cycles
calls them (kernels.shading.libm).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from ..vec import F32, F64, HALF, HALF_PI, INV_2PI, INV_4PI, INV_PI, ONE, PI, TWO_PI, ZERO, length_rows, length_xyz
from .libm import cosf, expf, libm, sinf

TWO_OVER_PI = F32(0.6366197723675813)  # M_2_PI_F

SKY_TYPES = ("SINGLE_SCATTERING", "MULTIPLE_SCATTERING", "PREETHAM", "HOSEK_WILKIE")
TABLE_WIDTH, TABLE_HEIGHT = 512, 256   # Cycles' SkyLoader


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


# ---- shared geometry ------------------------------------------------------------------------------

def _ray_sphere(origin_z, dir_z, radius):
    """Distance from (0, 0, origin_z) along a unit direction to a sphere about the origin; -1 if missed
    (`sky_math.h` ray_sphere_intersection)."""
    b = origin_z * dir_z
    c = origin_z * origin_z - F32(radius) * F32(radius)
    d = b * b - c
    with np.errstate(invalid="ignore"):
        root = np.sqrt(d)
    t = np.where(d >= b * b, -b + root, -b - root)
    return np.where(((c > ZERO) & (b > ZERO)) | (d < ZERO), F32(-1.0), t).astype(F32, copy=False)


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


# ---- multiple scattering (sky_multiple_scattering.cpp) -----------------------------------------------

class _Atmosphere:
    """Garcia Linan's atmosphere: 4 wavelengths (630, 560, 490, 430 nm), distances in km. Spectral
    quantities are (4, ...) arrays (wavelength first, so that per-position factors broadcast cheaply)."""
    EARTH_RADIUS = F32(6371.0)
    THICKNESS = F32(100.0)
    RADIUS = F32(6471.0)
    STEPS = 64                       # transmittance and in-scattering ray-march steps
    LUT_W, LUT_H = 256, 64           # transmittance table: cos(sun zenith) x altitude
    GROUND_ALBEDO = F32(0.3)
    RAYLEIGH_PHASE_SCALE = F32(3.0 / 16.0) * INV_PI
    G = F32(0.8)
    SUN_IRRADIANCE = np.array([1.679, 1.828, 1.986, 1.307], F32)
    MOLECULAR_SCATTERING = np.array([6.605e-3, 1.067e-2, 1.842e-2, 3.156e-2], F32)
    OZONE_CROSS_SECTION = np.array([3.472e-25, 3.914e-25, 1.349e-25, 11.03e-27], F32)
    OZONE_MEAN_DOBSON = F32(334.5)
    AEROSOL_ABSORPTION = np.array([2.8722e-24, 4.6168e-24, 7.9706e-24, 1.3578e-23], F32)
    AEROSOL_SCATTERING = np.array([1.5908e-22, 1.7711e-22, 2.0942e-22, 2.4033e-22], F32)
    AEROSOL_BASE_DENSITY = F32(1.3681e20)
    AEROSOL_BACKGROUND_DENSITY = F32(2e6)
    AEROSOL_HEIGHT_SCALE = F32(0.73)
    SPECTRAL_XYZ = np.array([[53.386917738564668023, 22.981337506691024754, 0.0],
                             [43.904844466369358263, 71.347795700053393866, 0.102506867965741307],
                             [1.6137278251608962005, 18.422960591455485011, 31.742921188390805758],
                             [20.762668673810577145, 2.3614213523314368527, 110.48009643252140334]], F32)
    MULTISCATTERING_FIT = F32(0.02) * np.array([0.217, 0.347, 0.594, 1.0], F32)

    def __init__(self, air: float, aerosol: float, ozone: float):
        self.air, self.aerosol, self.ozone = F32(air), F32(aerosol), F32(ozone)
        self.lut = None

    @staticmethod
    def _spectral(c: np.ndarray, ndim: int) -> np.ndarray:
        """A (4,) constant shaped to broadcast against (4, ...) arrays of ndim - 1 trailing axes."""
        return c.reshape((4,) + (1,) * (ndim - 1))

    def coefficients(self, h):
        """At altitudes h (km): extinction, aerosol scattering and molecular scattering, each (4, ...)."""
        s = functools.partial(self._spectral, ndim=h.ndim + 1)
        aerosol = self.AEROSOL_BASE_DENSITY * (expf(-h / self.AEROSOL_HEIGHT_SCALE)
                                               + self.AEROSOL_BACKGROUND_DENSITY / self.AEROSOL_BASE_DENSITY)
        aerosol = aerosol * self.aerosol
        log_h = libm(np.log, np.maximum(h, F32(1e-4)))
        ozone = F32(3.78547397e20) * expf(-np.square(log_h - F32(3.22261)) * F32(5.55555555) - log_h)
        powh = libm(lambda v: np.power(v, F64(F32(1.16364243))), h)
        molecular = expf(F32(-0.07771971) * powh)
        absorb_a = s(self.AEROSOL_ABSORPTION) * aerosol
        scatter_a = s(self.AEROSOL_SCATTERING) * aerosol
        absorb_m = s(self.OZONE_CROSS_SECTION * self.OZONE_MEAN_DOBSON) * ozone * self.ozone
        scatter_m = s(self.MOLECULAR_SCATTERING) * molecular * self.air
        return ((absorb_a + scatter_a) + absorb_m) + scatter_m, scatter_a, scatter_m

    def transmittance(self, cos_theta, normalized_altitude):
        """Transmittance from an altitude towards the sun, ray-marched: (4, ...)."""
        cos_theta, normalized_altitude = np.broadcast_arrays(F32(cos_theta), F32(normalized_altitude))
        sx = -np.sqrt(ONE - cos_theta * cos_theta)
        r0 = self.EARTH_RADIUS + normalized_altitude * (self.RADIUS - self.EARTH_RADIUS)
        t_step = _ray_sphere(r0, cos_theta, self.RADIUS) / F32(self.STEPS)
        depth = np.zeros((4,) + cos_theta.shape, F32)
        for step in range(self.STEPS):
            t = F32(step + 0.5) * t_step
            h = np.maximum(length_xyz((sx * t, ZERO, r0 + cos_theta * t)) - self.EARTH_RADIUS, ZERO)
            depth += self.coefficients(h)[0] * t_step
        return expf(-depth)

    def precompute_lut(self):
        u = np.arange(self.LUT_W, dtype=F32) / F32(self.LUT_W - 1)
        v = np.arange(self.LUT_H, dtype=F32) / F32(self.LUT_H - 1)
        self.lut = self.transmittance((u * F32(2.0) - ONE)[None, :], v[:, None]).reshape(4, -1)

    def _texels(self, cos_theta, normalized_altitude):
        """The table's bilinear footprint (lookup_transmittance): column and row pairs and weights."""
        x = F32(self.LUT_W - 1) * np.clip(cos_theta * HALF + HALF, ZERO, ONE)
        y = F32(self.LUT_H - 1) * np.clip(normalized_altitude, ZERO, ONE)
        x1, y1 = x.astype(np.int32), y.astype(np.int32)
        x2, y2 = np.minimum(x1 + 1, self.LUT_W - 1), np.minimum(y1 + 1, self.LUT_H - 1)
        return x1, x2, x - x1.astype(F32), y1 * self.LUT_W, y2 * self.LUT_W, y - y1.astype(F32)

    def inscattering(self, sun_x, sun_z, origin_z, dx, dy, dz, t_d):
        """Light scattered into the rays (0, 0, origin_z) + t (dx, dy, dz), t in [0, t_d]: (4, N)."""
        cos_theta = -dx * sun_x + -dz * sun_z
        molecular_phase = self.RAYLEIGH_PHASE_SCALE * (ONE + cos_theta * cos_theta)
        g2 = self.G * self.G
        den = (ONE + g2) + F32(2.0) * self.G * cos_theta
        aerosol_phase = (INV_4PI * (ONE - g2)) / (den * np.sqrt(den))
        dt = t_d / F32(self.STEPS)
        lut = self.lut
        top_column = self.LUT_W - 1
        ground_at_sun = lut[:, top_column:top_column + 1]      # lookup_transmittance_to_sun(0)
        albedo = self.GROUND_ALBEDO * INV_PI
        fit_colour = self.MULTISCATTERING_FIT[:, None]
        irradiance = self.SUN_IRRADIANCE[:, None]
        radiance = np.zeros((4,) + dx.shape, F32)
        transmittance = np.ones((4,) + dx.shape, F32)

        def take(i):
            return np.take(lut, i, axis=1)

        for i in range(self.STEPS):
            t = F32(i + 0.5) * dt
            x, y, z = dx * t, dy * t, origin_z + dz * t
            distance = length_xyz((x, y, z))
            h = np.maximum(distance - self.EARTH_RADIUS, ZERO)
            normalized_h = h / self.THICKNESS
            sample_cos = (x / distance) * sun_x + (z / distance) * sun_z
            extinction, scatter_a, scatter_m = self.coefficients(h)

            x1, x2, fx, row1, row2, fy = self._texels(sample_cos, normalized_h)
            a, b = take(row1 + x1), take(row1 + x2)
            bottom = a + fx * (b - a)
            a, b = take(row2 + x1), take(row2 + x2)
            to_sun = bottom + fy * ((a + fx * (b - a)) - bottom)       # lookup_transmittance
            a, b = take(x1), take(x2)
            to_ground = a + fx * (b - a)                                # lookup_transmittance_at_ground
            a, b = take(row1 + top_column), take(row2 + top_column)
            sample_at_sun = a + fy * (b - a)                            # lookup_transmittance_to_sun

            # Multiple scattering (lookup_multiscattering): from the ground, and the fit of the rest.
            omega = TWO_PI * (ONE - np.sqrt(np.maximum(ONE - np.square(self.EARTH_RADIUS / distance), ZERO)))
            ground = ((INV_4PI * omega * albedo) * to_ground) * (ground_at_sun / sample_at_sun) \
                * sample_cos
            fit = ONE / (ONE + F32(5.0) * expf(F32(-17.92) * sample_cos))
            ms = fit_colour * fit + ground

            source = irradiance * (scatter_m * (molecular_phase * to_sun + ms)
                                   + scatter_a * (aerosol_phase * to_sun + ms))
            step = expf(-dt * extinction)
            # Frostbite's energy-conserving integration over the step (Hillaire).
            integral = (source - source * step) / np.maximum(extinction, F32(1e-7))
            radiance += transmittance * integral
            transmittance *= step
        return radiance

    def to_xyz(self, spectrum):
        """(4, ...) spectrum -> (..., 3) XYZ."""
        m = self.SPECTRAL_XYZ
        out = np.zeros(spectrum.shape[1:] + (3,), F32)
        for i in range(4):
            out += m[i] * spectrum[i][..., None]
        return out


def _multiple_scattering_table(sun_elevation, altitude_m, air, aerosol, ozone) -> np.ndarray:
    """(TABLE_HEIGHT, TABLE_WIDTH, 3) XYZ sky radiance (SKY_multiple_scattering_precompute_texture)."""
    atmosphere = _Atmosphere(air, aerosol, ozone)
    atmosphere.precompute_lut()
    altitude = F32(np.clip(F32(altitude_m), F32(1.0), F32(99999.0))) / F32(1000.0)
    sun_cos = cosf(HALF_PI - F32(sun_elevation))
    sun_x, sun_z = -np.sqrt(ONE - sun_cos * sun_cos), sun_cos
    half = TABLE_WIDTH // 2
    u = (np.arange(half, dtype=F32) + HALF) / F32(TABLE_WIDTH)
    v = (np.arange(TABLE_HEIGHT, dtype=F32) + HALF) / F32(TABLE_HEIGHT)
    azimuth = TWO_PI * u
    lv = v * F32(2.0) - ONE
    elevation = np.copysign(lv * lv, lv) * HALF_PI   # more rows near the horizon
    cos_e, sin_e = cosf(elevation)[:, None], sinf(elevation)[:, None]
    dx, dy = cos_e * cosf(azimuth)[None, :], cos_e * sinf(azimuth)[None, :]
    dz = np.broadcast_to(sin_e, dx.shape)
    origin_z = atmosphere.EARTH_RADIUS + altitude
    to_air = _ray_sphere(origin_z, dz, atmosphere.RADIUS)
    to_ground = _ray_sphere(origin_z, dz, atmosphere.EARTH_RADIUS)
    t_d = np.where(to_ground < ZERO, to_air, to_ground)
    spectrum = atmosphere.inscattering(sun_x, sun_z, origin_z, dx.ravel(), dy.ravel(), dz.ravel(),
                                       t_d.ravel())
    xyz = atmosphere.to_xyz(spectrum).reshape(TABLE_HEIGHT, half, 3)
    return np.concatenate([xyz, xyz[:, ::-1]], axis=1)   # mirrored about the sun's azimuth


def _multiple_scattering_sun(sun_elevation, angular_diameter, altitude_m, air, aerosol, ozone):
    """XYZ radiance of the sun disc's lowest and highest points (SKY_multiple_scattering_precompute_sun)."""
    atmosphere = _Atmosphere(air, aerosol, ozone)
    altitude = F32(np.clip(F32(altitude_m), F32(1.0), F32(99999.0))) / F32(1000.0)
    half = F32(angular_diameter) / F32(2.0)
    solid_angle = TWO_PI * (ONE - cosf(half))
    elevations = np.array([F32(sun_elevation) - half, F32(sun_elevation) + half], F32)
    transmittance = atmosphere.transmittance(cosf(HALF_PI - elevations), altitude / atmosphere.THICKNESS)
    xyz = atmosphere.to_xyz(atmosphere.SUN_IRRADIANCE[:, None] * transmittance / solid_angle)
    return xyz[0], xyz[1]


# ---- single scattering (sky_single_scattering.cpp, the former Nishita model) -------------------------

class _SingleScattering:
    """Rayleigh, Mie and ozone over 21 wavelengths (380..780 nm), distances in m."""
    RAYLEIGH_SCALE = F32(8e3)
    MIE_SCALE = F32(1.2e3)
    MIE_COEFF = F32(2e-5)
    MIE_G = F32(0.76)
    EARTH_RADIUS = F32(6360e3)
    RADIUS = F32(6420e3)
    STEPS = 32
    STEP_LAMBDA = F32(20.0)
    IRRADIANCE = np.array([
        1.45756829855592995315, 1.56596305559738380175, 1.65148449067670455293, 1.71496242737209314555,
        1.75797983805020541226, 1.78256407885924539336, 1.79095108475838560302, 1.78541550133410664714,
        1.76815554864306845317, 1.74122069647250410362, 1.70647127164943679389, 1.66556087452739887134,
        1.61993437242451854274, 1.57083597368892080581, 1.51932335059305478886, 1.46628494965214395407,
        1.41245852740172450623, 1.35844961970384092709, 1.30474913844739281998, 1.25174963272610817455,
        1.19975998755420620867], F32)
    RAYLEIGH_COEFF = np.array([
        0.00005424820087636473, 0.00004418549866505454, 0.00003635151910165377, 0.00003017929012024763,
        0.00002526320226989157, 0.00002130859310621843, 0.00001809838025320633, 0.00001547057129129042,
        0.00001330284977336850, 0.00001150184784075764, 0.00000999557429990163, 0.00000872799973630707,
        0.00000765513700977967, 0.00000674217203751443, 0.00000596134125832052, 0.00000529034598065810,
        0.00000471115687557433, 0.00000420910481110487, 0.00000377218381260133, 0.00000339051255477280,
        0.00000305591531679811], F32)
    OZONE_COEFF = np.array([
        0.00000000325126849861, 0.00000000585395365047, 0.00000001977191155085, 0.00000007309568762914,
        0.00000020084561514287, 0.00000040383958096161, 0.00000063551335912363, 0.00000096707041180970,
        0.00000154797400424410, 0.00000209038647223331, 0.00000246128056164565, 0.00000273551299461512,
        0.00000215125863128643, 0.00000159051840791988, 0.00000112356197979857, 0.00000073527551487574,
        0.00000046450130357806, 0.00000033096079921048, 0.00000022512612292678, 0.00000014879129266490,
        0.00000016828623364192], F32)
    CMF_XYZ = np.array([
        [0.00136800000, 0.00003900000, 0.00645000100], [0.01431000000, 0.00039600000, 0.06785001000],
        [0.13438000000, 0.00400000000, 0.64560000000], [0.34828000000, 0.02300000000, 1.74706000000],
        [0.29080000000, 0.06000000000, 1.66920000000], [0.09564000000, 0.13902000000, 0.81295010000],
        [0.00490000000, 0.32300000000, 0.27200000000], [0.06327000000, 0.71000000000, 0.07824999000],
        [0.29040000000, 0.95400000000, 0.02030000000], [0.59450000000, 0.99500000000, 0.00390000000],
        [0.91630000000, 0.87000000000, 0.00165000100], [1.06220000000, 0.63100000000, 0.00080000000],
        [0.85444990000, 0.38100000000, 0.00019000000], [0.44790000000, 0.17500000000, 0.00002000000],
        [0.16490000000, 0.06100000000, 0.00000000000], [0.04677000000, 0.01700000000, 0.00000000000],
        [0.01135916000, 0.00410200000, 0.00000000000], [0.00289932700, 0.00104700000, 0.00000000000],
        [0.00069007860, 0.00024920000, 0.00000000000], [0.00016615050, 0.00006000000, 0.00000000000],
        [0.00004150994, 0.00001499000, 0.00000000000]], F32)
    # Gauss-Laguerre quadrature (8 nodes) of the optical depth along a ray, weights times e^x.
    QUADRATURE_NODES = np.array([0.006811185292, 0.03614807107, 0.09004346519, 0.1706680068, 0.2818362161,
                                 0.4303406404, 0.6296271457, 0.9145252695], F32)
    QUADRATURE_WEIGHTS = np.array([0.01750893642, 0.04135477391, 0.06678839063, 0.09507698807,
                                   0.1283416365, 0.1707430204, 0.2327233347, 0.3562490486], F32)

    def densities(self, h):
        """(..., 3): Rayleigh, Mie and ozone density factors at height h (m)."""
        rayleigh = expf(-h / self.RAYLEIGH_SCALE)
        mie = expf(-h / self.MIE_SCALE)
        # C evaluates the ozone profile in double (its literals are double).
        ozone = np.maximum(0.0, 1.0 - np.abs(h.astype(F64) - 25000.0) / 15000.0).astype(F32)
        return np.stack([rayleigh, mie, ozone], axis=-1)

    def to_air(self, px, py, pz, dx, dy, dz):
        """Where the ray leaves the atmosphere (atmosphere_intersection)."""
        b = F32(-2.0) * (dx * -px + dy * -py + dz * -pz)
        c = (px * px + py * py + pz * pz) - self.RADIUS * self.RADIUS
        t = (-b + np.sqrt(b * b - F32(4.0) * c)) / F32(2.0)
        return px + dx * t, py + dy * t, pz + dz * t

    def optical_depth(self, px, py, pz, dx, dy, dz):
        """(..., 3) optical depth factors from a point to the top of the atmosphere."""
        ex, ey, ez = self.to_air(px, py, pz, dx, dy, dz)
        length = length_xyz((px - ex, py - ey, pz - ez))
        sx, sy, sz = length * dx, length * dy, length * dz
        depth = np.zeros(np.shape(length) + (3,), F32)
        for node, weight in zip(self.QUADRATURE_NODES, self.QUADRATURE_WEIGHTS):
            h = length_xyz((px + node * sx, py + node * sy, pz + node * sz)) - self.EARTH_RADIUS
            depth += self.densities(h) * weight
        return depth * length[..., None]

    def earth_blocks(self, px, py, pz, dx, dy, dz):
        """surface_intersection: does the ray from P hit the ground."""
        b = F32(-2.0) * (dx * -px + dy * -py + dz * -pz)
        c = (px * px + py * py + pz * pz) - self.EARTH_RADIUS * self.EARTH_RADIUS
        return (dz < ZERO) & (b * b - F32(4.0) * c >= ZERO)

    def phases(self, mu):
        rayleigh = (F32(0.1875) * INV_PI) * (ONE + mu * mu)
        g2 = self.MIE_G * self.MIE_G
        base = (ONE + g2) - F32(2.0) * self.MIE_G * mu
        mie = (F32(3.0) * (ONE - g2) * (ONE + mu * mu)) / \
            (F32(8.0) * PI * (F32(2.0) + g2) * libm(lambda v: np.power(v, 1.5), base))
        return rayleigh, mie

    def to_xyz(self, spectrum):
        """(21, ...) spectrum -> (..., 3) XYZ."""
        out = np.zeros(spectrum.shape[1:] + (3,), F32)
        for i in range(len(self.CMF_XYZ)):
            out += self.CMF_XYZ[i] * spectrum[i][..., None]
        return out * self.STEP_LAMBDA

    def inscattering(self, dx, dy, dz, sun, origin_z, density_scale):
        """Single scattering of sunlight into rays from (0, 0, origin_z): (21, N) spectra."""
        zeros = np.zeros_like(dx)
        ex, ey, ez = self.to_air(zeros, zeros, origin_z + zeros, dx, dy, dz)
        segment_length = length_xyz((zeros - ex, zeros - ey, origin_z - ez)) / F32(self.STEPS)
        seg = (segment_length * dx, segment_length * dy, segment_length * dz)
        rayleigh_phase, mie_phase = self.phases(dx * sun[0] + dy * sun[1] + dz * sun[2])
        air, aerosol, ozone = (F32(v) for v in density_scale)
        rayleigh = self.RAYLEIGH_COEFF[:, None]
        ozone_coeff = self.OZONE_COEFF[:, None]
        mie_extinction = F32(1.11) * self.MIE_COEFF
        spectrum = np.zeros((21,) + dx.shape, F32)
        depth = [np.zeros_like(dx) for _ in range(3)]
        px, py, pz = zeros + HALF * seg[0], zeros + HALF * seg[1], origin_z + HALF * seg[2]
        sun_b = [np.broadcast_to(F32(c), dx.shape) for c in sun]
        for _ in range(self.STEPS):
            h = length_xyz((px, py, pz)) - self.EARTH_RADIUS
            density = self.densities(h)
            density = (air * density[..., 0], aerosol * density[..., 1], ozone * density[..., 2])
            for k in range(3):
                depth[k] = depth[k] + segment_length * density[k]
            lit = ~self.earth_blocks(px, py, pz, *sun_b)
            light = self.optical_depth(px, py, pz, *sun_b)
            total = [depth[k] + scale * light[..., k] for k, scale in enumerate((air, aerosol, ozone))]
            attenuation = expf(-((total[0] * rayleigh + total[1] * mie_extinction) + total[2] * ozone_coeff))
            scattering = rayleigh_phase * (density[0] * rayleigh) + mie_phase * (density[1] * self.MIE_COEFF)
            contribution = ((attenuation * scattering) * self.IRRADIANCE[:, None]) * segment_length
            spectrum += np.where(lit, contribution, ZERO)
            px, py, pz = px + seg[0], py + seg[1], pz + seg[2]
        return spectrum


def _single_scattering_table(sun_elevation, altitude_m, air, aerosol, ozone) -> np.ndarray:
    """(TABLE_HEIGHT, TABLE_WIDTH, 3) XYZ (SKY_single_scattering_precompute_texture): the upper half
    ray-marched, the lower half the horizon row faded out."""
    model = _SingleScattering()
    altitude = F32(np.clip(F32(altitude_m), F32(1.0), F32(59999.0)))
    half_w, half_h = TABLE_WIDTH // 2, TABLE_HEIGHT // 2
    elevation = F32(sun_elevation)
    sun = (cosf(elevation) * cosf(ZERO), cosf(elevation) * sinf(ZERO), sinf(elevation))
    rows = np.arange(half_h, TABLE_HEIGHT)
    latitude = HALF_PI * np.square(rows.astype(F32) / F32(half_h) - ONE)
    longitude = (TWO_PI / F32(TABLE_WIDTH)) * np.arange(half_w, dtype=F32) - PI
    cl = cosf(latitude)[:, None]
    dx = cl * cosf(longitude)[None, :]
    dy = cl * sinf(longitude)[None, :]
    dz = np.broadcast_to(sinf(latitude)[:, None], dx.shape)
    spectrum = model.inscattering(dx.ravel(), dy.ravel(), dz.ravel(), sun, model.EARTH_RADIUS + altitude,
                                  (air, aerosol, ozone))
    upper = model.to_xyz(spectrum).reshape(half_h, half_w, 3)
    upper = np.concatenate([upper, upper[:, ::-1]], axis=1)
    low_rows = np.arange(half_h)
    low_lat = HALF_PI * np.square(low_rows.astype(F32) / F32(half_h) - ONE)
    dir_z = sinf(low_lat)
    fade = ONE - dir_z * F32(2.5)
    fade = np.where(dir_z < F32(0.4), np.square(fade) * fade, ZERO)
    lower = upper[0][None, :, :] * fade[:, None, None]
    return np.concatenate([lower, upper], axis=0).astype(F32, copy=False)


def _single_scattering_sun(sun_elevation, angular_diameter, altitude_m, air, aerosol):
    model = _SingleScattering()
    altitude = F32(np.clip(F32(altitude_m), F32(1.0), F32(59999.0)))
    half = F32(angular_diameter) / F32(2.0)
    solid_angle = TWO_PI * (ONE - cosf(half))
    bottom, top = F32(sun_elevation) - half, F32(sun_elevation) + half
    if not top > ZERO:
        return np.zeros(3, F32), np.zeros(3, F32)
    elevation = np.array([max(bottom, ZERO), max(top, ZERO)], F32)
    dx, dy, dz = cosf(elevation) * cosf(ZERO), cosf(elevation) * sinf(ZERO), sinf(elevation)
    zeros = np.zeros(2, F32)
    depth = model.optical_depth(zeros, zeros, zeros + model.EARTH_RADIUS + altitude, dx, dy, dz)
    tau = (model.RAYLEIGH_COEFF[:, None] * depth[:, 0] * F32(air)
           + F32(1.11) * model.MIE_COEFF * depth[:, 1] * F32(aerosol))
    spectrum = model.IRRADIANCE[:, None] * expf(-tau) / solid_angle
    xyz = model.to_xyz(spectrum)
    return xyz[0], xyz[1]


def earth_intersection_angle(altitude_m: float) -> np.float32:
    """How far below the horizon the ground starts, seen from the altitude (SKY_earth_intersection_angle)."""
    earth = F32(6371.0)
    return HALF_PI - libm(np.arcsin, earth / (earth + F32(altitude_m) / F32(1000.0)))


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


# ---- the node -------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Sky:
    """The Sky node's export-time data, what Cycles' compiler writes into the SVM program."""
    sky_type: str
    table: np.ndarray | None = None          # (3, TABLE_HEIGHT, TABLE_WIDTH) X, Y, Z; row 0 lowest elevation
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
        raise NotImplementedError("the Hosek-Wilkie sky needs the model's data set, which Ember lacks")
    if sky_type not in SKY_TYPES:
        raise ValueError(f"unknown sky_type {sky_type!r}")
    elevation, rotation = _wrap_sun(sun_elevation, sun_rotation)
    diameter = max(F32(sun_size), F32(0.0005))           # Cycles clamps it for precision
    if sky_type == "MULTIPLE_SCATTERING":
        bottom, top = _multiple_scattering_sun(elevation, diameter, altitude, air_density, aerosol_density,
                                               ozone_density)
        table = _multiple_scattering_table(elevation, altitude, air_density, aerosol_density, ozone_density)
    else:
        bottom, top = _single_scattering_sun(elevation, diameter, altitude, air_density, aerosol_density)
        table = _single_scattering_table(elevation, altitude, air_density, aerosol_density, ozone_density)
    table = np.ascontiguousarray(np.moveaxis(table, -1, 0))
    return Sky(sky_type, table=table, sun_bottom=bottom, sun_top=top, sun_elevation=elevation,
               sun_rotation=rotation, angular_diameter=diameter if sun_disc else F32(-1.0),
               sun_intensity=F32(sun_intensity), horizon=-earth_intersection_angle(altitude))


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


def _preetham_eval(direction: np.ndarray, sky: Sky) -> np.ndarray:
    theta, phi = _spherical(direction)
    phi = -phi + HALF_PI
    cos_psi = (sinf(theta) * sinf(sky.sun_theta) * cosf(sky.sun_phi - phi)
               + cosf(theta) * cosf(sky.sun_theta))
    gamma = libm(np.arccos, np.clip(cos_psi, -ONE, ONE))
    theta = np.minimum(theta, HALF_PI - F32(0.001))
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
    return {"Color": _nishita(direction, sky)}
