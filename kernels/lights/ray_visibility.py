"""Lights' own Ray Visibility (a light object's Visibility > Ray Visibility: Diffuse, Glossy, Transmission,
Volume Scatter), as Cycles renders it.

Cycles turns each bounce kind a light object does not see into a flag of the light's shader,
SHADER_EXCLUDE_DIFFUSE, _GLOSSY, _TRANSMIT, _SCATTER (scene/light.cpp), and then:
- a BSDF ray that meets the lamp, or an escaped ray that looks into a sun, after a bounce of an excluded kind
  gets no light from it, though it still meets it and crosses it as a transparent bounce
  (light/common.h is_light_shader_visible_to_path, called by integrator/shade_light.h and
  integrator/shade_background.h; the glossy test also asks PATH_RAY_REFLECT, which Ember's glossy ray type,
  kernels/visibility.py ray_types, always is);
- a light sample at a surface evaluates only the closures the light does not exclude, by class: diffuse
  (CLOSURE_IS_BSDF_DIFFUSE, translucent and sheen included), glossy, transmission, and glass only where both
  glossy and transmission are excluded; the BSDF pdf that weighs the sample by MIS stays that of every closure
  (integrator/surface_shader.h, _surface_shader_exclude in _surface_shader_bsdf_eval_mis), so the BSDF rays
  of the closures left out, which no longer see the lamp either, and the light samples of the others keep
  their MIS pair;
- a light sample in a volume is dropped where the light excludes volume scatter (integrator/shade_volume.h).
The world's Ray Visibility works the same way for its light samples and for escaped rays, and a world the camera
does not see is black to camera rays (Cycles' background visibility, scene/background.cpp). When no light has a
bounce kind off, LightSampler.visibility is None (and world_restricted False) and nothing here runs.
"""
from __future__ import annotations

import numpy as np

from ..bsdf.lobes import DIFFUSE_LOBES, GLASS, GLOSSY_LOBES, TRANSMISSION_LOBES
from ..bsdf.mixture_eval import eval_closures, hit_rows
from ..scene.objects import BSDF_RAYS, RAY_DIFFUSE, RAY_GLOSSY, RAY_SCATTER, RAY_TRANSMIT
from ..vec import F32


def of_emitters(sampler, emitter: np.ndarray) -> np.ndarray:
    """(n,) uint8 the ray visibility of emitters (lamps' own, the world's; triangles see every bounce)."""
    out = np.full(len(emitter), BSDF_RAYS, np.uint8)
    if sampler.visibility is not None:
        lamp = emitter < sampler.light_count
        out = np.where(lamp, np.take(sampler.visibility, np.where(lamp, emitter, 0)), out).astype(np.uint8)
    if sampler.world_restricted:
        out[emitter == sampler.world_index] = sampler.world_visibility
    return out


def world_unseen(sampler, types: np.ndarray, camera: np.ndarray) -> np.ndarray | None:
    """(n,) bool: the escaped rays of types ((n,) uint8, visibility.ray_types) that do not see the world, camera
    ones ((n,) bool) by its Camera switch; None when every ray sees it."""
    if sampler.world_camera and not sampler.world_restricted:
        return None
    unseen = np.zeros(len(types), bool)
    if not sampler.world_camera:
        unseen |= camera
    if sampler.world_restricted:
        unseen |= ~camera & ((types & sampler.world_visibility) == 0)
    return unseen


def unseen(visibility: np.ndarray, types) -> np.ndarray:
    """(n,) bool: lights of `visibility` that rays of `types` ((n,) or one uint8) do not see."""
    return (visibility & np.asarray(types, np.uint8)) == 0


def scatter_excluded(visibility: np.ndarray) -> np.ndarray:
    """(n,) bool: light samples a volume's scattering may not take."""
    return (visibility & RAY_SCATTER) == 0


def eval_visible(cs, hits: np.ndarray, wi, visibility: np.ndarray) -> np.ndarray:
    """f |cos| (3, n) of the mixtures of hits (ascending, unique) toward wi, without the closures whose class
    the sampled lights (visibility (n,) uint8) exclude."""
    out = np.zeros((3, len(hits)), F32)
    if cs.single:
        rows = cs.row_of_hit[hits]
        have = np.flatnonzero(rows >= 0)
        if len(have):
            w = tuple(c[have] for c in wi)
            f, _ = eval_closures(cs, w, rows[have])
            out[:, have] = f * _kept(cs.lobe[rows[have]], visibility[have])
        return out
    idx, local = hit_rows(cs, hits)
    w = tuple(np.take(c, local) for c in wi)
    f, _ = eval_closures(cs, w, idx)
    f = f * _kept(cs.lobe[idx], np.take(visibility, local))
    return np.stack([np.bincount(local, f[k], minlength=len(hits)) for k in range(3)]).astype(F32)


def _kept(lobe: np.ndarray, visibility: np.ndarray) -> np.ndarray:
    """(n,) bool: closures of `lobe` that lights of `visibility` light (Cycles' _surface_shader_exclude)."""
    no_diffuse = (visibility & RAY_DIFFUSE) == 0
    no_glossy = (visibility & RAY_GLOSSY) == 0
    no_transmit = (visibility & RAY_TRANSMIT) == 0
    out = ~(no_diffuse & np.isin(lobe, DIFFUSE_LOBES))
    out &= ~(no_glossy & np.isin(lobe, GLOSSY_LOBES))
    out &= ~(no_transmit & np.isin(lobe, TRANSMISSION_LOBES))
    out &= ~(no_glossy & no_transmit & (lobe == GLASS))
    return out
