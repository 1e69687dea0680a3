"""A laser tracker (pure): an external instrument measuring one point of the tool, the
calibration's instrument (2) of issue 44 when a machine has no Gough metrology.

It reads the true tool point t (platform frame) in its own frame, placed at p_T with
rotation R_T in the world (its base frame, which calibration identifies too:
pkm_calibration.strut_errors' ``frame``):

    y = R_T^T (p + R t - p_T) + n,    n ~ N(0, sigma^2 I)

A tracker's noise is a few micrometres at a few metres (sigma, stated per run).
"""

from __future__ import annotations

import numpy as np

from pkm_kinematics.errors import FieldError
from pkm_kinematics.rotations import rotation_from_rpy

__all__ = ["LaserTracker", "MAX_SIGMA_M"]

MAX_SIGMA_M = 1e-3


class LaserTracker:
    """Constant: the tool point, the tracker's frame and its noise; ``measure`` draws
    the noise from its own seeded stream."""

    def __init__(self, tool=(0.0, 0.0, 0.0), sigma_m: float = 0.0, seed: int = 0,
                 frame_position=(0.0, 0.0, 0.0), frame_rpy_deg=(0.0, 0.0, 0.0)):
        for name, value in (("tool", tool), ("frame_position", frame_position), ("frame_rpy_deg", frame_rpy_deg)):
            if len(value) != 3 or not np.isfinite(np.asarray(value, dtype=float)).all():
                raise FieldError(name, f"expected 3 finite numbers, got {list(value)}")
        if not 0.0 <= sigma_m <= MAX_SIGMA_M:
            raise FieldError("sigma_m", f"must be in [0, {MAX_SIGMA_M:g}] m, got {sigma_m}")
        self.tool = np.asarray(tool, dtype=float)
        self.sigma_m = float(sigma_m)
        self.frame_position = np.asarray(frame_position, dtype=float)
        self.frame_rotation = rotation_from_rpy(*np.radians(np.asarray(frame_rpy_deg, dtype=float)))
        self._rng = np.random.default_rng(seed)

    def true_point(self, position, rotation) -> np.ndarray:
        """The tool point in the tracker's frame, without noise."""
        world = np.asarray(position, dtype=float) + np.asarray(rotation, dtype=float) @ self.tool
        return self.frame_rotation.T @ (world - self.frame_position)

    def measure(self, position, rotation) -> np.ndarray:
        """A reading of the platform at (position, rotation) in the world (module doc)."""
        point = self.true_point(position, rotation)
        return point + self.sigma_m * self._rng.standard_normal(3) if self.sigma_m else point
