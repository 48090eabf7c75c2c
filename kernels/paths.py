"""The state that travels with every live path of a wave, declared once, with one compact()."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .samples import Samples


@dataclass
class PathState:
    path: np.ndarray        # (N,) int64: wave index of the path, where its radiance is accumulated
    throughput: np.ndarray  # (3, N) float32: product of BSDF weights (and 1/q of Russian roulette)
    bsdf_pdf: np.ndarray    # (N,) float32: pdf of the direction that led here (for MIS); inf = camera ray
    samples: Samples        # the paths' random numbers
    bounce: np.ndarray      # (N,) int32: scattering events so far (0 = still the camera ray)
    transparent: np.ndarray  # (N,) int32: transparent surfaces passed straight through so far
    dp: np.ndarray          # (N,) float32: the ray's position spread (Cycles' compact differential dP)

    @classmethod
    def start(cls, n: int, samples: Samples) -> "PathState":
        return cls(np.arange(n), np.ones((3, n), np.float32), np.full(n, np.inf, np.float32), samples,
                   np.zeros(n, np.int32), np.zeros(n, np.int32), np.zeros(n, np.float32))

    def compact(self, idx: np.ndarray) -> None:
        """Keep only the paths idx (in that order)."""
        self.path = self.path[idx]
        self.throughput = np.take(self.throughput, idx, axis=1)
        self.bsdf_pdf = np.take(self.bsdf_pdf, idx)
        self.samples = self.samples.take(idx)
        self.bounce = np.take(self.bounce, idx)
        self.transparent = np.take(self.transparent, idx)
        self.dp = np.take(self.dp, idx)

    def __len__(self) -> int:
        return len(self.path)
