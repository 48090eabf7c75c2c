"""Volume shaders: a material's (or the world's) Volume output evaluated at points inside its medium, as
Cycles' volume_shader_eval (kernel/integrator/volume_shader.h) with the closures of kernel/svm/closure.h:
the scattering and extinction coefficients, the emission per unit length, and the phase closures.

At a point of a medium Cycles' shading point is the point itself: P, N = Ng = -D and the viewer direction
-D (shader_setup_from_volume), the medium's object (Object and Generated coordinates in its space), no UV.
Attributes are the object's voxel grids (a Volume object's, a smoke domain's), looked up at P: Volume Info,
the Attribute node and Principled Volume's Density, Color and Temperature Attribute read them; a mesh has
none, and a missing attribute leaves Principled Volume's density and colour as they are (Cycles'
is_attribute_found).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..scene import OBJ_FROM_WORLD, OBJECT_COLUMNS, object_row
from ..vec import F32, ONE, ZERO
from .color_nodes import REC709_TO_RGB, blackbody
from .input_ops import object_point
from .ops import OPS
from .program import OBJECT_ATTRIBUTE_PREFIXES, ProgramRun

# Stefan-Boltzmann's constant as Principled Volume's blackbody emission uses it (W m^-2 K^-4, per
# micrometre of wavelength and per steradian: svm_node_principled_volume).
STEFAN_BOLTZMANN = 5.670373e-8 * 1e-6 / np.pi

# Defaults of the volume nodes' inputs (Blender 5.0, node_shader_volume_*.cc; Cycles' scene/shader_nodes.cpp).
VOLUME_DEFAULTS = {
    "VOLUME_SCATTER": {"Color": (0.8, 0.8, 0.8), "Density": 1.0, "Anisotropy": 0.0, "IOR": 1.33,
                       "Backscatter": 0.1, "Alpha": 0.5, "Diameter": 20.0},
    "VOLUME_ABSORPTION": {"Color": (0.8, 0.8, 0.8), "Density": 1.0},
    "PRINCIPLED_VOLUME": {"Color": (0.5, 0.5, 0.5), "Density": 1.0, "Anisotropy": 0.0,
                          "Absorption Color": (0.0, 0.0, 0.0), "Emission Strength": 0.0,
                          "Emission Color": (1.0, 1.0, 1.0), "Blackbody Intensity": 0.0,
                          "Blackbody Tint": (1.0, 1.0, 1.0), "Temperature": 1000.0},
    "VOLUME_COEFFICIENTS": {"Absorption Coefficients": (1.0, 1.0, 1.0), "Scatter Coefficients": (1.0, 1.0, 1.0),
                            "Emission Coefficients": (0.0, 0.0, 0.0), "Anisotropy": 0.0, "IOR": 1.33,
                            "Backscatter": 0.1, "Alpha": 0.5, "Diameter": 20.0},
    "EMISSION": {"Color": (1.0, 1.0, 1.0), "Strength": 1.0},
}
# The phase parameters each scattering closure hands its phase function (kernels.media.phase).
PHASE_INPUTS = ("Anisotropy", "IOR", "Backscatter", "Alpha", "Diameter")


@dataclass
class PhaseClosure:
    """One phase closure at n points: its phase (Cycles' Volume Scatter Phase: HENYEY_GREENSTEIN,
    FOURNIER_FORAND, DRAINE, RAYLEIGH, MIE), its spectral weight (3, n) (its share of the scattering
    coefficient) and its parameters by input name ((n,) each)."""
    phase: str
    weight: np.ndarray
    params: dict


@dataclass
class VolumeCoefficients:
    """A medium's coefficients at n points: scattering and extinction (3, n) per unit length, emission (3, n)
    radiance per unit length, and the phase closures (their weights add up to sigma_s)."""
    sigma_s: np.ndarray
    sigma_t: np.ndarray
    emission: np.ndarray
    phases: list = field(default_factory=list)

    @classmethod
    def zeros(cls, n: int) -> "VolumeCoefficients":
        return cls(np.zeros((3, n), F32), np.zeros((3, n), F32), np.zeros((3, n), F32), [])

    def add(self, other: "VolumeCoefficients", idx: np.ndarray | None = None) -> None:
        """Add other's coefficients (of the points idx of these, or of all)."""
        if idx is None:
            self.sigma_s += other.sigma_s
            self.sigma_t += other.sigma_t
            self.emission += other.emission
            self.phases.extend(other.phases)
            return
        self.sigma_s[:, idx] += other.sigma_s
        self.sigma_t[:, idx] += other.sigma_t
        self.emission[:, idx] += other.emission
        n = self.sigma_s.shape[1]
        for p in other.phases:
            weight = np.zeros((3, n), F32)
            weight[:, idx] = p.weight
            params = {}
            for k, v in p.params.items():
                full = np.zeros(n, F32)
                full[idx] = v
                params[k] = full
            self.phases.append(PhaseClosure(p.phase, weight, params))

    def take(self, idx: np.ndarray) -> "VolumeCoefficients":
        """The coefficients of the points idx."""
        return VolumeCoefficients(self.sigma_s[:, idx], self.sigma_t[:, idx], self.emission[:, idx],
                                  [PhaseClosure(p.phase, p.weight[:, idx], {k: v[idx] for k, v in p.params.items()})
                                   for p in self.phases])


class _Points:
    """The SurfaceHit fields input ops read at medium points: only the path state (Light Path)."""
    __slots__ = ("ray",)

    def __init__(self, ray):
        self.ray = ray


class PointInputs:
    """program.HitInputs for points in a medium: P, the ray direction, the medium's object and its grids."""

    def __init__(self, scene, p: np.ndarray, d: np.ndarray, objects: np.ndarray | None, grids=None,
                 interpolation: str = "LINEAR", ray=None):
        """scene : shading.shader.ShadingData. p, d : (n, 3) points and unit ray directions. objects : (n,)
        rows of the object table (None: no object, the world's medium). grids : {name: grid} with
        lookup(points (n, 3) in object space, interpolation) -> (n, C), or None."""
        self.scene = scene
        self.n = len(p)
        self.idx = np.arange(self.n)
        self.hit = _Points(ray)
        self.P = np.ascontiguousarray(p, F32)
        self.I = -np.ascontiguousarray(d, F32)
        self.N = self.Ng = self.I
        self.backfacing = np.zeros(self.n, bool)
        self.uv = np.zeros((self.n, 3), F32)
        self.dp = np.zeros(self.n, F32)
        self.world = objects is None
        self._rows = objects
        # A medium's points are all of one object (Media evaluates one medium at a time): its row, read once.
        self._single = None
        if objects is not None and self.n and (objects == objects[0]).all():
            self._single = int(objects[0])
        self._grids = grids or {}
        self._interpolation = interpolation
        self._cache = {}

    def memo(self, key, compute):
        if key not in self._cache:
            self._cache[key] = compute()
        return self._cache[key]

    def objects(self) -> np.ndarray:
        if self._rows is None:
            return np.broadcast_to(_IDENTITY_OBJECT, (self.n, OBJECT_COLUMNS))
        if self._single is not None:
            return np.broadcast_to(self.scene.objects[self._single], (self.n, OBJECT_COLUMNS))
        return self.memo("objects", lambda: np.take(self.scene.objects, self._rows, axis=0))

    def _grid_lookup(self, grid) -> np.ndarray:
        """grid's values at the points: the object's world-to-object map and the grid's own taken as one
        product where the points are all of one object."""
        if self._single is None:
            return grid.lookup(object_point(self, self.P), self._interpolation)
        m = self.scene.objects[self._single, OBJ_FROM_WORLD:OBJ_FROM_WORLD + 12].reshape(3, 4)
        return grid.lookup(self.P, self._interpolation, to_object=m)

    def attribute(self, name: str, interpolate: bool = True) -> np.ndarray | None:
        """(n, C) a grid's values at the points (its name, or the Attribute node's "attr:" name), None when the
        medium has no grid of that name; an object attribute ("object:", "instancer:") of the points' object
        rows (none in the world's medium)."""
        if name.startswith(OBJECT_ATTRIBUTE_PREFIXES):
            table = self.scene.object_attributes.get(name) if self._rows is not None else None
            return None if table is None else np.take(table, self._rows, axis=0)
        grid = self._grids.get(name[5:] if name.startswith("attr:") else name)
        if grid is None:
            return None
        key = ("grid", name)
        if key not in self._cache:
            self._cache[key] = np.asarray(self._grid_lookup(grid), F32)
        return self._cache[key]

    def barycentrics(self):
        zero = np.zeros(self.n, F32)
        return zero, zero


_IDENTITY_OBJECT = object_row(np.eye(4))


class VolumeShader:
    """One Volume output (a material's or the world's): its closures and program, ready to evaluate."""

    def __init__(self, shader, data):
        """shader : kernels.scene.Shader with volume closures; data : shading.shader.ShadingData."""
        self.closures = shader.volume
        self.program = shader.program
        self.interpolation = shader.interpolation
        self.data = data
        # Constant inputs everywhere (no program): one evaluation gives a medium's coefficients, unless it reads
        # grids (Principled Volume's attributes) and its object has them.
        self.constant = not any(p.varies for c in self.closures for p in c.params())
        self.reads_grids = any(dict(c.options).get(k) for c in self.closures
                               for k in ("Density Attribute", "Color Attribute", "Temperature Attribute"))
        self.emits = any(_may_emit(c) for c in self.closures)

    def evaluate(self, p: np.ndarray, d: np.ndarray, objects: np.ndarray | None, grids=None, ray=None,
                 emission: bool = True) -> VolumeCoefficients:
        """The coefficients at points p (n, 3) seen along d (n, 3), of objects (n,) (None: the world)."""
        n = len(p)
        out = VolumeCoefficients.zeros(n)
        if n == 0:
            return out
        inputs = PointInputs(self.data, p, d, objects, grids, self.interpolation, ray)
        run = ProgramRun(self.program, inputs, OPS)

        def value(closure, name):
            """An input at the points: (3, n) for colours and vectors ((3, 1) where constant), (n,) for floats."""
            default = VOLUME_DEFAULTS[closure.kind][name]
            colour = isinstance(default, tuple)
            param = closure.input(name)
            if param is not None and param.link is not None:
                v = run.value(param.link)   # converted to the socket's type: (n,) or (n, 3)
                if v.ndim == 2:
                    return np.ascontiguousarray(v.T if colour else v.mean(axis=1), F32)
                return np.ascontiguousarray(np.broadcast_to(v, (3, n)) if colour else v, F32)
            const = np.asarray(default if param is None else param.value, F32).ravel()
            if colour:
                # (3, 1): a constant colour's arithmetic costs 3 values, not 3 n; it broadcasts against the
                # (n,) densities and factors every coefficient takes.
                return (np.repeat(const, 3) if const.size == 1 else const[:3])[:, None]
            return np.full(n, const.mean(), F32)

        for closure in self.closures:
            mix = np.ones(n, F32)
            for fac, second in closure.factors:
                f = np.clip(_factor(run, fac, n), 0.0, 1.0)
                mix = mix * (f if second else ONE - f)
            kind = closure.kind
            if kind == "EMISSION":
                if emission:
                    out.emission += value(closure, "Color") * value(closure, "Strength") * mix
                continue
            if kind in ("VOLUME_SCATTER", "VOLUME_ABSORPTION"):
                density = mix * np.maximum(value(closure, "Density"), ZERO)
                color = value(closure, "Color")
                weight = (ONE - color if kind == "VOLUME_ABSORPTION" else color) * density
                if kind == "VOLUME_SCATTER":
                    self._scatter(out, closure, weight, value)
                out.sigma_t += weight
            elif kind == "PRINCIPLED_VOLUME":
                self._principled(out, closure, mix, value, inputs, emission)
            elif kind == "VOLUME_COEFFICIENTS":
                scatter = value(closure, "Scatter Coefficients") * mix
                if np.any(scatter != 0):
                    self._scatter(out, closure, scatter, value)
                out.sigma_t += (scatter + value(closure, "Absorption Coefficients")) * mix
                if emission:
                    out.emission += value(closure, "Emission Coefficients") * mix
        out.sigma_t = np.maximum(out.sigma_t, ZERO)
        out.sigma_s = np.minimum(np.maximum(out.sigma_s, ZERO), out.sigma_t)
        return out

    @staticmethod
    def _scatter(out, closure, weight, value) -> None:
        phase = closure.option("phase", "HENYEY_GREENSTEIN")
        params = {name: value(closure, name) for name in PHASE_INPUTS if name in VOLUME_DEFAULTS[closure.kind]}
        out.phases.append(PhaseClosure(phase, weight, params))
        out.sigma_s += weight

    def _principled(self, out, closure, mix, value, inputs, emission: bool) -> None:
        """svm_node_principled_volume: density times the density grid where there is one, a Henyey-Greenstein
        scattering of Color (times the colour grid), absorption (1 - Color)(1 - sqrt(Absorption Color)), and
        emission: Emission Color x Strength plus blackbody radiation of Temperature (times its grid)."""
        density = mix * np.maximum(value(closure, "Density"), ZERO)
        attribute = closure.option("Density Attribute", "")
        grid = inputs.attribute(attribute) if attribute else None
        if grid is not None:
            density = np.maximum(density * grid[:, 0], ZERO)
        color = value(closure, "Color")
        attribute = closure.option("Color Attribute", "")
        grid = inputs.attribute(attribute) if attribute else None
        if grid is not None:
            color = color * (np.repeat(grid[:, :1], 3, axis=1) if grid.shape[1] == 1 else grid[:, :3]).T
        scatter = color * density
        out.phases.append(PhaseClosure("HENYEY_GREENSTEIN", scatter, {"Anisotropy": value(closure, "Anisotropy")}))
        out.sigma_s += scatter
        absorption_color = np.maximum(np.sqrt(np.maximum(value(closure, "Absorption Color"), ZERO)), ZERO)
        absorption = np.maximum(ONE - color, ZERO) * np.maximum(ONE - absorption_color, ZERO)
        out.sigma_t += (color + absorption) * density
        if not emission:
            return
        strength = value(closure, "Emission Strength")
        out.emission += value(closure, "Emission Color") * np.maximum(strength, ZERO) * mix * (strength > 0)
        blackbody_weight = value(closure, "Blackbody Intensity")
        if np.any(blackbody_weight > 0):
            t = value(closure, "Temperature")
            attribute = closure.option("Temperature Attribute", "")
            grid = inputs.attribute(attribute) if attribute else None
            if grid is not None:
                t = t * np.maximum(grid[:, 0], ZERO)
            t = np.maximum(t, ZERO)
            t4 = (t * t) * (t * t)
            intensity = F32(STEFAN_BOLTZMANN) * (ONE + blackbody_weight * (t4 - ONE))
            rgb = blackbody(t, rec709_to_rgb=REC709_TO_RGB)["Color"].T
            bb = value(closure, "Blackbody Tint") * intensity * rgb
            out.emission += np.where((blackbody_weight > 0) & (intensity > 0), bb * mix, ZERO)


def _factor(run, fac, n) -> np.ndarray:
    if fac.link is not None:
        v = run.value(fac.link)
        return (v.mean(axis=1) if v.ndim == 2 else v).astype(F32)
    return np.full(n, fac.value[0], F32)


def _may_emit(closure) -> bool:
    if closure.kind == "EMISSION":
        return True
    if closure.kind == "PRINCIPLED_VOLUME":
        return any(p is not None and (p.varies or p.value[0] > 0) for p in
                   (closure.input("Emission Strength"), closure.input("Blackbody Intensity")))
    if closure.kind == "VOLUME_COEFFICIENTS":
        p = closure.input("Emission Coefficients")
        return p is not None and (p.varies or any(v != 0 for v in p.value))
    return False
