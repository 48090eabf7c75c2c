"""The scene-linear colour-space constants the kernel uses, once: Cycles derives them from the OCIO config
(`scene/shader.cpp` `init_xyz_transforms`); these are Blender's own config's (scene linear = Linear
Rec.709). engine/export/node_tables.color_constants() reads them from the config in use. The colour nodes
(shading/color_nodes.py) and thin-film iridescence (bsdf/thin_film.py) read them here.
"""
from __future__ import annotations

import numpy as np

from .vec import F32

# Luminance of scene-linear RGB (Cycles' kernel_data.film.rgb_to_y): row Y of (Cycles' ACES AP0 -> XYZ D65
# matrix, scene/shader.cpp) x (OCIO's scene_linear -> aces_interchange). For Blender's config this is
# Rec.709's luminance: float32 values exactly as Cycles 5.0 holds them (probed: RGB to BW of unit colours).
RGB_TO_Y = np.array([0.21263912, 0.71516913, 0.07219276], F32)
# CIE XYZ (D65) -> scene-linear RGB (kernel_data.film.xyz_to_r/g/b), the same derivation in float64 for
# Blender's config (Cycles' own float32 arithmetic may differ in the last digit; Wavelength agrees to 3e-7).
XYZ_TO_RGB = np.array([[3.2409700, -1.5373843, -0.49861140],
                       [-0.96924340, 1.8759667, 0.041554690],
                       [0.055629883, -0.20397648, 1.0569712]], F32)
# Rec.709 -> scene linear: None when the scene-linear space is Rec.709 (Cycles' film.is_rec709).
REC709_TO_RGB = None
