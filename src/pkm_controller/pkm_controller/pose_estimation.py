"""The poses the controller feeds back (pure core, no rclpy), in the task coordinates
of the machine (pkm_kinematics.task_space): the encoders' pose by forward
kinematics, solved every cycle (Newton, warm-started) or carried by the drive
increments (Sliding Star §3.1), and for the metrology strategies the pose the Gough
struts (MoM3 §6.4) or the Gough's own DKM pose (§6.3) give. The formulas that differ
by task space and by what is fed back are chosen once, when the estimator is made.
"""

from __future__ import annotations

import math

import numpy as np

from pkm_gough_sensor.metrology import GoughSensorModel
from pkm_kinematics.errors import FieldError
from pkm_kinematics.online_fk import integrate_forward_kinematics
from pkm_kinematics.rotations import exp_so3, rpy_from_rotation, unwrap_to
from pkm_kinematics.task_space import PLANAR, SPATIAL

from .config import FORWARD_KINEMATICS
from .laws import task_pose_error, tool_pose_floats
from .sensor_space import SensorSpaceFeedback
from .strategies import Feedback

__all__ = ["PoseEstimator"]


def _gough_pose_planar(p, r, reference_pose) -> list:
    """(x, y, theta) of a Gough pose, theta on the revolution of the reference's."""
    r = np.asarray(r, dtype=float)
    theta = unwrap_to(math.atan2(r[1, 0], r[0, 0]), reference_pose[2])
    return [p[0], p[1], theta]


def _gough_pose_position(p, r, reference_pose) -> list:
    return p


def _gough_pose_spatial(p, r, reference_pose) -> list:
    """The Gough's rotation as roll, pitch, yaw (the error is rotation-based)."""
    return p + list(rpy_from_rotation(np.asarray(r, dtype=float).reshape(3, 3)))


def _minus_coordinates(x, e) -> list:
    return [a - b for a, b in zip(x, e)]


def _minus_spatial(x, e) -> list:
    """x - e on a spatial machine: the rotation exp(-e_w) R(x) as roll, pitch, yaw (e_w a
    rotation vector, not angle rates)."""
    _, r = tool_pose_floats(x, False)
    rot = exp_so3(np.array([-e[3], -e[4], -e[5]])) @ np.array(r).reshape(3, 3)
    return [x[0] - e[0], x[1] - e[1], x[2] - e[2], *rpy_from_rotation(rot)]


FUSE_ENCODER_STATE = True    # False: the forward kinematics and the measured state in two calls (a test's reference)


def sensor_feedback(machine, strategy, config) -> SensorSpaceFeedback | None:
    """The Gough's feedback of a metrology ``strategy`` (strategies.Strategy) on its
    nominal geometry (the true one is the plant's); None for an encoder strategy.
    ValueError when the machine has no 'metrology' section."""
    if not strategy.uses_metrology:
        return None
    if machine.metrology is None:
        raise FieldError("strategy", f"{strategy.name} needs a machine with a 'metrology' section, "
                                     f"{machine.name!r} has none")
    space = machine.model.task_space
    return SensorSpaceFeedback(GoughSensorModel(machine.metrology), space is PLANAR,
                               at_estimate=config.sensor_jacobian == "estimated", spatial=space is SPATIAL)


class PoseEstimator:
    """The encoder pose of each cycle (``encoder_pose``), and the measured pose and
    error the strategy's ``feedback`` sees (``measure``). ``metrology``: the
    strategy's sensor_space.SensorSpaceFeedback (sensor_space), else None."""

    def __init__(self, model, config, feedback: Feedback, metrology=None):
        self.model, self.space, self.config, self.metrology = model, model.task_space, config, metrology
        spatial = self.space is SPATIAL
        self.planar = self.space is PLANAR
        self._gough_pose = _gough_pose_spatial if spatial else \
            _gough_pose_planar if self.planar else _gough_pose_position
        self.pose_minus = _minus_spatial if spatial else _minus_coordinates
        self.measure = {Feedback.STRUTS: self._from_struts,
                        Feedback.GOUGH_POSE: self._from_gough_pose}.get(feedback, self._from_encoders)
        self.reset()

    def reset(self) -> None:
        self.pose = None                           # the last encoder pose (warm start)
        self._fk_q, self._fk_cycles = None, 0      # its readings, cycles since reset

    def encoder_pose(self, q) -> list:
        """The encoder pose (planar: warm-started at the last one); q checked finite.
        ``integrated`` / ``integrated_euler``: carried by the increments since the last
        cycle (Sliding Star §3.1), solved by Newton at the first cycle and every
        ``fk_resync_cycles``. Raises KinematicsError or ValueError."""
        c = self.config
        order = FORWARD_KINEMATICS[c.forward_kinematics]
        if order and self.pose is not None and self._fk_q is not None and (
                c.fk_resync_cycles == 0 or self._fk_cycles % c.fk_resync_cycles):
            pose = integrate_forward_kinematics(self.model, self.pose, np.asarray(q) - self._fk_q, order).tolist()
        else:
            pose = list(self.model.forward_kinematics_floats(q, self.pose))
        self.pose, self._fk_q, self._fk_cycles = pose, np.array(q, dtype=float), self._fk_cycles + 1
        return pose

    def encoder_state(self, q, qdot, dynamics) -> tuple[list, tuple | None]:
        """(``encoder_pose``, ``dynamics.measured_state`` there or None): in one
        compiled call where the machine's forward solver has one
        (DynamicModel.encoder_state) and the pose is solved every cycle; None: the
        caller asks ``measured_state``, which raises what the call refused. Raises
        what ``encoder_pose`` raises."""
        fused = getattr(dynamics, "encoder_state", None) if FUSE_ENCODER_STATE else None
        if fused is None or FORWARD_KINEMATICS[self.config.forward_kinematics]:
            return self.encoder_pose(q), None
        pose, state = fused(q, self.pose, qdot)
        if pose is None:
            return self.encoder_pose(q), None       # raises what the compiled call refused
        self.pose, self._fk_q, self._fk_cycles = list(pose), np.array(q, dtype=float), self._fk_cycles + 1
        return self.pose, state

    def keep_pose(self, pose: list, q: np.ndarray) -> None:
        """The encoder pose of the readings ``q``, solved by a compiled caller
        (compiled_prepare.prepare_kernel) as ``encoder_state`` solves it."""
        self.pose, self._fk_q, self._fk_cycles = pose, q, self._fk_cycles + 1

    def gough_task_pose(self, metrology_pose, reference_pose) -> list:
        """The task pose of a Gough pose (position, rotation), a planar machine's angle
        on the revolution of ``reference_pose``'s."""
        p, r = metrology_pose
        return self._gough_pose([float(v) for v in p], r, reference_pose)

    def hold_pose(self, feedback: Feedback, pose, struts, metrology_pose) -> list:
        """Where the machine is at the first cycle, as the strategy measures it: the
        encoder pose; the Gough's pose; or as the struts see the tool, one linearised
        step from the encoder pose (the sensor-space feedback reset after)."""
        if feedback == Feedback.GOUGH_POSE:
            return self.gough_task_pose(metrology_pose, pose)
        if feedback == Feedback.STRUTS:
            p, r = tool_pose_floats(pose, self.planar)
            e = self.metrology.task_error(p, r, list(struts))
            self.metrology.reset()
            return self.pose_minus(pose, e)
        return pose

    def _from_struts(self, pose, x_d, struts, metrology_pose) -> tuple[list, list]:
        error = self.metrology.error_from(list(struts))          # prepared at x_d
        return self.pose_minus(x_d, error), error

    def _from_gough_pose(self, pose, x_d, struts, metrology_pose) -> tuple[list, list]:
        measured = self.gough_task_pose(metrology_pose, x_d)
        return measured, task_pose_error(x_d, measured, self.space)

    def _from_encoders(self, pose, x_d, struts, metrology_pose) -> tuple[list, list]:
        return pose, task_pose_error(x_d, pose, self.space)
