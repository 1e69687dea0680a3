"""The pivot point: a platform that turns about the tool tip (or any point fixed to it).

With a tool offset ``t`` in force (G43's (0, 0, L); G43.1 X Y Z sets any point of the
platform: the pivot), the programmed point is the tip and the platform's pose is

    p = tip + R(a, b, c) t          R = Rz(c) Ry(b) Rx(a) (genhexkins; rotations.rotation_from_rpy)

so that with R = I the spindle is the tip plus the offset, as LinuxCNC's G43, and when
A B C change the tip stays on its programmed path while the platform turns about it
(PI's hexapod controllers' pivot point, LinuxCNC's tool-centre-point kinematics). A
:class:`PivotLine` moves the tip along a straight line while the angles go linearly
from the start's to the end's; its pose path is not straight, so its derivatives are
the chain rule's, by central differences of :func:`pivot_pose` in u.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pkm_kinematics.rotations import rotation_from_rpy

__all__ = ["PivotLine", "pivot_pose", "tip_of_pose"]

STEP = 1e-4          # du of the central differences (the path is smooth: rotations)
SAMPLES = 33         # points of the path its bounds are taken over


def pivot_pose(tip, angles, offset) -> list:
    """The platform's pose (x, y, z, a, b, c) that puts the point ``offset`` (platform
    frame, m) at ``tip`` (m) with the angles (rad)."""
    p = np.asarray(tip, dtype=float) + rotation_from_rpy(*angles) @ np.asarray(offset, dtype=float)
    return [*p.tolist(), *(float(a) for a in angles)]


def tip_of_pose(pose, offset) -> np.ndarray:
    """The inverse: where the point ``offset`` of the platform is at ``pose``."""
    return np.asarray(pose[:3], dtype=float) - rotation_from_rpy(*pose[3:6]) @ np.asarray(offset, dtype=float)


@dataclass(frozen=True)
class PivotLine:
    """The tip from ``tip_start`` to ``tip_end`` in a straight line while the platform
    turns from ``angles_start`` to ``angles_end`` about it (module doc). ``speed`` caps
    the tip's speed (the programmed feed is the tip's)."""

    tip_start: tuple
    tip_end: tuple
    angles_start: tuple
    angles_end: tuple
    offset: tuple
    speed: float | None = None
    line: int | None = field(default=None, compare=False)

    def _at(self, u):
        tip = [a + u * (b - a) for a, b in zip(self.tip_start, self.tip_end)]
        angles = [a + u * (b - a) for a, b in zip(self.angles_start, self.angles_end)]
        return pivot_pose(tip, angles, self.offset)

    def point(self, u):
        return self._at(1.0) if u >= 1.0 else self._at(u)

    def first(self, u):
        h = STEP
        return ((np.array(self._at(u + h)) - np.array(self._at(u - h))) / (2.0 * h)).tolist()

    def second(self, u):
        h = STEP
        ahead, here, behind = (np.array(self._at(v)) for v in (u + h, u, u - h))
        return ((ahead - 2.0 * here + behind) / (h * h)).tolist()

    def radius(self):
        return math.inf

    @property
    def start(self):
        return tuple(self._at(0.0))

    @property
    def end(self):
        return tuple(self._at(1.0))

    @property
    def tip_length(self) -> float:
        return math.dist(self.tip_start, self.tip_end)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The largest |x'| and |x''| of each coordinate over the path (SAMPLES points)."""
        us = np.linspace(0.0, 1.0, SAMPLES)
        return (np.max(np.abs([self.first(u) for u in us]), axis=0),
                np.max(np.abs([self.second(u) for u in us]), axis=0))
