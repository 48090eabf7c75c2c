"""The scattering skies' export-time tables (Cycles' `intern/sky`: sky_multiple_scattering.cpp,
sky_single_scattering.cpp), for the Sky Texture node (kernels.shading.sky).

MULTIPLE_SCATTERING is Fernando Garcia Linan's spectral atmosphere (4 wavelengths, a fitted multiple
scattering term), SINGLE_SCATTERING the former "Nishita" model (21 wavelengths). For each, from the sun's
elevation, the altitude and the air, aerosol and ozone densities: a TABLE_HEIGHT x TABLE_WIDTH XYZ table of
the sky (azimuth x elevation, more rows near the horizon, ray-marched through the atmosphere), and the XYZ
of the sun disc's lowest and highest points. Float32 in Cycles' order of operations, with the C library's
float functions as Cycles calls them (kernels.shading.libm).
"""
from __future__ import annotations

import functools

import numpy as np

from ..vec import F32, F64, HALF, HALF_PI, INV_4PI, INV_PI, ONE, PI, TWO_PI, ZERO, length_xyz
from .libm import cosf, expf, libm, sinf

TABLE_WIDTH, TABLE_HEIGHT = 512, 256   # Cycles' SkyLoader


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


def multiple_scattering_table(sun_elevation, altitude_m, air, aerosol, ozone) -> np.ndarray:
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


def multiple_scattering_sun(sun_elevation, angular_diameter, altitude_m, air, aerosol, ozone):
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


def single_scattering_table(sun_elevation, altitude_m, air, aerosol, ozone) -> np.ndarray:
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


def single_scattering_sun(sun_elevation, angular_diameter, altitude_m, air, aerosol):
    """XYZ radiance of the sun disc's lowest and highest points (SKY_single_scattering_precompute_sun);
    zeros when the whole disc is below the horizon."""
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
