"""sim_hw's ROS parameters, declared and range-checked (pkm_common.params), as the
plant's configuration (plant.PlantParameters) and the node's settings."""

from __future__ import annotations

import dataclasses
import math

from pkm_common.params import ParameterError, declare_bool, declare_float, declare_float_list, declare_int, declare_str
from pkm_common.credential import Verifier
from pkm_common.sources import AllowedSenders, node_names
from pkm_kinematics import load_machine
from pkm_kinematics.errors import ConfigError, FieldError
from pkm_sim_hw.authority import CommandGate
from pkm_sim_hw.homing import home, homing_plan
from pkm_sim_hw.loads import profile_entries, ramp_steps
from pkm_sim_hw.plant import Plant, PlantParameters
from pkm_sim_hw.sim_loop import SimHwSettings
from pkm_sim_hw.strut_plant import StrutPlant

# the plant of a machine kind (the rail machines': plant.Plant)
PLANTS = {"struts": StrutPlant}


def declare_settings(node) -> SimHwSettings:
    """Declare every parameter of sim_hw on ``node``; a bad value raises ParameterError
    naming it and its allowed range (the node does not start)."""
    machine = load_machine(declare_str(node, "machine", "archi", "config/machines/<name>.yaml"))
    plant = declare_plant(node, machine)
    homing = home_incremental(plant, machine)
    return dataclasses.replace(declare_loop(node, machine, plant, plant.params.dt_s), homing=homing)


def home_incremental(plant, machine) -> str:
    """Home a plant whose encoders are incremental (``encoder_offsets_m``) by the
    machine file's ``drives.homing`` (pkm_sim_hw.homing); what it did, "" if nothing."""
    if not plant.params.encoder_offsets_m:
        return ""
    try:
        plan = homing_plan(machine)
    except ConfigError as exc:
        raise ParameterError("machine", str(exc)) from None
    if plan is None:
        raise ParameterError("encoder_offsets_m", f"incremental encoders must be homed: machine {machine.name!r} "
                             "has no drives.homing section (methods, order, home positions)")
    dyn = machine.dynamics
    try:
        record = home(plant, plan, dyn.drive_mass_kg[0] + dyn.platform_mass_kg / plant.n)
    except ValueError as exc:
        raise ParameterError("encoder_offsets_m", str(exc)) from None
    return record.text(plant.names)


def declare_plant(node, machine):
    """The simulated plant of ``machine`` from ``node``'s parameters, its load schedules
    loaded (sim_hw; pkm_drives' virtual drives move one too)."""
    faults = declare_str(node, "faults", "", "comma-separated '<drive>:<kind>[:<at_s>[:<size_m>]]' (size: "
                         "encoder_slip)", allow_empty=True)
    params = PlantParameters(
        dt_s=declare_float(node, "dt_s", 0.001, 1e-5, 0.1, "exchange period", unit="s"),
        substeps=declare_int(node, "substeps", 1, 1, 1000, "physics substeps per period"),
        integrator=declare_str(node, "integrator", "semi_implicit", choices=("semi_implicit", "rk4")),
        force_limit_n=declare_float(node, "force_limit_n", 2000.0, 0.0, 1e6, lo_open=True, unit="N"),
        encoder_resolution_m=declare_float(node, "encoder_resolution_m", 1e-6, 0.0, 1e-3, unit="m"),
        encoder_noise_m=declare_float(node, "encoder_noise_m", 0.0, 0.0, 1e-3, unit="m"),
        seed=declare_int(node, "seed", 0, 0, 2**31 - 1),
        link_length_errors=tuple(declare_float_list(node, "link_length_errors", [], "relative, one per "
                                                    "drive (empty: none)", lo=-0.49, hi=0.49)),
        encoder_offsets_m=tuple(declare_float_list(node, "encoder_offsets_m", [], "incremental encoders' "
                                                   "offsets until homed, one per drive (empty: none)", unit="m")),
        rail_offset_errors_m=tuple(declare_float_list(node, "rail_offset_errors_m", [], "one per drive "
                                                      "(empty: none)", unit="m")),
        screw_errors_m=tuple(declare_float_list(node, "screw_errors_m", [], "each drive's screw error amplitude, "
                                                "one per drive (empty: none)", lo=-1e-3, hi=1e-3, unit="m")),
        screw_error_period_m=declare_float(node, "screw_error_period_m", 0.1, 1e-3, 10.0, "the screw error's "
                                           "period along the travel", unit="m"),
        compliance=tuple(declare_float_list(node, "compliance", [0.0, 0.0, 0.0], "the tool's deflection per unit "
                                            "load, one per load component (3, or 6 on a 6-DOF machine)", lo=0.0)),
        frame_compliance=tuple(declare_float_list(node, "frame_compliance", [0.0, 0.0, 0.0], "the actuation "
                                                  "frame's deflection per unit frame load, one per load component "
                                                  "(3, or 6 on a 6-DOF machine)", lo=0.0)),
        faults=tuple(f.strip() for f in faults.split(",") if f.strip()),
        max_load_n=declare_float(node, "max_load_n", 5000.0, 0.0, 1e9, "bound of each external load force "
                                 "component", lo_open=True, unit="N"),
        max_load_nm=declare_float(node, "max_load_nm", 500.0, 0.0, 1e9, "bound of an external load moment "
                                  "component", lo_open=True, unit="N m"),
        parallelogram_bar_errors_m=tuple(declare_float_list(
            node, "parallelogram_bar_errors_m", [], "a Delta's parallelogram bars: 6 length errors, two per leg "
            "(MoM3 §4.1's imperfect case; empty: perfect)", lo=-0.01, hi=0.01, unit="m")),
        parallelogram_half_width_m=declare_float(node, "parallelogram_half_width_m", 0.03, 0.0, 1.0,
                                                 "half the distance between a parallelogram's bars",
                                                 lo_open=True, unit="m"))
    initial = declare_float_list(node, "initial_pose", [], "empty: the machine's home pose")
    plant = PLANTS.get(machine.kind, Plant)(machine, params, initial_pose=initial or None)
    schedules = (("load_schedule", "load_profile", plant.schedule_load, "the load on the tool"),
                 ("frame_load_schedule", "frame_load_profile", plant.schedule_frame_load,
                  "the load on the machine's frame"))
    size = len(machine.model.task_space.loads)        # a load's components: 3, or 6 on a 6-DOF machine
    for name, profile_name, schedule_into, what in schedules:
        schedule = declare_float_list(node, name, [], f"flat [t_s, f1, f2, f3, ...]: {what} (task coordinates) "
                                      "from t_s on, in simulated time (deterministic, unlike the load topic)")
        profile = declare_float_list(node, profile_name, [], f"flat [t_s, ramp_s, f1, f2, f3, ...]: {what}, "
                                     "each reached linearly from the one before over ramp_s, one step per "
                                     f"period (pkm_sim_hw.loads; instead of {name})")
        if schedule and profile:
            raise ParameterError(profile_name, f"give {name} (steps) or {profile_name} (ramps), not both")
        if len(schedule) % (size + 1):
            raise ParameterError(name, f"must hold groups of {size + 1} numbers [t_s, "
                                       f"{', '.join(machine.model.task_space.loads)}], got {len(schedule)} numbers")
        given = profile_name if profile else name
        try:
            rows = ramp_steps(profile_entries(profile, size, profile_name), params.dt_s) if profile else \
                [(schedule[i], schedule[i + 1:i + 1 + size]) for i in range(0, len(schedule), size + 1)]
            schedule_into(rows, given)
        except ValueError as exc:
            raise ParameterError(given, exc.detail if isinstance(exc, FieldError) else str(exc)) from None
    return plant


def declare_loop(node, machine, plant, dt_s: float) -> SimHwSettings:
    """The loop's settings (pkm_sim_hw.sim_loop) around ``plant``: a simulated plant,
    or hardware that steps as one (pkm_drives.hardware.CanopenHardware)."""
    lockstep = declare_str(node, "mode", "lockstep", choices=("lockstep", "realtime")) == "lockstep"
    timeout_s = declare_float(node, "command_timeout_s", 1.0, 0.0, 3600.0, lo_open=True, unit="s")
    sync_error_limit = declare_int(node, "sync_error_limit", 12, 0, 1_000_000, "realtime: brake when the "
                                   "count (+3 per cycle on a held setpoint, -1 per fresh one) exceeds it (0: off)")
    gate = CommandGate(
        declare_str(node, "command_source", "", "the controller node's full name (empty: the one publisher at "
                    "the first command); any other publisher on drives/command stops the machine",
                    allow_empty=True),
        lockstep, round(1e9 * declare_float(node, "command_max_age_s", 0.02, 0.0, 10.0, "real time: older "
                                            "commands are refused", lo_open=True, unit="s")))
    publish_markers = declare_bool(node, "publish_markers", True)
    duration_s = declare_float(node, "duration_s", 0.0, 0.0, 1e7, "stop after this simulated time "
                               "(0: run until shut down)", unit="s")
    summary_path = declare_str(node, "summary_path", "", "write a JSON run summary here at exit", allow_empty=True)
    shutdown_on_finish = declare_bool(node, "shutdown_on_finish", True, "end the process when duration_s is "
                                      "reached (in-process runs: False)")
    # 60 s at 1 kHz: 60000 steps (plant.t, a sum of dt, would make it 60001)
    duration_steps = math.ceil(duration_s / dt_s - 1e-6) if duration_s else 0
    load_senders = AllowedSenders("load", node_names(declare_str(
        node, "load_sources", "", "full node names allowed to publish a load, comma-separated (empty: anyone); "
        "another's load stops the machine (cause intruder)", allow_empty=True)), "load_sources")
    path = declare_str(node, "credential_file", "", "the run's key (pkm_common.credential; empty: a load needs "
                       "no credential)", allow_empty=True)
    try:
        credentials = Verifier.from_file(path)
    except ValueError as exc:
        raise ParameterError("credential_file", exc.detail if isinstance(exc, FieldError) else str(exc)) from None
    return SimHwSettings(machine, plant, lockstep, timeout_s, sync_error_limit, gate, publish_markers, duration_s,
                         duration_steps, summary_path, shutdown_on_finish, load_senders, credentials)
