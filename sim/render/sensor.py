"""The camera sensor: radiance in, raw digital numbers out (seeded, reproducible).

DN = response(gain · (radiance · exposure · sensitivity + ambient)) + black level, with photon (Poisson)
noise on the electrons (``electrons_per_dn`` is the inverse of the conversion gain) and Gaussian read
noise before the analogue gain, quantisation to ``bits`` and clipping at the top code.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np


@dataclass(frozen=True)
class SensorModel:
    bits: int = 12
    sensitivity: float = 4095.0  # DN per (radiance unit · second) before the response curve
    electrons_per_dn: float | None = 4.0  # None: no photon noise
    read_noise_dn: float = 1.5
    response: Literal["linear", "gamma"] = "linear"
    gamma: float = 2.2
    ambient: float = 0.0  # radiance added everywhere (stray light), same units as the render
    black_level_dn: float = 0.0  # the ADC's offset: what a dark pixel reads on average

    @property
    def top(self) -> int:
        return 2**self.bits - 1

    def expose(
        self, radiance: np.ndarray, exposure_s: float, rng: np.random.Generator, gain_db: float = 0.0
    ) -> np.ndarray:
        """(H, W, 3) radiance → (H, W, 3) uint16 DN for one exposure at an analogue gain (dB)."""
        signal = np.clip(
            (np.asarray(radiance, np.float64) + self.ambient) * exposure_s * self.sensitivity, 0, None
        )
        if self.electrons_per_dn:
            signal = rng.poisson(signal * self.electrons_per_dn) / self.electrons_per_dn
        signal = (signal + rng.normal(0.0, self.read_noise_dn, signal.shape)) * 10 ** (gain_db / 20)
        if self.response == "gamma":
            signal = self.top * (np.clip(signal, 0, None) / self.top) ** (1.0 / self.gamma)
        return np.clip(np.round(signal + self.black_level_dn), 0, self.top).astype(np.uint16)
