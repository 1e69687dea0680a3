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
from .encoder_check import ENC_OK, GOUGH_NO_POSE, innovation_kernel, rail_gough_check_kernel
from .laws import three_axis_tool_pose_kernel
from .reference import sample_reference_kernel
from .sensor_space import sensor_space_desired_kernel
from .strategies import Feedback

__all__ = ["COMPILE_PREPARE", "CompiledPrepare", "prepare_kernel"]

COMPILE_PREPARE = True     # False: every cycle interpreted (the reference of the tests)
PREPARED, INTERPRETED = 0, 1

_F, _B, _T, _R = "float64", "boolean", "UniTuple(float64, 3)", "UniTuple(float64, 9)"
_V, _M, _I = "float64[:]", "float64[:, :]", "int64[:]"
_SIGNATURE = "(" + ", ".join((
    _V, _V, _V, _B, _V, _F,                                       # q, qdot, applied, has_applied, commanded, mismatch_n
    _B, _M, "int64[:, :]", _V, _F, _T, _I, _V, _V, _V, _F, _F, _F, _F, _F, _F,   # the encoder state
    _B, _V, _T, "int64", _M, _M, _V, _V, _V, _V, _I, _V, "boolean[:]", _F, _B,  # the Gough cross-check
    _V, _M, _M, _M, _F,                                              # the reference
    _B, _V, _V, _B, _F, _V, _V, _V, _V, "boolean[:]", _F, _F, _B,    # the innovation test
    _B, _B, _M, _T, _R, _R, _T, _T, _R, _B)) + ")"                   # l_des and J_h


@kernel()
def _finite_sum(values):
    """Whether the sum of ``values`` in order is finite (supervisor.check_state's test)."""
    total = 0.0
    for value in values:
        total += value
    return math.isfinite(total)


@kernel(_SIGNATURE)
def prepare_kernel(q, qdot, applied, has_applied, commanded, mismatch_n,
                   spheres, bars, pairs, sides, side, guess, columns, md, k, dg, mn0, mn1, mn2, pg0, pg1, pg2,
                   gough, pending_q, pending_x, n_legs, history_q, history_g, hold_g, last_d, g_bias, g_mean_square,
                   over, off, g_skip, gough_m, gough_first,
                   ref_t, ref_x, ref_v, ref_a, tau,
                   monitor, last_q, last_dq, second, dt, bias, mean_square, held, candidate, skip, jump_m, freeze_m,
                   redundant,
                   desired, planar, gough_bars, p_wb, r_bw, r_tp, p_tp, p_at, r_at, at_estimate):
    """ControllerCore.prepare of a usual cycle (module doc), in its order: the state's
    values finite (supervisor.check_state), the last cycle's readings against the
    Gough (rail_gough_check_kernel; ``gough``: one is pending, ``pending_q`` and the
    Gough's pose ``pending_x``), the encoder state (rail_encoder_state_kernel from the
    last pose ``guess``), the drive supervision (a force off its command: not usual),
    the reference at ``tau`` (sample_reference_kernel), the innovation test
    (innovation_kernel, ``monitor``) and, ``desired``, l_des and J_h
    (sensor_space_desired_kernel at the tool pose of x_d). Returns (PREPARED or
    INTERPRETED, the pose, J_m, v, A, H, x_d, v_d, a_d, whether the Gough judged, p_bp,
    R_bp, l_des, J_h, R_t); the checks' state arrays written only when PREPARED."""
    n = q.shape[0]
    code = INTERPRETED
    pose = (0.0, 0.0, 0.0)
    rows = np.empty((0, 3))
    v = (0.0, 0.0, 0.0)
    a_rows = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    h = (0.0, 0.0, 0.0)
    x_d, v_d, a_d = np.empty(0), np.empty(0), np.empty(0)
    judged = False
    identity = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    p_bp, r_bp, r_t = (0.0, 0.0, 0.0), identity, identity
    l_des, j_h = np.empty(0), np.empty((0, 0))
    # the checks' state, worked on in copies
    hq, hg, hold, ld, gb, gms, gover, goff = (history_q.copy(), history_g.copy(), hold_g.copy(), last_d.copy(),
                                              g_bias.copy(), g_mean_square.copy(), over.copy(), off.copy())
    lq, ldq, mb, mms, mh, mc = (last_q.copy(), last_dq.copy(), bias.copy(), mean_square.copy(), held.copy(),
                                candidate.copy())
    usual = _finite_sum(q) and _finite_sum(qdot) and (not has_applied or _finite_sum(applied))
    if usual and gough:
        drive = rail_gough_check_kernel(bars, n_legs, columns, pending_x[0], pending_x[1], pending_x[2], pending_q,
                                        hq, hg, hold, ld, gb, gms, gover, goff, g_skip, gough_m, gough_first)
        judged = drive != GOUGH_NO_POSE
        usual = drive < 0
    if usual:
        x0, x1, x2, solved, rows, v0, v1, v2, a00, a01, a02, a11, a12, a22, h0, h1, h2, vt, _ = \
            rail_encoder_state_kernel(spheres, bars, pairs, sides, side, q, guess[0], guess[1], guess[2], columns,
                                      qdot, md, k, dg, mn0, mn1, mn2, pg0, pg1, pg2)
        usual = solved and vt == B.VT_OK
        pose, v, h = (x0, x1, x2), (v0, v1, v2), (h0, h1, h2)
        a_rows = ((a00, a01, a02), (a01, a11, a12), (a02, a12, a22))
    if usual and has_applied:
        for i in range(n):
            if abs(applied[i] - commanded[i]) > mismatch_n:
                usual = False          # the drive supervision counts it, and the innovation test waits
    if usual:
        x_d, v_d, a_d = sample_reference_kernel(ref_t, ref_x, ref_v, ref_a, tau)
    if usual and monitor:
        a = np.empty((3, 3))
        for i in range(3):
            for j in range(3):
                a[i, j] = a_rows[i][j]
        forces = applied if has_applied else np.zeros(n)
        outcome, _, _ = innovation_kernel(q, lq, ldq, second, a, np.array(h), rows, forces, v_d, dt, mb, mms, mh, mc,
                                          skip, jump_m, freeze_m, redundant)
        usual = outcome == ENC_OK
    if usual and desired:
        p_t, r_t = three_axis_tool_pose_kernel(x_d[0], x_d[1], x_d[2], planar)
        p_bp, r_bp, l_des, j_h = sensor_space_desired_kernel(gough_bars, p_t, r_t, p_wb, r_bw, r_tp, p_tp, p_at,
                                                             r_at, at_estimate)
    if usual:
        code = PREPARED
        history_q[:, :], history_g[:, :], hold_g[:], last_d[:] = hq, hg, hold, ld
        g_bias[:], g_mean_square[:], over[:], off[:] = gb, gms, gover, goff
        last_q[:], last_dq[:], bias[:], mean_square[:], held[:], candidate[:] = lq, ldq, mb, mms, mh, mc
    return code, pose, rows, v, a_rows, h, x_d, v_d, a_d, judged, p_bp, r_bp, l_des, j_h, r_t


_prepare = direct_call(prepare_kernel)      # CompiledPrepare.prepare makes each argument with its declared type

_NO_GOUGH_STATE = (np.zeros((3, 0)), np.zeros((3, 0)), np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0),
                   np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0, dtype=bool), 1.0)
_NO_MONITOR_STATE = (np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0),
                     np.zeros(0, dtype=bool), 1.0, 1.0)
_NO_PLATE = (np.zeros((0, 0)), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0),
             (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0), (0.0, 0.0, 0.0))
_NO_ESTIMATE = ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0))
_NOTHING = np.zeros(0)


class CompiledPrepare:
    """:func:`prepare_kernel` for one configured ControllerCore: ``of(core)`` when its
    machine and configuration have it (a rail machine whose encoder state is one
    kernel, the pose solved every cycle, no drive tables, a 3-axis task, commands
    applied at once), else None. ``prepare`` answers a Cycle, or None when the cycle is
    not a usual one (the interpreted path takes it)."""

    def __init__(self, core, encoder_inputs: tuple):
        self.core = core
        self.head, self.tail = encoder_inputs
        self.bars = core.model.bars
        self.n = core.n
        checks = core.encoder_checks
        self.gough_check, self.monitor = checks.gough_check, checks.encoders
        self.desired = core.strategy.feedback == Feedback.STRUTS
        self.mismatch_n = float(core.config.drive_mismatch_n)
        self.plate = _NO_PLATE
        if self.desired:
            self.plate = core.metrology.kernel_constants()

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
        core = self.core
        sup, checks, feed, n = core.supervisor, core.encoder_checks, core.tracker.feed, self.n
        if (held is not None or sup.stopped or core.last_time_s is None or sup.failed or len(sup.active) != n
                or len(q) != n or len(qdot) != n or not feed.nominal):
            return None
        has_applied = applied is not None and len(applied) > 0
        if has_applied and len(applied) != n:
            return None
        pending, gough, monitor = checks.pending, self.gough_check, self.monitor
        if pending is not None and pending[2] is not None:      # a suspect for the Gough to judge
            return None
        if (monitor is not None and (not monitor.started or monitor.skip_set)) or \
                (gough is not None and gough.skip_set):
            return None
        q_array, qdot_array = np.array(q, dtype=float), np.array(qdot, dtype=float)
        applied_array = np.array(applied, dtype=float) if has_applied else _NOTHING
        t_s = stamp_ns * 1e-9
        dt = core.config.dt_s if t_s <= core.last_time_s else t_s - core.last_time_s
        tau = feed.peek(t_s)
        guess, reference = core.estimator.pose, core.tracker.reference
        if guess is None or reference is None:
            return None
        if pending is not None:
            measured = pending[1]
            gough_args = (True, pending[0], (float(measured[0]), float(measured[1]), float(measured[2])), n,
                          gough.history_q, gough.history_g, gough.hold_g, gough.last_d, gough.bias,
                          gough.mean_square, gough.over, gough.off, gough.skip, float(gough.jump_m),
                          gough.cycles == 0)
        else:
            gough_args = (False, _NOTHING, (0.0, 0.0, 0.0), n, *_NO_GOUGH_STATE, False)
        if monitor is not None:
            second = bool(monitor.second and abs(dt - monitor.last_dt) <= 1e-3 * monitor.last_dt)
            monitor_args = (True, monitor.last_q, monitor.last_dq, second, float(dt), monitor.bias,
                            monitor.mean_square, monitor.held, monitor.candidate, monitor.skip, monitor.jump_m,
                            monitor.freeze_m, n > 3)
        else:
            monitor_args = (False, *_NO_MONITOR_STATE[:2], False, float(dt), *_NO_MONITOR_STATE[2:], False)
        if self.desired:
            metrology = core.metrology
            estimate = metrology.estimate if metrology.at_estimate and metrology.estimate is not None else None
            p_at, r_at = estimate if estimate is not None else _NO_ESTIMATE
            desired_args = (True, core.planar, *self.plate, p_at, r_at, estimate is not None)
        else:
            desired_args = (False, False, *self.plate, *_NO_ESTIMATE, False)
        out = _prepare(q_array, qdot_array, applied_array, has_applied, np.array(core.last_command, dtype=float),
                       self.mismatch_n, *self.head, (float(guess[0]), float(guess[1]), float(guess[2])), *self.tail,
                       *gough_args, *reference.arrays, tau, *monitor_args, *desired_args)
        if out[0] != PREPARED:
            return None
        _, pose, rows, v, a_rows, h, x_d, v_d, a_d, judged, p_bp, r_bp, l_des, j_h, r_t = out
        # the cycle is a usual one: what the interpreted path keeps of it
        core.last_stamp_ns, core.last_time_s = stamp_ns, t_s
        feed.advance(t_s)
        pose = list(pose)
        core.estimator.keep_pose(pose, q_array)
        sup.forces_mismatched = False
        if has_applied:
            sup.drives_agree()
        if pending is not None:
            checks.pending = None
            gough.cycles += judged
        if monitor is not None:
            monitor.second, monitor.last_dt = True, dt
        if self.desired:
            core.metrology.keep_prepared(p_bp, r_bp, l_des, j_h, r_t)
        c = Cycle(stamp_ns, t_s, dt, False, list(q), q_array, list(qdot), pose, rows, rows, v)
        c.a_model, c.h_model, c.applied, c.held = a_rows, h, applied, False
        c.x_d, c.v_d, c.a_d = x_d.tolist(), v_d.tolist(), a_d.tolist()
        return c
