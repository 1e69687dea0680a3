"""``drives_node``: the drive interface, in the graph where sim_hw is for a simulated
machine: the same topics, types and QoS (``drives/command`` in, ``drives/state`` and
``/clock`` out), the same loop (pkm_sim_hw.sim_loop: lockstep or real time, command
authority, watchdog, E-stop, summary), stepping the machine's CiA 402 drives over
CANopen (hardware.CanopenHardware) instead of a simulated plant. The controller cannot
tell, except that a real machine publishes no ``platform/true_pose``.

Before anything opens, the bus's time for one cycle is checked against ``dt_s``
(bus_timing: refused naming the figures); the drives are booted, configured and
switched on, brakes closed, and the first command enables them. Each drive's CiA 402
state and error code are published on ``drives/cia402`` (on a change, and each
second); a drive's trip (fault, EMCY, left operation enabled, missed TPDO, lost
heartbeat) stops the machine: quick stop on every drive, the cause in ``drives/state``'s
status word and in the diagnostics.

Parameters: those of sim_hw's loop (mode, dt_s, command_timeout_s, command_source,
duration_s, summary_path, ...), and ``can_interface``/``can_channel``/``can_bitrate``
(empty/0: the machine file's ``drives.bus``), ``can_channel_file`` (read the channel
from this file: a bridge's URL), ``eds`` (empty: pkm_drives' CiA 402 EDS),
``pdo_timeout_s``, ``heartbeat_factor``, ``boot_timeout_s``.
"""

from __future__ import annotations

import dataclasses
import time

import canopen

from pkm_common import topics
from pkm_common.conversions import diagnostic_array, diagnostic_status, ns_to_stamp
from pkm_common.endpoints import publisher
from pkm_common.params import ParameterError, declare_float, declare_int, declare_str
from pkm_common.runner import main_exit, run_node
from pkm_kinematics import load_machine
from pkm_kinematics.errors import FieldError
from pkm_sim_hw.parameters import declare_loop
from pkm_sim_hw.sim_hw_node import SimHwNode

from .bus import open_network
from .bus_timing import check_rate, cycle_load
from .canopen_master import CanopenMaster, DriveStartError, pdo_bytes
from .cia402 import State, error_text
from .drive_config import drive_settings
from .hardware import CanopenHardware
from .virtual_drive import DEFAULT_EDS

STATUS_PERIOD_S = 1.0


class DrivesNode(SimHwNode):
    """sim_hw's node on CiA 402 drives (the module docstring)."""

    simulated = False

    def __init__(self, context=None, **kwargs):
        self.network = None
        super().__init__(context=context, node_name="drives", **kwargs)
        self.pub_cia402 = publisher(self, topics.DRIVES_CIA402)
        self.last_words: list[int] = []
        self.last_status_s = 0.0
        self.create_timer(STATUS_PERIOD_S, self.publish_drive_states)
        self.create_timer(0.1, self.repeat_before_start)
        self.publish_drive_states()

    def repeat_before_start(self) -> None:
        """Until the loop starts the states are repeated (as sim_hw repeats its state):
        a recorder or a panel that joins before the start sees the drives switched on."""
        if not self.loop.started:
            self.publish_drive_states()

    def make_settings(self):
        machine = load_machine(declare_str(self, "machine", "archi", "config/machines/<name>.yaml"))
        dt_s = declare_float(self, "dt_s", 0.002, 1e-5, 0.1, "the bus cycle (one SYNC)", unit="s")
        bus = {key: value for key, value in (
            ("interface", declare_str(self, "can_interface", "", "python-can interface (empty: the machine "
                                      "file's drives.bus)", allow_empty=True)),
            ("channel", declare_str(self, "can_channel", "", "(empty: the machine file's)", allow_empty=True)),
            ("bitrate", declare_int(self, "can_bitrate", 0, 0, 1_000_000, "bit/s (0: the machine file's)")))
            if value}
        channel_file = declare_str(self, "can_channel_file", "", "read the channel from this file (a bridge's "
                                   "URL, pkm_drives.bus)", allow_empty=True)
        eds = declare_str(self, "eds", "", "the drives' EDS (empty: pkm_drives' CiA 402 drive)",
                          allow_empty=True) or str(DEFAULT_EDS)
        pdo_timeout_s = declare_float(self, "pdo_timeout_s", 0.5, 0.0, 10.0, "a TPDO later than this after "
                                      "its SYNC is missed (a trip)", lo_open=True, unit="s")
        heartbeat_factor = declare_float(self, "heartbeat_factor", 3.0, 1.0, 100.0, "a drive's heartbeat "
                                         "silent for this many periods is lost (a trip)")
        boot_timeout_s = declare_float(self, "boot_timeout_s", 10.0, 0.0, 600.0, "how long to wait for the "
                                       "bus and the drives at start", lo_open=True, unit="s")
        try:
            settings = drive_settings(machine, bus)
            rpdo, tpdo = pdo_bytes(canopen.import_od(eds, settings.node_ids[0]))
            check_rate(cycle_load(settings.bus.bitrate, dt_s, [rpdo] * settings.n, [tpdo] * settings.n,
                                  settings.heartbeat_s))
        except FieldError as exc:
            raise ParameterError(exc.name, exc.detail) from None
        self.network = open_network(settings.bus, channel_file, boot_timeout_s)
        master = CanopenMaster(self.network, settings, eds, pdo_timeout_s, heartbeat_factor)
        self.hardware = CanopenHardware(master, settings, dt_s)
        self.start_drives(boot_timeout_s)
        loop = declare_loop(self, machine, self.hardware, dt_s)
        return dataclasses.replace(loop, publish_markers=False, homing=self.homing_text())

    def homing_text(self) -> str:
        """What the drives' homing did (its cycles, each drive's method and position)."""
        hw = self.hardware
        if not hw.homing:
            return ""
        s = hw.settings
        return f"homed in {len(hw.homing)} cycles: " + ", ".join(
            f"{n} method {m} at {p:.6f}" for n, m, p in zip(s.names, s.homing_methods, hw.reading.positions))

    def start_drives(self, timeout_s: float) -> None:
        """Boot and switch on the drives, retrying while they power up (DriveStartError
        after ``timeout_s``, naming the drive)."""
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                self.hardware.start()
                break
            except DriveStartError as exc:
                if time.monotonic() > deadline or str(exc).startswith("homing:"):   # a homing fails once
                    raise
                self.get_logger().info(f"waiting for the drives: {exc}", throttle_duration_sec=2.0)
                time.sleep(0.2)
        names = ", ".join(f"{n} (node {i})" for n, i in zip(self.hardware.settings.names,
                                                             self.hardware.settings.node_ids))
        self.get_logger().info(f"drives switched on: {names}")

    def after_cycle(self) -> None:
        super().after_cycle()
        words = [w for _, w in self.hardware.drive_states()]
        if words != self.last_words:
            self.publish_drive_states()

    def publish_drive_states(self) -> None:
        """drives/cia402: each drive's state, statusword and error code."""
        hw = self.hardware
        states = hw.drive_states()
        self.last_words = [w for _, w in states]
        statuses = []
        for k, (state, word) in enumerate(states):
            code = hw.master.emcy[k] or 0
            level = 0 if state is State.OPERATION_ENABLED else 2 if state in (State.FAULT,
                                                                            State.FAULT_REACTION_ACTIVE) else 1
            homing = f"homed (method {hw.settings.homing_methods[k]})" if hw.homing else "absolute encoder"
            statuses.append(diagnostic_status(hw.names[k], level, state.label if state else "unknown",
                                              {"node_id": hw.settings.node_ids[k], "statusword": f"0x{word:04X}",
                                               "error_code": f"0x{code:04X}",
                                               "error": error_text(code) if code else "none", "homing": homing}))
        self.pub_cia402.publish(diagnostic_array(ns_to_stamp(self.now_ns()), statuses))

    def destroy_node(self):
        result = super().destroy_node()
        if self.network is not None:
            self.network.disconnect()
            self.network = None
        return result


def main(args=None):
    main_exit(run_node(DrivesNode, args=args, name="drives", executor="events"))


if __name__ == "__main__":
    main()
