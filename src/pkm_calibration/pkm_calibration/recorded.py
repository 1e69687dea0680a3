"""The readings of a calibration run: a recorded run (pkm-run) of a calibration program
(poses.calibration_program: a move to each pose, a dwell there).

The dwells are found from the controller's reference (``controller/reference``): the
stretches where it stands still (no coordinate changing by more than STILL, the
round-off of its interpolation) for at least ``min_dwell_s``. At each, the
encoders (``drives/state``) and the instrument, when the run has one (the laser
tracker's ``instrument/laser``, the Gough sensor's ``metrology/pose``), are
averaged over the dwell's last ``settled`` fraction, where the machine has stopped;
their spread there is kept (the readings' noise, for the identification's standard
deviations). A dwell where the encoders still move (any drive's spread over
``max_spread_m``: the machine had not settled) is not a reading of one pose: it is
left out, and counted.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pkm_kinematics import load_machine
from pkm_kinematics.errors import FieldError
from pkm_kinematics.rotations import rotation_from_quaternion
from pkm_kinematics.task_space import task_pose
from pkm_runs.report_data import load_run

from .poses import workspace_bounds

__all__ = ["Dwell", "CalibrationReadings", "dwells", "read_calibration_run", "run_record"]

MAX_SPREAD_M = 2e-6          # a settled dwell's encoders: within a count or two of still
STILL = 1e-9                # m, and quaternion components: a reference step smaller is round-off
# instrument -> the run's stream
INSTRUMENTS = {"laser": "instrument", "gough": "metrology_pose", "gough-struts": "struts"}


@dataclass(frozen=True)
class Dwell:
    start_s: float              # from the run's first drive state
    end_s: float
    pose: np.ndarray            # the reference pose there (task coordinates, m and rad)
    readings: np.ndarray        # the encoders' mean over the settled part (n,)
    spread: np.ndarray          # their standard deviation there (n,)
    samples: int                # drive states averaged
    instrument: np.ndarray | None = None       # the instrument's mean there (a point (3,), struts (6,)), or None

    def settled(self, max_spread_m: float) -> bool:
        """The machine stood still over the averaged part (every drive's spread within)."""
        return bool(np.all(self.spread <= max_spread_m))


@dataclass(frozen=True)
class CalibrationReadings:
    """Every dwell of a run, as arrays: poses (N, dof), readings (N, n), instrument (N, 3) or None."""
    dwells: list
    leg_names: tuple
    unsettled: int = 0          # dwells left out: the machine still moving (module doc)

    @property
    def poses(self) -> np.ndarray:
        return np.array([d.pose for d in self.dwells])

    @property
    def readings(self) -> np.ndarray:
        return np.array([d.readings for d in self.dwells])

    @property
    def instrument(self) -> np.ndarray | None:
        points = [d.instrument for d in self.dwells]
        return None if any(p is None for p in points) else np.array(points)


def _still_runs(reference: np.ndarray, t_s: np.ndarray, min_dwell_s: float) -> list[tuple[int, int]]:
    """[start, end) index ranges where no reference coordinate changes by more than
    STILL for at least ``min_dwell_s`` (rows with NaN break a range)."""
    same = np.all(np.abs(reference[1:] - reference[:-1]) <= STILL, axis=1)
    out, start = [], None
    for i, s in enumerate(np.append(same, False)):
        if s and start is None:
            start = i
        elif not s and start is not None:
            if t_s[i] - t_s[start] >= min_dwell_s:
                out.append((start, i + 1))
            start = None
    return out


def dwells(steps: dict, space, min_dwell_s: float = 0.2, settled: float = 0.5,
           instrument: np.ndarray | None = None) -> list[Dwell]:
    """The dwells of a run's per-step arrays ``steps`` (``t_s``, ``q``, and the
    reference's ``ref_position`` (N, 3), ``ref_orientation`` (N, 4)); ``instrument``:
    the instrument's point per step (N, 3; NaN where none), or None (module doc)."""
    if not 0.0 < settled <= 1.0:
        raise FieldError("settled", f"the fraction of a dwell averaged must be in (0, 1], got {settled}")
    t_s, q = steps["t_s"], steps["q"]
    reference = np.column_stack((steps["ref_position"], steps["ref_orientation"]))
    out = []
    for start, end in _still_runs(reference, t_s, min_dwell_s):
        first = start + int((1.0 - settled) * (end - start))
        window = slice(first, end)
        rows = q[window]
        rows = rows[np.isfinite(rows).all(axis=1)]
        if not len(rows):
            continue
        rotation = rotation_from_quaternion(steps["ref_orientation"][start])
        pose = task_pose(space, steps["ref_position"][start], rotation)
        point = None
        if instrument is not None:
            seen = instrument[window]
            seen = seen[np.isfinite(seen).all(axis=1)]
            point = seen.mean(axis=0) if len(seen) else None
        out.append(Dwell(float(t_s[start]), float(t_s[end - 1]), pose, rows.mean(axis=0), rows.std(axis=0),
                         len(rows), point))
    return out


def run_record(run_dir) -> dict:
    """A pkm-run run's run.json (empty without one)."""
    try:
        data = json.loads((Path(run_dir) / "run.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _run_machine(run_dir) -> str | None:
    """The name of the machine a pkm-run run says it ran (run.json), or None."""
    try:
        machine = run_record(run_dir).get("machine")
        return load_machine(machine).name if machine else None
    except (ValueError, AttributeError):
        return None


def read_calibration_run(run_dir, machine, min_dwell_s: float = 0.2, instrument: str | None = None,
                         min_dwells: int = 1, max_spread_m: float = MAX_SPREAD_M) -> CalibrationReadings:
    """The dwells of the recorded run in ``run_dir`` of ``machine`` (a MachineConfig);
    ``instrument``: "laser" or "gough" (the run must have recorded it). FieldError
    naming what is missing: a run of another machine (its drives), no reference, no
    instrument's stream, fewer than ``min_dwells`` dwells."""
    recorded = _run_machine(run_dir)
    if recorded is not None and recorded != machine.name:
        raise FieldError("machine", f"{run_dir}: a run of {recorded}, not of {machine.name}")
    run = load_run(run_dir)
    steps, model = run.steps, machine.model
    state, reference = steps.rows.get("state"), steps.rows.get("reference")
    if state is None or not state.present.any():
        raise FieldError("run", f"{run_dir}: no drives/state recorded")
    if state.position.shape[1] != model.n_legs:
        raise FieldError("machine", f"{run_dir}: the run has {state.position.shape[1]} drives, machine "
                                    f"{machine.name} {model.n_legs} ({', '.join(model.leg_names)}): not this "
                                    "machine's run")
    if reference is None or not reference.present.any():
        raise FieldError("run", f"{run_dir}: no controller/reference recorded: the dwells cannot be found")
    keep = state.present
    stamp = steps.stamp_ns[keep]
    arrays = {"t_s": (stamp - stamp[0]) * 1e-9, "q": state.position[keep],
              "ref_position": np.where(reference.present[keep, None], reference.position[keep], np.nan),
              "ref_orientation": np.where(reference.present[keep, None], reference.orientation[keep], np.nan)}
    points = None
    if instrument is not None:
        if instrument not in INSTRUMENTS:
            raise FieldError("instrument", f"must be one of {', '.join(INSTRUMENTS)}, got {instrument!r}")
        rows = steps.rows.get(INSTRUMENTS[instrument])
        if rows is None or not rows.present[keep].any():
            raise FieldError("instrument", f"{run_dir}: the run recorded no {instrument} readings "
                                           f"(stream {INSTRUMENTS[instrument]})")
        points = np.where(rows.present[keep, None], rows.position[keep], np.nan)
    found = dwells(arrays, model.task_space, min_dwell_s, instrument=points)
    lo, hi = workspace_bounds(model)
    slack = np.where(np.arange(len(lo)) < model.task_space.translation_axes, 1e-3, np.radians(1.0))
    for k, d in enumerate(found):
        out = (d.pose < lo - slack) | (d.pose > hi + slack)
        if out.any():
            axis = int(np.argmax(out))
            raise FieldError("poses", f"{run_dir}: dwell {k + 1} at {model.task_space.axes[axis]} = "
                                      f"{d.pose[axis]:.6g} is outside {machine.name}'s workspace "
                                      f"[{lo[axis]:.6g}, {hi[axis]:.6g}]: not a calibration of this machine's "
                                      "workspace")
    still = [d for d in found if d.settled(max_spread_m)]
    if len(still) < min_dwells:
        moving = f" ({len(found) - len(still)} more where the machine had not settled: longer dwells?)" \
            if len(still) < len(found) else ""
        raise FieldError("run", f"{run_dir}: {len(still)} dwells of at least {min_dwell_s:g} s found{moving}, "
                                f"{min_dwells} needed (is it a calibration program's run?)")
    return CalibrationReadings(still, tuple(model.leg_names), len(found) - len(still))
