"""A recorded run as pandas DataFrames, for analysis in a notebook (pure; no rclpy).

    from pkm_runs.runs import open_run
    run = open_run("runs/2026-12-02_07-10-00_archi_demo")
    state = run.frame("state")          # index t_s; position.q1 .. effort.q4
    error = run.frame("true_pose")[["x", "y"]] - run.frame("reference")[["x", "y"]]
    run.metrics["tracking_error"]["max_m"], run.scenario["controller"], run.info["status"]

``frame(stream)`` for the per-step streams of report_data.STEP_STREAMS: ``state``,
``command`` (drives), ``struts`` (Gough struts), ``true_pose``, ``reference``,
``metrology_pose``, ``clock``. One row per step stamp, as the report reads them
(report_data.RunReader: deduplicated by stamp, the last message of a stamp kept),
indexed by ``t_s``, the stamp in simulated seconds. Columns: a JointState stream has
``position.<name>``, ``velocity.<name>``, ``effort.<name>`` per drive or strut name; a
pose stream ``x``, ``y``, ``z``, ``qx``, ``qy``, ``qz``, ``qw`` and ``yaw`` (rad, about
z); ``clock`` only its index. Every column also has ``log_s``, when the recorder got
the message (wall clock, s).

A frame holds its whole stream in memory (~100 bytes per step and drive): for runs of
minutes. The frames are made from the one in-memory view of a run
(report_data.load_run, also the gallery's); the report streams the bag block by block
instead (report_data.RunReader, bounded memory however long the run), and load_run
reads through the same reader, so all see the same values.
"""

from __future__ import annotations

import json
from functools import cached_property
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from pkm_kinematics.errors import FieldError
from pkm_runs.report_data import JOINT, JOINT_FIELDS, POSE, STEP_STREAMS, JointRows, PoseRows, load_run, yaw_of

STREAMS = tuple(STEP_STREAMS)


class Run:
    """A run directory (``pkm-run``'s): its streams as DataFrames, its scenario, run.json
    and metrics. The bag is read once, on the first ``frame``."""

    def __init__(self, path):
        self.path = Path(path)
        if not self.path.is_dir():
            raise FileNotFoundError(f"run directory {self.path}: no such directory")
        self._frames: dict | None = None

    @cached_property
    def info(self) -> dict:
        """run.json (status, cause, summaries of the nodes ...); {} without it."""
        return _json(self.path / "run.json")

    @cached_property
    def scenario(self) -> dict:
        """The scenario the run was started with (its scenario.yaml)."""
        path = self.path / "scenario.yaml"
        return (yaml.safe_load(path.read_text(encoding="utf-8")) or {}) if path.exists() else {}

    @cached_property
    def metrics(self) -> dict:
        """The report's metrics (report/metrics.json, as pkm-report writes them); {} if
        the run has no report."""
        return _json(self.path / "report" / "metrics.json") or dict(self.info.get("metrics") or {})

    def frame(self, stream: str) -> pd.DataFrame:
        """The per-step stream ``stream`` (module docstring)."""
        if stream not in STREAMS:
            raise FieldError("stream", f"one of {', '.join(STREAMS)}, got {stream!r}")
        frames = self._read()
        if stream not in frames:
            raise KeyError(f"{stream}: not recorded in {self.path} (recorded: {', '.join(frames) or 'none'})")
        return frames[stream]

    @property
    def streams(self) -> list[str]:
        """The per-step streams this run recorded."""
        return list(self._read())

    def _read(self) -> dict:
        if self._frames is None:
            data = load_run(self.path, namespace=self.info.get("namespace"))
            steps = data.steps
            self._frames = {}
            for key, rows in steps.rows.items():
                if rows is not None and rows.present.any():
                    keep = rows.present
                    self._frames[key] = _frame(key, [(steps.stamp_ns[keep], rows.take(keep))],
                                               data.info.streams[key].names or [])
        return self._frames


def open_run(path) -> Run:
    """A run directory as DataFrames (:class:`Run`)."""
    return Run(path)


def _json(path: Path) -> dict:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _frame(key: str, chunks: list, names: list) -> pd.DataFrame:
    stamps = np.concatenate([s for s, _ in chunks])
    index = pd.Index(stamps * 1e-9, name="t_s")
    rows = [r for _, r in chunks]
    columns: dict = {}
    kind = STEP_STREAMS[key][1]
    if kind == JOINT:
        n = rows[0].position.shape[1]
        labels = list(names) if len(names) == n else [str(i) for i in range(n)]
        for field_name in JOINT_FIELDS:
            values = np.concatenate([getattr(r, field_name) for r in rows if isinstance(r, JointRows)])
            for i, label in enumerate(labels):
                columns[f"{field_name}.{label}"] = values[:, i]
    elif kind == POSE:
        position = np.concatenate([r.position for r in rows if isinstance(r, PoseRows)])
        orientation = np.concatenate([r.orientation for r in rows if isinstance(r, PoseRows)])
        for i, axis in enumerate("xyz"):
            columns[axis] = position[:, i]
        for i, axis in enumerate(("qx", "qy", "qz", "qw")):
            columns[axis] = orientation[:, i]
        columns["yaw"] = yaw_of(orientation)
    columns["log_s"] = np.concatenate([r.log_ns for r in rows]) * 1e-9
    return pd.DataFrame(columns, index=index)
