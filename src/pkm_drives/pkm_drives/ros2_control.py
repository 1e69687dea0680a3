"""A ros2_control system as the graph's machine (no rclpy): the drive interface's mode
for a machine whose drives already have a ros2_control hardware interface. This
controller then commands their effort interfaces through ros2_control's standard
controllers' topics, as any client of them does:

- ``effort_controllers/JointGroupEffortController`` (a forward_command_controller):
  ``/<controller>/commands``, ``std_msgs/Float64MultiArray``, one effort per joint in the
  controller's ``joints`` order;
- ``joint_state_broadcaster``: ``/joint_states``, ``sensor_msgs/JointState`` (every
  joint of the system, by name, in its own order).

The machine file maps each leg to its ros2_control joint::

    drives:
      ros2_control:
        controller: effort_controller      # its commands: /effort_controller/commands
        joints: [rail_1_joint, rail_2_joint, rail_3_joint, rail_4_joint]   # the legs' order
        joint_states: /joint_states
        max_age_s: 0.05                    # samples silent this long (this process's own stalls
                                           # not counted): a trip

ros2_control runs its own real-time loop: this mode is real time only (each cycle of
the drive interface sends the command held and reads the newest sample; no lockstep).
A stop sends zero efforts: the effort controller then holds zero, and the hardware
interface's own safety (brakes on its deactivation or a lost command) is what holds a
loaded machine; say so to the integrator (docs/drives.md).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

from pkm_common.causes import TripCause
from pkm_common.watchdog import SilenceWatchdog
from pkm_kinematics.config import FieldReader, MachineConfig
from pkm_kinematics.errors import ConfigError, FieldError
from pkm_sim_hw.plant import PlantOutput

from .hardware import HardwareParameters

__all__ = ["Ros2ControlSettings", "ros2_control_settings", "Ros2ControlHardware"]


@dataclass(frozen=True)
class Ros2ControlSettings:
    controller: str
    joints: tuple[str, ...]
    joint_states: str = "/joint_states"
    max_age_s: float = 0.05

    @property
    def commands(self) -> str:
        """The effort controller's command topic."""
        return f"/{self.controller}/commands"


def ros2_control_settings(machine: MachineConfig) -> Ros2ControlSettings:
    """The machine file's ``drives.ros2_control`` (the module docstring); ConfigError
    naming a missing or bad field."""
    drives = machine.data.get("drives")
    if not isinstance(drives, dict) or "ros2_control" not in drives:
        raise ConfigError("drives.ros2_control", f"machine {machine.name!r} has no drives.ros2_control section "
                          "(controller, joints): docs/drives.md")
    r = FieldReader(drives["ros2_control"], "drives.ros2_control")
    controller = r.string("controller")
    if not controller.replace("_", "").isalnum():
        raise ConfigError("drives.ros2_control.controller", f"must be a controller name (letters, digits, '_'), "
                          f"got {controller!r}")
    joints = r.raw("joints")
    n = machine.model.n_legs
    if not isinstance(joints, list) or len(joints) != n or not all(isinstance(j, str) and j for j in joints):
        raise ConfigError("drives.ros2_control.joints", f"expected {n} joint names (one per leg, in the legs' "
                          f"order), got {joints!r}")
    if len(set(joints)) != n:
        raise ConfigError("drives.ros2_control.joints", f"each leg needs its own joint, got {joints!r}")
    topic = r.string("joint_states", "/joint_states")
    return Ros2ControlSettings(controller, tuple(joints), topic,
                               r.number("max_age_s", 0.05, lo=0.0, lo_open=True, hi=10.0, unit="s"))


class Ros2ControlHardware:
    """The machine through a ros2_control system (the loop's plant, as
    hardware.CanopenHardware): ``send(efforts)`` publishes the effort controller's
    command (in its joints' order), ``on_joint_states`` takes each sample."""

    homed = True

    def __init__(self, settings: Ros2ControlSettings, names, dt_s: float, send, clock=time.monotonic):
        self.settings, self.send, self.clock = settings, send, clock
        self.names, self.n = list(names), len(names)
        self.params = HardwareParameters(dt_s)
        self.dt_ns = round(dt_s * 1e9)
        self.k, self.t = 0, 0.0
        self.stopped, self.stop_reason, self.stop_cause = False, "", TripCause.NONE
        self.sample: tuple | None = None            # (positions, velocities, efforts) in the legs' order
        # the samples' silence, without this process's own stalls (a late cycle finds the
        # samples still queued: not the system's silence): three of its periods
        self.silence = SilenceWatchdog(own_stall_s=3.0 * dt_s)
        self.refused = ""                            # why the last sample was refused ("": it was not)
        self._index: dict[str, int] | None = None

    def on_joint_states(self, names, position, velocity, effort) -> None:
        """A joint_states message: the legs' joints picked by name (others ignored)."""
        if self._index is None or list(self._index) != list(names):
            self._index = {name: i for i, name in enumerate(names)}
        try:
            rows = [self._index[j] for j in self.settings.joints]
        except KeyError as exc:
            self.refused = f"joint_states has no joint {exc.args[0]!r} (drives.ros2_control.joints)"
            return
        pick = lambda values: [float(values[i]) if i < len(values) else math.nan for i in rows]   # noqa: E731
        self.sample, self.refused = (pick(position), pick(velocity), pick(effort)), ""
        self.silence.feed(self.clock())

    def start(self) -> None:
        if self.sample is None:
            raise FieldError("joint_states", f"no sample on {self.settings.joint_states} with the joints "
                             f"{list(self.settings.joints)}" + (f": {self.refused}" if self.refused else ""))

    def step(self, forces, hold: bool = False) -> PlantOutput:
        """One cycle: the command out (zeros once stopped), the newest sample in."""
        if len(forces) != self.n:
            raise FieldError("drive forces", f"expected {self.n} values, got {len(forces)}")
        self.send([0.0] * self.n if self.stopped else [float(f) for f in forces])
        self.k += 1
        self.t = self.k * self.params.dt_s
        age = self.silence.silence_s(self.clock()) or 0.0
        if not self.stopped and (self.refused or age > self.settings.max_age_s):
            why = self.refused or (f"joint_states silent for {age * 1e3:.0f} ms (max_age_s "
                                   f"{self.settings.max_age_s:g})")
            self.safe_stop(f"ros2_control: {why}", TripCause.WATCHDOG if not self.refused else
                           TripCause.INPUT_REFUSED)
        return self.output()

    def safe_stop(self, reason: str, cause: TripCause = TripCause.PLANT_SAFE_STOP) -> None:
        if not self.stopped:
            self.stopped, self.stop_reason, self.stop_cause = True, reason, TripCause(cause)
        self.send([0.0] * self.n)

    def output(self) -> PlantOutput:
        positions, velocities, efforts = self.sample
        return PlantOutput(self.t, self.k, self.k * self.dt_ns, list(positions), list(velocities), list(efforts),
                           [False] * self.n, None, None, [], 0.0, [], self.stopped)

    def load_components(self, force, moment):
        raise FieldError("load", "a ros2_control system takes no simulated load")
