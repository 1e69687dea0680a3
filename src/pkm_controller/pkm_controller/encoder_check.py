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
  fast, confirmed when the reading still holds in the next cycle; slower, the reading
  stays unchanged while the reference moves the drive: tripped when the net
  displacement the reference asked for since the reading last changed (``J_i v_d dt``
  summed) exceeds ``freeze_m``.

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
from typing import NamedTuple

import numpy as np

from pkm_common.causes import TripCause
from pkm_kinematics.errors import FieldError, KinematicsError
from pkm_kinematics.bars import IK_OK, rail_task_inverse_kinematics_kernel
from pkm_kinematics.jit import direct_call, kernel
from pkm_kinematics.rails import RailMachine

from .supervisor import Trip

__all__ = ["EncoderChecks", "EncoderFault", "EncoderMonitor", "GoughCrossCheck"]

BIAS_GAIN = 0.2             # of the unexplained acceleration's low-pass (time constant ~5 cycles)
NOISE_GAIN = 0.01           # of the innovation's running mean square (~100 cycles)
NOISE_SIGMAS = 8.0          # the jump threshold is at least this many of its running RMS
CONSISTENT_FRACTION = 0.1   # a redundant machine's readings agree when their residual is under this of the jump
CONSISTENT_FLOOR_M = 2e-6   # ... or two counts

# outcomes of innovation_kernel
ENC_OK, ENC_FROZEN_SLOW, ENC_FROZEN, ENC_SLIPPED = 0, 1, 2, 3
MONITOR_STATE_ROWS = 6      # EncoderMonitor.state: last_q, last_dq, bias, mean_square, held, candidate
GOUGH_STATE_ROWS = 11       # GoughCrossCheck.state: history_q (3), history_g (3), hold_g, last_d, bias, mean_sq., off


@kernel("(float64[:], float64[:], float64[:, :])")
def _readings_consistent(dq, jump_abs, rows):
    """(jump_abs as a 1-array) Do the readings of a redundant machine agree with one
    platform motion: |dq - J (J^T J)^-1 J^T dq| under a tenth of the jump, or two counts?"""
    j = np.ascontiguousarray(rows)            # contiguous for BLAS (and no performance warning)
    d = np.ascontiguousarray(dq)
    gram = j.T @ j
    x = np.linalg.solve(gram, j.T @ d)
    residual = d - j @ x
    return math.sqrt(np.sum(residual * residual)) < max(CONSISTENT_FRACTION * jump_abs[0], CONSISTENT_FLOOR_M)


@kernel("(float64[:], float64[:], float64[:], boolean, float64[:, :], float64[:], float64[:, :], float64[:], "
        "float64[:], float64, float64[:], float64[:], float64[:], float64[:], boolean[:], float64, float64, boolean)")
def innovation_kernel(q, last_q, last_dq, second, a, h, rows, applied, v_d, dt, bias, mean_square, held, candidate,
                      skip, jump_m, freeze_m, redundant):
    """One cycle of the test (module docstring) on the readings ``q``; updates the
    state arrays (last_q, last_dq, bias, mean_square, held, candidate: NaN for none) in
    place. ``second``: last_dq holds the previous period's, of the same length.
    Returns (outcome, drive, value): ENC_FROZEN_SLOW with the displacement asked for,
    ENC_FROZEN / ENC_SLIPPED with the jump; (ENC_OK, -1, 0) if none."""
    n, dof = q.shape[0], a.shape[0]
    rhs = np.empty(dof)
    for j in range(dof):                    # A acc = J^T f - H (ARCHI §3.4)
        total = -h[j]
        for i in range(n):
            total += rows[i, j] * applied[i]
        rhs[j] = total
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(rhs))):
        return ENC_OK, -1, 0.0                # a non-finite model: the law's checks name it
    acc = np.linalg.solve(a, rhs)
    dq = q - last_q
    previous = last_dq.copy()
    last_q[:] = q
    last_dq[:] = dq
    dt2 = dt * dt
    for i in range(n):
        expected_dq = 0.0
        for j in range(dof):
            expected_dq += rows[i, j] * v_d[j]
        expected_dq *= dt
        if skip[i]:
            held[i] = 0.0
            candidate[i] = np.nan
            continue
        held[i] = held[i] + expected_dq if dq[i] == 0.0 else 0.0
        if abs(held[i]) > freeze_m:
            return ENC_FROZEN_SLOW, i, held[i]
        if not second:
            candidate[i] = np.nan
            continue
        expected_ddq = 0.0
        for j in range(dof):
            expected_ddq += rows[i, j] * acc[j]
        expected_ddq *= dt2
        r = dq[i] - previous[i] - expected_ddq - bias[i]
        jump = candidate[i]
        candidate[i] = np.nan
        if not np.isnan(jump):
            if dq[i] == 0.0 and previous[i] == 0.0:
                return ENC_FROZEN, i, jump
            if r * jump < 0.0 and abs(r) > 0.5 * abs(jump):
                return ENC_SLIPPED, i, jump
        threshold = max(jump_m, NOISE_SIGMAS * math.sqrt(mean_square[i]))
        if abs(r) > threshold and np.isnan(jump):
            magnitude = np.empty(1)
            magnitude[0] = abs(r)
            if not (redundant and _readings_consistent(dq, magnitude, rows)):
                candidate[i] = r              # judged next cycle; the low-passes wait
                continue
        bias[i] += BIAS_GAIN * r
        mean_square[i] += NOISE_GAIN * (r * r - mean_square[i])
    return ENC_OK, -1, 0.0


_innovation = direct_call(innovation_kernel)


class EncoderFault(NamedTuple):
    """What a check found: the drive whose reading is wrong, and how."""
    drive: int
    what: str


class EncoderMonitor:
    """Per-drive innovation test (module docstring; innovation_kernel), ``check`` once
    per cycle. ``jump_m`` or ``freeze_m`` infinite: that test is off."""

    def __init__(self, n: int, jump_m: float, freeze_m: float):
        if not (jump_m > 0.0 and freeze_m > 0.0):
            raise ValueError(f"encoder_jump_m, encoder_freeze_m: must be > 0 m (inf: off), got {jump_m}, {freeze_m}")
        self.n, self.jump_m, self.freeze_m = n, float(jump_m), float(freeze_m)
        self.reset()

    def reset(self) -> None:
        n = self.n
        # the arrays innovation_kernel updates, as rows of one (``state``, for a compiled caller)
        self.state = np.zeros((MONITOR_STATE_ROWS, n))
        self.last_q, self.last_dq, self.bias, self.mean_square, self.held, self.candidate = self.state
        self.candidate[:] = np.nan            # the jump that waits for its confirmation, per drive
        self.started = self.second = False
        self.last_dt = None
        self.skip = np.zeros(n, dtype=bool)
        self.skip_set = False                 # some drive in skip
        self.fault_size = 0.0                 # |jump| (or the displacement asked for) of the last verdict
        self.fault_held = False               # ... and whether it holds the reading (a freeze) or not (a slip)

    def threshold(self, i: int) -> float:
        """encoder_jump_m, raised above the innovation's own noise (encoder noise, a
        noisy load): NOISE_SIGMAS times its running RMS."""
        return max(self.jump_m, NOISE_SIGMAS * math.sqrt(self.mean_square[i]))

    def check(self, q, a, h, rows, applied, v_d, dt: float, skip=(),
              setpoint_held: bool = False) -> EncoderFault | None:
        """This cycle's encoder fault (drive, what), None if none: ``q`` the
        readings; the dynamic model at the measured pose, ``a`` = A (d x d, d the task
        DOF), ``h`` = H, ``rows`` = J_m (n x d); ``applied`` the forces the drives report for the last
        period ``dt``; ``v_d`` the reference velocity; ``skip`` drives not to judge
        (dropped ones). A period unlike the previous one (states skipped in real
        time) gives no second difference. A jump is confirmed in the next cycle,
        which tells it from a load step: a slip is +delta then about -delta (the
        reading moved once), a freeze holds the reading; a load step keeps its sign.
        ``setpoint_held``: the drives applied an older command again in this period (a
        missed deadline): the motion the reference asked for since the readings last
        changed is not what they were driven to do, and the slow-freeze watch starts
        again (a plant starved of commands stands still, its encoders are fine); the
        innovation test, on the forces the drives report, still runs."""
        q = np.asarray(q, dtype=float)
        if setpoint_held:
            self.held[:] = 0.0
            v_d = np.zeros(len(h))
        if not self.started:
            self.started, self.last_dt = True, dt
            self.last_q[:] = q
            return None
        second = bool(self.second and abs(dt - self.last_dt) <= 1e-3 * self.last_dt)
        self.second, self.last_dt = True, dt
        if len(skip) or self.skip_set:
            self.skip[:] = False
            for i in skip:
                self.skip[i] = True
            self.skip_set = bool(len(skip))
        code, drive, value = _innovation(       # the declared types exactly: made here
            q, self.last_q, self.last_dq, second, np.asarray(a, dtype=float), np.asarray(h, dtype=float),
            np.asarray(rows, dtype=float), np.asarray(applied, dtype=float), np.asarray(v_d, dtype=float),
            float(dt), self.bias, self.mean_square, self.held, self.candidate, self.skip, self.jump_m,
            self.freeze_m, self.n > len(h))
        if code == ENC_OK:
            return None
        self.fault_size = abs(value)
        self.fault_held = code != ENC_SLIPPED
        if code == ENC_FROZEN_SLOW:
            return EncoderFault(drive, f"frozen: reading unchanged at {q[drive]:.6f} m while the reference moved "
                                       f"it {value * 1e6:.1f} um (encoder_freeze_m {self.freeze_m:g})")
        if code == ENC_FROZEN:
            return EncoderFault(drive, f"frozen: reading held after a jump of {value * 1e6:+.1f} um off the motion "
                                       f"its force explains (encoder_jump_m {self.jump_m:g})")
        return EncoderFault(drive, f"slipped: reading {value * 1e6:+.1f} um off the motion its force explains in "
                                   f"one cycle, and back (encoder_jump_m {self.jump_m:g})")


GOUGH_BIAS_GAIN = 0.02      # of the encoder-Gough difference's low-pass (time constant ~50 cycles)


@kernel("(float64[:], float64[:], float64[:], float64[:], int64[:], float64[:], boolean[:], float64)")
def gough_kernel(d, last_d, bias, mean_square, over, off, skip, jump_m):
    """One cycle of GoughCrossCheck on d = q - q(x_g) (``last_d`` the previous cycle's);
    updates bias, mean_square, over (cycles over the threshold, per drive) and off
    (d - bias) in place. Returns the drive that has been alone over its threshold for
    two cycles, or -1. The noise is estimated from the increments of d (half their
    mean square: white noise counts twice in an increment), not from d - bias, whose
    slow growth would raise its own threshold and hide a drift."""
    n = d.shape[0]
    count, last = 0, -1
    for i in range(n):
        off[i] = 0.0 if skip[i] else d[i] - bias[i]
        if abs(off[i]) > max(jump_m, NOISE_SIGMAS * math.sqrt(mean_square[i])):
            over[i] += 1
            count, last = count + 1, i
        else:
            over[i] = 0
    if count > 1:                    # the tool or the metrology moved: start again from here
        for i in range(n):
            bias[i], over[i] = d[i], 0
        return -1
    for i in range(n):
        if over[i] == 0:
            bias[i] += GOUGH_BIAS_GAIN * off[i]
            step = d[i] - last_d[i]
            mean_square[i] += NOISE_GAIN * (0.5 * step * step - mean_square[i])
    return last if count == 1 and over[last] >= 2 else -1


@kernel("(float64[:], float64[:], float64[:, :], float64[:, :], float64[:], float64[:], float64[:], float64[:], "
        "int64[:], float64[:], boolean[:], float64, boolean)")
def gough_check_kernel(q, g, history_q, history_g, hold_g, last_d, bias, mean_square, over, off, skip, jump_m, first):
    """One cycle of GoughCrossCheck on the readings ``q`` and q(x_g) ``g``, its state
    updated in place: the history of the last three cycles (the newest last) and
    q(x_g) where each reading last changed, then ``gough_kernel`` on d = q - g
    (``first``: the first cycle, which only starts the low-pass at d). Returns the
    drive named, or -1."""
    n = q.shape[0]
    for i in range(n):
        if q[i] != history_q[2, i]:
            hold_g[i] = g[i]
        history_q[0, i], history_q[1, i], history_q[2, i] = history_q[1, i], history_q[2, i], q[i]
        history_g[0, i], history_g[1, i], history_g[2, i] = history_g[1, i], history_g[2, i], g[i]
    d = q - g
    if first:
        hold_g[:] = g
        bias[:] = d
        last_d[:] = d
        return -1
    drive = gough_kernel(d, last_d, bias, mean_square, over, off, skip, jump_m)
    last_d[:] = d
    return drive


GOUGH_NO_POSE = -2          # rail_gough_check_kernel: the measured pose has no inverse kinematics


@kernel("(float64[:, :], int64, int64[:], float64, float64, float64, float64[:], float64[:, :], float64[:, :], "
        "float64[:], float64[:], float64[:], float64[:], int64[:], float64[:], boolean[:], float64, boolean)")
def rail_gough_check_kernel(bars, n_legs, columns, x0, x1, x2, q, history_q, history_g, hold_g, last_d, bias,
                            mean_square, over, off, skip, jump_m, first):
    """``gough_check_kernel`` on the drive positions q(x_g) of a rail machine's pose
    (x0, x1, x2) the Gough measured (bars.rail_task_inverse_kinematics_kernel, the
    machine's ``inverse_kinematics``): the drive named, -1, or GOUGH_NO_POSE (a pose
    not finite or out of reach: nothing judged, the state untouched)."""
    if not (math.isfinite(x0) and math.isfinite(x1) and math.isfinite(x2)):
        return GOUGH_NO_POSE
    g, code, _ = rail_task_inverse_kinematics_kernel(bars, n_legs, columns, x0, x1, x2)
    if code != IK_OK:
        return GOUGH_NO_POSE
    return gough_check_kernel(q, g, history_q, history_g, hold_g, last_d, bias, mean_square, over, off, skip, jump_m,
                              first)


class GoughCrossCheck:
    """Each encoder against the Gough metrology, where the strategy has it (sensor_space,
    measured_space): the reading q_i against q_i(x_g), the machine's inverse kinematics
    at the tool pose the struts measure (MoM3 §5: an independent measurement of the
    platform).

    Their difference d_i = q_i - q_i(x_g) holds what the two disagree on slowly (the
    Gough's calibration, the machine's geometric errors along the path, the lag of a
    linearised measurement): ``b_i``, a low-pass of d_i (``GOUGH_BIAS_GAIN`` a cycle),
    follows it. A frozen reading makes ``d_i - b_i`` grow with the drive's motion, a
    slip steps it, and neither needs the dynamic model. A drive is named when its
    ``|d_i - b_i|`` exceeds max(``jump_m``, eight times its running RMS) in two cycles
    running while every other drive stays under its own threshold: a disagreement in
    several drives at once is the tool's or the metrology's (a strut glitch, a knock on
    the tool), not one encoder's, and is left to the law's checks (gough_kernel).

    ``agrees(i, size, held)``: drive i's reading moved as the Gough saw the tool move,
    over the suspect's window (since the reading last changed for a freeze, the last
    two cycles for a slip); a drive that really stopped (a brake) agrees, a frozen
    encoder does not. The controller asks it before it names an encoder the
    innovation test (``EncoderMonitor``) suspects. Raw displacements, not the
    low-passed difference: the low-pass follows a slow freeze's ramp."""

    def __init__(self, n: int, jump_m: float):
        if not jump_m > 0.0:
            raise FieldError("encoder_gough_m", f"must be > 0 m (inf: off), got {jump_m}")
        self.n, self.jump_m = n, jump_m
        self.reset()

    def reset(self) -> None:
        n = self.n
        self.cycles = 0
        # the float arrays gough_check_kernel updates, as rows of one (``state``, for a
        # compiled caller): (reading, q(x_g)) of the last three cycles (the newest last),
        # q(x_g) when each reading last changed, the last d, its low-pass, mean square and offset
        self.state = np.zeros((GOUGH_STATE_ROWS, n))
        self.history_q, self.history_g = self.state[0:3], self.state[3:6]
        self.hold_g, self.last_d, self.bias, self.mean_square, self.off = self.state[6:]
        self.over = np.zeros(n, dtype=np.int64)
        self.skip = np.zeros(n, dtype=bool)
        self.skip_set = False

    def agrees(self, i: int, size: float, held: bool) -> bool:
        """Did drive i's reading move as the Gough saw the tool move, against a
        suspected fault of ``size`` (m)? ``held``: a freeze, compared since the reading
        last changed; else a slip, over the last two cycles. Yes when their
        displacements differ by under half of ``size`` and the Gough's noise (four
        RMS of the difference) is under half of it too (a noisier Gough cannot tell);
        no before three cycles of history."""
        if self.cycles < 3:
            return False
        if held:
            mismatch = self.history_g[2, i] - self.hold_g[i]       # the reading did not move
        else:
            mismatch = (self.history_q[2, i] - self.history_q[0, i]) - (self.history_g[2, i] - self.history_g[0, i])
        return abs(mismatch) < 0.5 * size and 4.0 * math.sqrt(self.mean_square[i]) < 0.5 * size

    def check(self, q, q_gough, skip=()) -> EncoderFault | None:
        """The fault (drive, what) when one drive's reading has left the Gough's (class
        docstring), None otherwise; ``q`` the readings, ``q_gough`` = q(x_g);
        ``skip``: drives not to judge (dropped ones)."""
        q, g = np.asarray(q, dtype=float), np.asarray(q_gough, dtype=float)
        if q.shape != (self.n,) or g.shape != (self.n,):
            raise ValueError(f"Gough cross-check: {self.n} readings and {self.n} drive positions of the Gough's pose "
                             f"needed, got shapes {q.shape} and {g.shape}")
        self._skip(skip)
        self.cycles += 1
        return self._fault(gough_check_kernel(q, g, self.history_q, self.history_g, self.hold_g, self.last_d,
                                              self.bias, self.mean_square, self.over, self.off, self.skip, self.jump_m,
                                              self.cycles == 1))

    def check_rail(self, model, q: np.ndarray, pose, skip=()) -> tuple[bool, EncoderFault | None]:
        """:meth:`check` with q(x_g) the inverse kinematics of the rail machine ``model``
        at the Gough's ``pose`` (3 task coordinates), in one compiled call; ``q`` the
        readings as n floats (an array). (judged: False when the pose has no inverse
        kinematics, nothing judged then; the fault or None)."""
        if q.shape != (self.n,) or q.dtype != np.float64:
            raise ValueError(f"Gough cross-check: {self.n} readings as floats needed, got {q.shape} {q.dtype}")
        self._skip(skip)
        drive = _rail_gough_check(model.bars, model.n_legs, model.twist_columns, float(pose[0]), float(pose[1]),
                                  float(pose[2]), q, self.history_q, self.history_g, self.hold_g, self.last_d,
                                  self.bias, self.mean_square, self.over, self.off, self.skip, self.jump_m,
                                  self.cycles == 0)
        if drive == GOUGH_NO_POSE:
            return False, None
        self.cycles += 1
        return True, self._fault(drive)

    def _skip(self, skip) -> None:
        if len(skip):
            self.skip[:] = False
            for i in skip:
                self.skip[i] = True
        elif self.skip_set:
            self.skip[:] = False
        self.skip_set = bool(len(skip))

    def _fault(self, i: int) -> EncoderFault | None:
        if i < 0:
            return None
        return EncoderFault(i, f"off the Gough metrology: reading {self.off[i] * 1e6:+.1f} um from the drive position "
                               f"the measured tool pose gives, {self.over[i]} cycles running (encoder_gough_m "
                               f"{self.jump_m:g})")


class EncoderChecks:
    """A controller's encoder checks, each returning a supervisor.Trip or None: the
    innovation test of every cycle (:class:`EncoderMonitor`, when encoder_jump_m or
    encoder_freeze_m is set) and, for a metrology strategy, the Gough's view of the
    same cycle (:class:`GoughCrossCheck`, encoder_gough_m), judged at the next one."""

    def __init__(self, model, names: list, config, uses_metrology: bool):
        c, n = config, len(names)
        self.model, self.names = model, names
        self.encoders = EncoderMonitor(n, c.encoder_jump_m or math.inf, c.encoder_freeze_m or math.inf) \
            if c.encoder_jump_m or c.encoder_freeze_m else None
        self.gough_check = GoughCrossCheck(n, c.encoder_gough_m) \
            if c.encoder_gough_m and uses_metrology else None
        self.pending = None                # (q, Gough pose, suspect) of the last cycle, for the next prepare
        # a rail machine's q(x_g) and the cross-check in one compiled call (rail_gough_check_kernel)
        self.rails = isinstance(model, RailMachine)
        self._no_forces = np.zeros(n)

    def check_cycle(self, c, forces_mismatched: bool, failed: dict) -> Trip | None:
        """EncoderMonitor on the prepared cycle ``c``: the second difference of the
        readings the dynamic model predicts from the forces the drives report,
        J_m A^-1 (J_m^T f - H) dt^2, and the displacement the reference asked for,
        J_m v_d dt. With a Gough cross-check a suspect is kept on ``c`` for it."""
        if self.encoders is None:
            return None
        applied = c.applied
        if forces_mismatched:             # the drive supervision saw it in this cycle
            # a drive that does not apply its command (a brake engaging is an impulse the
            # reported forces do not hold): the drive supervision's, not an encoder's
            self.encoders.reset()
            return None
        fault = self.encoders.check(c.q_array, c.a_model, c.h_model, c.rows,
                                    applied if applied is not None and len(applied) == len(self.names) else
                                    self._no_forces, c.v_d, c.dt, failed, setpoint_held=c.held)
        if fault is None:
            return None
        drive, what = fault
        if self.gough_check is not None:
            # judged with the Gough's view of the same cycle, at the next prepare
            c.suspect = (drive, what, self.encoders.fault_size, self.encoders.fault_held)
            return None
        return Trip(f"encoder of drive {self.names[drive]} {what}", TripCause.ENCODER_FAULT)

    def keep_for_gough(self, q, measured, suspect) -> None:
        """The readings of a cycle and the Gough's pose of it, judged at the next prepare."""
        if self.gough_check is not None:
            self.pending = (q, measured, suspect)

    def check_against_gough(self, failed: dict) -> Trip | None:
        """GoughCrossCheck on the last cycle's readings and Gough pose (judged while the
        metrology of this cycle is on its way, not between it and the command): each
        reading against q(x_g), the inverse kinematics of the tool pose the Gough
        measured; then that cycle's suspect of the innovation test, if any: a drive
        whose reading moved as the Gough saw the tool move has stopped for real (a
        brake, a jam: the following error's and the drive supervision's to name), not
        lost its encoder."""
        if self.pending is None:
            return None
        (q, measured, suspect), self.pending = self.pending, None
        check = self.gough_check
        if self.rails:                          # one compiled call
            judged, fault = check.check_rail(self.model, q, measured, failed)
        else:
            try:
                q_gough = self.model.inverse_kinematics(np.asarray(measured, dtype=float), check_limits=False)
            except (KinematicsError, ValueError):   # an unreachable measured pose: the law's limits name it
                q_gough = None
            judged = q_gough is not None
            fault = check.check(q, q_gough, failed) if judged else None
        if fault is not None:
            return Trip(f"encoder of drive {self.names[fault.drive]} {fault.what}", TripCause.ENCODER_FAULT)
        if suspect is None:
            return None
        drive, what, size, held = suspect
        if judged and check.agrees(drive, size, held):
            self.encoders.reset()
            return None
        # the Gough saw the drive move where its reading did not (or cannot tell): the encoder
        return Trip(f"encoder of drive {self.names[drive]} {what}", TripCause.ENCODER_FAULT)


_rail_gough_check = direct_call(rail_gough_check_kernel)     # check_rail makes each argument with its declared type
