"""What every simulated machine's drives do, whatever moves the platform (no rclpy):
force saturation and the no-force fault (``applied_forces``), and the encoders
(``Encoders``: quantised at the resolution, optional Gaussian noise, velocity by
backward difference; ``encoder_freeze`` holds the last reading, ``encoder_slip``
adds its constant offset). ``plant.Plant`` (rails) and ``strut_plant.StrutPlant``
(struts) both use them."""

from __future__ import annotations

import numpy as np


def applied_forces(commanded, limit: float, faults) -> tuple[list, list]:
    """(applied, saturated): each command clamped to +-``limit``, zero on a drive with
    an active ``no_force`` fault; saturated: the command was beyond the limit."""
    saturated = [abs(f) > limit for f in commanded]
    applied = [max(-limit, min(limit, f)) for f in commanded]
    for f in faults:
        if f.kind == "no_force":
            applied[f.drive] = 0.0
    return applied, saturated


class Encoders:
    """The drive encoders of one plant: ``read(q_true, faults)`` once per step."""

    def __init__(self, resolution_m: float, noise_m: float, seed: int, dt_s: float):
        self.resolution_m, self.noise_m, self.dt_s = resolution_m, noise_m, dt_s
        self._rng = np.random.default_rng(seed)
        self.last: list = []

    def quantise(self, q) -> list:
        """Noise (one draw per drive), then the resolution."""
        res, noise = self.resolution_m, self.noise_m
        if noise > 0.0:
            q = [qi + noise * self._rng.standard_normal() for qi in q]
        if res > 0.0:
            q = [round(qi / res) * res for qi in q]
        return q

    def start(self, q_true) -> None:
        """The first reading (no velocity before it)."""
        self.last = self.quantise(q_true)

    def read(self, q_true, faults) -> tuple[list, list]:
        """(readings, velocities) of the true drive positions under the active faults."""
        reading = self.quantise(q_true)
        frozen = {f.drive for f in faults if f.kind == "encoder_freeze"}
        for f in faults:
            if f.kind == "encoder_slip":
                reading[f.drive] += f.size
        reading = [self.last[i] if i in frozen else r for i, r in enumerate(reading)]
        velocity = [(r - p) / self.dt_s for r, p in zip(reading, self.last)]
        self.last = reading
        return reading, velocity
