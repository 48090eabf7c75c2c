"""Next-event estimation: choosing a light, sampling it, and the pdfs MIS needs.

Three kinds of emitters share one discrete distribution: Blender lights (the Lights table), emissive
triangles (materials with emission) and the world. Local emitters (point, spot and area lights,
triangles) are chosen in proportion to their power (W); distant ones (suns and the world), whose power
is a flux per unit area, share DISTANT_SHARE of the choices, among themselves in proportion to their
irradiance. No scene size enters the choice: a far-away ground plane changes nothing.
With two or more local emitters whose choice per point would differ from that (TREE_MIN_EMITTERS,
TREE_MIN_DIVERGENCE), their share is instead split per shading point by a light tree
(kernels.light_tree): nearby lamps facing the point are chosen more often; among two to
SOLID_ANGLE_MAX_EMITTERS emissive triangles alone (a quad lamp), by the solid angle each subtends at the
point (SolidAngleChoice). The probability of choosing emitter e at point p is then
selection_pmf(e, p), which the MIS pdfs of BSDF rays use with the ray's origin; otherwise it is
select_pmf[e] everywhere.
`sample` returns, per shading point, a direction toward a point on the chosen light, the distance to
it, the radiance arriving along it and its pdf per unit solid angle *including the probability of
choosing that light*, so MIS weights compare like with like. Delta lights (zero-size point and spot,
zero-angle sun) return their irradiance-producing term with pdf = selection probability.

Conventions of the Lights table (see scene.Lights): Blender lights shine down their local -Z, so
the sun lies along +Z and an area light emits toward -Z only. Emissive triangles emit from both sides,
as Cycles' mesh lights do.

Modules: selection (the choice of an emitter), sampler (LightSampler: the emitter table, sampling by kind,
what BSDF rays meet), one module per kind with its sample / pdf / intersect (point_spot, sun, area, triangles,
world), proxies (Embree's help for many lights), nee (next-event estimation and shadow rays: the integrator's
light samples), links (Light and Shadow Linking: the sets, the masks, a choice per light set), common (what
the kinds share).
"""
from .proxies import LightProxies
from .sampler import LightHits, LightSample, LightSampler
from .selection import DISTANT_SHARE, TREE_MIN_EMITTERS

__all__ = ["DISTANT_SHARE", "TREE_MIN_EMITTERS", "LightHits", "LightProxies", "LightSample", "LightSampler"]
