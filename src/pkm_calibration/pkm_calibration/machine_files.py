"""A calibrated machine file: the nominal file with the identified geometry in place
of the drawn one, and a ``calibration`` section saying where it comes from (the run,
the method, every identified parameter with its standard deviation, the ones held at
nominal, the residuals before and after). Scenarios use it as the controller's
``model`` (or as the ``machine`` of a real machine); pkm-analyze, pkm-run's summary and
the panel name it by its ``calibration.label``.

A machine on struts (strut_errors.StrutErrorModel) is written with its joints moved
(a_k + da_k, b_k + db_k, in the file's length unit), and its encoders' zeros and
scales, l = q + z + s q, as each strut's compensation table (pkm_kinematics.compensation:
c(q) = z + s q, two points at the strut's limits, exact between them), which the
controller applies to its readings (``calibrated_strut_machine``); an as-built machine
for a simulation the same way, joints only (``strut_machine_data``).

A planar machine on rails (self_calibration.PlanarRailErrorModel's parameters per leg:
length, zero, b.x, b.y, rail.across) is written in its own words: the link length
L + dL, the platform point b + db, and the rail origin a + z u + across n (the
encoder's zero moves the rail's origin along it, as the plant's rail_offset_errors_m).
Calibrated with its Gough strut by strut (gough_errors), the Gough's joint centres go
into its metrology section as ``geometry.joint_offsets`` (its own frames), which the
sensor's forward kinematics then uses.
"""

from __future__ import annotations

import copy
import datetime
from pathlib import Path

import numpy as np
import yaml

from pkm_kinematics import load_machine
from pkm_kinematics.compensation import compensation_of
from pkm_kinematics.config import LENGTH_UNITS, load_machine_data
from pkm_kinematics.errors import FieldError

__all__ = ["calibrated_rail_machine", "calibrated_strut_machine", "strut_machine_data", "write_machine_file",
           "calibrated_path"]


def _without_calibration(data: dict) -> dict:
    """A copy of a machine file's data without an earlier calibration's section and drive
    tables: the identification's parameters are deltas from its geometry, measured on
    raw readings, so the old tables must not be applied on top of the new ones."""
    data = copy.deepcopy(data)
    data.pop("calibration", None)
    data.pop("compensation", None)
    return data


def calibrated_path(nominal: Path) -> Path:
    """Beside the nominal file: ``archi.yaml`` -> ``archi.calibrated.yaml``."""
    nominal = Path(nominal)
    return nominal.with_name(nominal.stem + ".calibrated.yaml")


def calibrated_rail_machine(config, names, theta, std, calibration: dict) -> dict:
    """The machine file's data of rail machine ``config`` (a MachineConfig: planar or
    translating) with the parameters ``theta`` (named ``names``: rail_errors.RailErrorModel's,
    module doc) and their ``std``; the ``calibration`` section's other entries (label,
    source, method, ...) as given; the instrument's frame, if any, in it only."""
    if config.kind not in ("planar", "translational"):
        raise FieldError("machine", f"{config.name}: a calibrated file of a machine on rails, not a "
                                    f"{config.kind} machine")
    data = _without_calibration(config.data)
    unit = LENGTH_UNITS[data.get("length_unit", "m")]
    values = dict(zip(names, np.asarray(theta, dtype=float).tolist()))
    for leg in data["legs"]:
        name = leg["name"]
        u = np.asarray(leg["rail_direction"], dtype=float)
        u = u / np.linalg.norm(u)
        origin = np.asarray(leg["rail_origin"], dtype=float) + values[f"zero.{name}"] / unit * u
        if f"rail.across.{name}" in values:                    # planar: n = z x u
            origin = origin + values[f"rail.across.{name}"] / unit * np.array([-u[1], u[0]])
        leg["rail_origin"] = [float(v) for v in origin]
        leg["link_length"] = float(leg["link_length"] + values[f"length.{name}"] / unit)
        key = "platform_point" if "platform_point" in leg else "platform_offset"
        leg[key] = [float(v + values.get(f"b.{axis}.{name}", 0.0) / unit) for v, axis in zip(leg[key], "xyz")]
    if any(n.startswith("gough.") for n in names):           # gough_errors: the sensor's joints, its own frames
        m = config.metrology
        geometry = data["metrology"]["geometry"]
        old = geometry.get("joint_offsets", {})
        for part, rotation in (("base", m.base_rotation), ("plate", m.plate_rotation_in_tool)):
            delta = np.array([[values[f"gough.{part}.{j + 1}.{c}"] for c in "xyz"] for j in range(6)])
            delta = delta @ np.asarray(rotation, dtype=float) + np.asarray(old.get(part, np.zeros((6, 3))))
            old[part] = [[float(v) for v in row] for row in delta]
        geometry["joint_offsets"] = old
    data["calibration"] = {**calibration,
                           "written": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
                           "parameters": {n: {"value": float(v), "std": float(s)}
                                          for n, v, s in zip(names, values.values(), std)}}
    return data


def write_machine_file(path: Path, data: dict, header: str = "") -> Path:
    """Write ``data`` as a machine file (checked by loading it first, its drive tables
    too: a file the loader or the controller would refuse is not written); returns the
    path."""
    compensation_of(load_machine_data(data, str(path)))
    text = "".join(f"# {line}\n" for line in header.splitlines()) + yaml.safe_dump(data, sort_keys=False)
    path = Path(path)
    path.write_text(text, encoding="utf-8")
    compensation_of(load_machine(path))          # its drive tables, if any, as the controller will read them
    return path


def strut_machine_data(config, names, theta, calibration: dict | None = None, std=None) -> dict:
    """The machine file's data of strut machine ``config`` with its joints moved by the
    a.* and b.* of ``theta`` (named ``names``, SI: written in the file's length unit);
    with ``calibration``, its section (every parameter, zero and scale included)."""
    if config.kind != "struts":
        raise FieldError("machine", f"{config.name}: a strut machine's file, not a {config.kind} machine's")
    data = _without_calibration(config.data)
    unit = LENGTH_UNITS[data.get("length_unit", "m")]
    values = dict(zip(names, np.asarray(theta, dtype=float).tolist()))
    for strut in data["struts"]:
        for part, key in (("a", "base"), ("b", "platform")):
            strut[key] = [float(strut[key][c] + values[f"{part}.{strut['name']}.{axis}"] / unit)
                          for c, axis in enumerate("xyz")]
    if calibration is not None:
        std = np.zeros(len(names)) if std is None else np.asarray(std, dtype=float)
        data["calibration"] = {**calibration,
                               "written": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
                               "parameters": {n: {"value": float(v), "std": float(e)}
                                              for n, v, e in zip(names, values.values(), std)}}
    return data


def calibrated_strut_machine(config, names, theta, std, calibration: dict) -> dict:
    """The calibrated file's data of strut machine ``config``: its joints moved and its
    encoders' zeros and scales as compensation tables (module doc)."""
    data = strut_machine_data(config, names, theta, calibration, std)
    values = dict(zip(names, np.asarray(theta, dtype=float).tolist()))
    model = config.model
    data["compensation"] = {}
    for k, leg in enumerate(model.leg_names):
        z, s = values[f"zero.{leg}"], values[f"scale.{leg}"]
        ends = (float(model.joint_lower[k]), float(model.joint_upper[k]))
        unit = LENGTH_UNITS[data.get("length_unit", "m")]
        data["compensation"][leg] = [[q / unit, (z + s * q) / unit] for q in ends]
    return data

