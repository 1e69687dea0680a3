"""Control laws of the papers, one function per formula (pure core).

They run every control cycle (1-2 kHz) on 3 DOF and 3-6 drives, where numpy costs
~1 us per operation and the interpreter's glue around a handful of float operations
costs more than the operations: the Cartesian laws with the supervisor's limits, the
distribution and the clamp (``cartesian_command_kernel``) and the condition number
of J are compiled kernels (pkm_kinematics.jit); the joint PIDs stay on Python floats.
The sensor-space feedback (MoM3 §6.4) is sensor_space.py's.

Notation: x task pose (planar (x, y, theta), translational (x, y, z)), v its velocity,
q drive positions, J the nominal Jacobian J_m (qdot = J v) given as rows of 3 floats
(or an (n, 3) array),
F the platform wrench J^T f, f the drive forces.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np

from pkm_kinematics.distribution import (check_wrench_kernel, distribute_kernel, gram_condition_kernel,
                                        gram_solve_n_kernel, project_forces, project_rows)
from pkm_kinematics.struts import weighted_condition_kernel
from pkm_kinematics.jit import kernel
from pkm_kinematics.rotations import log_so3_kernel, mul3_kernel, rpy_rotation_kernel, wrap_angle
from pkm_kinematics.task_space import PLANAR, SPATIAL, TaskSpace


@dataclass(frozen=True)
class Gains:
    """PID gains placed from a bandwidth omega (rad/s), a damping ratio zeta and an
    integral time T_i (0: no integral action): closed-loop characteristic
    (s^2 + 2 zeta omega s + omega^2)(1 + 1/(T_i s)) per axis. Stability of the
    integral needs T_i > 1 / (2 zeta omega) (Routh) where the gains' mass is the
    mode's; see weakest_mode_ratio for the modes it is not."""

    omega: float
    zeta: float
    integral_time_s: float

    @property
    def kp(self) -> float:
        """Position gain per unit mass (1/s^2)."""
        return self.omega * self.omega

    @property
    def kd(self) -> float:
        """Velocity gain per unit mass (1/s)."""
        return 2.0 * self.zeta * self.omega

    @property
    def ki(self) -> float:
        """Integral gain per unit mass (1/s^3)."""
        return self.kp / self.integral_time_s if self.integral_time_s > 0.0 else 0.0

    @property
    def outer_kp(self) -> float:
        """Outer position loop of a cascade (1/s): with the inner velocity loop kd it
        gives the same characteristic s^2 + kd s + kd outer_kp = s^2 + 2 zeta omega s + omega^2."""
        return self.omega / (2.0 * self.zeta)

    @property
    def outer_ki(self) -> float:
        return self.outer_kp / self.integral_time_s if self.integral_time_s > 0.0 else 0.0


def pose_error(x_d, x, planar: bool) -> list:
    """x_d - x, the angle of a planar machine wrapped to (-pi, pi]."""
    e = [x_d[0] - x[0], x_d[1] - x[1], x_d[2] - x[2]]
    if planar:
        e[2] = wrap_angle(e[2])
    return e


def spatial_pose_error(x_d, x) -> list:
    """x_d - x of two spatial poses (x, y, z, a, b, c) as the controller feeds it back:
    the translation and the rotation vector of R_d R^T (base frame, the same frame as
    the twist's w), not the difference of the angles (which is not a rotation)."""
    return list(spatial_pose_error_kernel(tuple(float(v) for v in x_d[:6]), tuple(float(v) for v in x[:6])))


_SEXTUPLE = "UniTuple(float64, 6)"


@kernel(f"({_SEXTUPLE}, {_SEXTUPLE})")
def spatial_pose_error_kernel(x_d, x):
    """:func:`spatial_pose_error` compiled: (e_x, e_y, e_z, w_x, w_y, w_z)."""
    r_d = rpy_rotation_kernel(x_d[3], x_d[4], x_d[5])
    r = rpy_rotation_kernel(x[3], x[4], x[5])
    r_t = (r[0], r[3], r[6], r[1], r[4], r[7], r[2], r[5], r[8])
    w0, w1, w2 = log_so3_kernel(mul3_kernel(r_d, r_t))
    return x_d[0] - x[0], x_d[1] - x[1], x_d[2] - x[2], w0, w1, w2


def task_pose_error(x_d, x, space: TaskSpace) -> list:
    """x_d - x in the task space of the machine: ``pose_error`` for planar (angle
    wrapped) and position machines, ``spatial_pose_error`` for a spatial pose."""
    if space is SPATIAL:
        return spatial_pose_error(x_d, x)
    return pose_error(x_d, x, space is PLANAR)


def error_norms(error, space: TaskSpace) -> tuple[float, float]:
    """(|translation error| (m), |rotation error| (rad)) of a task error: planar
    (hypot(e_x, e_y), |e_theta|), position (|e|, 0), spatial (|e_p|, |e_w|)."""
    if space is PLANAR:
        return math.hypot(error[0], error[1]), abs(error[2])
    trans = math.sqrt(error[0] * error[0] + error[1] * error[1] + error[2] * error[2])
    if space is SPATIAL:
        return trans, math.sqrt(error[3] * error[3] + error[4] * error[4] + error[5] * error[5])
    return trans, 0.0


def project_to_range(rows, forces) -> list:
    """n = J (J^T J)^-1 J^T n_d (Sliding Star eq. 8): the least-norm forces producing the
    same wrench F_d = J^T n_d (eq. 6-7); the fighting (null-space) part is removed.
    Rows of 3 (the 3-DOF machines: compiled closed form), or of any width."""
    if np.shape(rows)[1] == 3:
        return project_rows(rows, forces)
    return project_forces(rows, forces).tolist()


# ------------------------------------------------------------- safety limits
class CycleCode(IntEnum):
    """The outcome of limits_kernel, spatial_limits_kernel and the command kernels (as
    Ruckig's Result): OK, the first limit violated, a non-finite wrench or command, or
    DISTRIBUTION_FAILED + the distribution's code (distribution.DistributionCode).
    The caller words the message (supervisor.Supervisor.limit_trip)."""
    OK = 0
    JOINT_LIMIT = 1
    WORKSPACE_LIMIT = 2
    SINGULARITY_MARGIN = 3
    FOLLOWING_ERROR_M = 4
    FOLLOWING_ERROR_RAD = 5
    WRENCH_NOT_FINITE = 6
    FORCES_NOT_FINITE = 7
    DISTRIBUTION_FAILED = 10


CYCLE_CODES = {
    CycleCode.OK: "every limit kept; the value is the translation error",
    CycleCode.JOINT_LIMIT: "a drive outside its joint limits (index: the drive, value: its position)",
    CycleCode.WORKSPACE_LIMIT: "the measured pose outside the workspace box (index: the task axis, value: it)",
    CycleCode.SINGULARITY_MARGIN: "cond(J of the active drives) above max_condition (value: the condition)",
    CycleCode.FOLLOWING_ERROR_M: "the translation error above following_error_m (value: the error)",
    CycleCode.FOLLOWING_ERROR_RAD: "the rotation error above following_error_rad (value: the error)",
    CycleCode.WRENCH_NOT_FINITE: "the law's wrench has a NaN or infinite component",
    CycleCode.FORCES_NOT_FINITE: "the distributed drive forces have a NaN or infinite value",
    CycleCode.DISTRIBUTION_FAILED: "plus the distribution's code: the compiled distribution failed",
}
# the kernels' constants (a compiled kernel reads a module's ints)
LIMITS_OK, JOINT_LIMIT, WORKSPACE_LIMIT, SINGULARITY_MARGIN, FOLLOWING_ERROR_M, FOLLOWING_ERROR_RAD = (
    int(CycleCode.OK), int(CycleCode.JOINT_LIMIT), int(CycleCode.WORKSPACE_LIMIT), int(CycleCode.SINGULARITY_MARGIN),
    int(CycleCode.FOLLOWING_ERROR_M), int(CycleCode.FOLLOWING_ERROR_RAD))
WRENCH_NOT_FINITE, FORCES_NOT_FINITE = int(CycleCode.WRENCH_NOT_FINITE), int(CycleCode.FORCES_NOT_FINITE)
DISTRIBUTION_FAILED = int(CycleCode.DISTRIBUTION_FAILED)
_TRIPLE, _ROTATION = "UniTuple(float64, 3)", "UniTuple(float64, 9)"

# The packed inputs of the limits and command kernels: typed tuples that numba unboxes
# without an array, made once per configuration (``boxes``, ``settings``, ``modes``) or
# once per cycle (``task``, ``model``); their fields by these indices:
# boxes:    (joint_box, workspace_box), each (lower, upper) per drive / task axis
# settings: float64 x 5
SET_MAX_CONDITION, SET_FOLLOWING_ERROR_M, SET_FOLLOWING_ERROR_RAD, SET_FORCE_LIMIT, SET_LENGTH = range(5)
# modes:    int64 x 3 (MODE_PLANAR: 1 for a planar machine's theta error; the law
#           LAW_*; the distribution DIST_* or NUMPY_DISTRIBUTION)
MODE_PLANAR, MODE_LAW, MODE_DISTRIBUTION = range(3)
# task:     the cycle's task-space rows, 3-DOF five triples, 6-DOF a (5, 6) array
TASK_MEASURED, TASK_ERROR, TASK_V_D, TASK_V, TASK_A_D = range(5)
# model:    (A(x), H(x, v)) of the model-based laws
_BOXES = "UniTuple(float64[:, :], 2)"
_SETTINGS = "UniTuple(float64, 5)"
_MODES = "UniTuple(int64, 3)"


def kernel_settings(max_condition: float, following_error_m: float, following_error_rad: float,
                    force_limit_n: float, length_m: float = 0.0) -> tuple:
    """The ``settings`` tuple of the kernels (``length_m``: a spatial machine's
    characteristic length, weighting its rotation columns in cond(J_m))."""
    return (float(max_condition), float(following_error_m), float(following_error_rad), float(force_limit_n),
            float(length_m))


@kernel(f"(float64[:], float64[:, :], {_TRIPLE}, {_TRIPLE}, {_BOXES}, {_SETTINGS}, boolean)")
def limits_kernel(q, active_rows, measured, error, boxes, settings, planar):
    """(code, index, value): the supervisor's per-cycle limits in order, the first one
    violated (``boxes`` and ``settings``: the packed tuples above). JOINT_LIMIT:
    drive ``index`` at q = value outside its row of ``joint_box`` (lower, upper);
    WORKSPACE_LIMIT: task axis ``index`` of the measured pose at ``value`` outside
    its row of ``workspace_box``; SINGULARITY_MARGIN: cond(J of the active drives) =
    value > max_condition; FOLLOWING_ERROR_M: the translation error ``value``;
    FOLLOWING_ERROR_RAD: |rotation error| = value (planar). LIMITS_OK: ``value`` is the translation error. NaN fails every range."""
    joint_box, workspace_box = boxes
    max_condition = settings[SET_MAX_CONDITION]
    following_error_m, following_error_rad = settings[SET_FOLLOWING_ERROR_M], settings[SET_FOLLOWING_ERROR_RAD]
    for i in range(q.shape[0]):
        if not joint_box[i, 0] <= q[i] <= joint_box[i, 1]:
            return JOINT_LIMIT, i, q[i]
    for k in range(workspace_box.shape[0]):
        if not workspace_box[k, 0] <= measured[k] <= workspace_box[k, 1]:
            return WORKSPACE_LIMIT, k, measured[k]
    cond = gram_condition_kernel(active_rows)
    if cond > max_condition:
        return SINGULARITY_MARGIN, -1, cond
    if planar:
        trans = math.hypot(error[0], error[1])
    else:
        trans = math.sqrt(error[0] * error[0] + error[1] * error[1] + error[2] * error[2])
    if trans > following_error_m:
        return FOLLOWING_ERROR_M, -1, trans
    if planar and abs(error[2]) > following_error_rad:
        return FOLLOWING_ERROR_RAD, 2, abs(error[2])
    return LIMITS_OK, -1, trans


@kernel(f"(float64[:], float64[:, :], float64[:], float64[:], {_BOXES}, {_SETTINGS})")
def spatial_limits_kernel(q, active_rows, measured, error, boxes, settings):
    """:func:`limits_kernel` for a spatial machine (6 task coordinates): the same limits
    in the same order, the same codes; the condition number of the active drives' J_m
    the machine's own (rotation columns divided by its characteristic length,
    ``settings[SET_LENGTH]``, ``struts.weighted_condition_kernel``); the rotation
    error is |e_w|, the angle of the rotation vector."""
    joint_box, workspace_box = boxes
    length, max_condition = settings[SET_LENGTH], settings[SET_MAX_CONDITION]
    following_error_m, following_error_rad = settings[SET_FOLLOWING_ERROR_M], settings[SET_FOLLOWING_ERROR_RAD]
    for i in range(q.shape[0]):
        if not joint_box[i, 0] <= q[i] <= joint_box[i, 1]:
            return JOINT_LIMIT, i, q[i]
    for k in range(workspace_box.shape[0]):
        if not workspace_box[k, 0] <= measured[k] <= workspace_box[k, 1]:
            return WORKSPACE_LIMIT, k, measured[k]
    cond = weighted_condition_kernel(active_rows, length) if active_rows.shape[0] >= 6 else math.inf
    if not cond <= max_condition:
        return SINGULARITY_MARGIN, -1, cond
    trans = math.sqrt(error[0] * error[0] + error[1] * error[1] + error[2] * error[2])
    rot = math.sqrt(error[3] * error[3] + error[4] * error[4] + error[5] * error[5])
    if trans > following_error_m:
        return FOLLOWING_ERROR_M, -1, trans
    if rot > following_error_rad:
        return FOLLOWING_ERROR_RAD, 3, rot
    return LIMITS_OK, -1, trans


@kernel("(float64[:], float64)")
def clamp_forces_kernel(forces, limit):
    """(clamped copy, number of forces beyond +-limit, peak |clamped force|, finite):
    the commands as the drives get them. Not finite: nothing clamped (the caller trips)."""
    for f in forces:
        if not math.isfinite(f):
            return forces.copy(), 0, 0.0, False
    out = np.empty(forces.shape[0])
    saturated, peak = 0, 0.0
    for k in range(forces.shape[0]):
        f = forces[k]
        if abs(f) > limit:
            saturated += 1
        f = max(-limit, min(limit, f))
        out[k] = f
        peak = max(peak, abs(f))
    return out, saturated, peak, True


# the Cartesian laws of cartesian_command_kernel (strategies.Law); ``gains`` rows: kp, kd, ki (per axis), mass
LAW_CARTESIAN_PID, LAW_COMPUTED_TORQUE, LAW_VELOCITY_CASCADE = 0, 1, 2


# ------------------------------------------------ the task-space laws, per axis
# e = x_d - x, edot = v_d - v, integral = int Ki e; compiled helpers of
# cartesian_command_kernel (one function per law, called by it on each task axis)
@kernel()
def cartesian_pid_wrench(kp, kd, mass, e, edot, integral, a_d):
    """F = Kp e + Kd edot + I + m a_d: Sliding Star eq. 9, ARCHI §4.2 (the PID on the
    task pose, with diagonal-mass acceleration feed-forward)."""
    return kp * e + kd * edot + integral + mass * a_d


@kernel()
def computed_torque_acceleration(kp, kd, e, edot, integral, a_d):
    """u = a_d + Kd edot + Kp e + I, then F = A(x) u + H(x, v): ARCHI §4.2-4.4
    (gains per unit mass)."""
    return a_d + kd * edot + kp * e + integral


@kernel()
def velocity_cascade_acceleration(kp, kv, e, v_d, v, integral, a_d):
    """u = a_d + Kv (v_c - v) with v_c = v_d + Kp e + I, then F = A(x) u + H(x, v):
    MoM3 §6.1 (PI on the pose with velocity feed-forward, inner velocity loop Kv)."""
    return a_d + kv * (v_d + kp * e + integral - v)
# its distributions: the compiled ones, or NUMPY_DISTRIBUTION (the wrench is returned)
DIST_PSEUDO_INVERSE, DIST_INF_NORM, NUMPY_DISTRIBUTION = 0, 1, -1
# numba's spellings of cartesian_command_kernel's packed (A, H) and configuration
# (boxes, gains, settings, modes), for the kernels that call it (sensor_space.py)
MODEL_TYPE = f"Tuple((UniTuple({_TRIPLE}, 3), {_TRIPLE}))"
CONFIGURATION_TYPES = f"{_BOXES}, float64[:, :], {_SETTINGS}, {_MODES}"


@kernel(f"(float64[:], float64[:, :], UniTuple({_TRIPLE}, 5), {MODEL_TYPE}, {_TRIPLE}, boolean, "
        f"float64, {CONFIGURATION_TYPES})")
def cartesian_command_kernel(q, active_rows, task, model, integral, integrate, dt, boxes, gains, settings, modes):
    """The second half of a Cartesian cycle in one compiled call, after the feedback:
    the limits (:func:`limits_kernel`), the integral, the law, the distribution and the
    clamp. The inputs packed (the indices above): ``task`` the cycle's measured pose,
    error, v_d, v and a_d; ``model`` (A(x), H(x, v)); ``gains`` rows kp, kd, ki, mass
    per axis; ``boxes``, ``settings`` and ``modes`` of the configuration. Returns
    (code, index, value, integral, wrench, forces, saturated, peak):

    - code LIMITS_OK: ``forces`` clamped (``saturated`` beyond the limit, ``peak``
      the largest), ``value`` the translation error; empty with NUMPY_DISTRIBUTION,
      whose caller distributes ``wrench`` itself;
    - a limits code with its index and value; WRENCH_NOT_FINITE; DISTRIBUTION_FAILED
      plus the code of :func:`distribute_kernel` (``index`` the wrench component J^T f
      missed, ``value`` what it achieved); FORCES_NOT_FINITE (``forces`` unclamped).

    The laws, with I = int Ki e (conditional integration: only when ``integrate``,
    i.e. the last command was not saturated): LAW_CARTESIAN_PID
    :func:`cartesian_pid_wrench`; LAW_COMPUTED_TORQUE
    :func:`computed_torque_acceleration`, LAW_VELOCITY_CASCADE
    :func:`velocity_cascade_acceleration` (Kv in the kd row), both through
    F = A(x) u + H(x, v).
    The distribution: f = J (J^T J)^-1 F, moved along ker(J^T) to the least peak for
    DIST_INF_NORM (ARCHI §4.4.1-4.4.2)."""
    empty = np.zeros(0)
    error, v_d, v, a_d = task[TASK_ERROR], task[TASK_V_D], task[TASK_V], task[TASK_A_D]
    a_model, h_model = model
    law, distribution = modes[MODE_LAW], modes[MODE_DISTRIBUTION]
    code, index, value = limits_kernel(q, active_rows, task[TASK_MEASURED], error, boxes, settings,
                                       modes[MODE_PLANAR] != 0)
    if code != LIMITS_OK:
        return code, index, value, integral, (0.0, 0.0, 0.0), empty, 0, 0.0
    i0, i1, i2 = integral
    if integrate:
        i0 = i0 + gains[2, 0] * error[0] * dt
        i1 = i1 + gains[2, 1] * error[1] * dt
        i2 = i2 + gains[2, 2] * error[2] * dt
    i_new = (i0, i1, i2)
    w = np.empty(3)
    u = np.empty(3)
    for k in range(3):
        edot = v_d[k] - v[k]
        if law == LAW_CARTESIAN_PID:
            w[k] = cartesian_pid_wrench(gains[0, k], gains[1, k], gains[3, k], error[k], edot, i_new[k], a_d[k])
        elif law == LAW_COMPUTED_TORQUE:
            u[k] = computed_torque_acceleration(gains[0, k], gains[1, k], error[k], edot, i_new[k], a_d[k])
        else:
            u[k] = velocity_cascade_acceleration(gains[0, k], gains[1, k], error[k], v_d[k], v[k], i_new[k], a_d[k])
    if law != LAW_CARTESIAN_PID:
        for k in range(3):
            w[k] = a_model[k][0] * u[0] + a_model[k][1] * u[1] + a_model[k][2] * u[2] + h_model[k]
    wrench = (w[0], w[1], w[2])
    if distribution == NUMPY_DISTRIBUTION:
        return LIMITS_OK, -1, value, i_new, wrench, empty, 0, 0.0
    if not (math.isfinite(w[0]) and math.isfinite(w[1]) and math.isfinite(w[2])):
        return WRENCH_NOT_FINITE, -1, 0.0, i_new, wrench, empty, 0, 0.0
    forces, dcode, k, achieved = distribute_kernel(active_rows, w[0], w[1], w[2], distribution == DIST_INF_NORM,
                                                    True)
    if dcode != 0:
        return DISTRIBUTION_FAILED + dcode, k, achieved, i_new, wrench, empty, 0, 0.0
    clamped, saturated, peak, finite = clamp_forces_kernel(forces, settings[SET_FORCE_LIMIT])
    if not finite:
        return FORCES_NOT_FINITE, -1, value, i_new, wrench, forces, 0, 0.0
    return LIMITS_OK, -1, value, i_new, wrench, clamped, saturated, peak


@kernel(f"(float64[:], float64[:, :], float64[:, :], Tuple((float64[:, :], float64[:])), float64[:], boolean, "
        f"float64, {_BOXES}, float64[:, :], {_SETTINGS}, {_MODES})")
def spatial_command_kernel(q, active_rows, task, model, integral, integrate, dt, boxes, gains, settings, modes):
    """:func:`cartesian_command_kernel` of a spatial machine (the same packed inputs,
    ``task`` a (5, 6) array of the twists' rows): the limits
    (:func:`spatial_limits_kernel`), the integral, the law of each of the six axes (the
    twist's error and rate; the same named laws), F = A(x) u + H(x, t) for the
    model-based ones, and, with the distribution DIST_PSEUDO_INVERSE,
    f = J (J^T J)^-1 F on the n x 6 J_m of the active drives (``gram_solve_n_kernel``),
    checked and clamped; with NUMPY_DISTRIBUTION the caller distributes ``wrench``
    (inf-norm LP, p-norm). Returns (code, index, value, integral, wrench, forces,
    saturated, peak) with the codes of the 3-DOF kernel."""
    empty = np.zeros(0)
    wrench = np.zeros(6)
    error, v_d, v, a_d = task[TASK_ERROR], task[TASK_V_D], task[TASK_V], task[TASK_A_D]
    a_model, h_model = model
    law = modes[MODE_LAW]
    code, index, value = spatial_limits_kernel(q, active_rows, task[TASK_MEASURED], error, boxes, settings)
    if code != LIMITS_OK:
        return code, index, value, integral, wrench, empty, 0, 0.0
    i_new = integral.copy()
    if integrate:
        for k in range(6):
            i_new[k] = integral[k] + gains[2, k] * error[k] * dt
    u = np.empty(6)
    for k in range(6):
        edot = v_d[k] - v[k]
        if law == LAW_CARTESIAN_PID:
            wrench[k] = cartesian_pid_wrench(gains[0, k], gains[1, k], gains[3, k], error[k], edot, i_new[k], a_d[k])
        elif law == LAW_COMPUTED_TORQUE:
            u[k] = computed_torque_acceleration(gains[0, k], gains[1, k], error[k], edot, i_new[k], a_d[k])
        else:
            u[k] = velocity_cascade_acceleration(gains[0, k], gains[1, k], error[k], v_d[k], v[k], i_new[k], a_d[k])
    if law != LAW_CARTESIAN_PID:
        for k in range(6):
            total = h_model[k]
            for j in range(6):
                total += a_model[k, j] * u[j]
            wrench[k] = total
    for k in range(6):
        if not math.isfinite(wrench[k]):
            return WRENCH_NOT_FINITE, -1, 0.0, i_new, wrench, empty, 0, 0.0
    if modes[MODE_DISTRIBUTION] != DIST_PSEUDO_INVERSE:
        return LIMITS_OK, -1, value, i_new, wrench, empty, 0, 0.0
    y, ok = gram_solve_n_kernel(active_rows, wrench)
    if not ok:
        return DISTRIBUTION_FAILED + 1, -1, 0.0, i_new, wrench, empty, 0, 0.0
    forces = np.ascontiguousarray(active_rows) @ y
    k, achieved = check_wrench_kernel(active_rows, forces, wrench, 1e-9)
    if k >= 0:
        return DISTRIBUTION_FAILED + 3, k, achieved, i_new, wrench, empty, 0, 0.0
    clamped, saturated, peak, finite = clamp_forces_kernel(forces, settings[SET_FORCE_LIMIT])
    if not finite:
        return FORCES_NOT_FINITE, -1, value, i_new, wrench, forces, 0, 0.0
    return LIMITS_OK, -1, value, i_new, wrench, clamped, saturated, peak


# --------------------------------------------------------------- joint space
def apparent_drive_mass(rows, a) -> np.ndarray:
    """m_i = 1 / (J A^-1 J^T)_ii: the mass drive i moves when it pushes alone (its
    acceleration per newton is J_i A^-1 J_i^T), the gain scale of the joint PIDs of a
    spatial machine. diag(J^+T A J^+) (the 3-DOF machines') overstates it where J_m
    transmits poorly: on hexapod8 it gave 101 kg a strut against 19 kg, and joint
    PIDs 13-15 times too stiff in the vertical, unstable at 1 kHz."""
    j = np.asarray(rows, dtype=float)
    return 1.0 / np.einsum("ij,ji->i", j, np.linalg.solve(np.asarray(a, dtype=float), j.T))


def mode_ratios(shape, a) -> np.ndarray:
    """Every r of (K - r A) v = 0, ascending (K = ``shape``, A the task mass matrix):
    how much of each mode's mass a PID law's common gain shape carries
    (weakest_mode_ratio explains; 1 for every mode of a law through A(x))."""
    chol = np.linalg.cholesky(np.asarray(a, dtype=float))
    m = np.linalg.solve(chol, np.linalg.solve(chol, np.asarray(shape, dtype=float)).T)
    return np.linalg.eigvalsh(0.5 * (m + m.T))


def sampled_mode_matrix(r: float, gains: Gains, dt: float, euler: bool = False) -> np.ndarray:
    """One mode of a hold under a PID law sampled every ``dt``, state (z, zdot, I):
    the command of step k from the state at k, I first (I_{k+1} = I_k - k_i z_k dt,
    as ControllerCore does), then held for the step: zddot = r (-k_p z - k_d zdot + I).
    The plant's step is exact for a held force (the machine: z += dt zdot + dt^2/2
    zddot) or, ``euler``, sim_hw's semi-implicit Euler (z += dt zdot + dt^2 zddot)."""
    kp, kd, ki = gains.kp, gains.kd, gains.ki
    acc = r * np.array([-(kp + ki * dt), -kd, 1.0])
    step = np.array([[1.0, dt, 0.0], [0.0, 1.0, 0.0], [-ki * dt, 0.0, 1.0]])
    step[0] += (dt * dt if euler else 0.5 * dt * dt) * acc
    step[1] += dt * acc
    return step


def sampled_hold_radius(r: float, gains: Gains, dt: float) -> float:
    """The spectral radius of a mode of mass ratio ``r`` held by ``gains`` sampled
    every ``dt`` (sampled_mode_matrix), the larger of the machine's (exact) and the
    simulated plant's (Euler): >= 1 grows. The continuous bound T_i > 1/(2 zeta omega r)
    is its limit for small dt; sampling adds a bound on the stiff modes (r omega^2 dt^2)
    and, through the exact step, on low damping. Not in it: a computation delay
    (a late command is a held setpoint, counted as a deadline miss)."""
    size = 3 if gains.ki > 0.0 else 2              # without an integral its state stays put: not a mode
    return max(float(np.abs(np.linalg.eigvals(sampled_mode_matrix(r, gains, dt, euler)[:size, :size])).max())
               for euler in (False, True))


def weakest_mode_ratio(shape, a) -> float:
    """The smallest r of (K - r A) v = 0, K = ``shape``: the task stiffness shape every
    gain of a PID law shares (K_p = kp K, K_d = kd K, K_i = ki K; J^T diag(m) J for the
    joint PIDs, diag(A) for the Cartesian PID), A the task mass matrix. Each mode of the
    hold is s^3 + r (kd s^2 + kp s + ki) = 0, which Routh makes stable only if
    r kd kp > ki: T_i > 1 / (2 zeta omega r). r = 1 for every mode of a law through A(x).
    A necessary condition, at home and in continuous time: the sampling is not in it.
    hexapod8's joint PIDs have r = 0.059 (its x-roll and y-pitch modes): with the
    default T_i = 0.05 s they grew from the encoders' quantisation until a
    following-error trip ~10 s into a hold."""
    return float(mode_ratios(shape, a)[0])


def joint_pid(e, edot, integral, kp, kd) -> list:
    """f_i = kp_i e_i + kd_i edot_i + I_i: independent PID per drive on the
    inverse-kinematics setpoints (ARCHI §4.1, the industrial baseline; I_i is the
    integral term, integrated by the caller)."""
    return [p * a + d * b + c for a, b, c, p, d in zip(e, edot, integral, kp, kd)]


def tool_pose_floats(x, planar: bool) -> tuple[tuple, tuple]:
    """Task pose -> tool position (3 floats) and row-major rotation (9 floats): planar
    (x, y, 0) with yaw theta, translational p with the identity, spatial (x, y, z, a,
    b, c) p with R = Rz(c) Ry(b) Rx(a)."""
    if len(x) == 6:
        return (x[0], x[1], x[2]), rpy_rotation_kernel.py_func(x[3], x[4], x[5])
    return three_axis_tool_pose_kernel.py_func(x[0], x[1], x[2], planar)


@kernel()
def three_axis_tool_pose_kernel(x0, x1, x2, planar):
    """:func:`tool_pose_floats` of a planar (x, y, theta) or translational (x, y, z)
    task pose, for compiled callers too."""
    if planar:
        c, s = math.cos(x2), math.sin(x2)
        return (x0, x1, 0.0), (c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
    return (x0, x1, x2), (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
