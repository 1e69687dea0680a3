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

* **slip** (a reading jumps by delta): ``r_i - b_i = delta`` in the cycle of the jump
  and about ``-delta`` in the next; tripped when the first exceeds ``jump_m`` (or
  eight times the innovation's running RMS: encoder noise) and the second reverses it
  (a load step keeps its sign);
* **freeze** (the reading holds): ``r_i = -qdot_i dt`` at once when the drive moves
  fast, confirmed when the reading still holds in the next cycle; slower, the reading stays unchanged while the reference moves the drive:
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
    """Per-drive innovation test (module docstring); ``check`` once per cycle.
    ``jump_m`` or ``freeze_m`` infinite: that test is off."""

    BIAS_GAIN = 0.2             # of the unexplained acceleration's low-pass (time constant ~5 cycles)
    NOISE_GAIN = 0.01           # of the innovation's running mean square (~100 cycles)
    NOISE_SIGMAS = 8.0          # the jump threshold is at least this many of its running RMS

    def __init__(self, n: int, jump_m: float, freeze_m: float):
        if not (jump_m > 0.0 and freeze_m > 0.0):
            raise ValueError(f"encoder_jump_m, encoder_freeze_m: must be > 0 m (inf: off), got {jump_m}, {freeze_m}")
        self.n, self.jump_m, self.freeze_m = n, jump_m, freeze_m
        self.reset()

    def reset(self) -> None:
        self.last_q = None
        self.last_dq = None
        self.last_dt = None
        self.bias = [0.0] * self.n
        self.mean_square = [0.0] * self.n
        self.candidate: dict[int, float] = {}   # drive -> the jump that waits for its confirmation
        self.held_m = [0.0] * self.n          # displacement asked for since the reading last changed

    def threshold(self, i: int) -> float:
        """encoder_jump_m, raised above the innovation's own noise (encoder noise, a
        noisy load): NOISE_SIGMAS times its running RMS."""
        return max(self.jump_m, self.NOISE_SIGMAS * math.sqrt(self.mean_square[i]))

    def check(self, q, expected_ddq, expected_dq, dt: float, skip=(), rows=None) -> tuple[int, str]:
        """(drive, what) of this cycle's encoder fault, (-1, "") if none: ``q`` the
        readings, ``expected_ddq`` their second difference the dynamic model predicts,
        ``expected_dq`` the displacement the reference asked for over the last period
        ``dt`` (a period unlike the previous one, states skipped in real time: no
        second difference then), ``skip`` drives not to judge (dropped ones),
        ``rows``: J_m (n x 3) of a redundant machine, for the consistency of a jump.

        A jump is confirmed in the next cycle, which tells it from a load step: a slip
        is +delta then about -delta (the reading moved once), a freeze holds the
        reading; a load step keeps its sign (the unexplained acceleration lasts)."""
        last, self.last_q = self.last_q, list(q)
        last_dt, self.last_dt = self.last_dt, dt
        if last is None:
            return -1, ""
        dq = [a - b for a, b in zip(q, last)]
        last_dq, self.last_dq = self.last_dq, dq
        if last_dt is None or abs(dt - last_dt) > 1e-3 * last_dt:
            last_dq = None
            self.candidate.clear()
        for i in range(self.n):
            self.held_m[i] = self.held_m[i] + expected_dq[i] if dq[i] == 0.0 and i not in skip else 0.0
            if i in skip:
                self.candidate.pop(i, None)
                continue
            if abs(self.held_m[i]) > self.freeze_m:
                return i, (f"frozen: reading unchanged at {q[i]:.6f} m while the reference moved it "
                           f"{self.held_m[i] * 1e6:.1f} um (encoder_freeze_m {self.freeze_m:g})")
            if last_dq is None:
                continue
            r = dq[i] - last_dq[i] - expected_ddq[i] - self.bias[i]
            jump = self.candidate.pop(i, None)
            if jump is not None:
                if dq[i] == 0.0 and last_dq[i] == 0.0:
                    return i, (f"frozen: reading held after a jump of {jump * 1e6:+.1f} um off the motion its force "
                               f"explains (encoder_jump_m {self.jump_m:g})")
                if r * jump < 0.0 and abs(r) > 0.5 * abs(jump):
                    return i, (f"slipped: reading {jump * 1e6:+.1f} um off the motion its force explains in one "
                               f"cycle, and back (encoder_jump_m {self.jump_m:g})")
            if abs(r) > self.threshold(i) and jump is None and not self._consistent(dq, rows, abs(r)):
                self.candidate[i] = r             # judged next cycle; the low-passes wait
                continue
            self.bias[i] += self.BIAS_GAIN * r
            self.mean_square[i] += self.NOISE_GAIN * (r * r - self.mean_square[i])
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
