"""The simulated lamp's output over a night: its power, a warm-up, a slow drift and a little flicker.

output(t) = power · (1 − warm_up · e^(−t/warm_up_s) + per_hour · t/3600) · (1 + flicker · N(0, 1))

``power`` is the warm lamp's output: a cold one gives ``warm_up`` less and approaches it.

t is simulated seconds since the world started (the lamp is taken to be warm or cold with the rig, not
with each switching: a halogen filament cools in seconds, but its housing, which sets the drift, does
not). A true rig file gives it as ``[light] power`` and ``[light] drift = {warm_up, warm_up_s, per_hour,
flicker}``; without ``drift`` the lamp is steady.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LampModel:
    power: float = 1.0  # Φ relative to the scene's own power
    warm_up: float = 0.0  # how much less the cold lamp gives, made up while warming up (0.04: 4 %)
    warm_up_s: float = 1.0  # its time constant, simulated seconds
    per_hour: float = 0.0  # fractional change per simulated hour (−0.01: −1 % per hour)
    flicker: float = 0.0  # rms fractional flicker, independent per frame

    def output(self, t_s: float, rng: np.random.Generator | None = None) -> float:
        """Φ at ``t_s`` simulated seconds, relative to the scene's power (flicker drawn from ``rng``)."""
        steady = 1.0 - self.warm_up * np.exp(-t_s / self.warm_up_s) + self.per_hour * t_s / 3600.0
        wobble = 1.0 + self.flicker * rng.standard_normal() if (rng is not None and self.flicker) else 1.0
        return float(self.power * steady * wobble)
