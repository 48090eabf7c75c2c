"""Progressive film: float64 sums per pixel over a region of the frame, resolved to float32 RGBA.

Axes are (row, col, channel) with row 0 at the top of the region.
"""
from __future__ import annotations

import numpy as np


class Film:
    """Accumulates RGBA sample sums for a width x height region; every row keeps its sample count."""

    def __init__(self, width: int, height: int):
        self.width, self.height = width, height
        self.sums = np.zeros((height, width, 4), np.float64)
        self.row_samples = np.zeros(height, np.int64)

    def add_rows(self, row0: int, row_sums: np.ndarray, samples: int) -> None:
        """Add (rows, width, 4) sums holding `samples` samples per pixel, starting at region row row0."""
        rows = row_sums.shape[0]
        self.sums[row0:row0 + rows] += row_sums
        self.row_samples[row0:row0 + rows] += samples

    def resolve(self, row0: int = 0, row1: int | None = None) -> np.ndarray:
        """(rows, width, 4) float32 mean of rows [row0, row1); rows without samples are zero."""
        row1 = self.height if row1 is None else row1
        count = self.row_samples[row0:row1].astype(np.float64)
        scale = np.divide(1.0, count, out=np.zeros_like(count), where=count > 0)
        return (self.sums[row0:row1] * scale[:, None, None]).astype(np.float32)

    @property
    def samples_done(self) -> int:
        """Samples every pixel has (a pass that stopped part-way counts for no pixel)."""
        return int(self.row_samples.min()) if self.height else 0
