"""Feedback on the Gough strut lengths without the DKM (MoM3 §6.4, Figure 15; pure
core): ``SensorSpaceFeedback`` and its compiled kernels, l_des and J_h before the
readings arrive, the task error from them after."""

from __future__ import annotations

import numpy as np

from pkm_gough_sensor.metrology import plate_in_base_kernel
from pkm_kinematics.bars import pose_from_lengths_jacobian_kernel, strut_lengths_kernel
from pkm_kinematics.jit import direct_call, kernel
from pkm_kinematics.rotations import exp_so3_kernel, mul3_kernel

from .laws import CONFIGURATION_TYPES, MODE_PLANAR, MODEL_TYPE, cartesian_command_kernel

__all__ = ["SensorSpaceFeedback", "sensor_space_command_kernel", "sensor_space_desired_kernel"]

_TRIPLE, _ROTATION = "UniTuple(float64, 3)", "UniTuple(float64, 9)"


class SensorSpaceFeedback:
    """Feedback on the Gough strut lengths (MoM3 §6.4, Figure 15), without the DKM.

    e_l = l_des - l: the desired lengths are the nominal IKM_GP of the desired tool
    pose. J_t maps e_l to a TCP pose error, evaluated at the estimated REAL pose of
    the plate (the paper: at the desired pose a static error of some microns remains,
    because a 3-DOF machine cannot follow the parasitic orientation that l_des
    assumes). The real pose is estimated as x_h,des - J_h e_l, with J_h from the
    previous estimate (one cycle old: um apart at 1 kHz). J_t here is J_h (6 x 6,
    MoM3 eq. 1-3) followed by the mounting transform of the tool (the lever arm of the
    plate to the tool, MoM3 eq. 10-11) and the selection of the machine's task axes.
    ``at_estimate=False``: J_h at the desired plate pose instead (the paper's first
    variant, kept to show its static error: scenario mom3_imperfect).
    """

    def __init__(self, sensor, planar: bool, at_estimate: bool = True, spatial: bool = False):
        self.sensor = sensor                       # GoughSensorModel (nominal geometry used)
        self.platform = sensor.nominal
        self.planar = planar
        self.spatial = spatial                     # 6 task DOF: the whole error (e_p, e_w)
        self.at_estimate = at_estimate
        self._bars = self.platform.bars
        self._r_wb = sensor.base_rotation_floats
        self._p_tp = sensor.plate_position_in_tool
        self._plate = sensor.plate_constants         # the mounting, for plate_in_base_kernel
        self.estimate = None                       # (p_bp, R_bp) of the real plate, or None
        self._desired = None                       # what prepare() computed for the cycle

    def reset(self) -> None:
        self.estimate = None
        self._desired = None

    def task_error(self, tool_position, tool_rotation, lengths) -> list:
        """The task-space error x_des - x_real (3) from the strut readings."""
        self.prepare(tool_position, tool_rotation)
        return self.error_from(lengths)

    def prepare(self, tool_position, tool_rotation) -> None:
        """What does not depend on the readings, done before they arrive: the plate
        pose of the desired tool pose, l_des = IKM_GP (nominal geometry) and J_h at
        the estimated real pose (the estimate of the previous cycle)."""
        p, t = (float(tool_position[0]), float(tool_position[1]), float(tool_position[2])), tuple(tool_rotation)
        at_estimate = self.at_estimate and self.estimate is not None
        p_at, r_at = self.estimate if at_estimate else _NO_ESTIMATE
        p_bp, r_bp, l_des, j_h = _desired_call(self._bars, p, t, *self._plate, p_at, r_at, at_estimate)
        self._desired = (p_bp, r_bp, l_des, j_h, t)

    def kernel_constants(self) -> tuple:
        """What sensor_space_desired_kernel takes of the sensor before the tool pose
        (the Gough's bars, then the mounting: p_wb, R_wb^T, R_tp, p_tp), then R_wb,
        which sensor_space_command_kernel takes besides p_tp."""
        return (self._bars, *self._plate, self._r_wb)

    def error_from(self, lengths) -> list:
        """The task-space error x_des - x_real for the readings ``lengths`` (6, m), at
        the desired pose of the last ``prepare``: (e_x, e_y, e_theta) planar, (e_x, e_y,
        e_z) translational, (e_x, e_y, e_z, w_x, w_y, w_z) spatial (the rotation vector
        of R_des R_real^T, base frame)."""
        if self._desired is None:
            raise RuntimeError("SensorSpaceFeedback.error_from: call prepare() first")
        p_bp, r_bp, l_des, j_h, t = self._desired
        ex, ey, ez, wx, wy, wz, real_p, real_r = _sensor_space_error(j_h, l_des, np.asarray(lengths, dtype=float),
                                                                     p_bp, r_bp, self._r_wb, self._p_tp, t)
        self.estimate = (real_p, real_r)
        if self.spatial:
            return [ex, ey, ez, wx, wy, wz]
        return [ex, ey, wz] if self.planar else [ex, ey, ez]

    def prepared(self) -> tuple:
        """What ``error_from`` takes of the last ``prepare`` and of the mounting, as
        ``sensor_space_command_kernel`` takes it: (J_h, l_des, p_bp, R_bp, R_wb, p_tp, R_t)."""
        if self._desired is None:
            raise RuntimeError("SensorSpaceFeedback.prepared: call prepare() first")
        p_bp, r_bp, l_des, j_h, t = self._desired
        return j_h, l_des, p_bp, r_bp, self._r_wb, self._p_tp, t



@kernel(f"(float64[:, :], {_TRIPLE}, {_ROTATION}, {_TRIPLE}, {_ROTATION})")
def _desired_lengths_and_jacobian(bars, p_des, r_des, p_at, r_at):
    """l_des = IKM_GP at the desired plate pose (MoM3 §5.2: l_i = |p + R b_i - A_i|,
    nominal geometry) and J_h at the estimated one (eq. 1-3). ``bars``: the Gough's
    struts (``GoughPlatform.bars``)."""
    l_des = strut_lengths_kernel(bars, p_des[0], p_des[1], p_des[2], r_des[0], r_des[1], r_des[2], r_des[3],
                                 r_des[4], r_des[5], r_des[6], r_des[7], r_des[8])
    j_h = pose_from_lengths_jacobian_kernel(bars, p_at[0], p_at[1], p_at[2], r_at[0], r_at[1], r_at[2], r_at[3],
                                            r_at[4], r_at[5], r_at[6], r_at[7], r_at[8])
    return l_des, j_h


_NO_ESTIMATE = ((0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0))


@kernel(f"(float64[:, :], {_TRIPLE}, {_ROTATION}, {_TRIPLE}, {_ROTATION}, {_ROTATION}, {_TRIPLE}, {_TRIPLE}, "
        f"{_ROTATION}, boolean)")
def sensor_space_desired_kernel(bars, p_t, r_t, p_wb, r_bw, r_tp, p_tp, p_at, r_at, at_estimate):
    """SensorSpaceFeedback.prepare in one call: the plate pose (p_bp, R_bp) of the
    desired tool pose (p_t, R_t) (``metrology.plate_in_base_kernel``, the mounting
    (p_wb, R_wb^T, R_tp, p_tp)), then l_des there and J_h at (p_at, R_at) when
    ``at_estimate``, else at the desired plate pose. Returns (p_bp, R_bp, l_des, J_h)."""
    p_des, r_des = plate_in_base_kernel(p_t, r_t, p_wb, r_bw, r_tp, p_tp)
    if at_estimate:
        l_des, j_h = _desired_lengths_and_jacobian(bars, p_des, r_des, p_at, r_at)
    else:
        l_des, j_h = _desired_lengths_and_jacobian(bars, p_des, r_des, p_des, r_des)
    return p_des, r_des, l_des, j_h


@kernel(f"(float64[:, :], float64[:], float64[:], {_TRIPLE}, {_ROTATION}, {_ROTATION}, {_TRIPLE}, {_ROTATION})")
def _sensor_space_error(j_h, l_des, lengths, p_bp, r_bp, r_wb, p_tp, t):
    """(e_x, e_y, e_z, w_x, w_y, w_z, real plate position, real plate rotation): the
    tool error x_des - x_real in the world frame from the strut errors e_l = l_des - l."""
    e = l_des - lengths
    d = np.zeros(6)
    for k in range(6):                          # [dp; dw] = J_h e_l (MoM3 eq. 1)
        for j in range(6):
            d[k] += j_h[k, j] * e[j]
    # estimate of the real plate pose for the next cycle: x_h,des - J_h e_l
    real_r = mul3_kernel(exp_so3_kernel(-d[3], -d[4], -d[5]), r_bp)
    real_p = (p_bp[0] - d[0], p_bp[1] - d[1], p_bp[2] - d[2])
    # to the tool in world: dw_w = R_wb dw; dp_t = R_wb dp + (R_t p_tp) x dw_w
    wwx = r_wb[0] * d[3] + r_wb[1] * d[4] + r_wb[2] * d[5]
    wwy = r_wb[3] * d[3] + r_wb[4] * d[4] + r_wb[5] * d[5]
    wwz = r_wb[6] * d[3] + r_wb[7] * d[4] + r_wb[8] * d[5]
    pwx = r_wb[0] * d[0] + r_wb[1] * d[1] + r_wb[2] * d[2]
    pwy = r_wb[3] * d[0] + r_wb[4] * d[1] + r_wb[5] * d[2]
    pwz = r_wb[6] * d[0] + r_wb[7] * d[1] + r_wb[8] * d[2]
    lx, ly, lz = p_tp
    ax = t[0] * lx + t[1] * ly + t[2] * lz
    ay = t[3] * lx + t[4] * ly + t[5] * lz
    az = t[6] * lx + t[7] * ly + t[8] * lz
    return (pwx + ay * wwz - az * wwy, pwy + az * wwx - ax * wwz, pwz + ax * wwy - ay * wwx, wwx, wwy, wwz,
            real_p, real_r)


@kernel(f"(float64[:, :], float64[:], float64[:], {_TRIPLE}, {_ROTATION}, {_ROTATION}, {_TRIPLE}, {_ROTATION}, "
        f"{_TRIPLE}, float64[:], float64[:, :], {_TRIPLE}, {_TRIPLE}, {_TRIPLE}, {MODEL_TYPE}, {_TRIPLE}, boolean, "
        f"float64, {CONFIGURATION_TYPES})")
def sensor_space_command_kernel(j_h, l_des, lengths, p_bp, r_bp, r_wb, p_tp, t, x_d, q, active_rows, v_d, v, a_d,
                                model, integral, integrate, dt, boxes, gains, settings, modes):
    """The second half of a sensor-space cycle of a 3-axis machine in one call: the
    task error e from the strut readings (SensorSpaceFeedback.error_from's kernel,
    e = (e_x, e_y, e_theta) planar, (e_x, e_y, e_z) translational, ``modes``'
    MODE_PLANAR), the measured pose x_d - e (pose_estimation), then
    ``laws.cartesian_command_kernel`` on them. Returns (the real plate's position and
    rotation, measured, error, then cartesian_command_kernel's eight outputs)."""
    ex, ey, ez, _, _, wz, real_p, real_r = _sensor_space_error(j_h, l_des, lengths, p_bp, r_bp, r_wb, p_tp, t)
    error = (ex, ey, wz) if modes[MODE_PLANAR] != 0 else (ex, ey, ez)
    measured = (x_d[0] - error[0], x_d[1] - error[1], x_d[2] - error[2])
    code, index, value, i_new, wrench, forces, saturated, peak = cartesian_command_kernel(
        q, active_rows, (measured, error, v_d, v, a_d), model, integral, integrate, dt, boxes, gains, settings, modes)
    return real_p, real_r, measured, error, code, index, value, i_new, wrench, forces, saturated, peak


_desired_call = direct_call(sensor_space_desired_kernel)    # prepare() makes each argument with its declared type
