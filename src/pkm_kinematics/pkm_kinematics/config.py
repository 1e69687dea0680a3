"""Machine configurations: ``config/machines/<name>.yaml`` -> model objects.

Every field is validated when the file is loaded; a missing, mistyped or out-of-range
field raises ConfigError naming its dotted path and the allowed range, e.g.
``archi.yaml: legs[2].link_length: must be > 0 m, got -1.0``.
"""

from __future__ import annotations

import collections
import functools
import hashlib
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .errors import ConfigError, JointLimitError, KinematicsError, UnreachablePoseError
from .dynamics import DynamicsParameters
from .gough import GoughPlatform, mom3_points
from .struts import StrutMachine
from .parallelogram import ParallelogramMachine
from .rails import FORWARD_SOLVERS, RailLeg, RailMachine
from .rigid_body import RigidBodyParameters
from .rotations import rotation_from_rpy
from .task_space import PLANAR, POSITION
from .yaml_files import UnreadableFileError, YamlFileError, read_yaml

MACHINE_KINDS = ("planar", "translational", "struts", "parallelograms")
LENGTH_UNITS = {"m": 1.0, "mm": 1e-3, "inch": 0.0254}


def config_dir() -> Path:
    """The project's ``config/`` directory.

    ``PKM_CONFIG_DIR`` wins; else the first ``config/machines`` found walking up from
    this file (a source checkout, an editable install, or a colcon workspace built
    inside the repository).
    """
    env = os.environ.get("PKM_CONFIG_DIR")
    if env:
        return Path(env)
    return _found_config_dir()


@functools.lru_cache(maxsize=1)
def _found_config_dir() -> Path:
    """The walk of ``config_dir`` (the files do not move while a process runs; a
    scenario's loading asks ~50 times)."""
    here = Path(__file__).resolve()
    for parent in here.parents:
        if (parent / "config" / "machines").is_dir():
            return parent / "config"
    raise FileNotFoundError("config directory not found: set PKM_CONFIG_DIR")


_NAMES: dict = {}           # machines directory -> (its mtime_ns, the names in it)


def machine_names() -> list[str]:
    """The machines of ``config/machines`` (listed again when a file is added or removed)."""
    folder = config_dir() / "machines"
    mtime = folder.stat().st_mtime_ns
    found = _NAMES.get(folder)
    if found is None or found[0] != mtime:
        found = _NAMES[folder] = (mtime, sorted(p.stem for p in folder.glob("*.yaml")))
    return list(found[1])


# --------------------------------------------------------------------- readers
class FieldReader:
    """Typed access to a YAML mapping with dotted-path error messages (ConfigError naming
    the field); public so that a package owning a section of the machine file (pkm_drives:
    ``drives``) reads it the same way."""

    def __init__(self, data: Any, path: str):
        if not isinstance(data, dict):
            raise ConfigError(path or "<root>", f"expected a mapping, got {type(data).__name__}")
        self.data = data
        self.path = path

    def field_name(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def has(self, key: str) -> bool:
        return key in self.data

    def sub(self, key: str) -> "FieldReader":
        if key not in self.data:
            raise ConfigError(self.field_name(key), "missing section")
        return FieldReader(self.data[key], self.field_name(key))

    def raw(self, key: str, default: Any = ...) -> Any:
        if key not in self.data:
            if default is ...:
                raise ConfigError(self.field_name(key), "missing field")
            return default
        return self.data[key]

    def number(self, key: str, default: Any = ..., lo: float = -math.inf, hi: float = math.inf,
               lo_open: bool = False, unit: str = "") -> float:
        value = self.raw(key, default)
        name = self.field_name(key)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(name, f"expected a number{' in ' + unit if unit else ''}, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise ConfigError(name, f"must be finite, got {value}")
        if (value <= lo if lo_open else value < lo) or value > hi:
            left = "(" if lo_open else "["
            raise ConfigError(name, f"must be in {left}{lo:g}, {hi:g}] {unit}, got {value:g}".replace("  ", " "))
        return value

    def vector(self, key: str, size: int, default: Any = ..., unit: str = "") -> np.ndarray:
        value = self.raw(key, default)
        name = self.field_name(key)
        if not isinstance(value, (list, tuple)) or len(value) != size:
            raise ConfigError(name, f"expected a list of {size} numbers{' (' + unit + ')' if unit else ''}, got {value!r}")
        out = []
        for k, v in enumerate(value):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(float(v)):
                raise ConfigError(f"{name}[{k}]", f"expected a finite number, got {v!r}")
            out.append(float(v))
        return np.array(out)

    def interval(self, key: str, default: Any = ..., unit: str = "") -> tuple[float, float]:
        lo, hi = self.vector(key, 2, default, unit)
        if not lo < hi:
            raise ConfigError(self.field_name(key), f"expected [min, max] with min < max, got [{lo:g}, {hi:g}]")
        return float(lo), float(hi)

    def choice(self, key: str, options: tuple, default: Any = ...) -> Any:
        value = self.raw(key, default)
        if value not in options:
            raise ConfigError(self.field_name(key), f"must be one of {list(options)}, got {value!r}")
        return value

    def string(self, key: str, default: Any = ...) -> str:
        value = self.raw(key, default)
        if not isinstance(value, str) or not value:
            raise ConfigError(self.field_name(key), f"expected a non-empty string, got {value!r}")
        return value

    def items(self, key: str, min_len: int = 1) -> list["FieldReader"]:
        value = self.raw(key)
        name = self.field_name(key)
        if not isinstance(value, list) or len(value) < min_len:
            raise ConfigError(name, f"expected a list of at least {min_len} entries, got {value!r}")
        return [FieldReader(v, f"{name}[{k}]") for k, v in enumerate(value)]


def _assembly(r: FieldReader) -> int:
    value = r.raw("assembly")
    if value not in (-1, 1) or isinstance(value, bool):
        raise ConfigError(r.field_name("assembly"), f"must be -1 or +1 (assembly branch), got {value!r}")
    return int(value)


# -------------------------------------------------------------------- builders
@dataclass(frozen=True)
class MachineConfig:
    """A loaded machine file: the actuated model, the metrology (if any), raw data.
    Read-only (``load_machine`` hands the same one to every loader of an unchanged
    file): a changed machine is a new one (``dataclasses.replace``)."""

    name: str
    kind: str
    model: RailMachine | StrutMachine | ParallelogramMachine
    metrology: "GoughMetrologyConfig | None"
    data: dict
    dynamics: "DynamicsParameters | RigidBodyParameters | None" = None

    @property
    def model_label(self) -> str:
        """Which model this is, for reports and the panel: the machine's name, and the
        calibration a calibrated file carries (its ``calibration.label``)."""
        calibration = self.data.get("calibration")
        label = calibration.get("label") if isinstance(calibration, dict) else None
        return f"{self.name} (calibrated: {label})" if label else f"{self.name} (nominal)"


@dataclass
class GoughMetrologyConfig:
    """A Gough metrology platform with its sensing parameters (MoM3 §4.3, §5)."""

    platform: GoughPlatform
    encoder_resolution_m: float
    tool_box: np.ndarray            # (3, 2): [L_x, L_y, L_z] bounds, plate frame (MoM3 eq. 4, Fig. 12)
    workspace_center: np.ndarray    # plate-centre workspace cube, Gough base frame
    workspace_size_m: float
    # mounting (REP-103 frames): the Gough base in the machine's world frame, and the
    # Gough plate in the tool frame of the machine (planar machines: tool = (x, y, 0),
    # yaw theta; translational: tool = p, identity orientation)
    base_position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    base_rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    plate_position_in_tool: np.ndarray = field(default_factory=lambda: np.zeros(3))
    plate_rotation_in_tool: np.ndarray = field(default_factory=lambda: np.eye(3))
    # the MoM3 §5.2 parameters the joints were made from (design sweeps vary them)
    geometry: dict = field(default_factory=dict)

    def design_parameters(self) -> tuple[float, float, float, float]:
        """(r_b m, r_tp m, alpha_b deg, alpha_tp deg), design.GOUGH_PARAMETERS' order."""
        g = self.geometry
        return g["r_base"], g["r_plate"], g["alpha_base_deg"], g["alpha_plate_deg"]


def _legs(r: FieldReader, dim: int, attachment: str) -> list[RailLeg]:
    """The ``legs`` list: prismatic rail + link to a platform attachment point, in
    ``dim`` dimensions (``attachment`` is platform_point or platform_offset)."""
    legs = []
    for lr in r.items("legs", min_len=3):
        direction = lr.vector("rail_direction", dim)
        if np.linalg.norm(direction) < 1e-9:
            raise ConfigError(lr.field_name("rail_direction"), "must be a non-zero vector")
        legs.append(RailLeg(
            lr.string("name"), tuple(lr.vector("rail_origin", dim, unit="m")), tuple(direction),
            lr.number("link_length", lo=0.0, lo_open=True, unit="m"),
            tuple(lr.vector(attachment, dim, unit="m")), _assembly(lr), lr.interval("joint_limits", unit="m")))
    names = [leg.name for leg in legs]
    if len(set(names)) != len(names):           # the drives' names: the messages' joint names
        raise ConfigError(r.field_name("legs"), f"leg names must be unique, got {names}")
    return legs


def _planar(r: FieldReader, name: str, description: str) -> RailMachine:
    legs = _legs(r, 2, "platform_point")
    home = r.vector("home_pose", 3, unit="x m, y m, theta rad")
    workspace = _workspace(r, planar=True)
    solver = _forward_solver(r, "least_squares")
    try:
        model = RailMachine(name, legs, home, PLANAR, solver, workspace, description)
        model.inverse_kinematics(home)          # reachable and inside the joint limits
    except (UnreachablePoseError, JointLimitError) as exc:
        raise ConfigError(r.field_name("home_pose"), str(exc)) from None
    except ValueError as exc:                   # a solver for another task space
        raise ConfigError(r.field_name("forward_solver"), str(exc)) from None
    return model


def _forward_solver(r: FieldReader, default: str) -> str:
    """``forward_solver``: a rail machine's forward kinematics, a key of
    ``rails.FORWARD_SOLVERS`` (default: its kind's)."""
    return r.choice("forward_solver", tuple(sorted(FORWARD_SOLVERS)), default)


def _workspace(r: FieldReader, planar: bool) -> dict:
    if not r.has("workspace"):
        raise ConfigError(r.field_name("workspace"), "missing section")
    w = r.sub("workspace")
    if planar:
        return {"x": w.interval("x", unit="m"), "y": w.interval("y", unit="m"),
                "theta_deg": w.interval("theta_deg", unit="deg")}
    return {"center": w.vector("center", 3, unit="m"),
            "size": w.number("size", lo=0.0, lo_open=True, unit="m")}


def _translational(r: FieldReader, name: str, description: str) -> RailMachine:
    legs = _legs(r, 3, "platform_offset")
    if len(legs) != 3:
        raise ConfigError(r.field_name("legs"), f"a translational machine has exactly 3 legs, got {len(legs)}")
    bounds = None
    if r.has("transmission_bounds"):
        lo, hi = r.interval("transmission_bounds")
        if lo <= 0.0:
            raise ConfigError(r.field_name("transmission_bounds"), f"must be > 0, got [{lo:g}, {hi:g}]")
        bounds = (lo, hi)
    home = r.vector("home_position", 3, unit="m")
    workspace = _workspace(r, planar=False)
    margin = r.number("parallel_margin", 0.0, lo=0.0, hi=0.99)     # |det| of the unit leg directions
    solver = _forward_solver(r, "three_spheres")
    try:
        model = RailMachine(name, legs, home, POSITION, solver, workspace, description, bounds, margin)
        model.inverse_kinematics(home)
    except (UnreachablePoseError, JointLimitError) as exc:
        raise ConfigError(r.field_name("home_position"), str(exc)) from None
    except ValueError as exc:
        raise ConfigError(r.field_name("forward_solver"), str(exc)) from None
    try:
        model.check_parallel_singularity(home)
    except KinematicsError as exc:
        raise ConfigError(r.field_name("home_position"), str(exc)) from None
    return model


def _struts(r: FieldReader, name: str, description: str) -> StrutMachine:
    """A machine on actuated struts (the hexapods): ``struts`` (at least 6, each with
    its base and platform joint and its length limits), ``home`` (position and the
    A, B, C rotations in degrees), ``workspace`` (a box about a centre, half-ranges of
    the rotations); every length in ``length_unit`` (m, mm or inch, converted to m)."""
    unit_name = r.choice("length_unit", tuple(LENGTH_UNITS), "m")
    scale = LENGTH_UNITS[unit_name]
    names, base, platform, limits = [], [], [], []
    for sr in r.items("struts", min_len=6):
        names.append(sr.string("name"))
        base.append(sr.vector("base", 3, unit=unit_name) * scale)
        platform.append(sr.vector("platform", 3, unit=unit_name) * scale)
        lo, hi = sr.interval("limits", unit=unit_name)
        if lo <= 0.0:
            raise ConfigError(sr.field_name("limits"), f"strut lengths must be > 0, got [{lo:g}, {hi:g}] {unit_name}")
        limits.append((lo * scale, hi * scale))
    if len(set(names)) != len(names):
        raise ConfigError(r.field_name("struts"), f"strut names must be unique, got {names}")
    h, w = r.sub("home"), r.sub("workspace")
    home = np.concatenate((h.vector("position", 3, unit=unit_name) * scale,
                           np.radians(h.vector("abc_deg", 3, [0.0, 0.0, 0.0], unit="deg"))))
    half = w.vector("half_size", 3, unit=unit_name) * scale
    if not (half > 0.0).all():
        raise ConfigError(w.field_name("half_size"), f"must be > 0 on every axis, got {half / scale}")
    abc = w.vector("abc_half_range_deg", 3, [0.0, 0.0, 0.0], unit="deg")
    if not ((abc >= 0.0) & (abc < 90.0)).all():
        raise ConfigError(w.field_name("abc_half_range_deg"), f"must be in [0, 90) deg, got {abc}")
    workspace = {"center": w.vector("center", 3, unit=unit_name) * scale, "half_size": half,
                 "abc_half_range_deg": abc}
    model = StrutMachine(name, names, base, platform, limits, home, workspace, description)
    try:
        model.inverse_kinematics(home)
        cond = model.condition_number(home)
    except KinematicsError as exc:
        raise ConfigError(r.field_name("home"), str(exc)) from None
    if not cond < 1e6:
        raise ConfigError(r.field_name("struts"), f"the struts do not hold the platform at home: J_m is singular "
                                             f"(condition number {cond:.3g})")
    return model


def _parallelograms(r: FieldReader, name: str, description: str) -> ParallelogramMachine:
    """A Delta whose legs are parallelograms of two bars each (``parallelogram.py``):
    the translational machine's ``legs``, and ``parallelogram``: its ``half_width``
    (m) and each bar's length error (``bar_length_errors``, m, two per leg: MoM3
    §4.1's imperfect case; zeros make a translating platform)."""
    legs = _legs(r, 3, "platform_offset")
    if len(legs) != 3:
        raise ConfigError(r.field_name("legs"), f"a parallelogram Delta has exactly 3 legs, got {len(legs)}")
    pr = r.sub("parallelogram")
    half_width = pr.number("half_width", lo=0.0, lo_open=True, unit="m")
    errors = pr.raw("bar_length_errors", [[0.0, 0.0]] * 3)
    if not isinstance(errors, list) or len(errors) != 3:
        raise ConfigError(pr.field_name("bar_length_errors"), f"expected 3 pairs (two bars per leg), got {errors!r}")
    pairs = [FieldReader({"pair": e}, pr.field_name(f"bar_length_errors[{i}]")).vector("pair", 2, unit="m")
             for i, e in enumerate(errors)]
    for i, (pair, leg) in enumerate(zip(pairs, legs)):
        if not (np.abs(pair) < 0.1 * leg.link_length).all():
            raise ConfigError(pr.field_name(f"bar_length_errors[{i}]"),
                              f"must be below a tenth of the link length ({0.1 * leg.link_length:g} m), got {pair}")
    home = r.vector("home_position", 3, unit="m")
    try:
        model = ParallelogramMachine(name, legs, half_width, pairs, home, _workspace(r, planar=False), description)
        model.inverse_kinematics(home)
    except KinematicsError as exc:
        raise ConfigError(r.field_name("home_position"), str(exc)) from None
    return model


MAX_JOINT_OFFSET_M = 0.01     # a calibration's correction of a Gough joint centre, at most


def _joint_rows(r: FieldReader, key: str) -> np.ndarray:
    """Six (x, y, z) offsets of the Gough's joint centres (m), each within MAX_JOINT_OFFSET_M."""
    rows = r.raw(key)
    if not isinstance(rows, list) or len(rows) != 6:
        raise ConfigError(r.field_name(key), f"expected 6 offsets [x, y, z] (m), one per strut, got {rows!r}")
    out = np.array([FieldReader({f"{key}[{k}]": row}, r.path).vector(f"{key}[{k}]", 3, unit="m")
                    for k, row in enumerate(rows)])
    if np.abs(out).max() > MAX_JOINT_OFFSET_M:
        k = int(np.argmax(np.abs(out).max(axis=1)))
        raise ConfigError(r.field_name(f"{key}[{k}]"), f"offsets must be within {MAX_JOINT_OFFSET_M:g} m, got "
                                                       f"{out[k].tolist()}")
    return out


def _gough(r: FieldReader) -> GoughMetrologyConfig:
    g = r.sub("geometry")
    geometry = {"r_base": g.number("r_base", lo=0.0, lo_open=True, unit="m"),
                "r_plate": g.number("r_plate", lo=0.0, lo_open=True, unit="m"),
                "alpha_base_deg": g.number("alpha_base_deg", lo=0.0, lo_open=True, hi=120.0, unit="deg"),
                "alpha_plate_deg": g.number("alpha_plate_deg", lo=0.0, lo_open=True, hi=120.0, unit="deg"),
                "plate_line_offset_deg": g.number("plate_line_offset_deg", default=60.0, lo=-180.0, hi=180.0,
                                                  unit="deg")}
    base, plate = mom3_points(geometry["r_base"], geometry["r_plate"], math.radians(geometry["alpha_base_deg"]),
                              math.radians(geometry["alpha_plate_deg"]),
                              math.radians(geometry["plate_line_offset_deg"]))
    if g.has("joint_offsets"):      # a calibration's (pkm-calibrate --instrument gough-struts): m, the Gough's frames
        offsets = g.sub("joint_offsets")
        base = base + _joint_rows(offsets, "base")
        plate = plate + _joint_rows(offsets, "plate")
    limits = r.interval("strut_limits", unit="m")
    if limits[0] <= 0.0:
        raise ConfigError(r.field_name("strut_limits"), f"min must be > 0 m, got {limits[0]:g}")
    home = r.vector("home_position", 3, unit="m")
    if home[2] <= 0.0:
        raise ConfigError(r.field_name("home_position"), f"z must be > 0 m (plate above the base), got {home[2]:g}")
    box = r.sub("tool_box")
    tool_box = np.array([box.interval("x", unit="m"), box.interval("y", unit="m"), box.interval("z", unit="m")])
    platform = GoughPlatform(base, plate, limits, home, name="gough")
    home_struts = platform.strut_lengths(home, np.eye(3))
    if not platform.within_strut_limits(home_struts):
        raise ConfigError(r.field_name("home_position"),
                          f"strut lengths at home {np.round(home_struts, 4).tolist()} m leave strut_limits "
                          f"[{limits[0]:g}, {limits[1]:g}] m")
    w = r.sub("workspace")
    mount = {}
    if r.has("mount"):
        m = r.sub("mount")
        mount = {
            "base_position": m.vector("base_position", 3, default=[0.0, 0.0, 0.0], unit="m"),
            "base_rotation": rotation_from_rpy(*np.radians(m.vector("base_rpy_deg", 3, default=[0.0, 0.0, 0.0]))),
            "plate_position_in_tool": m.vector("plate_position_in_tool", 3, default=[0.0, 0.0, 0.0], unit="m"),
            "plate_rotation_in_tool": rotation_from_rpy(
                *np.radians(m.vector("plate_rpy_in_tool_deg", 3, default=[0.0, 0.0, 0.0]))),
        }
    return GoughMetrologyConfig(
        **mount,
        platform=platform,
        encoder_resolution_m=r.number("encoder_resolution", lo=0.0, lo_open=True, hi=1e-3, unit="m"),
        tool_box=tool_box,
        workspace_center=w.vector("center", 3, unit="m"),
        workspace_size_m=w.number("size", lo=0.0, lo_open=True, unit="m"),
        geometry=geometry,
    )


def load_machine_data(data: dict, source: str = "<dict>") -> MachineConfig:
    """Build a MachineConfig from an already-parsed mapping (``source`` names it in errors)."""
    try:
        r = FieldReader(data, "")
        name = r.string("name")
        kind = r.choice("kind", MACHINE_KINDS)
        description = str(r.raw("description", ""))
        model = {"planar": _planar, "translational": _translational, "struts": _struts,
                 "parallelograms": _parallelograms}[kind](r, name, description)
        metrology = _gough(r.sub("metrology")) if r.has("metrology") else None
        dynamics = (DYNAMICS.get(kind, _dynamics)(r.sub("dynamics"), model.n_legs, kind)
                    if r.has("dynamics") else None)
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc.field}", exc.detail) from None
    return MachineConfig(name, kind, model, metrology, data, dynamics)


def _per_drive(r: FieldReader, key: str, n_legs: int, lo_open: bool) -> list:
    """A value per drive, or one number for all of them (>= 0; > 0 with ``lo_open``)."""
    value = r.raw(key)
    if isinstance(value, list):
        if len(value) != n_legs:
            raise ConfigError(r.field_name(key), f"expected one number or a list of {n_legs}, got {value!r}")
        return [FieldReader({key: v}, r.path).number(key, lo=0.0, lo_open=lo_open) for v in value]
    return [r.number(key, lo=0.0, lo_open=lo_open)] * n_legs


def _rigid_body(r: FieldReader, n_legs: int, kind: str) -> RigidBodyParameters:
    """A strut machine's platform in SE(3) and its drives (rigid_body.py): the inertia
    about the platform point as its diagonal in the platform's frame."""
    inertia = r.vector("platform_inertia_kgm2", 3, unit="kg m^2 (Ixx, Iyy, Izz)")
    if not (inertia > 0.0).all():
        raise ConfigError(r.field_name("platform_inertia_kgm2"), f"must be 3 positive numbers, got {inertia.tolist()}")
    return RigidBodyParameters(
        platform_mass_kg=r.number("platform_mass_kg", lo=0.0, lo_open=True, unit="kg"),
        platform_inertia_kgm2=tuple(np.diag(inertia).ravel().tolist()),
        drive_mass_kg=tuple(_per_drive(r, "drive_mass_kg", n_legs, True)),
        friction_ns_per_m=tuple(_per_drive(r, "friction_ns_per_m", n_legs, False)),
        gravity_m_s2=tuple(r.vector("gravity_m_s2", 3, unit="m/s^2").tolist()))


def _dynamics(r: FieldReader, n_legs: int, kind: str) -> DynamicsParameters:
    """ARCHI §3.4 parameters; per-drive values may be one number for all drives."""
    planar = kind == "planar"
    return DynamicsParameters(
        drive_mass_kg=tuple(_per_drive(r, "drive_mass_kg", n_legs, True)),
        platform_mass_kg=r.number("platform_mass_kg", lo=0.0, lo_open=True, unit="kg"),
        platform_inertia_kgm2=(r.number("platform_inertia_kgm2", lo=0.0, lo_open=True, unit="kg m^2")
                               if planar else math.nan),
        friction_ns_per_m=tuple(_per_drive(r, "friction_ns_per_m", n_legs, False)),
        gravity_m_s2=tuple(r.vector("gravity_m_s2", 2 if planar else 3, unit="m/s^2")),
    )


# how a kind's 'dynamics' section is read (the others: _dynamics, ARCHI §3.4's form)
DYNAMICS = {"struts": _rigid_body}


_MACHINES: collections.OrderedDict = collections.OrderedDict()    # (path, SHA-1 of the file) -> MachineConfig
MACHINES_KEPT = 32


def load_machine(name_or_path: str | os.PathLike) -> MachineConfig:
    """Load ``config/machines/<name>.yaml`` (or a path to a YAML file). A file loaded
    before and unchanged since (the same bytes) gives the same
    MachineConfig (a run's loops each load its machine, a study loads it for every
    run): a MachineConfig and its model are read-only (a changed machine is a new
    one: ``with_legs``, ``dataclasses.replace``)."""
    path = Path(name_or_path)
    if path.suffix not in (".yaml", ".yml"):
        path = config_dir() / "machines" / f"{name_or_path}.yaml"
        if not path.is_file():
            raise ConfigError("machine", f"unknown machine {str(name_or_path)!r}; "
                              f"known: {', '.join(machine_names())}")
    try:
        key = (str(path.resolve()), hashlib.sha1(path.read_bytes()).digest())    # its contents, not its mtime
    except OSError:
        key = None                                # read_yaml names what is wrong
    else:
        found = _MACHINES.get(key)
        if found is not None:
            _MACHINES.move_to_end(key)
            return found
    config = _load_machine_file(path)
    if key is not None:
        _MACHINES[key] = config
        while len(_MACHINES) > MACHINES_KEPT:
            _MACHINES.popitem(last=False)
    return config


def _load_machine_file(path: Path) -> MachineConfig:
    try:
        data = read_yaml(path)                   # UnreadableFileError (not text) as it is
    except UnreadableFileError:
        raise
    except YamlFileError as exc:
        raise ConfigError(path.name, exc.reason) from None
    return load_machine_data(data, path.name)
