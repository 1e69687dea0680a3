"""Why a machine stopped: one enumeration of trip causes (pure, no rclpy).

Every safe stop of the graph carries one ``TripCause``: the controller's supervisor
and node, the plant (sim_hw) and the bringup. The cause travels as its string value
in the ``cause`` key of ``controller/status`` and of sim_hw's ``diagnostics``, in
the node summaries and in ``run.json``; the report states the cause of the *first*
stop of a run (the one that started it), never a consequence of it (a plant that
brakes on its own is seen by the controller as drives that stop following their
commands: that is ``plant_safe_stop``, not ``drive_failure``).
"""

from __future__ import annotations

import enum

__all__ = ["TripCause", "parse_cause", "run_status", "plant_status_word", "plant_stop_cause",
           "SETPOINT_HELD", "HELD_COMMAND_UNKNOWN", "setpoint_held", "setpoint_held_word"]

STATUS_PREFIX = "safe_stop:"
# The status word of a running plant's step that applied an earlier setpoint again,
# "setpoint_held:<stamp ns of that command>": the command for the step before missed
# the cycle (realtime mode), so the forces it reports answer that older command (an
# EtherCAT drive's sync error flag, in band)
SETPOINT_HELD = "setpoint_held"
HELD_COMMAND_UNKNOWN = -1           # held, by a plant that does not say which command


class TripCause(str, enum.Enum):
    """The cause that started a safe stop (value: the string on the wire)."""

    NONE = "none"
    JOINT_LIMIT = "joint_limit"              # a drive outside its range
    WORKSPACE = "workspace"                  # the tool outside the workspace box
    SINGULARITY = "singularity"              # condition number over max_condition
    FOLLOWING_ERROR = "following_error"      # tracking error over its bound
    SATURATION = "saturation"                # drive forces saturated too long
    DRIVE_FAILURE = "drive_failure"          # a drive's force differs from its command
    ENCODER_FAULT = "encoder_fault"          # a frozen or slipping encoder
    INPUT_REFUSED = "input_refused"          # a malformed, NaN, stale or future input
    INTRUDER = "intruder"                    # a second publisher on drives/command, drives/state, metrology
    ESTOP = "estop"                          # an operator's estop
    WATCHDOG = "watchdog"                    # an input went silent
    DEADLINE_MISSED = "deadline_missed"      # realtime: commands missed the plant's cycle too often
    PLANT_SAFE_STOP = "plant_safe_stop"      # the plant braked on its own (end stop, timeout, ...)
    LOAD_REFUSED = "load_refused"            # an external load over its bound
    KINEMATICS = "kinematics"                # FK/IK failed, a law produced non-finite forces
    DEACTIVATED = "deactivated"              # lifecycle deactivate
    NODE_DIED = "node_died"                  # a process of the graph ended unbidden (a signal, a crash)

    def __str__(self) -> str:
        return self.value


def parse_cause(text: str) -> TripCause:
    """The cause of its wire string; an unknown string (a newer peer) is kept visible
    as ``ValueError`` rather than mapped to a wrong cause."""
    try:
        return TripCause(text)
    except ValueError:
        raise ValueError(f"cause: must be one of {[c.value for c in TripCause]}, got {text!r}") from None


def plant_status_word(cause: TripCause) -> str:
    """The plant's status in ``drives/state``'s ``header.frame_id`` once braked (empty
    while running): in band, like a drive's status word."""
    return f"{STATUS_PREFIX}{TripCause(cause).value}"


def plant_stop_cause(frame_id: str) -> TripCause | None:
    """The cause in a drive state's status word, None while the plant runs (an unknown
    cause from a newer plant: ``PLANT_SAFE_STOP``)."""
    if not frame_id.startswith(STATUS_PREFIX):
        return None
    try:
        return TripCause(frame_id[len(STATUS_PREFIX):])
    except ValueError:
        return TripCause.PLANT_SAFE_STOP


def setpoint_held_word(command_stamp_ns: int) -> str:
    """The status word of a step that applied the command of ``command_stamp_ns`` again."""
    return f"{SETPOINT_HELD}:{int(command_stamp_ns)}"


def setpoint_held(frame_id: str) -> int | None:
    """None when a drive state's step applied a fresh setpoint; else the stamp (ns) of
    the command it applied again (``HELD_COMMAND_UNKNOWN`` when the word does not say)."""
    if not frame_id.startswith(SETPOINT_HELD):
        return None
    _, _, stamp = frame_id.partition(":")
    try:
        return int(stamp)
    except ValueError:
        return HELD_COMMAND_UNKNOWN


def run_status(error: str, cause: TripCause) -> str:
    """A run's status: ``failed`` (it could not run), ``tripped`` (the machine was
    stopped by a safety function) or ``completed``."""
    if error:
        return "failed"
    return "completed" if cause in (TripCause.NONE, TripCause.DEACTIVATED) else "tripped"
