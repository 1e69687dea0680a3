"""The first half of a usual control cycle in one compiled call (pure core, no rclpy).

``ControllerCore.prepare`` on a rail machine (ARCHI, the linear Delta) runs, per
cycle: the drive state's checks, the Gough's judgement of the last cycle's readings
(GoughCrossCheck), the encoder forward kinematics and measured state, the drive
supervision, the reference, the innovation test (EncoderMonitor) and the
sensor-space l_des and J_h. Each is a compiled kernel, but called one by one from
Python they took about four times their work in conversions and calls.
:func:`prepare_kernel` runs the same kernels in the same order on the same floats in
one call. It works on copies of the checks' state and writes them back only when the
cycle is a usual one: nothing to trip, suspect or drop. Otherwise it answers
``INTERPRETED`` with nothing changed, and the interpreted ``prepare`` takes the cycle
from the start and names what it finds, as it always did. So the two paths give the
same bits (tests/controller/test_compiled_prepare.py; tools/golden.py).
"""

from __future__ import annotations

import math

import numpy as np

from pkm_kinematics.dynamics import rail_encoder_state_kernel
from pkm_kinematics import bars as B
from pkm_kinematics.jit import direct_call, kernel

from .config import FORWARD_KINEMATICS
from .cycle import Cycle
from .encoder_check import (ENC_OK, GOUGH_NO_POSE, GOUGH_STATE_ROWS, MONITOR_STATE_ROWS, innovation_kernel,
                            rail_gough_check_kernel)
from .laws import CONFIGURATION_TYPES, three_axis_tool_pose_kernel
from .reference import sample_reference_kernel
from .sensor_space import sensor_space_command_kernel, sensor_space_desired_kernel
from .strategies import Feedback

__all__ = ["COMPILE_PREPARE", "CompiledPrepare", "prepare_kernel"]

COMPILE_PREPARE = True     # False: every cycle interpreted (the reference of the tests)
PREPARED, INTERPRETED = 0, 1

_F, _B, _T, _R = "float64", "boolean", "UniTuple(float64, 3)", "UniTuple(float64, 9)"
_V, _M, _I, _IM = "float64[:]", "float64[:, :]", "int64[:]", "int64[:, :]"
_SIGNATURE = "(" + ", ".join((
    _M, _V, _I,                          # io, constants, modes (CompiledPrepare.prepare)
    _M, _IM, _V, _I, _M,                 # the machine's bars, the solver's pairs and sides, columns, the Gough's bars
    _M, _I, _M, _M, _V, _M,              # the Gough check's state and counts, the innovation test's, the reference,
                                         # the cycle's sensor-space inputs (CYCLE_*) and J_h, written
    _F, _F, _T, _T, _T, _R,              # tau, dt, the last pose, the last cycle's Gough pose, the plate's estimate
    _B, _B, _B, _B, _B)) + ")"           # has_applied, pending, gough_first, second, at_estimate

# CompiledPrepare's constants: the indices of its floats, then md, k, dg (n each)
C_SIDE, C_MISMATCH_N, C_GOUGH_M, C_JUMP_M, C_FREEZE_M, C_MASS, C_P_WB, C_R_BW, C_R_TP, C_P_TP, C_R_WB, C_DRIVES = (
    0, 1, 2, 3, 4, 5, 11, 14, 23, 32, 35, 44)
# ... its modes
M_SPHERES, M_MONITOR, M_DESIRED, M_PLANAR, M_REDUNDANT, M_LEGS = range(6)
# ... and the sensor-space inputs of a cycle, kept for complete_kernel: x_d, v_d, a_d, v, A (row-major), H,
# p_bp, R_bp, R_t, l_des, dt
X_D, V_D, A_D, V, A, H, P_BP, R_BP, R_T, L_DES, DT, CYCLE_SIZE = 0, 3, 6, 9, 12, 21, 24, 27, 36, 45, 51, 52


@kernel()
def _finite_sum(values):
    """Whether the sum of ``values`` in order is finite (supervisor.check_state's test)."""
    total = 0.0
    for value in values:
        total += value
    return math.isfinite(total)


@kernel()
def _tuple3(c, i):
    return c[i], c[i + 1], c[i + 2]


@kernel()
def _tuple9(c, i):
    return c[i], c[i + 1], c[i + 2], c[i + 3], c[i + 4], c[i + 5], c[i + 6], c[i + 7], c[i + 8]


@kernel(_SIGNATURE)
def prepare_kernel(io, constants, modes, bars, pairs, sides, columns, gough_bars, gough_state, over, monitor_state,
                   table, cycle, cycle_j_h, tau, dt, guess, pending_x, p_at, r_at, has_applied, pending, gough_first,
                   second, at_estimate):
    """ControllerCore.prepare of a usual cycle (module doc), in its order: the state's
    values finite (supervisor.check_state; ``io`` its rows q, qdot, applied, then the
    last command and the last cycle's q), the last cycle's readings against the Gough
    (rail_gough_check_kernel, when ``pending``, at the Gough's pose ``pending_x``), the
    encoder state (rail_encoder_state_kernel from the last pose ``guess``), the drive
    supervision (a force off its command: not usual), the reference at ``tau``
    (sample_reference_kernel), the innovation test (innovation_kernel) and l_des and
    J_h (sensor_space_desired_kernel at the tool pose of x_d), each where ``modes``
    has it; then what complete_kernel takes of the cycle into ``cycle`` and
    ``cycle_j_h``. Returns (PREPARED or INTERPRETED, the pose, J_m, v, A, H, x_d, v_d,
    a_d, whether the Gough judged); the state arrays written only when PREPARED."""
    n = io.shape[1]
    q, qdot, applied, commanded, pending_q = io[0], io[1], io[2], io[3], io[4]
    c = constants
    drives = c[C_DRIVES:]
    md, k, dg = drives[:n], drives[n:2 * n], drives[2 * n:3 * n]
    code = INTERPRETED
    pose, v, h = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    rows = np.empty((0, 3))
    a_rows = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    x_d, v_d, a_d = (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)
    judged = False
    no_skip = np.zeros(n, dtype=np.bool_)         # every drive judged: a usual cycle drops none
    gs, g_over, ms = gough_state.copy(), over.copy(), monitor_state.copy()     # worked on in copies
    usual = _finite_sum(q) and _finite_sum(qdot) and (not has_applied or _finite_sum(applied))
    if usual and pending:
        drive = rail_gough_check_kernel(bars, modes[M_LEGS], columns, pending_x[0], pending_x[1], pending_x[2],
                                        pending_q, gs[0:3], gs[3:6], gs[6], gs[7], gs[8], gs[9], g_over, gs[10],
                                        no_skip, c[C_GOUGH_M], gough_first)
        judged = drive != GOUGH_NO_POSE
        usual = drive < 0
    if usual:
        x0, x1, x2, solved, rows, v0, v1, v2, a00, a01, a02, a11, a12, a22, h0, h1, h2, vt, _ = \
            rail_encoder_state_kernel(modes[M_SPHERES] != 0, bars, pairs, sides, c[C_SIDE], q, guess[0], guess[1],
                                      guess[2], columns, qdot, md, k, dg, c[C_MASS], c[C_MASS + 1], c[C_MASS + 2],
                                      c[C_MASS + 3], c[C_MASS + 4], c[C_MASS + 5])
        usual = solved and vt == B.VT_OK
        pose, v, h = (x0, x1, x2), (v0, v1, v2), (h0, h1, h2)
        a_rows = ((a00, a01, a02), (a01, a11, a12), (a02, a12, a22))
    if usual and has_applied:
        for i in range(n):
            if abs(applied[i] - commanded[i]) > c[C_MISMATCH_N]:
                usual = False          # the drive supervision counts it, and the innovation test waits
    if usual:
        xs, vs, accs = sample_reference_kernel(table, tau)
        x_d, v_d, a_d = (xs[0], xs[1], xs[2]), (vs[0], vs[1], vs[2]), (accs[0], accs[1], accs[2])
        if modes[M_MONITOR]:
            a = np.empty((3, 3))
            for i in range(3):
                for j in range(3):
                    a[i, j] = a_rows[i][j]
            outcome, _, _ = innovation_kernel(q, ms[0], ms[1], second, a, np.array(h), rows,
                                              applied if has_applied else np.zeros(n), vs, dt, ms[2], ms[3], ms[4],
                                              ms[5], no_skip, c[C_JUMP_M], c[C_FREEZE_M], modes[M_REDUNDANT] != 0)
            usual = outcome == ENC_OK
    if usual and modes[M_DESIRED]:
        p_t, r_t = three_axis_tool_pose_kernel(x_d[0], x_d[1], x_d[2], modes[M_PLANAR] != 0)
        p_bp, r_bp, l_des, j_h = sensor_space_desired_kernel(
            gough_bars, p_t, r_t, _tuple3(c, C_P_WB), _tuple9(c, C_R_BW), _tuple9(c, C_R_TP), _tuple3(c, C_P_TP),
            p_at, r_at, at_estimate)
        for i, values in ((X_D, x_d), (V_D, v_d), (A_D, a_d), (V, v), (H, h), (P_BP, p_bp)):
            for j in range(3):
                cycle[i + j] = values[j]
        for i, values in ((R_BP, r_bp), (R_T, r_t)):
            for j in range(9):
                cycle[i + j] = values[j]
        for i in range(3):
            for j in range(3):
                cycle[A + 3 * i + j] = a_rows[i][j]
        cycle[L_DES:L_DES + 6] = l_des
        cycle[DT] = dt
        cycle_j_h[:, :] = j_h
    if usual:
        code = PREPARED
        gough_state[:, :], over[:], monitor_state[:, :] = gs, g_over, ms
    return code, pose, rows, v, a_rows, h, x_d, v_d, a_d, judged


@kernel(f"(float64[:], float64[:, :], float64[:], float64[:, :], float64[:], float64[:], UniTuple(float64, 3), "
        f"boolean, {CONFIGURATION_TYPES})")
def complete_kernel(cycle, j_h, q, rows, lengths, constants, integral, integrate, boxes, gains, settings, modes):
    """sensor_space_command_kernel on a cycle prepare_kernel prepared (its inputs in
    ``cycle`` and ``j_h``), the readings ``lengths`` and the law's state and settings:
    ThreeAxis.sensor_space without its inputs made into Python objects and back."""
    c = cycle
    model = (((c[A], c[A + 1], c[A + 2]), (c[A + 3], c[A + 4], c[A + 5]), (c[A + 6], c[A + 7], c[A + 8])),
             _tuple3(c, H))
    return sensor_space_command_kernel(j_h, c[L_DES:L_DES + 6], lengths, _tuple3(c, P_BP), _tuple9(c, R_BP),
                                       _tuple9(constants, C_R_WB), _tuple3(constants, C_P_TP), _tuple9(c, R_T),
                                       _tuple3(c, X_D), q, rows, _tuple3(c, V_D), _tuple3(c, V), _tuple3(c, A_D),
                                       model, integral, integrate, c[DT], boxes, gains, settings, modes)


_prepare = direct_call(prepare_kernel)      # CompiledPrepare.prepare makes each argument with its declared type
_complete = direct_call(complete_kernel)    # CompiledPrepare.sensor_space makes each argument with its declared type

_NO_ESTIMATE = ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0))
_NO_POSE = (0.0, 0.0, 0.0)


class CompiledPrepare:
    """:func:`prepare_kernel` for one configured ControllerCore: ``of(core)`` when its
    machine and configuration have it (a rail machine whose encoder state is one
    kernel, the pose solved every cycle, no drive tables, a 3-axis task, commands
    applied at once), else None. ``prepare`` answers a Cycle, or None when the cycle is
    not a usual one (the interpreted path takes it). Made again when the controller
    is reset or its settings change."""

    def __init__(self, core, encoder_inputs: tuple):
        # the forward solver's bars are the machine's own (DynamicModel.encoder_state_inputs), which the
        # Gough cross-check takes too
        (spheres, self.bars, self.pairs, self.sides, side), (self.columns, md, k, dg, *mass) = encoder_inputs
        self.core, self.n = core, core.n
        checks, c, n = core.encoder_checks, core.config, core.n
        self.gough, self.monitor = checks.gough_check, checks.encoders
        self.desired = core.strategy.feedback == Feedback.STRUTS
        self.gough_bars, plate = np.zeros((0, 6)), (_NO_POSE, _NO_ESTIMATE[1], _NO_ESTIMATE[1], _NO_POSE,
                                                    _NO_ESTIMATE[1])
        if self.desired:
            self.gough_bars, *plate = core.metrology.kernel_constants()
        self.cycle, self.cycle_j_h = np.zeros(CYCLE_SIZE), np.zeros((6, 6))
        monitor = self.monitor
        self.constants = np.array([
            side, c.drive_mismatch_n, self.gough.jump_m if self.gough is not None else 0.0,
            monitor.jump_m if monitor is not None else 0.0, monitor.freeze_m if monitor is not None else 0.0,
            *mass, *(value for part in plate for value in part), *md, *k, *dg], dtype=float)
        assert len(self.constants) == C_DRIVES + 3 * n
        self.modes = np.array([spheres, monitor is not None, self.desired, core.planar, n > 3, n], dtype=np.int64)
        self.zero_floats = (0.0,) * n
        self.no_gough = (np.zeros((GOUGH_STATE_ROWS, n)), np.zeros(n, dtype=np.int64))
        self.no_monitor = np.zeros((MONITOR_STATE_ROWS, n))

    @classmethod
    def of(cls, core) -> "CompiledPrepare | None":
        inputs = getattr(core.dynamics, "encoder_state_inputs", lambda: None)()
        c, checks = core.config, core.encoder_checks
        if (not COMPILE_PREPARE or inputs is None or FORWARD_KINEMATICS[c.forward_kinematics]
                or core.compensation is not None or core.dof != 3 or core.kernels.twists is not None
                or c.actuation_delay_cycles or (checks.gough_check is not None and not checks.rails)
                or (core.strategy.feedback == Feedback.STRUTS and not core.fused_struts)):
            return None
        return cls(core, inputs)

    def prepare(self, stamp_ns: int, q, qdot, applied, held) -> Cycle | None:
        core, n = self.core, self.n
        sup, feed, last_t = core.supervisor, core.tracker.feed, core.last_time_s
        if (held is not None or sup.stopped or last_t is None or sup.failed or len(sup.active) != n
                or len(q) != n or len(qdot) != n or not feed.nominal):
            return None
        has_applied = applied is not None and len(applied) > 0
        checks, gough, monitor = core.encoder_checks, self.gough, self.monitor
        pending = checks.pending
        guess, reference = core.estimator.pose, core.tracker.reference
        if ((has_applied and len(applied) != n) or (pending is not None and pending[2] is not None)
                or (monitor is not None and (not monitor.started or monitor.skip_set))
                or (gough is not None and gough.skip_set) or guess is None or reference is None):
            return None                # not a usual cycle: a suspect to judge, a drive skipped, ...
        # one array of the five rows' floats (a flat tuple: ~1 us less than five sequences)
        zeros = self.zero_floats
        io = np.array((*q, *qdot, *(applied if has_applied else zeros), *core.last_command,
                       *(zeros if pending is None else pending[0].tolist())), dtype=float).reshape(5, n)
        t_s = stamp_ns * 1e-9
        dt = core.config.dt_s if t_s <= last_t else t_s - last_t
        tau = feed.advance(t_s)[0]     # at the nominal feed the same again if the cycle is interpreted
        if pending is not None:
            x = pending[1]
            pending_x, gough_state, over = (float(x[0]), float(x[1]), float(x[2])), gough.state, gough.over
        else:
            pending_x, (gough_state, over) = _NO_POSE, self.no_gough
        if monitor is not None:
            second = bool(monitor.second and abs(dt - monitor.last_dt) <= 1e-3 * monitor.last_dt)
            monitor_state = monitor.state
        else:
            second, monitor_state = False, self.no_monitor
        estimate = core.metrology.estimate if self.desired and core.metrology.at_estimate else None
        p_at, r_at = _NO_ESTIMATE if estimate is None else estimate
        out = _prepare(io, self.constants, self.modes, self.bars, self.pairs, self.sides, self.columns,
                       self.gough_bars, gough_state, over, monitor_state, reference.table, self.cycle,
                       self.cycle_j_h, tau, float(dt),
                       (float(guess[0]), float(guess[1]), float(guess[2])), pending_x, p_at, r_at, has_applied,
                       pending is not None, gough is not None and gough.cycles == 0, second, estimate is not None)
        if out[0] != PREPARED:
            return None
        _, pose, rows, v, a_rows, h, x_d, v_d, a_d, judged = out
        # a usual cycle: what the interpreted path keeps of it
        core.last_stamp_ns, core.last_time_s = stamp_ns, t_s
        pose, q_array = list(pose), io[0]
        core.estimator.keep_pose(pose, q_array)
        sup.forces_mismatched = False
        if has_applied:
            sup.drives_agree()
        if pending is not None:
            checks.pending = None
            gough.cycles += judged
        if monitor is not None:
            monitor.second, monitor.last_dt = True, dt
        c = Cycle(stamp_ns, t_s, dt, False, list(q), q_array, list(qdot), pose, rows, rows, v)
        c.a_model, c.h_model, c.applied, c.held = a_rows, h, applied, False
        c.x_d, c.v_d, c.a_d = list(x_d), list(v_d), list(a_d)
        c.compiled = self.desired          # complete() takes the sensor-space inputs from the buffers
        return c

    def sensor_space(self, c: Cycle, struts) -> tuple:
        """commands.ThreeAxis.sensor_space of a cycle ``prepare`` made (``c.compiled``),
        by complete_kernel on what it kept: (measured, error, the outcome); the
        feedback's estimate of the real plate kept."""
        core = self.core
        s = core.setup
        real_p, real_r, measured, error, code, index, value, integral, wrench, forces, saturated, peak = _complete(
            self.cycle, self.cycle_j_h, c.q_array, c.rows, np.asarray(struts, dtype=float), self.constants,
            core.integral, core.record.saturated == 0, s.boxes, s.gains, s.settings, s.modes)
        core.metrology.estimate = (real_p, real_r)
        return measured, error, core.kernels.outcome(core, core.supervisor.active, True, code, index, value,
                                                     integral, wrench, forces, saturated, peak)
