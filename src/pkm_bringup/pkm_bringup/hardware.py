"""The machine side of a run's graph (pure): which node is the machine (``hardware``:
sim_hw, the CANopen drive interface, a ros2_control system's interface) and what
simulates the machine behind an interface (virtual drives, the ros2_control stand-in),
with their parameters, and what a scenario may ask of them.

A scenario's ``drives`` section holds the drive interface's parameters (config/drives.yaml)
and pkm-run's own keys (``DRIVES_BRINGUP_KEYS``): ``virtual`` (a simulated machine behind
the interface: default true) and ``drive_faults`` (the virtual drives' CiA 402 faults).
"""

from __future__ import annotations

from pathlib import Path

from pkm_drives.drive_config import drive_settings
from pkm_drives.ros2_control import ros2_control_settings
from pkm_drives.virtual_drive import parse_drive_faults
from pkm_kinematics.errors import FieldError

__all__ = ["HARDWARE", "MACHINE_NODE", "DRIVES_BRINGUP_KEYS", "CAN_BUS_URL", "LOOP_ONLY", "check_hardware",
           "machine_nodes", "controller_wiring"]

HARDWARE = ("sim", "canopen", "ros2_control")
MACHINE_NODE = {"sim": "sim_hw", "canopen": "drives", "ros2_control": "ros2_control"}
DRIVES_BRINGUP_KEYS = ("virtual", "drive_faults")
CAN_BUS_URL = "can_bus.url"          # in the run directory: the virtual drives' bridge (pkm_drives.bus)
# sim_hw parameters of its loop, not of its plant (a simulated machine behind an interface takes the plant's)
LOOP_ONLY = ("mode", "command_timeout_s", "command_max_age_s", "sync_error_limit", "command_source", "duration_s",
             "summary_path", "publish_markers")


def check_hardware(hardware: str, drives: dict, mode: str, ground_truth: bool, simulated_inputs: bool,
                   config) -> None:
    """FieldError naming the scenario key when the machine side cannot be what the
    scenario asks (``simulated_inputs``: it has a metrology or a load)."""
    if hardware not in HARDWARE:
        raise FieldError("hardware", f"must be one of {list(HARDWARE)}, got {hardware!r}")
    if drives and hardware == "sim":
        raise FieldError("drives", "only with hardware: canopen or ros2_control")
    if hardware == "ros2_control":
        if mode != "realtime":
            raise FieldError("mode", "must be realtime with hardware: ros2_control (its system runs its own "
                             "real-time loop)")
        ros2_control_settings(config)
    if not ground_truth and simulated_inputs:
        raise FieldError("hardware", "a real machine (drives.virtual: false) has no simulated metrology or load")
    try:
        parse_drive_faults(str(drives.get("drive_faults", "")), config.model.n_legs)
    except FieldError as exc:
        raise FieldError("drives.drive_faults", exc.detail) from None


def machine_nodes(s, plant: dict, loop: dict, drive_defaults: dict, run_dir: Path) -> dict:
    """node -> parameters of the machine side: ``plant`` (sim_hw's plant parameters),
    ``loop`` (its loop's, wired by the run), ``drive_defaults`` (config/drives.yaml)."""
    summaries = run_dir / "summaries"
    behind = {k: v for k, v in plant.items() if k not in LOOP_ONLY}
    if s.hardware == "sim":
        return {"sim_hw": {**plant, **loop}}
    if s.hardware == "ros2_control":
        nodes = {"ros2_control": {"boot_timeout_s": float(s.drives.get("boot_timeout_s", 10.0)), **loop}}
        if s.virtual_drives:
            nodes["ros2_control_sim"] = {**behind, "summary_path": str(summaries / "ros2_control_sim.json")}
        return nodes
    drives = {k: v for k, v in {**drive_defaults, **s.drives}.items() if k not in DRIVES_BRINGUP_KEYS}
    nodes = {"drives": {**drives, **loop}}
    if s.virtual_drives:
        # the bus: served by the virtual drives' process on the loopback (pkm_drives.bus); in one
        # process (in_process) a virtual channel
        nodes["drives"].update(can_interface="remote", can_channel_file=str(run_dir / CAN_BUS_URL))
        nodes["virtual_drives"] = {**behind, "can_channel": f"pkm_{s.name}",
                                   "bridge_url_file": str(run_dir / CAN_BUS_URL),
                                   "drive_faults": str(s.drives.get("drive_faults", ""))}
    return nodes


def controller_wiring(s, config) -> dict:
    """The controller's parameters the machine side decides: CiA 402 drives with
    synchronous RPDOs apply a command one cycle after the state that follows it
    (``actuation_delay_cycles``: the drive supervision compares their forces with the
    command they applied)."""
    if s.hardware == "canopen" and drive_settings(config).rpdo_synchronous:
        return {"actuation_delay_cycles": 1}
    return {}
