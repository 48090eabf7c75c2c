"""Participating media: phase functions (phase.py: Cycles' Henyey-Greenstein, Fournier-Forand, Draine and
Rayleigh, set up from the volume nodes' inputs, the Mie fit included; evaluated and sampled alone or as a mixture
of a point's closures)."""
