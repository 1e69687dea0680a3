"""Frozen and slipping encoders, seen from the motion the controller commands (pure).

The drives' readings must move as the forces they report applying move them. Each
cycle the controller predicts the second difference of every reading from the
dynamic model (ARCHI §3.4, A xddot + H = J^T f: the forces the drives applied over
the last period, at the measured pose and velocity) and compares:

    r_i(k) = q_i(k) - 2 q_i(k-1) + q_i(k-2) - J_i(x) A(x)^-1 (J^T f - H) dt^2

What the model does not know varies slowly: the external load (110 N on MoM3's
18 kg is 6 um at 1 kHz, 24 um at 500 Hz), model errors; ``b_i``, a low-pass of r_i
(``BIAS_GAIN`` a cycle), follows it. Quantisation adds two counts. Two faults break
it:

* **slip** (a reading jumps by delta): ``r_i - b_i = delta`` in the cycle of the jump;
  tripped when ``|r_i - b_i| > jump_m``;
* **freeze** (the reading holds): ``r_i = -qdot_i dt`` at once when the drive moves
  fast; slower, the reading stays unchanged while the reference moves the drive:
  tripped when the net displacement the reference asked for since the reading last
  changed (``J_i v_d dt`` summed) exceeds ``freeze_m``.

A drive that stops (a brake) is not an encoder fault. On a redundant machine the
readings tell them apart at once: after a brake (or a knock) they still agree with one
platform motion (their least-squares residual, ``dq - J J^+ dq``, stays under a tenth
of the jump), after a freeze or a slip they do not. On a 3-drive machine nothing tells them apart in the first cycle: a
brake engaging at speed is reported as that drive's encoder frozen (the drive is
named either way). The test needs neither redundancy nor the
Gough, so it covers every machine; it cannot see a freeze while nothing moves.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["EncoderMonitor"]


class EncoderMonitor:
    """Per-drive innovation test (module docstring); ``check`` once per cycle."""

    BIAS_GAIN = 0.2             # of the unexplained acceleration's low-pass (time constant ~5 cycles)

    def __init__(self, n: int, jump_m: float, freeze_m: float):
        if not (0.0 < jump_m < math.inf and 0.0 < freeze_m < math.inf):
            raise ValueError(f"encoder_jump_m, encoder_freeze_m: must be in (0, inf) m, got {jump_m}, {freeze_m}")
        self.n, self.jump_m, self.freeze_m = n, jump_m, freeze_m
        self.reset()

    def reset(self) -> None:
        self.last_q = None
        self.last_dq = None
        self.bias = [0.0] * self.n
        self.held_m = [0.0] * self.n          # displacement asked for since the reading last changed

    def check(self, q, expected_ddq, expected_dq, skip=(), consecutive: bool = True, rows=None) -> tuple[int, str]:
        """(drive, what) of this cycle's encoder fault, (-1, "") if none: ``q`` the
        readings, ``expected_ddq`` their second difference the dynamic model predicts,
        ``expected_dq`` the displacement the reference asked for over the last period,
        ``skip`` drives not to judge (dropped ones); ``consecutive`` False when states
        were skipped since the last check (real time): no second difference then;
        ``rows``: J_m (n x 3) of a redundant machine, for the consistency of a stop."""
        last, self.last_q = self.last_q, list(q)
        if last is None:
            return -1, ""
        dq = [a - b for a, b in zip(q, last)]
        last_dq, self.last_dq = self.last_dq, dq
        if not consecutive:
            last_dq = self.last_dq = None
        for i in range(self.n):
            self.held_m[i] = self.held_m[i] + expected_dq[i] if dq[i] == 0.0 and i not in skip else 0.0
            if i in skip:
                continue
            if abs(self.held_m[i]) > self.freeze_m:
                return i, (f"frozen: reading unchanged at {q[i]:.6f} m while the reference moved it "
                           f"{self.held_m[i] * 1e6:.1f} um (encoder_freeze_m {self.freeze_m:g})")
            if last_dq is None:
                continue
            r = dq[i] - last_dq[i] - expected_ddq[i] - self.bias[i]
            self.bias[i] += self.BIAS_GAIN * r
            if abs(r) > self.jump_m:
                what = "frozen" if dq[i] == 0.0 else "slipped"
                if self._consistent(dq, rows, abs(r)):
                    self.bias[i] += r             # physical (a brake, a knock): not the encoder's
                    continue
                return i, (f"{what}: reading {r * 1e6:+.1f} um off the motion its force explains in one cycle "
                           f"(encoder_jump_m {self.jump_m:g})")
        return -1, ""

    def _consistent(self, dq, rows, jump: float) -> bool:
        """Do the readings of a redundant machine still agree with one platform motion?
        (Their least-squares residual under a tenth of the jump, or two counts.)"""
        if rows is None or self.n <= 3:
            return False
        j = np.asarray(rows, dtype=float)
        d = np.asarray(dq, dtype=float)
        residual = d - j @ np.linalg.lstsq(j, d, rcond=None)[0]
        return float(np.linalg.norm(residual)) < max(0.1 * jump, 2e-6)
