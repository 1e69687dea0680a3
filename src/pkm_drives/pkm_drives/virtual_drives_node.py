"""``virtual_drives_node``: a simulated machine behind virtual CiA 402 drives, for a
graph whose drive interface (drives_node) talks CANopen: the plant of sim_hw's
parameters (pkm_sim_hw.parameters.declare_plant: geometry errors, compliance, faults,
load schedules) moved by one virtual drive per leg (virtual_drive.VirtualMachine) on
python-can's virtual bus ``can_channel``, served to other processes on the loopback
when ``bridge_url_file`` is set (bus.serve_bus). The simulation's ground truth,
``platform/true_pose``, is published at each step, stamped as the drive interface
stamps its states (both count the SYNCs from the machine's start).

``drive_faults``: CiA 402 faults to inject, comma-separated ``<drive>:<kind>[:<at_s>]``,
drive counted from 0, kind one of virtual_drive.InjectedFault (over_current,
following_error, encoder, heartbeat_lost, silent), at simulated time ``at_s``.
"""

from __future__ import annotations

import time

import can
import canopen
from rclpy.node import Node

from pkm_common import topics
from pkm_common.cdr import PoseStampedEncoder
from pkm_common.endpoints import publisher
from pkm_common.params import ParameterError, declare_str
from pkm_common.runner import main_exit, run_node
from pkm_kinematics import load_machine
from pkm_kinematics.errors import FieldError
from pkm_sim_hw.parameters import declare_plant
from pkm_sim_hw.run_record import true_pose_components

from .bus import NOTIFIER_CYCLE_S, TimedBus, serve_bus
from .drive_config import drive_settings
from .hardware import PlantAxes
from .virtual_drive import DEFAULT_EDS, HomingSetup, VirtualMachine, parse_drive_faults

__all__ = ["VirtualDrivesNode"]

REPEAT_AFTER_S = 0.1          # as sim_hw (pkm_sim_hw.sim_loop.REPEAT_AFTER_S)


class VirtualDrivesNode(Node):
    def __init__(self, context=None, **kwargs):
        super().__init__("virtual_drives", context=context, **kwargs)
        machine = load_machine(declare_str(self, "machine", "archi", "config/machines/<name>.yaml"))
        self.plant = declare_plant(self, machine)
        channel = declare_str(self, "can_channel", "pkm_drives", "python-can virtual channel of the drives")
        url_file = declare_str(self, "bridge_url_file", "", "serve the bus on 127.0.0.1 and write its URL here "
                               "(empty: this process only)", allow_empty=True)
        try:
            settings = drive_settings(machine, {"interface": "virtual", "channel": channel})
            self.faults = parse_drive_faults(declare_str(self, "drive_faults", "", "'<drive>:<kind>[:<at_s>]', "
                                                         "comma-separated", allow_empty=True), settings.n)
        except FieldError as exc:
            raise ParameterError(exc.name, exc.detail) from None
        self.space = machine.model.task_space
        self.pub_pose = publisher(self, topics.TRUE_POSE)
        self.pose_encoder = PoseStampedEncoder("world")
        self.server = serve_bus(channel, url_file) if url_file else None
        # the drives' frames take their time on the wire (the master's take theirs: drives_node)
        self.network = canopen.Network(TimedBus(can.Bus(interface="virtual", channel=channel), channel,
                                                settings.bus.bitrate))
        self.network.NOTIFIER_CYCLE = NOTIFIER_CYCLE_S
        self.network.connect()
        dyn = machine.dynamics               # each drive moves its own mass and a share of the platform's
        mass = dyn.drive_mass_kg[0] + dyn.platform_mass_kg / settings.n
        homing = HomingSetup(mass_kg=mass, pitch=settings.index_pitch, dt_s=self.plant.params.dt_s)
        self.machine = VirtualMachine(self.network, PlantAxes(self.plant), settings.node_ids, settings.scaling,
                                      DEFAULT_EDS, settings.names, on_step=self.on_step, homing=homing)
        self.last_pose: bytes | None = None       # the last step's, published again while no step comes
        self.last_step_s = time.monotonic()
        self.create_timer(REPEAT_AFTER_S, self.repeat_pose)
        self.machine.boot()
        self.get_logger().info(f"virtual drives up: nodes {list(settings.node_ids)} on {channel}"
                               + (f", served at {self.server.url}" if self.server else ""))

    def on_step(self, k: int) -> None:
        """After the machine's step k (the bus's notifier thread): the true pose, and
        the drive faults due."""
        ns = k * self.plant.dt_ns
        out = self.plant.output()
        self.last_pose = self.pose_encoder.encode(ns, *true_pose_components(self.space, out))
        self.last_step_s = time.monotonic()
        self.pub_pose.publish(self.last_pose)
        t = k * self.plant.params.dt_s
        while self.faults and self.faults[0][2] <= t + 1e-12:
            drive, fault, _ = self.faults.pop(0)
            self.machine.drives[drive].inject(fault)
            self.get_logger().warning(f"injected {fault.value} on drive {drive} at {t:.4f} s")

    def repeat_pose(self) -> None:
        """The last true pose again when no step came for a while (as sim_hw repeats its
        state): a sensor that joined late, or lost it, gets it (lockstep waits for it)."""
        pose = self.last_pose
        if pose is not None and time.monotonic() - self.last_step_s >= REPEAT_AFTER_S:
            self.pub_pose.publish(pose)

    def destroy_node(self):
        self.network.disconnect()
        if self.server is not None:
            self.server.close()
        return super().destroy_node()


def main(args=None):
    main_exit(run_node(VirtualDrivesNode, args=args, name="virtual_drives", executor="events"))


if __name__ == "__main__":
    main()
