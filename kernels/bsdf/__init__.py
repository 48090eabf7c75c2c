"""BSDF lobes: see the contract in this package's docstring."""
