"""The control strategies, one registry (pure): what each one is, where its feedback
comes from and which metrology input it waits for.

Every module that makes a choice by strategy (the controller core, its node, the core
closed loop, bringup's scenario checks and graph wiring, replay) reads it here, so a
new strategy is one entry, not a dozen string comparisons. ``strategy(name)`` is the
lookup; a name not in ``REGISTRY`` is refused with the list of the known ones.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from pkm_common import topics
from pkm_kinematics.errors import FieldError

__all__ = ["Feedback", "Law", "Projection", "Strategy", "REGISTRY", "NAMES", "strategy"]


class Feedback(str, Enum):
    """Where the law's measured pose comes from."""

    ENCODERS = "encoders"          # forward kinematics of the drive encoders
    STRUTS = "struts"              # the Gough strut lengths, the error mapped through J_t (sensor space)
    GOUGH_POSE = "gough_pose"      # the Gough's forward-kinematics pose


class Law(str, Enum):
    """The control law (pkm_controller.laws names one function per law)."""

    JOINT_PID = "joint_pid"                    # per drive, on IK setpoints
    CARTESIAN_PID = "cartesian_pid"            # task wrench, diagonal mass
    COMPUTED_TORQUE = "computed_torque"        # task wrench through A(x), H(x, v)
    VELOCITY_CASCADE = "velocity_cascade"      # PI on the pose + velocity loop, through A(x), H(x, v)


class Projection(str, Enum):
    """What of a joint-space law is projected on range(J), n = J (J^T J)^-1 J^T n_d
    (Sliding Star eq. 8): nothing, the whole command (and the integral state, so that
    it cannot wind up along ker(J^T)), or the integral component only (its Fig. 9)."""

    NONE = "none"
    FORCES = "forces"
    INTEGRAL = "integral"


# what the node subscribes to for each metrology feedback, and the key of its pairing
_METROLOGY_TOPICS = {Feedback.STRUTS: topics.METROLOGY_STRUTS, Feedback.GOUGH_POSE: topics.METROLOGY_POSE}
_READINGS = {Feedback.STRUTS: "struts", Feedback.GOUGH_POSE: "pose"}


@dataclass(frozen=True)
class Strategy:
    """One control strategy. ``joint_space``: the law acts per drive (its integral is
    one state per drive); else on the task wrench, then distributed. ``projection``:
    what of a joint-space law is projected on range(J) (Projection)."""

    name: str
    law: Law
    feedback: Feedback
    projection: Projection
    source: str                    # the paper and section it implements

    @property
    def joint_space(self) -> bool:
        return self.law == Law.JOINT_PID

    @property
    def uses_metrology(self) -> bool:
        """The loop closes on the Gough: the controller waits for its reading."""
        return self.feedback != Feedback.ENCODERS

    @property
    def metrology_topic(self) -> str:
        """The topic of the reading it waits for ("" for none)."""
        return _METROLOGY_TOPICS.get(self.feedback, "")

    @property
    def reading(self) -> str:
        """What the reading is: "struts" (a JointState of lengths), "pose" (a
        PoseStamped), "" for none (lockstep.StampPairing, configuration.metrology_inputs)."""
        return _READINGS.get(self.feedback, "")


REGISTRY: dict[str, Strategy] = {s.name: s for s in (
    Strategy("joint_pid", Law.JOINT_PID, Feedback.ENCODERS, Projection.NONE, "ARCHI §4.1"),
    Strategy("decentralized_projected", Law.JOINT_PID, Feedback.ENCODERS, Projection.FORCES,
             "Sliding Star eq. 6-8, Fig. 8"),
    Strategy("decentralized_integral_projected", Law.JOINT_PID, Feedback.ENCODERS, Projection.INTEGRAL,
             "Sliding Star Fig. 9 (the lab model's variant)"),
    Strategy("cartesian_pid", Law.CARTESIAN_PID, Feedback.ENCODERS, Projection.NONE, "Sliding Star eq. 9, ARCHI §4.2"),
    Strategy("computed_torque", Law.COMPUTED_TORQUE, Feedback.ENCODERS, Projection.NONE, "ARCHI §4.2-4.4"),
    Strategy("sensor_space", Law.VELOCITY_CASCADE, Feedback.STRUTS, Projection.NONE, "MoM3 §6.4"),
    Strategy("measured_space", Law.VELOCITY_CASCADE, Feedback.GOUGH_POSE, Projection.NONE, "MoM3 §6.3"),
)}
NAMES = tuple(REGISTRY)


def strategy(name: str) -> Strategy:
    """The strategy called ``name``; ValueError naming the known ones otherwise."""
    try:
        return REGISTRY[name]
    except (KeyError, TypeError):
        raise FieldError("strategy", f"must be one of {list(NAMES)}, got {name!r}") from None
