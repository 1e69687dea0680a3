"""Calibrating a machine in three steps (pkm-calibrate's plan and identify; pkm-run runs
the program in between):

1. ``plan_calibration``: the error model the machine and the instrument call for, N
   poses chosen from candidates in its workspace by the observability index O1
   (poses.select_poses), written as a calibration program;
2. pkm-run runs the program (its scenario: the machine's, ``program`` the plan's)
   and records it;
3. ``identify_run``: the dwells of the recorded run (recorded.read_calibration_run),
   the identification (self-calibration from the redundancy: self_calibration; an
   external instrument: identify), and the calibrated machine file's data
   (machine_files).

The models by machine and instrument (``MODELS``): a planar machine on rails with more
drives than degrees of freedom, no instrument: self-calibration; a machine on struts,
the laser tracker (its tool point): strut_errors.StrutErrorModel; a machine on rails
and its Gough, by the pose the sensor reports ("gough": rail_errors) or strut by strut
with the sensor's own joints ("gough-struts": gough_errors).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from pkm_kinematics.config import LENGTH_UNITS
from pkm_kinematics.errors import FieldError
from pkm_kinematics.struts import StrutMachine

from .as_built import strut_gauge
from .compensation_fit import fit_tables, true_drive_positions
from .gough_errors import GoughStrutRailModel, gough_joints
from .identify import Identifiability, gauge, identifiability, identify
from .machine_files import calibrated_rail_machine, calibrated_strut_machine
from .poses import calibration_program, candidate_poses, observability_index, route, select_poses
from .recorded import read_calibration_run, run_record
from .rail_errors import RailErrorModel
from .self_calibration import ENCODER_NOISE_M, PlanarRailErrorModel, calibrate_rails, self_calibrate
from .strut_errors import StrutErrorModel

ENCODER_COUNT_M = 1e-6     # the drives' encoder count (the plant's and the machine files' 1 um)
INSTRUMENT_NOISE_M = 1e-6  # an instrument's mean at a dwell, for planning (identify takes the run's)

__all__ = ["CalibrationPlan", "RunIdentification", "error_model", "plan_calibration", "identify_run"]


@dataclass(frozen=True)
class CalibrationPlan:
    program: str               # the G-code
    poses: np.ndarray          # (N, dof) task coordinates
    observability: float       # O1 of the chosen poses (their identifiable columns scaled)
    identifiable: Identifiability
    method: str


@dataclass
class RunIdentification:
    names: tuple
    theta: np.ndarray
    std: np.ndarray
    identifiable: Identifiability
    misfit_before_m: float
    misfit_after_m: float
    dwells: int
    method: str
    covariance: np.ndarray     # of the identified parameters (identifiable.identified's order)
    extra: dict = field(default_factory=dict)

    def chi_square(self, truth) -> float:
        """(theta - truth)^T C^-1 (theta - truth) over the identified parameters: chi-square
        distributed with as many degrees of freedom when the predicted covariance C is
        right (a simulation's check against its true parameters)."""
        free = list(self.identifiable.identified)
        error = self.theta[free] - np.asarray(truth, dtype=float)[free]
        return float(error @ np.linalg.solve(self.covariance, error))

    def table(self) -> list[list[str]]:
        """Identified parameters (value and standard deviation in um; a scale in ppm), then
        the held ones."""
        rows = [["parameter", "identified (um, ppm)", "std"]]
        rows += [[self.names[k], f"{1e6 * self.theta[k]:.2f}", f"{1e6 * self.std[k]:.2f}"]
                 for k in self.identifiable.identified]
        rows += [[self.names[k], "held at nominal", "-"] for k in self.identifiable.held]
        return rows


def instrument_for(config, instrument: str | None) -> str | None:
    """The instrument of ``instrument`` "auto": a laser tracker for a strut machine; none
    (self-calibration) for a machine on rails with more drives than degrees of freedom;
    the Gough metrology for one without but with a metrology section (MoM3); "none" ->
    None."""
    if instrument == "auto":
        model = config.model
        if isinstance(model, StrutMachine):
            return "laser"
        if model.n_legs <= model.task_space.dof and config.metrology is not None:
            return "gough"
        return None
    return None if instrument == "none" else instrument


def error_model(config, instrument: str | None, tool=(0.0, 0.0, 0.0)):
    """(model, method) for a machine and an instrument (instrument_for; module doc);
    FieldError naming a combination not modelled yet."""
    machine = config.model
    instrument = instrument_for(config, instrument)
    if instrument is None:
        return PlanarRailErrorModel(machine), "self-calibration from the redundancy, no instrument"
    if instrument == "laser" and isinstance(machine, StrutMachine):
        return StrutErrorModel(machine, tuple(tool)), "laser tracker on the tool point"
    if instrument == "gough" and config.metrology is None:
        raise FieldError("instrument", f"{config.name} has no metrology section: no Gough to calibrate with")
    if instrument == "gough-struts" and config.metrology is not None and hasattr(machine, "rail_directions"):
        base, plate = gough_joints(config.metrology)
        return (GoughStrutRailModel(machine, base=base, plate=plate),
                "the Gough metrology strut by strut, its own joints identified too")
    if instrument == "gough-struts":
        raise FieldError("instrument", f"{config.name}: gough-struts needs a machine on rails with a metrology "
                                       "section (MoM3)")
    if instrument in ("laser", "gough") and hasattr(machine, "rail_directions"):
        return (RailErrorModel(machine, instrument=True, tool=tuple(tool) if instrument == "laser" else (0.0,) * 3),
                "laser tracker on the tool point" if instrument == "laser" else "the Gough metrology's tool pose")
    raise FieldError("instrument", f"{config.name}: {instrument} calibration of a {config.kind} machine is not "
                                   "modelled yet (machines on rails: none, laser, gough, gough-struts; strut "
                                   "machines: laser)")


def _blocks(model, poses: np.ndarray, readings: np.ndarray) -> np.ndarray:
    """Each pose's rows of the identification Jacobian (N, rows, size)."""
    if isinstance(model, RailErrorModel):
        return model.pose_blocks(poses, readings, (ENCODER_NOISE_M, INSTRUMENT_NOISE_M))
    jac = model.jacobian(np.zeros(model.size), readings)
    return jac.reshape(len(poses), 3, model.size)


def plan_calibration(config, count: int, instrument: str | None = None, candidates: int = 400, seed: int = 0,
                     tool=(0.0, 0.0, 0.0), angle_half_range_deg: float | None = None, dwell_s: float = 0.5,
                     feed_mm_min: float = 600.0) -> CalibrationPlan:
    """Step 1 (module doc)."""
    model, method = error_model(config, instrument, tool)
    machine = config.model
    pool = candidate_poses(machine, candidates, seed, angle_half_range_deg)
    q, _ = machine.inverse_kinematics_batch(pool)
    blocks = _blocks(model, pool, q)
    which = identifiability(blocks.reshape(-1, model.size), model.names)
    free = list(which.identified)
    chosen = select_poses(blocks[:, :, free], count)
    jac = blocks[:, :, free]
    norms = np.linalg.norm(jac.reshape(-1, len(free)), axis=0)
    index = observability_index(jac[chosen].reshape(-1, len(free)) / norms)
    poses, is_pose = route(machine, machine.home, pool[chosen], pool)
    comment = (f"{config.name}, {method}, O1 {index:.4g} by Borm & Menq, of {len(free)} parameters"
               + (f", tool {list(tool)} m" if instrument_for(config, instrument) else ""))
    return CalibrationPlan(calibration_program(machine.task_space, poses, dwell_s, feed_mm_min, comment, is_pose),
                           poses[is_pose], index, which, method)


def identify_run(config, run_dir, instrument: str | None = None, min_dwell_s: float = 0.2, tool=None,
                 sigma_m: float | None = None, held=None, validate_every: int = 0,
                 table_spacing_m: float | None = None) -> RunIdentification:
    """Step 3 (module doc): the parameters from the recorded run in ``run_dir``.
    ``tool``: the laser tracker's point (default: the run's, from run.json).
    ``sigma_m``: the readings' noise (default: the encoders' 1 um count's
    quantisation, 1/sqrt(12) um, for self-calibration; with an instrument, its spread at the dwells over the square root
    of the samples averaged, with the encoders' count in quadrature on a strut machine).
    ``held`` defaults to one convention (identify.gauge: with an instrument, its frame
    first), the same whatever the poses; with an instrument every
    ``validate_every``-th dwell is kept out of the identification to validate it: the
    instrument's residuals there with the nominal and the identified model
    (``extra["validation"]``). ``table_spacing_m``: compensation tables too
    (compensation_fit, where the instrument fixes the pose), knots this far apart:
    ``extra["compensation"]``, and the validation with them."""
    instrument = instrument_for(config, instrument)
    tool = _tool_of_run(run_dir, instrument, tool)
    model, method = error_model(config, instrument, tool)
    if table_spacing_m and (instrument is None or isinstance(model, (StrutErrorModel, GoughStrutRailModel))
                            or model.planar):
        raise FieldError("table_spacing_m", f"{config.name}: drive tables need an instrument that fixes the pose "
                                            "(a translating machine on rails and its Gough's pose or a tracker: "
                                            "MoM3)")
    if validate_every and instrument is None:
        raise FieldError("validate_every", "self-calibration has no instrument to validate against")
    n, dof = config.model.n_legs, config.model.task_space.dof
    rows = n - dof + (0 if instrument is None else 3 if isinstance(model, StrutErrorModel) else
                      model.readings_per_point)
    readings = read_calibration_run(run_dir, config, min_dwell_s, instrument, min_dwells=1 + model.size // rows)
    if instrument is None:
        if held is None:          # identify.gauge: the same names whatever the poses
            held = gauge(model.parameter_jacobian(readings.poses, readings.readings), model.names)
        result = self_calibrate(model, readings.readings, readings.poses, held=held,
                                **({"sigma_m": sigma_m} if sigma_m else {}))
        return RunIdentification(model.names, result.theta, result.std, result.identifiable,
                                 result.misfit_before_m, result.misfit_after_m, len(readings.dwells), method,
                                 result.covariance, {"poses": result.poses, "unsettled": readings.unsettled})
    q, poses, y = readings.readings, readings.poses, readings.instrument
    tables = None
    check = np.zeros(len(q), dtype=bool)
    if validate_every:
        check[validate_every - 1::validate_every] = True
    if sigma_m is None:      # a dwell's mean: the instrument's noise averaged
        sigma_m = max(1e-9, float(np.median([np.mean(d.spread) / np.sqrt(d.samples) for d in readings.dwells])))
    if isinstance(model, StrutErrorModel):
        sigma_m = float(np.hypot(sigma_m, ENCODER_NOISE_M))       # the encoders' count: not averaged
        if held is None:
            held = strut_gauge(model, q[~check])
        result = identify(model, q[~check], y[~check], sigma_m, held=held)
        theta, before, after = result.theta, result.rms_before_m, result.rms_after_m

        def predicted(t, rows):
            return model.predict(t, q[rows]).y
    else:
        if held is None:        # the instrument's frame is the machine's base frame, then identify.gauge
            frame = tuple(n for n in model.names if n.startswith("frame."))
            held = gauge(model.parameter_jacobian(poses[~check], q[~check], (ENCODER_NOISE_M, sigma_m)),
                         model.names, frame)
        fit = ~check
        result = calibrate_rails(model, q[fit], poses[fit], y[fit], point_sigma_m=sigma_m, held=held)
        d = model.readings_per_point
        tables = None
        if table_spacing_m:       # compensation_fit: the tables, then the geometry on compensated readings
            tables, _, _ = fit_tables(q[fit], true_drive_positions(model, result.theta, y[fit]), table_spacing_m)
            compensated = np.array([tables.positions(row) for row in q])
            result = calibrate_rails(model, compensated[fit], poses[fit], y[fit], point_sigma_m=sigma_m, held=held)
            tables, drive_before, drive_after = fit_tables(q[fit], true_drive_positions(model, result.theta, y[fit]),
                                                           table_spacing_m)
        theta, before, after = result.theta, result.misfit_before_m, result.misfit_after_m

        def predicted(t, rows, tables=None):     # the points at the poses the readings close to (the model's FK)
            readings_ = q[rows] if tables is None else np.array([tables.positions(row) for row in q[rows]])
            return model.points(t, _closed_poses(model, t, readings_, poses[rows]))[:, :d]
        y = y[:, :d]
    extra = {"sigma_m": sigma_m, "unsettled": readings.unsettled}
    if not isinstance(model, StrutErrorModel) and tables is not None:
        extra["compensation"] = tables
        extra["drive_error_rms_m"] = {"before": drive_before.tolist(), "after": drive_after.tolist()}
        if check.any():
            e2 = predicted(theta, check, tables) - y[check]
            extra["validation_compensated"] = {"rms_m": float(np.sqrt(np.mean(e2 ** 2))),
                                               "max_m": float(np.linalg.norm(e2, axis=1).max())}
    if check.any():
        e0 = predicted(np.zeros(model.size), check) - y[check]
        e1 = predicted(theta, check) - y[check]
        extra["validation"] = {"dwells": int(check.sum()), "rms_before_m": float(np.sqrt(np.mean(e0 ** 2))),
                               "rms_after_m": float(np.sqrt(np.mean(e1 ** 2))),
                               "max_before_m": float(np.linalg.norm(e0, axis=1).max()),
                               "max_after_m": float(np.linalg.norm(e1, axis=1).max())}
    return RunIdentification(model.names, theta, result.std, result.identifiable, before, after,
                             int((~check).sum()), method, result.covariance, extra)


def _tool_of_run(run_dir, instrument, tool):
    """The laser tracker's tool point: the run's (run.json) when ``tool`` is None, and
    FieldError when the one given is not what the run's tracker read."""
    tracker = run_record(run_dir).get("laser_tracker") if instrument == "laser" else None
    ran = tuple(float(v) for v in tracker["tool"]) if isinstance(tracker, dict) and "tool" in tracker else None
    if tool is None:
        return ran or (0.0, 0.0, 0.0)
    if ran is not None and np.abs(np.subtract(tool, ran)).max() > 1e-9:
        raise FieldError("tool", f"the run's laser tracker read the point {list(ran)} m of the platform, not "
                                 f"{list(tool)}")
    return tuple(tool)


def _closed_poses(model, theta, readings, guesses) -> np.ndarray:
    """The poses where the bars of ``theta`` close at ``readings`` (least squares from
    ``guesses``): what the machine's model says the encoders' pose is."""
    out = []
    for q, guess in zip(readings, guesses):
        fit = least_squares(lambda x: model.residuals(theta, x[None], q[None]).ravel(), guess,
                            jac=lambda x: model.jacobian(theta, x[None], q[None])[0], xtol=1e-15, ftol=1e-15,
                            gtol=1e-15)
        out.append(fit.x)
    return np.array(out)


def calibrated_machine_data(config, result: RunIdentification, label: str, source: str) -> dict:
    """The calibrated machine file's data (machine_files) of an identification."""
    calibration = {"label": label, "source": source, "method": result.method, "dwells": result.dwells,
                   "held": [result.names[k] for k in result.identifiable.held],
                   "misfit_before_m": result.misfit_before_m, "misfit_after_m": result.misfit_after_m}
    if config.kind == "struts":
        return calibrated_strut_machine(config, result.names, result.theta, result.std, calibration)
    data = calibrated_rail_machine(config, result.names, result.theta, result.std, calibration)
    tables = result.extra.get("compensation")
    if tables is not None:       # pkm_kinematics.compensation's section: the drives' tables (m)
        unit = LENGTH_UNITS[data.get("length_unit", "m")]
        data["compensation"] = {name: [[float(p) / unit, float(c) / unit] for p, c in zip(t.positions, t.corrections)]
                                for name, t in zip(config.model.leg_names, tables.tables) if t is not None}
    return data
