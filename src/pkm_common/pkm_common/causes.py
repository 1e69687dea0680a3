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
import functools
from dataclasses import dataclass

from pkm_kinematics.errors import FieldError

__all__ = ["TripCause", "parse_cause", "run_status", "PlantState", "PlantStatus", "RUNNING", "plant_status",
           "safe_stop_status", "setpoint_held_status", "SETPOINT_HELD", "HELD_COMMAND_UNKNOWN"]

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
    # the servo drives' own (pkm_drives): each names the drive and its error code
    DRIVE_FAULT = "drive_fault"              # a drive in fault (its statusword or its EMCY), with its code
    DRIVE_DISABLED = "drive_disabled"        # a drive left operation enabled without a fault (its own quick stop)
    HEARTBEAT_LOST = "heartbeat_lost"        # a drive's heartbeat missed for its consumer time
    PDO_MISSED = "pdo_missed"                # a drive's TPDO did not come for a SYNC

    def __str__(self) -> str:
        return self.value


def parse_cause(text: str) -> TripCause:
    """The cause of its wire string; an unknown string (a newer peer) is kept visible
    as ``ValueError`` rather than mapped to a wrong cause."""
    try:
        return TripCause(text)
    except ValueError:
        raise FieldError("cause", f"must be one of {[c.value for c in TripCause]}, got {text!r}") from None


class PlantState(enum.IntEnum):
    """What the plant's step did (``PlantStatus.state``)."""

    RUNNING = 0          # a fresh setpoint applied
    SETPOINT_HELD = 1    # an earlier setpoint applied again (realtime: the answer missed its tick)
    SAFE_STOP = 2        # braked, for ``PlantStatus.cause``


@dataclass(frozen=True, slots=True)
class PlantStatus:
    """The plant's status on one drive state, as a drive's status word would give it.

    On the wire it rides in ``drives/state``'s ``header.frame_id`` (sensor_msgs/JointState
    has no status field and these wheels cannot generate a message of our own:
    docs/decisions.md): ``""`` running, ``setpoint_held:<stamp ns>`` (a step that
    applied the command of that stamp again), ``safe_stop:<cause>`` once braked. The
    text lives here only: ``word`` writes it, ``plant_status`` reads it back."""

    state: PlantState = PlantState.RUNNING
    cause: TripCause = TripCause.NONE          # SAFE_STOP: why the plant braked
    held_ns: int | None = None                 # SETPOINT_HELD: the stamp of the command applied again

    @property
    def stopped(self) -> bool:
        return self.state is PlantState.SAFE_STOP

    def word(self) -> str:
        """The status word in ``header.frame_id``."""
        if self.state is PlantState.SAFE_STOP:
            return f"{STATUS_PREFIX}{TripCause(self.cause).value}"
        if self.state is PlantState.SETPOINT_HELD:
            return f"{SETPOINT_HELD}:{int(self.held_ns)}"
        return ""


RUNNING = PlantStatus()


def safe_stop_status(cause: TripCause) -> PlantStatus:
    """The status of a braked plant."""
    return PlantStatus(PlantState.SAFE_STOP, TripCause(cause))


def setpoint_held_status(command_stamp_ns: int) -> PlantStatus:
    """The status of a step that applied the command of ``command_stamp_ns`` again."""
    return PlantStatus(PlantState.SETPOINT_HELD, held_ns=int(command_stamp_ns))


@functools.lru_cache(maxsize=64)
def plant_status(word: str) -> PlantStatus:
    """The status in a drive state's ``header.frame_id`` (read once per distinct word: a
    running plant sends the same one every step). A word this version does not know
    reads as running; a stop with an unknown cause (a newer plant) as
    ``PLANT_SAFE_STOP``; a held setpoint that does not say which as
    ``HELD_COMMAND_UNKNOWN``."""
    if word.startswith(STATUS_PREFIX):
        try:
            return safe_stop_status(TripCause(word[len(STATUS_PREFIX):]))
        except ValueError:
            return safe_stop_status(TripCause.PLANT_SAFE_STOP)
    if word.startswith(SETPOINT_HELD):
        _, _, stamp = word.partition(":")
        try:
            return setpoint_held_status(int(stamp))
        except ValueError:
            return setpoint_held_status(HELD_COMMAND_UNKNOWN)
    return RUNNING


def run_status(error: str, cause: TripCause) -> str:
    """A run's status: ``failed`` (it could not run), ``tripped`` (the machine was
    stopped by a safety function) or ``completed``."""
    if error:
        return "failed"
    return "completed" if cause in (TripCause.NONE, TripCause.DEACTIVATED) else "tripped"
