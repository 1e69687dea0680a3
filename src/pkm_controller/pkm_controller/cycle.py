"""The records of one control cycle (pure core): :class:`Cycle`, what ``prepare``
computed on the drive state for ``complete`` to finish (ControllerCore);
:class:`CycleRecord`, what the last cycle saw and did (status, recording, tests);
:class:`AnswerLog`, the last answers by the stamp of their state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pkm_kinematics.distribution import internal_force, internal_force_rows


@dataclass
class CycleRecord:
    """What the last cycle saw and did (status, recording, tests)."""

    time_s: float = 0.0
    reference: tuple = (0.0, 0.0, 0.0)
    measured: tuple = (0.0, 0.0, 0.0)        # the pose the strategy feeds back (task coordinates)
    error: tuple = (0.0, 0.0, 0.0)
    forces: tuple = ()
    saturated: int = 0
    rows: tuple = ()                         # J_m of the cycle (nominal model), (n, 3) array once run

    @property
    def internal_force_norm_n(self) -> float:
        """|null-space part of the commands| (nominal model); computed when asked (status,
        every status_decimation answers), not in the 1-2 kHz loop."""
        rows = self.rows
        if not len(rows) or len(rows) <= len(rows[0]) or len(self.forces) != len(rows):   # not run, no redundancy
            return 0.0
        if len(rows[0]) != 3:              # a spatial machine's n x 6
            return float(np.linalg.norm(internal_force(rows, self.forces)))
        return math.sqrt(sum(f * f for f in internal_force_rows(rows, self.forces)))


class Cycle:
    """What ``prepare`` computed for the cycle ``complete`` finishes."""

    __slots__ = ("stamp_ns", "t_s", "dt", "first", "q", "q_array", "qdot", "pose", "rows", "active_rows", "v",
                 "x_d", "v_d", "a_d", "a_model", "h_model", "applied", "suspect", "held", "compiled")

    def __init__(self, stamp_ns, t_s, dt, first, q, q_array, qdot, pose, rows, active_rows, v):
        self.stamp_ns = stamp_ns   # the state's stamp (int ns): the key of the cycle's answer
        # q as floats (the joint PIDs) and as the array the compiled kernels take
        self.t_s, self.dt, self.first, self.q, self.q_array, self.qdot = t_s, dt, first, q, q_array, qdot
        # J_m as the (n, 3) array measured_state made, and the rows of the active drives
        self.pose, self.rows, self.active_rows, self.v = pose, rows, active_rows, v
        self.x_d = self.v_d = self.a_d = self.a_model = self.h_model = None
        self.suspect = None        # (drive, what, size) the innovation test names, for the Gough to judge
        self.held = False          # the plant applied an older setpoint again in this period
        self.compiled = False      # prepared by compiled_prepare: its sensor-space inputs are in its buffers


class AnswerLog:
    """The last ``size`` answers by the stamp (ns) of the state they answered: a realtime
    plant may apply one of them again (a held setpoint) and report the forces of
    that one (ControllerCore.prepare's ``held``)."""

    def __init__(self, size: int):
        self.size = size
        self._answers: dict[int, list] = {}

    def keep(self, stamp_ns: int, forces: list) -> None:
        answers = self._answers
        if len(answers) >= self.size:
            del answers[next(iter(answers))]          # the oldest (insertion order)
        answers[stamp_ns] = forces

    def get(self, stamp_ns: int) -> list | None:
        return self._answers.get(stamp_ns)

    def before_last(self, cycles: int) -> list | None:
        """The answer ``cycles`` answers before the last one (0: the last); None when
        there were not that many yet."""
        if cycles >= len(self._answers):
            return None
        return list(self._answers.values())[-1 - cycles]
