"""A machine on rails calibrated with its Gough metrology read strut by strut: the
machine's error parameters (rail_errors) and the Gough's own geometry, identified
together (pure).

The Gough's pose (``metrology/pose``, rail_errors with an instrument) is the sensor's
forward kinematics on its nominal geometry: an error of the sensor's joints goes into
every pose it reports, and a calibration on those poses copies it into the machine's
model. Here the instrument's readings are the six strut lengths themselves (MoM3
§4.3's linear scales, ``metrology/struts``), and the parameters are the machine's and
the sensor's joint centres: strut j between its base joint G_j (world frame, the
metrology section's mounting applied) and its plate joint C_j (tool frame),

    s_ij = |p_i + R_i (C_j + dC_j) - (G_j + dG_j)|          (MoM3 eq. 1, the sensor's)

at the pose (p_i, R_i) that closes the machine's bars (rail_errors). Parameters: the
machine's (rail_errors, per leg), then ``gough.base.<j>.<x|y|z>`` (dG_j, world) and
``gough.plate.<j>.<x|y|z>`` (dC_j, tool frame). The Jacobian in closed form, with
e = unit(p + R C' - G'):

    ds/dp = e,   ds/dtheta = e . (z x R C'),   ds/ddG = -e,   ds/ddC = e^T R

What a machine's motions cannot separate, identifiability names and holds: on a
translating platform (R = I) only C_j - G_j enters, so each plate joint is held beside
its base joint; and one shift of every G_j together is a shift of the platform's
origin against the machine's platform joints (the datum: where the tool is on the
platform), held as the convention the procedure states.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pkm_kinematics.errors import FieldError

from .rail_errors import RailErrorModel, distance_pose_jacobian

__all__ = ["GoughStrutRailModel", "gough_joints"]

STRUTS = 6


def gough_joints(metrology) -> tuple[np.ndarray, np.ndarray]:
    """The nominal joint centres of a metrology section (pkm_kinematics.config's
    GoughMetrologyConfig): the base joints in the world frame, the plate joints in the
    tool frame (6, 3) each (its mounting applied, as the sensor measures)."""
    platform = metrology.platform
    base = np.asarray(metrology.base_position, dtype=float) + np.asarray(platform.base_points) @ np.asarray(
        metrology.base_rotation, dtype=float).T
    plate = np.asarray(metrology.plate_position_in_tool, dtype=float) + np.asarray(platform.plate_points) @ np.asarray(
        metrology.plate_rotation_in_tool, dtype=float).T
    return base, plate


@dataclass(frozen=True, eq=False)
class GoughStrutRailModel(RailErrorModel):
    """A machine on rails (RailErrorModel's) and its Gough metrology's six struts as the
    instrument (module doc): constant; the methods take the parameters ``theta``."""

    base: np.ndarray = None            # G (6, 3), world frame: gough_joints
    plate: np.ndarray = None           # C (6, 3), tool frame
    instrument: bool = field(default=True, init=False)

    def __post_init__(self):
        base, plate = (np.asarray(a, dtype=float) for a in (self.base, self.plate))
        if base.shape != (STRUTS, 3) or plate.shape != (STRUTS, 3) or not np.isfinite([base, plate]).all():
            raise FieldError("metrology", f"expected the Gough's 6 base and 6 plate joint centres (m), got shapes "
                                          f"{base.shape} and {plate.shape}")
        object.__setattr__(self, "base", base)
        object.__setattr__(self, "plate", plate)
        super().__post_init__()

    def _instrument_names(self) -> list[str]:
        """The Gough's joint centres (module doc), in place of an instrument's frame."""
        return [f"gough.{part}.{j + 1}.{c}" for part in ("base", "plate") for j in range(STRUTS) for c in "xyz"]

    @property
    def readings_per_point(self) -> int:
        """The instrument's readings at a pose: the six strut lengths."""
        return STRUTS

    @property
    def gough_columns(self) -> int:
        """The first of the Gough's parameters (after the machine's)."""
        return 5 * self.machine.n_legs

    def _joints(self, theta) -> tuple[np.ndarray, np.ndarray]:
        g = np.asarray(theta, dtype=float)[self.gough_columns:]
        return self.base + g[:3 * STRUTS].reshape(STRUTS, 3), self.plate + g[3 * STRUTS:].reshape(STRUTS, 3)

    def _struts(self, theta, poses):
        base, plate = self._joints(theta)
        p, rot = self._pose(poses)
        rc = np.einsum("nij,kj->nki", rot, plate)                          # (N, 6, 3): R C'
        e = p[:, None, :] + rc - base
        length = np.linalg.norm(e, axis=-1)
        return length, e / length[..., None], rc, rot

    def points(self, theta, poses) -> np.ndarray:
        """The strut lengths at ``poses`` (N, 6), m."""
        return self._struts(theta, poses)[0]

    def point_jacobian(self, theta, poses) -> tuple[np.ndarray, np.ndarray]:
        """The struts' (d s / d poses, d s / d theta): (6 N, 3 N), (6 N, size) (module doc)."""
        _, e, rc, rot = self._struts(theta, poses)
        N = len(e)
        d_pose = distance_pose_jacobian(e, rc, self.planar)
        d_theta = np.zeros((N, STRUTS, self.size))
        er = np.einsum("nkj,nji->nki", e, rot)                              # e^T R (N, 6, 3)
        g = self.gough_columns
        for j in range(STRUTS):
            d_theta[:, j, g + 3 * j:g + 3 * j + 3] = -e[:, j]
            d_theta[:, j, g + 3 * STRUTS + 3 * j:g + 3 * STRUTS + 3 * j + 3] = er[:, j]
        return d_pose.reshape(N * STRUTS, 3 * N), d_theta.reshape(N * STRUTS, self.size)

    def machine_for(self, theta):
        return super().machine_for(np.asarray(theta, dtype=float)[:self.gough_columns])
