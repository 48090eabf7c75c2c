"""The lobe families' ids and what each is: the vocabulary the closure table, the integrator's passes and the
node compiler share. Which functions evaluate and sample each lobe, and what its parameter columns mean, is
registry.py's table.
"""
from __future__ import annotations

# Lobe ids.
(LAMBERT, OREN_NAYAR, TRANSLUCENT, SHEEN, TRANSPARENT, REFLECTION, REFRACTION, GLASS, ASHIKHMIN_SHIRLEY, TOON_DIFFUSE,
 TOON_GLOSSY, PORTAL, HAIR_REFLECTION, HAIR_TRANSMISSION, BSSRDF, HAIR_CHIANG, HAIR_HUANG, VELVET) = range(18)

# What a lobe is, as flags:
# DIFFUSE       Cycles' CLOSURE_IS_BSDF_DIFFUSE: the bump shadowing term's softening, the Diffuse light passes.
# GLOSSY        reflecting microfacets and the like: the Glossy light passes (glass counts as glossy on its
#               reflection side, as Cycles' kernel/film/light_passes.h).
# TRANSMISSION  Cycles' CLOSURE_IS_BSDF_TRANSMISSION: the Transmission light and Color passes.
# MICROFACET    a roughness-dependent singular (delta) limit; eval of a singular closure is 0.
# SINGULAR      always singular (Cycles' CLOSURE_IS_BSDF_SINGULAR).
# SELF_EVALUATED  a sampled direction keeps the value its sampler gave it, as Cycles keeps the sampling
#               closure's own eval: re-evaluating a toon cone narrower than float32's acos resolution gives 0,
#               the hair lobes' samplers reach directions their eval does not (and report another pdf), and the
#               Huang hair's eval is a random quadrature that its sampler does not follow.
# ANY_SIDE      samples leave on whichever side of the surface they point to, untested (Cycles' hair samplers,
#               the Principled Hair's included, and Ray Portal): the integrator sees which side that is.
# SUBSURFACE    a BSSRDF (Cycles' CLOSURE_IS_BSSRDF): nothing evaluates it (it is singular for the mixture), its
#               sample is the direction into the surface a subsurface walk starts along (kernels/subsurface.py);
#               diffuse for the light passes, as Cycles files it.
DIFFUSE, GLOSSY, TRANSMISSION, MICROFACET, SINGULAR, SELF_EVALUATING, ANY_SIDE, SUBSURFACE = (1 << i for i in range(8))

CLASSES = {
    LAMBERT: DIFFUSE,
    OREN_NAYAR: DIFFUSE,
    TRANSLUCENT: DIFFUSE,
    SHEEN: DIFFUSE,
    TRANSPARENT: SINGULAR,
    REFLECTION: MICROFACET | GLOSSY,
    REFRACTION: MICROFACET | TRANSMISSION,
    GLASS: MICROFACET,
    ASHIKHMIN_SHIRLEY: MICROFACET | GLOSSY,
    TOON_DIFFUSE: DIFFUSE | SELF_EVALUATING,
    TOON_GLOSSY: GLOSSY | SELF_EVALUATING,
    PORTAL: SINGULAR | ANY_SIDE,
    HAIR_REFLECTION: GLOSSY | SELF_EVALUATING | ANY_SIDE,
    HAIR_TRANSMISSION: TRANSMISSION | SELF_EVALUATING | ANY_SIDE,
    BSSRDF: DIFFUSE | SINGULAR | SUBSURFACE,
    # Cycles files both Principled Hair models as glossy (CLOSURE_IS_BSDF_GLOSSY), whatever side they scatter to.
    HAIR_CHIANG: GLOSSY | ANY_SIDE,
    HAIR_HUANG: GLOSSY | SELF_EVALUATING | ANY_SIDE,
    # Cycles' Ashikhmin velvet is a glossy closure (the Glossy passes, no diffuse softening) whose samples are
    # labelled diffuse (LABEL_DIFFUSE: they count as diffuse bounces): DIFFUSE_LABEL_LOBES.
    VELVET: GLOSSY,
}


# Self-evaluated lobes whose closure, alone at its hit, keeps its sample as the mixture's without the mixture being
# evaluated there again: the result is the same (the kept value replaces the evaluation, and nothing else is in
# the mixture), and the Huang hair's evaluation is a quadrature costing some twenty times its sample. The other
# self-evaluated lobes keep the general path, bit for bit.
SAMPLED_ALONE = (HAIR_HUANG,)


def lobes_with(flag: int) -> tuple:
    """The ids of the lobes that have `flag`, in id order."""
    return tuple(k for k, classes in sorted(CLASSES.items()) if classes & flag)


MICROFACET_LOBES = lobes_with(MICROFACET)
SINGULAR_LOBES = lobes_with(SINGULAR)
DIFFUSE_LOBES = lobes_with(DIFFUSE)
GLOSSY_LOBES = lobes_with(GLOSSY)
TRANSMISSION_LOBES = lobes_with(TRANSMISSION)
SELF_EVALUATED = lobes_with(SELF_EVALUATING)
ANY_SIDE_LOBES = lobes_with(ANY_SIDE)
SUBSURFACE_LOBES = lobes_with(SUBSURFACE)
# The lobes whose samples Cycles labels diffuse (LABEL_DIFFUSE: bounce counts, what a path has been through).
DIFFUSE_LABEL_LOBES = DIFFUSE_LOBES + (VELVET,)
# The lobes that take light from behind the surface (Cycles' SD_BSDF_HAS_TRANSMISSION): the light tree's
# choice at such a point counts lights on both sides.
TRANSMITTING_LOBES = tuple(sorted(set(TRANSMISSION_LOBES) | {TRANSLUCENT, GLASS, HAIR_CHIANG, HAIR_HUANG}))
