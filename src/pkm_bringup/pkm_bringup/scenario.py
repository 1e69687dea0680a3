"""Scenario files (``config/scenarios/*.yaml``) -> the parameters of every node.

A scenario says what to run; the node parameter files (config/*.yaml) say how each
node runs by default. Keys (all optional but ``machine``)::

    name, description
    machine: archi                    # config/machines/<name>.yaml, or a machine file (a path relative to
                                      # the scenario file, else to the working directory); its `name`
                                      # picks the controller defaults (config/controller/<name>.yaml)
    model: ../machines/archi.calibrated.yaml   # the machine file the controller and the planner use (a
                                      # calibrated one: pkm-calibrate identify), relative to the scenario
                                      # file; the plant and the Gough sensor keep ``machine`` (and the
                                      # plant its errors). Default: the machine. Same kind and legs.
    namespace: /pkm
    mode: lockstep | realtime
    dt_s: 0.001                       # exchange period of the plant and the controller
    program: ../programs/x.nc         # G-code, relative to the scenario file (realtime: optional; the
                                      # planner runs anyway, for an operator's goals and programs)
    duration_s: 0                     # simulated time; 0: the program's duration + settle_s
    settle_s: 0.2
    trajectory: {...}                 # trajectory_node parameters (limits, feed_override, ...)
    controller: {...}                 # controller_node parameters (strategy, distribution, ...)
    metrology: true                   # run gough_sensor_node (the machine needs a metrology section)
    laser_tracker: {sigma_m: 2.0e-6, tool: [0, 0, -0.05]}   # run laser_tracker_node: the true tool point plus
                                      # noise on instrument/laser, for calibration (config/laser_tracker.yaml)
    sensor: {...}                     # gough_sensor_node parameters (noise_std_m, calibration_error_m, ...)
    plant: {...}                      # sim_hw_node parameters (compliance, link_length_errors, faults, ...)
    recorder: {...}                   # recorder_node parameters (compression, flush_period_s, ...;
                                      # config/recorder.yaml)
    load: [{t_s: 0.5, wrench: [fx, fy, mz | fz], ramp_s: 0.05}, ...]   # cutting load, simulated time
                                      # (a 6-DOF machine: [fx, fy, fz, mx, my, mz])
    frame_load: [...]                 # the same on the machine's frame (plant frame_compliance)
    spindle_load: {wrench: [...], ramp_s: 0.05, reference_rpm: 12000}   # instead of load: the load while
                                      # the program's spindle turns (program_plan; lockstep)
    record: true
    timeout_s: 600                    # wall-clock bound of the whole run
    realtime_profile: false           # SCHED_FIFO for the loop's nodes (controller 80, gough_sensor 70,
                                      # sim_hw 60) and their memory locked; recorder and trajectory
                                      # unchanged (pkm_bringup/rt_profile.py). Meant for mode: realtime;
                                      # needs root, or CAP_SYS_NICE and CAP_IPC_LOCK: pkm-run refuses
                                      # (exit 2, nothing started) where the OS does not allow it.
                                      # pkm-run --rt-profile sets it.
    loop_process: separate            # as processes, the loop's nodes (sim_hw, the instruments, the
                                      # controller) each in its own process, or composed: in one, one
                                      # executor, still separate nodes exchanging messages
                                      # (pkm_bringup/composed_loop.py; hardware sim). Default: composed
                                      # with the realtime profile (1 kHz within 2x the machine's
                                      # floor: benchmarks/realtime.py), separate otherwise.
    hardware: sim                     # sim: sim_hw_node; canopen: drives_node on CiA 402 drives; ros2_control:
                                      # a ros2_control system's effort controller (docs/drives.md)
    drives: {...}                     # drives_node parameters (config/drives.yaml), virtual: true (virtual
                                      # drives on this scenario's plant) | false (a real machine's bus),
                                      # drive_faults: "2:over_current:0.5" (the virtual drives')
    operators: [/pkm/my_script]       # nodes (full names) that may command the run beside pkm-run and
                                      # the panel (<namespace>/panel): goals, programs, settings, feed
                                      # override; a command while any other node publishes on its
                                      # topic is refused, and during a motion stops the machine

Every error names the key and what is allowed; nothing is started on a bad scenario:
the parameters each node will get (node defaults < scenario section < the run's wiring)
go through the node's own pure validation when the scenario is loaded
(``ControllerConfig`` and the controller core, ``PlantParameters`` and ``Fault``,
``GoughSensorModel``; the program through the trajectory planner).

Why over 600 lines: it is the one place every scenario key is read and checked against
the node that takes it (the sections, the machine and its model, the program, the
loads, the hardware); the checks of one key would otherwise sit in two files.
"""

from __future__ import annotations

import copy
import functools
import math
import re
from dataclasses import dataclass, field, fields
from pathlib import Path

import yaml

from pkm_bringup.hardware import MACHINE_NODE, check_hardware, controller_wiring, machine_nodes
from pkm_bringup.owner_checks import OWNER_CHECKS
from pkm_common import topics
from pkm_common.credential import KEY_FILE, RunKey, Signer
from pkm_common.poses import MACHINE_KINDS as GRAPH_KINDS
from pkm_controller.configuration import NODE_PARAMETERS
from pkm_controller.config import ControllerConfig
from pkm_controller.strategies import REGISTRY as STRATEGIES
from pkm_kinematics import load_machine
from pkm_kinematics.config import config_dir, machine_names
from pkm_kinematics.errors import FieldError
from pkm_kinematics.yaml_files import YamlFileError, parse_yaml, read_yaml, read_yaml_text
from pkm_bringup.program_plan import plan_program, spindle_load_entries

KEYS = ("name", "description", "machine", "model", "namespace", "mode", "dt_s", "program", "duration_s", "settle_s",
        "trajectory", "controller", "metrology", "sensor", "plant", "recorder", "load", "frame_load", "spindle_load",
        "record", "timeout_s", "realtime_profile", "loop_process", "operators", "hardware", "drives",
        "laser_tracker")
# how the nodes of the loop run as processes (pkm_bringup.composed_loop)
LOOP_PROCESSES = ("separate", "composed")
# scenario section -> node whose parameters it sets
SECTIONS = {"trajectory": "trajectory", "controller": "controller", "sensor": "gough_sensor", "plant": "sim_hw",
            "recorder": "recorder", "drives": "drives", "laser_tracker": "laser_tracker"}
# parameters with a fixed set of values, checked when the scenario is loaded
CHOICES = {("recorder", "compression"): ("lz4", "zstd", "none"), ("recorder", "cpu_priority"): ("normal", "idle")}

# sim_hw defaults sized for one machine (config/sim_hw.yaml: ARCHI's four drives)
PER_DRIVE = ("link_length_errors", "rail_offset_errors_m", "initial_pose", "encoder_offsets_m", "screw_errors_m")


class ScenarioError(ValueError):
    """A scenario key is missing, unknown or out of range; the message names it."""


@dataclass
class Scenario:
    name: str
    machine: str                 # what the nodes load: a name in config/machines, or a file's absolute path
    source: Path
    machine_name: str = ""       # the machine file's `name` (picks the controller defaults)
    model: str = ""              # the controller's and the planner's machine file (absolute), "" = machine
    namespace: str = "/pkm"
    mode: str = "lockstep"
    dt_s: float = 0.001
    program: Path | None = None
    duration_s: float = 0.0
    settle_s: float = 0.2
    trajectory: dict = field(default_factory=dict)
    controller: dict = field(default_factory=dict)
    metrology: bool = False
    sensor: dict = field(default_factory=dict)
    plant: dict = field(default_factory=dict)
    recorder: dict = field(default_factory=dict)
    load: list = field(default_factory=list)      # [(t_s, ramp_s, (a, b, c))]: pkm_sim_hw.loads
    frame_load: list = field(default_factory=list)
    record: bool = True
    timeout_s: float = 600.0
    description: str = ""
    realtime_profile: bool = False
    loop_process: str = "separate"
    operators: list = field(default_factory=list)     # more nodes that may command (full names)
    hardware: str = "sim"
    drives: dict = field(default_factory=dict)
    laser_tracker: dict | None = None     # laser_tracker_node's parameters when it runs

    @property
    def controller_machine(self) -> str:
        """What the controller and the planner load: the ``model`` (a calibrated machine
        file), else the machine."""
        return self.model or self.machine

    @property
    def machine_node(self) -> str:
        """The graph's node of the machine: sim_hw (simulated), drives (CANopen drives) or
        ros2_control (a ros2_control system's effort controller)."""
        return MACHINE_NODE[self.hardware]

    @property
    def virtual_drives(self) -> bool:
        """The machine behind the interface is simulated (virtual_drives_node, or the
        ros2_control stand-in ros2_control_sim_node)."""
        return self.hardware != "sim" and bool(self.drives.get("virtual", True))

    @property
    def ground_truth(self) -> bool:      # a simulated plant publishes platform/true_pose (not a real machine)
        return self.hardware == "sim" or self.virtual_drives

    def section_node(self, key: str) -> str:
        """The node a scenario section parameterises (the plant: sim_hw's, or the virtual drives')."""
        if key == "plant" and self.hardware != "sim":
            return "virtual_drives" if self.hardware == "canopen" else "ros2_control_sim"
        return SECTIONS[key]

    @property
    def strategy(self) -> str:
        """The controller's strategy: the scenario's, else its machine's default."""
        return {**controller_defaults(self.machine_name or self.machine), **self.controller}.get(
            "strategy", ControllerConfig.strategy)

    def topic(self, name: str) -> str:
        """A topic's full name: relative names are taken in the scenario's namespace."""
        return name if name.startswith("/") else f"{self.namespace.rstrip('/')}/{name}"


def _number(data: dict, key: str, default: float, lo: float, hi: float) -> float:
    value = data.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or not lo <= value <= hi:
        raise ScenarioError(f"{key}: must be a number in [{lo:g}, {hi:g}], got {_got(value)}")
    return float(value)


def _got(value) -> str:
    """A refused value as a message shows it. YAML 1.1 (PyYAML) reads a float only with
    a '.' and, with an exponent, its sign: 1e12 and 1.0e12 are strings, 1.0e+12 is a
    float; such a string is called out with what to write instead."""
    if not isinstance(value, str):
        return repr(value)
    try:
        number = float(value)
    except ValueError:
        number = math.nan
    if not math.isfinite(number):
        return f"the string {value!r}"
    if isinstance(yaml.safe_load(value), (int, float)):
        return f"the string {value!r} (quoted: write it without the quotes)"
    hint = f"YAML reads {value.strip()} as a string"
    m = re.fullmatch(r"\s*([-+]?)(\d*)\.?(\d*)[eE]([-+]?)(\d+)\s*", value)
    if m:
        sign, whole, fraction, exponent_sign, exponent = m.groups()
        written = f"{sign}{whole or 0}.{fraction or 0}e{exponent_sign or '+'}{exponent}"
        if yaml.safe_load(written) == number:
            hint += f": write {written}"
    return f"the string {value!r} ({hint})"


def _boolean(data: dict, key: str, default: bool) -> bool:
    value = data.get(key, default)
    if not isinstance(value, bool):
        raise ScenarioError(f"{key}: must be true or false, got {value!r}")
    return value


def _parameter_defaults(node: str) -> dict:
    """Every parameter of ``node`` with its default: config/<node>.yaml, or for the
    controller its dataclass and node parameters (its YAML is per machine). To read
    only: the parsed file itself, not a copy (a study's run asked for them ~40 times)."""
    if node == "controller":
        return {**{f.name: f.default for f in fields(ControllerConfig)}, **NODE_PARAMETERS}
    return _parsed_defaults(node)


def node_parameter_names(node: str) -> set[str]:
    """The parameters a scenario section may set for ``node``."""
    return set(_parameter_defaults(node)) - {"machine", "summary_path"}


def _check_type(key: str, value, default) -> None:
    """``value`` of the type ROS will declare the parameter with: that of its default
    (pkm_common.params.declare_like), an integer being taken for a double. The
    ranges are the owners' (_check_nodes)."""
    if isinstance(default, list):
        if not isinstance(value, list):
            raise ScenarioError(f"{key}: must be a list of finite numbers, got {_got(value)}")
        for k, v in enumerate(value):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ScenarioError(f"{key}: must be a list of finite numbers, at index {k} got {_got(v)}")
        return
    if isinstance(default, bool):
        wanted, ok = "true or false", isinstance(value, bool)
    elif isinstance(default, int):
        wanted, ok = "an integer", isinstance(value, int) and not isinstance(value, bool)
    elif isinstance(default, float):
        wanted, ok = "a number", isinstance(value, (int, float)) and not isinstance(value, bool)
    elif isinstance(default, str):
        wanted, ok = "a string", isinstance(value, str)
    else:
        return
    if not ok:
        raise ScenarioError(f"{key}: must be {wanted}, got {_got(value)}")


def _mapping(data: dict, key: str, node: str) -> dict:
    value = data.get(key) or {}
    if not isinstance(value, dict):
        raise ScenarioError(f"{key}: must be a mapping of {node} parameters, got {value!r}")
    defaults = _parameter_defaults(node)
    allowed = node_parameter_names(node)
    for name, item in value.items():
        if name not in allowed:
            raise ScenarioError(f"{key}.{name}: not a {node} parameter; allowed: {', '.join(sorted(allowed))}")
        _check_type(f"{key}.{name}", item, defaults[name])
        choices = CHOICES.get((key, name))
        if choices is not None and item not in choices:
            raise ScenarioError(f"{key}.{name}: must be one of {list(choices)}, got {item!r}")
    return dict(value)


def _load_profile(value, key: str = "load", size: int = 3) -> list:
    """[(t_s, ramp_s, wrench)] load entries (pkm_sim_hw.loads: an entry with ``ramp_s``
    reaches its wrench linearly from the previous one over that time, a tool entering
    the material; the plant expands them to steps). A wrench has ``size`` components
    (the machine's task space: 3, or 6 on a 6-DOF machine)."""
    if not isinstance(value, list):
        raise ScenarioError(f"{key}: must be a list of {{t_s, wrench: [{size} numbers], ramp_s}}, got {value!r}")
    entries, last_t = [], 0.0
    for i, row in enumerate(value):
        unknown = sorted(set(row) - {"t_s", "wrench", "ramp_s"}) if isinstance(row, dict) else []
        if unknown:
            raise ScenarioError(f"{key}[{i}].{unknown[0]}: unknown key; allowed: t_s, wrench, ramp_s")
        wrench = row.get("wrench") if isinstance(row, dict) else None
        t = row.get("t_s") if isinstance(row, dict) else None
        ramp = row.get("ramp_s", 0.0) if isinstance(row, dict) else None
        if not isinstance(t, (int, float)) or not 0 <= t < 1e6 or not isinstance(wrench, list) or len(wrench) != size \
                or not all(isinstance(w, (int, float)) and math.isfinite(w) for w in wrench) \
                or not isinstance(ramp, (int, float)) or not 0.0 <= ramp <= 10.0:
            raise ScenarioError(f"{key}[{i}]: must be {{t_s: >= 0, wrench: [{size} finite numbers], ramp_s: [0, 10] "
                                f"(optional)}}, got {row!r}")
        if t < last_t - 1e-9:
            raise ScenarioError(f"{key}[{i}]: starts at t_s = {t:g} s, before the previous entry ends "
                                f"({last_t:g} s, ramp included)")
        entries.append((float(t), float(ramp), tuple(float(w) for w in wrench)))
        last_t = float(t) + ramp
    return entries


def read_mapping_file(path: str | Path, folder: str, what: str, error: type) -> tuple[Path, dict]:
    """(its path, its content) of a YAML mapping file given by path, or by name in
    ``config/<folder>``; ``error`` names ``what`` and the file when it cannot be read
    or is not a mapping."""
    path = Path(path)
    if not path.exists() and not path.suffix:
        path = config_dir() / folder / f"{path}.yaml"
    try:
        data = copy.deepcopy(_parsed_text(read_yaml_text(path), str(path))) or {}
    except (OSError, YamlFileError) as exc:       # not UTF-8, invalid, an alias bomb (yaml_files)
        raise error(f"{what} {path}: {exc}") from None
    if not isinstance(data, dict):
        raise error(f"{what} {path}: must be a mapping")
    return path, data


@functools.lru_cache(maxsize=32)
def _parsed_text(text: str, where: str):
    """parse_yaml of a file's text, once per text: a study loads its scenario for
    every run (~0.5 ms of pure-Python YAML each); the caller copies it."""
    return parse_yaml(text, where)


def load_scenario(path: str | Path, overrides: dict | None = None) -> Scenario:
    """Read and validate a scenario; ``overrides`` replace top-level keys (tests, CLI)."""
    path, data = read_mapping_file(path, "scenarios", "scenario", ScenarioError)
    data.update(overrides or {})
    unknown = sorted(set(data) - set(KEYS))
    if unknown:
        raise ScenarioError(f"{unknown[0]}: unknown scenario key; allowed: {', '.join(KEYS)}")
    machine = data.get("machine")
    if isinstance(machine, str) and machine not in machine_names() and not Path(machine).is_absolute() \
            and (path.parent / machine).is_file():       # a file beside the scenario (an as-built machine)
        machine = str((path.parent / machine).resolve())
    try:
        config = load_machine(machine) if isinstance(machine, str) else None
    except (ValueError, FileNotFoundError) as exc:
        raise ScenarioError(f"machine: {exc}") from None
    if config is None:
        raise ScenarioError(f"machine: required, the name of a file in config/machines, got {machine!r}")
    if config.kind not in GRAPH_KINDS:
        raise ScenarioError(f"machine: {config.name} is a {config.kind} machine; the graph (plant, controller, "
                            f"planner) runs {', '.join(GRAPH_KINDS)} machines so far: analyse it with "
                            f"pkm-analyze and pkm_kinematics")
    given_as_file = machine not in machine_names()
    if given_as_file:       # every node loads the same file, whatever its working directory
        machine = str(Path(machine).resolve())
    s = Scenario(name=str(data.get("name", path.stem)), machine=machine, source=path.resolve(),
                 machine_name=config.name, description=str(data.get("description", "")))
    if data.get("model") is not None:
        s.model = _model_file(data["model"], path, config)
    s.namespace = str(data.get("namespace", s.namespace))
    if not re.fullmatch(r"(/[A-Za-z][A-Za-z0-9_]*)+", s.namespace):
        raise ScenarioError(f"namespace: must be an absolute ROS namespace such as '/pkm' (letters, digits, "
                            f"'_'), got {s.namespace!r}")
    if not re.fullmatch(r"[A-Za-z0-9_.-]+", s.name):
        raise ScenarioError(f"name: letters, digits, '_', '-' and '.' only (it names the run directory), "
                            f"got {s.name!r}")
    s.mode = data.get("mode", s.mode)
    if s.mode not in ("lockstep", "realtime"):
        raise ScenarioError(f"mode: must be lockstep or realtime, got {s.mode!r}")
    s.dt_s = _number(data, "dt_s", s.dt_s, 1e-5, 0.1)
    s.duration_s = _number(data, "duration_s", 0.0, 0.0, 1e6)
    s.settle_s = _number(data, "settle_s", s.settle_s, 0.0, 1e3)
    s.timeout_s = _number(data, "timeout_s", s.timeout_s, 1.0, 1e6)
    if data.get("program"):
        program = (path.parent / str(data["program"])).resolve()
        if not program.is_file():
            raise ScenarioError(f"program: no such file {program}")
        s.program = program
    if s.program is None and not s.duration_s:
        raise ScenarioError("duration_s: required (> 0) when there is no program")
    for key, node in SECTIONS.items():
        setattr(s, key, _mapping(data, key, node))
    if s.trajectory.get("tool_table"):         # a tool.tbl beside the programs, relative to the scenario file
        table = (path.parent / str(s.trajectory["tool_table"])).resolve()
        if not table.is_file():
            raise ScenarioError(f"trajectory.tool_table: no such file {table}")
        s.trajectory = {**s.trajectory, "tool_table": str(table)}
    s.metrology = _boolean(data, "metrology", False)
    if "laser_tracker" not in data:         # its node runs only when the scenario has the section
        s.laser_tracker = None
    s.record = _boolean(data, "record", True)
    s.realtime_profile = _boolean(data, "realtime_profile", False)
    operators = data.get("operators") or []
    if not isinstance(operators, list) or not all(
            isinstance(o, str) and re.fullmatch(r"(/[A-Za-z][A-Za-z0-9_]*)+", o) for o in operators):
        raise ScenarioError(f"operators: must be a list of full node names such as '/pkm/my_script', got "
                            f"{operators!r}")
    s.operators = list(operators)
    s.hardware = data.get("hardware", s.hardware)
    if s.laser_tracker is not None and not s.ground_truth:
        raise ScenarioError("laser_tracker: reads the simulated plant's true pose; a real machine's tracker is "
                            "its own instrument")
    try:
        check_hardware(s.hardware, s.drives, s.mode, s.ground_truth,
                       bool(s.metrology or data.get("load") or data.get("spindle_load")), config)
    except FieldError as exc:
        raise ScenarioError(f"{exc.name}: {exc.detail}") from None
    s.loop_process = data.get("loop_process", "composed" if s.realtime_profile and s.hardware == "sim" else "separate")
    if s.loop_process not in LOOP_PROCESSES:
        raise ScenarioError(f"loop_process: must be one of {', '.join(LOOP_PROCESSES)}, got {s.loop_process!r}")
    if s.loop_process == "composed" and s.hardware != "sim":
        raise ScenarioError(f"loop_process: composed runs the simulated machine's loop (hardware: sim), not "
                            f"hardware {s.hardware}: its drive interface's nodes are processes of their own")
    size = len(config.model.task_space.loads)
    s.load = _load_profile(data.get("load") or [], "load", size)
    s.frame_load = _load_profile(data.get("frame_load") or [], "frame_load", size)
    if s.frame_load and not any(s.plant.get("frame_compliance") or []):
        raise ScenarioError("frame_load: needs plant.frame_compliance (one per load component): without it the frame "
                            "does not deflect and the load would do nothing")
    if s.strategy in STRATEGIES and STRATEGIES[s.strategy].uses_metrology and not s.metrology:
        raise ScenarioError(f"metrology: strategy {s.strategy} closes its loop on the Gough sensor; "
                            "set metrology: true")
    if s.metrology and config.metrology is None:
        raise ScenarioError(f"metrology: machine {machine} has no metrology section")
    if s.metrology and given_as_file:
        raise ScenarioError(f"metrology: gough_sensor_node takes the name of a machine in config/machines "
                            f"({', '.join(machine_names())}), not a file: {machine}")
    _check_nodes(s, config)
    spindle = data.get("spindle_load")
    samples = None
    if s.program is not None and (not s.duration_s or spindle is not None):
        try:      # planned as trajectory_node will: a program it would refuse fails here
            samples = plan_program(s.program.read_text(encoding="utf-8"), s.controller_machine,
                                   _typed("trajectory", {**_node_defaults("trajectory"), **s.trajectory}))
        except (ValueError, KeyError) as exc:          # TrajectoryRejected is a ValueError
            raise ScenarioError(f"program: {exc}") from None
    if spindle is not None:      # the plant's load while the program's spindle turns (program_plan)
        if s.mode != "lockstep" or samples is None or data.get("load"):
            raise ScenarioError("spindle_load: needs a lockstep scenario with a program, and replaces load")
        try:
            s.load = _load_profile(spindle_load_entries(samples.events, spindle, size), "spindle_load", size)
        except FieldError as exc:
            raise ScenarioError(str(exc)) from None
    if s.program is not None and not s.duration_s:
        s.duration_s = round(samples.duration_s + s.settle_s, 6)
    return s


def _model_file(value, scenario: Path, config) -> str:
    """The ``model`` key: a machine file (relative to the scenario file, or a name in
    config/machines) of the same kind and legs as the machine; its absolute path."""
    if not isinstance(value, str) or not value:
        raise ScenarioError(f"model: a machine file (the controller's model), got {value!r}")
    path = value if value in machine_names() else str((scenario.parent / value).resolve())
    try:
        model = load_machine(path)
    except (ValueError, FileNotFoundError) as exc:
        raise ScenarioError(f"model: {exc}") from None
    ours, theirs = config.model, model.model
    if model.kind != config.kind or tuple(theirs.leg_names) != tuple(ours.leg_names):
        raise ScenarioError(f"model: {value} is a {model.kind} machine with legs {', '.join(theirs.leg_names)}; "
                            f"it does not match the machine {config.name} ({config.kind}, legs "
                            f"{', '.join(ours.leg_names)})")
    return path


def controller_defaults(machine_name: str) -> dict:
    """controller_node's parameters for the machine named ``machine_name``
    (config/controller/<name>.yaml); empty for a machine without a file there (the
    node then runs on ControllerConfig's defaults)."""
    if not re.fullmatch(r"[\w.-]+", machine_name) or machine_name.startswith(".") \
            or not (config_dir() / "controller" / f"{machine_name}.yaml").is_file():
        return {}                  # (a name, not a path: an as-built machine's file has none)
    return _node_defaults(f"controller/{machine_name}")


def _check_nodes(s: Scenario, config) -> None:
    """Refuse what a node would refuse once started: the parameters each node gets
    (node_parameters; the run directory aside) through its owner's validation, then
    the scenario's non-finite doubles (pkm_common.params declares finite ones; after
    the owners, so that a NaN is told the owner's range where there is one)."""
    params = node_parameters(s, Path("run"))
    for key, check in OWNER_CHECKS.items():
        node = s.section_node(key)
        if node not in params or (key == "drives" and s.hardware != "canopen"):
            continue
        try:
            check(params[node], config)
        except ValueError as exc:
            raise _owner_refusal(s, key, exc) from None
    for key in SECTIONS:
        floats = _float_parameters(s.section_node(key))
        for name, value in (getattr(s, key) or {}).items():
            if name in floats and not math.isfinite(value):
                raise ScenarioError(f"{key}.{name}: must be a finite number, got {value!r}")


def _owner_refusal(s: Scenario, key: str, exc: ValueError) -> ScenarioError:
    """An owner's refusal (a FieldError naming the parameter; any other ValueError names
    none) as a ScenarioError naming the scenario key; a value the scenario did not set
    is said to be the node's default."""
    message = str(exc)
    name, rest = (exc.name, exc.detail) if isinstance(exc, FieldError) else ("", message)
    if name in KEYS and name not in getattr(s, key):
        # a top-level key of the scenario the run wires into the node (machine, load, dt_s)
        return ScenarioError(f"{name}: {rest}")
    if name not in node_parameter_names(SECTIONS[key]):
        return ScenarioError(f"{key}: {message}")            # a message naming no parameter
    if name not in getattr(s, key):
        source = f"config/{SECTIONS[key]}.yaml"
        if key == "controller":
            source = f"config/controller/{s.machine_name}.yaml" if name in controller_defaults(s.machine_name) \
                else "ControllerConfig"
        rest += f" (not set by the scenario: the default of {source})"
    return ScenarioError(f"{key}.{name}: {rest}")


@functools.lru_cache(maxsize=16)
def _machine(machine: str):
    """The scenario's machine file, loaded once (node_parameters runs at load and at start)."""
    return load_machine(machine)


def _node_defaults(name: str) -> dict:
    """The ros__parameters of config/<name>.yaml (empty if there is none); a copy the
    caller may change."""
    return copy.deepcopy(_parsed_defaults(name))


def _parsed_defaults(name: str) -> dict:
    """The same, not copied: to read only."""
    path = config_dir() / f"{name}.yaml"
    return _ros_parameters(str(path), path.stat().st_mtime_ns) if path.is_file() else {}


@functools.lru_cache(maxsize=64)
def _ros_parameters(path: str, mtime_ns: int) -> dict:
    """A node's YAML parsed once per version of the file (``mtime_ns`` in the key):
    loading one scenario asked for them ~20 times, 0.3 s of pure-Python YAML each time."""
    data = read_yaml(path) or {}
    return dict(data.get("/**", {}).get("ros__parameters", {}))


def _float_parameters(node: str) -> set[str]:
    """The parameters ROS declares as doubles: float defaults (config/<node>.yaml, the
    controller's dataclass and node parameters)."""
    return {k for k, v in _parameter_defaults(node).items() if isinstance(v, float)}


def _typed(node: str, params: dict) -> dict:
    """Floats where ROS declares doubles; empty lists and strings dropped (node defaults)."""
    out = {}
    floats = _float_parameters(node)
    for key, value in params.items():
        if value == [] or value == "":
            continue
        if key in floats and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if isinstance(value, list):
            value = [float(v) for v in value]
        out[key] = value
    return out


def controller_node_name(s: Scenario) -> str:
    """The full name of the run's controller: the one node sim_hw takes commands from."""
    return run_node_name(s, "controller")


def run_node_name(s: Scenario, node: str) -> str:
    """The full name of one of the run's nodes (the one source of what it publishes)."""
    return f"{s.namespace.rstrip('/')}/{node}"


def laser_tracker_parameters(s: Scenario) -> dict | None:
    """What the run's laser tracker reads (its node's parameters: config/laser_tracker.yaml
    and the scenario's section), or None without one; run.json keeps them, so that
    pkm-calibrate identify takes the tool point the tracker read."""
    return None if s.laser_tracker is None else {**_node_defaults("laser_tracker"), **s.laser_tracker}


def operator_names(s: Scenario) -> list[str]:
    """The nodes that may command the run (pkm_common.sources.AllowedSenders): pkm-run's
    own (the start, an interrupt's E-stop), the panel's, and the scenario's
    ``operators``."""
    return [run_node_name(s, "bringup_monitor"), run_node_name(s, "panel"), *s.operators]


def node_parameters(s: Scenario, run_dir: Path, credential: Path | None = None) -> dict[str, dict]:
    """node name -> its parameters for this run (node defaults < scenario < run wiring);
    ``credential``: the run's key file (pkm_common.credential; default the run
    directory's)."""
    summaries = run_dir / "summaries"
    key = str(credential or run_dir / KEY_FILE)
    flat_load = [v for t, ramp, w in s.load for v in (t, ramp, *w)]
    flat_frame_load = [v for t, ramp, w in s.frame_load for v in (t, ramp, *w)]
    plant = {**{k: v for k, v in _node_defaults("sim_hw").items() if k not in PER_DRIVE}, **s.plant,
             "machine": s.machine, "dt_s": s.dt_s, "load_profile": flat_load, "frame_load_profile": flat_frame_load}
    loop = {"machine": s.machine, "mode": s.mode, "dt_s": s.dt_s, "duration_s": s.duration_s,
            "command_source": controller_node_name(s), "load_sources": ",".join(operator_names(s)),
            "credential_file": key, "summary_path": str(summaries / f"{s.machine_node}.json")}
    nodes = machine_nodes(s, plant, loop, _node_defaults("drives"), run_dir)
    nodes.update({
        "controller": {**controller_defaults(s.machine_name or s.machine), **controller_wiring(s, _machine(s.machine)),
                       **s.controller, "machine": s.controller_machine,
                       "dt_s": s.dt_s, "end_time_s": s.duration_s, "autostart": True,
                       # the loop starts at pkm-run's start signal, once the graph is connected and
                       # the recorder ready; with a program, when the trajectory is there too
                       "wait_for_trajectory": s.program is not None,
                       "wait_for_start": True,
                       "state_source": run_node_name(s, s.machine_node),
                       "trajectory_source": run_node_name(s, "trajectory"),
                       "operator_sources": ",".join(operator_names(s)), "credential_file": key,
                       "metrology_source": run_node_name(s, "gough_sensor") if s.metrology else "",
                       "summary_path": str(summaries / "controller.json")},
    })
    if s.metrology:
        nodes["gough_sensor"] = {**_node_defaults("gough_sensor"), **s.sensor, "machine": s.machine,
                                 "summary_path": str(summaries / "gough_sensor.json")}
    if s.laser_tracker is not None:
        nodes["laser_tracker"] = {**laser_tracker_parameters(s), "summary_path": str(summaries / "laser_tracker.json")}
    if s.program is not None or s.mode == "realtime":     # realtime: goals and programs from an operator too
        nodes["trajectory"] = {**_node_defaults("trajectory"), **s.trajectory, "machine": s.controller_machine,
                               "program_file": str(s.program or ""),
                               "operator_sources": ",".join(operator_names(s)), "credential_file": key,
                               "controller_source": controller_node_name(s), "wait_for_start": True}
    if s.record:
        # the loop's nodes hand their per-step streams to the recorder in batches
        # (pkm_recording.tap) instead of a delivery per message to one more process
        tapped = []
        for node in (n for n in TAPPED_STREAMS if n in nodes):
            nodes[node]["tap"] = True
            tapped += TAPPED_STREAMS[node]
        nodes["recorder"] = {**_node_defaults("recorder"), **s.recorder,   # cpu_priority idle: its own process
                             "tap_sources": ",".join(run_node_name(s, n) for n in TAPPED_STREAMS if n in nodes),
                             "output": str(run_dir / "bag"), "ready_file": str(run_dir / "recorder.ready"),
                             "expect_topics": ",".join(expected_topics(s)), "tapped_topics": ",".join(tapped),
                             "summary_path": str(summaries / "recorder.json")}
    return {name: _typed(name, params) for name, params in nodes.items()}


# node -> the per-step streams it publishes through its recording tap when recorded
TAPPED_STREAMS = {"sim_hw": ("drives/state", "platform/true_pose", "/clock"), "drives": ("drives/state", "/clock"),
                  "ros2_control": ("drives/state", "/clock"),
                  "gough_sensor": ("metrology/struts", "metrology/pose"), "laser_tracker": ("instrument/laser",),
                  "controller": ("drives/command", "controller/reference")}

START_TOPIC = topics.RUN_START    # latched String "start" with its credential: the orchestrator's start signal
                               # (every run: the controller and a run's planner wait for it)


def start_signal(credential: Path, sender: str) -> bytes:
    """The start signal, serialized: the String "start" with the run's credential of
    ``sender`` (pkm_common.credential)."""
    return Signer(RunKey.read(credential), sender).text(START_TOPIC, "start")


def expected_topics(s: Scenario) -> list[str]:
    """The streams that must be connected before a run starts (relative names)."""
    topics = ["drives/state", "drives/command", "controller/reference", "controller/status", "/clock"]
    if s.ground_truth:
        topics.append("platform/true_pose")
    if s.hardware == "canopen":
        topics.append("drives/cia402")
    if s.metrology:
        topics += ["metrology/struts", "metrology/pose"]
    if s.laser_tracker is not None:
        topics.append("instrument/laser")
    return topics


# libyaml's emitter where PyYAML has it: the same text as PyYAML's own (every node's
# file of every shipped scenario compared), ~4x faster (a study's run writes four)
_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)


def params_file_text(params: dict) -> str:
    """A ROS 2 ``--params-file`` for one node."""
    return yaml.dump({"/**": {"ros__parameters": params}}, Dumper=_DUMPER, sort_keys=False)
