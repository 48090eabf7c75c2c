"""Participating media: one module per kind of medium, and the voxel grids they look values up in."""
