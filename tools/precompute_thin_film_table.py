"""Regenerate kernels/bsdf/data/thin_film_cmf.npz: the Fourier transform of the CIE 1931 2-degree colour
matching functions that thin-film iridescence integrates against (Belcour & Barla 2017, as Cycles does).

The recipe is Cycles' (`doc/precompute/thin_film_table.py`, used by `ShaderManager::compute_thin_film_table`
in `scene/shader.cpp`): the CMFs (zero at 359 and 831 nm) are interpolated with a not-a-knot cubic spline and
resampled at 1022 frequencies f = k pi / 60 (k = 0..1021, 1/um; the table covers optical path differences of
0 to 60 um), each value S(1000 / f) / f^2 (a change of variable from wavelength to frequency), with 0
outside the data; the real FFT of those samples gives 512 complex values per CMF. The kernel turns X, Y, Z
into RGB and normalises by the DC term (kernels/bsdf/thin_film.py).

Needs colour-science (the CIE data) and scipy (the spline), which Ember itself does not:
    python -m pip install colour-science scipy && python tools/precompute_thin_film_table.py
"""
from __future__ import annotations

import os

import numpy as np

OUT = os.path.join(os.path.dirname(__file__), "..", "kernels", "bsdf", "data", "thin_film_cmf.npz")
SIZE = 512                  # complex values per CMF (Cycles' THIN_FILM_TABLE_SIZE)
SAMPLES = 2 * SIZE - 2      # real samples whose rfft has SIZE values
RANGE_UM = 60.0             # optical path differences covered


def cie_1931() -> tuple[np.ndarray, np.ndarray]:
    """(wavelengths (W,) nm, xyz (W, 3)): the CIE 1931 2-degree observer at 1 nm, 360..830, with a zero
    row on either side, as Cycles pads it."""
    import colour
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    nm = np.asarray(cmfs.wavelengths, np.float64)
    keep = (nm >= 360) & (nm <= 830)
    nm, xyz = nm[keep], np.asarray(cmfs.values, np.float64)[keep]
    nm = np.concatenate([[nm[0] - 1], nm, [nm[-1] + 1]])
    xyz = np.concatenate([np.zeros((1, 3)), xyz, np.zeros((1, 3))])
    return nm, xyz


def table() -> np.ndarray:
    """(SIZE, 6) float64: Re X, Re Y, Re Z, Im X, Im Y, Im Z of the resampled CMFs' real FFT."""
    from scipy.interpolate import CubicSpline
    nm, xyz = cie_1931()
    freq = np.maximum(np.linspace(0.0, np.pi * (SAMPLES - 1) / RANGE_UM, SAMPLES), 1e-40)
    out = []
    for c in range(3):
        spline = CubicSpline(nm, xyz[:, c], extrapolate=False)
        with np.errstate(over="ignore", invalid="ignore"):
            samples = np.nan_to_num(spline(1000.0 / freq) / (freq * freq))
        out.append(np.fft.rfft(samples))
    return np.stack([o.real for o in out] + [o.imag for o in out], axis=1)


def main() -> None:
    t = table().astype(np.float32)
    assert t.shape == (SIZE, 6)
    np.savez_compressed(OUT, xyz_fft=t)
    print(f"wrote {os.path.normpath(OUT)}: {t.shape}")


if __name__ == "__main__":
    main()
