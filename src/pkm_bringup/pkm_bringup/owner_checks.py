"""The owners' validations of a node's parameters (pure): what each node would refuse
once started, checked when a scenario is loaded (scenario._check_nodes), each by the
owner's own code (ControllerConfig and the controller core, PlantParameters and Fault,
GoughSensorModel, the planner's budget, the drives' settings and bus timing). Each
``check_<section>(p, config)`` takes the node's parameters ``p`` (as
scenario.node_parameters gives them) on the scenario's machine ``config`` and raises the
owner's ValueError (a FieldError naming the parameter)."""

from __future__ import annotations

import inspect
from dataclasses import fields

import canopen

from pkm_controller.configuration import core_from_parameters
from pkm_controller.config import ControllerConfig
from pkm_drives.bus_timing import check_rate, cycle_load
from pkm_drives.canopen_master import pdo_bytes
from pkm_drives.drive_config import drive_settings
from pkm_drives.virtual_drive import DEFAULT_EDS
from pkm_gough_sensor.laser import LaserTracker
from pkm_gough_sensor.metrology import GoughSensorModel
from pkm_kinematics.config import load_machine
from pkm_kinematics.errors import FieldError
from pkm_sim_hw.homing import homing_plan
from pkm_sim_hw.loads import profile_entries
from pkm_sim_hw.plant import Fault, PlantParameters, check_load
from pkm_trajectory.planner import RATE_HZ_RANGE, PlanBudget

__all__ = ["OWNER_CHECKS"]


PASSED_KEPT = 8


class _Passed:
    """The last PASSED_KEPT checks that passed, by (an object loaded once while its file
    is unchanged, the repr of the settings): a study's runs check the same controller
    (a core, ~1 ms) and sensor (~0.3 ms) at every scenario load."""

    def __init__(self):
        self._kept: list = []

    def check(self, owner, settings, make) -> None:
        """``make()`` unless these settings of ``owner`` passed already (``owner`` None:
        always); ``make`` raises what it refuses."""
        key = repr(settings)
        if owner is not None and any(o is owner and k == key for o, k in self._kept):
            return
        make()
        if owner is not None:
            self._kept.append((owner, key))
            del self._kept[:-PASSED_KEPT]


_CONTROLLERS, _SENSORS = _Passed(), _Passed()


def check_controller(p: dict, config) -> None:
    known = {f.name for f in fields(ControllerConfig)}
    controller = ControllerConfig.from_dict({k: v for k, v in p.items() if k in known})
    try:
        machine = load_machine(p["machine"])     # the same object while the file is unchanged
    except ValueError:
        machine = None                           # core_from_parameters names it
    _CONTROLLERS.check(machine, controller, lambda: core_from_parameters(p["machine"], controller))


def check_plant(p: dict, config) -> None:
    known = {f.name for f in fields(PlantParameters)}
    values = {k: tuple(v) if isinstance(v, list) else v for k, v in p.items() if k in known}
    if "faults" in values:          # one string to ROS; split as sim_hw_node does
        values["faults"] = tuple(f.strip() for f in values["faults"].split(",") if f.strip())
    params = PlantParameters(**values)
    params.validate(config.model.n_legs, config.model.task_space)
    loads = config.model.task_space.loads
    for name in ("compliance", "frame_compliance"):
        values = getattr(params, name)
        if any(values) and len(values) != len(loads):
            raise FieldError(name, f"must be {len(loads)} values on {config.name} (one per load component "
                                   f"{', '.join(loads)}), got {list(values)}")
    for text in params.faults:
        Fault.parse(text, config.model.n_legs)
    if params.encoder_offsets_m and homing_plan(config) is None:
        raise FieldError("encoder_offsets_m", f"incremental encoders must be homed: machine {config.name!r} has no "
                                              "drives.homing section (methods, order, home positions)")
    space = config.model.task_space
    size = len(space.loads)
    for name, profile, key in (("load_schedule", "load_profile", "load"),
                               ("frame_load_schedule", "frame_load_profile", "frame_load")):
        # flat [t_s, f1, f2, f3, ...] steps, or [t_s, ramp_s, f1, ...] entries: a ramp
        # stays between the wrenches it joins, each checked
        rows = [(t, w) for t, _, w in profile_entries(p.get(profile, []), size, profile)]
        schedule = p.get(name, [])
        rows += [(schedule[i], schedule[i + 1:i + 1 + size]) for i in range(0, len(schedule), size + 1)]
        for t, wrench in rows:
            try:
                check_load(wrench, space, params, key)
            except FieldError as exc:
                raise FieldError(exc.name, f"{exc.detail} at t_s = {t:g} s") from None


def check_sensor(p: dict, config) -> None:
    known = set(inspect.signature(GoughSensorModel).parameters) - {"metrology"}
    values = {k: v for k, v in p.items() if k in known}
    if not values.get("resolution_m"):         # 0: the machine file's (gough_sensor_node)
        values.pop("resolution_m", None)
    _SENSORS.check(config.metrology, sorted(values.items()), lambda: GoughSensorModel(config.metrology, **values))


def check_trajectory(p: dict, config) -> None:
    """trajectory_node's rate and plan budget (its other parameters: program_plan.plan_program)."""
    lo, hi = RATE_HZ_RANGE
    rate = p.get("rate_hz", 1000.0)
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not lo <= rate <= hi:
        raise FieldError("rate_hz", f"must be in [{lo:g}, {hi:g}] Hz, got {rate!r}")
    PlanBudget(p.get("max_points", 200_000), p.get("max_segments", 10_000), float(p.get("max_planning_s", 10.0)))


def check_drives(p: dict, config) -> None:
    """The machine file's drives section and the bus's time for one cycle at dt_s
    (pkm_drives.drive_config, bus_timing): a rate the bus cannot carry is refused here."""
    bus = {k: p[f"can_{k}"] for k in ("interface", "channel", "bitrate") if p.get(f"can_{k}")}
    settings = drive_settings(config, bus)
    eds = p.get("eds") or str(DEFAULT_EDS)
    rpdo, tpdo = pdo_bytes(canopen.import_od(eds, settings.node_ids[0]))
    check_rate(cycle_load(settings.bus.bitrate, p["dt_s"], [rpdo] * settings.n, [tpdo] * settings.n,
                          settings.heartbeat_s))


def check_laser_tracker(p: dict, config) -> None:
    LaserTracker(p["tool"], p["sigma_m"], p["seed"], p["frame_position"], p["frame_rpy_deg"])


OWNER_CHECKS = {"controller": check_controller, "plant": check_plant, "sensor": check_sensor,
                "trajectory": check_trajectory, "drives": check_drives, "laser_tracker": check_laser_tracker}
