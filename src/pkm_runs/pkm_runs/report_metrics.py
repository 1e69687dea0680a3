"""Metrics of a recorded run, folded block by block: memory independent of its length.

Pure module (no rclpy). :class:`RunAnalysis` takes the :class:`~pkm_runs.report_data.StepBlock`
s of a run in stamp order (from a ``RunReader`` or a whole ``RunData``) and keeps running
sums, extrema with their stamps and the decimated curves of the figures
(``report_plots.FigureCurves``); :meth:`RunAnalysis.finish` returns an
:class:`Analysis`, :func:`metrics_dict` its JSON form (definitions there). Every
per-step quantity is computed by one function on rows (:func:`tracking_error_rows`,
:func:`internal_force_rows`, :func:`null_space_part`), whatever the block size: a maximum
and its time are exact, a RMS differs from a whole-array one by rounding only.

The internal force needs the machine: ``run.json``'s, else the config whose drive names
are the recorded ones (``pkm_kinematics``), found at the first block with drive states.

Why over 600 lines: every metric of the report folds the same blocks in one pass
(RunAnalysis); a metric's sums, extrema and curves stay beside its definition.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import pkm_kinematics
from pkm_common.causes import TripCause
from pkm_common.poses import MACHINE_KINDS as GRAPH_KINDS
from pkm_kinematics.distribution import GRAM_RTOL
from pkm_kinematics.rotations import wrap_angles
from pkm_kinematics.task_space import PLANAR, POSITION
from pkm_runs.report_data import COMMAND, STATE, JointRows, RunInfo, StatusRecord, StepBlock, rpy_of, yaw_of
from pkm_runs.report_plots import MAX_PLOT_POINTS, FigureCurves, FigureSpec

UNKNOWN_CAUSE = "unknown"           # a stop whose status names no cause (recorded before causes were)


# ------------------------------------------------------------ running statistics
@dataclass
class PeakRms:
    """Running RMS and largest magnitude (with the stamp of its first occurrence) of the
    finite values of a series fed in order."""
    count: int = 0                  # finite values
    sum_sq: float = 0.0
    peak: float | None = None       # max |x|
    peak_stamp_ns: int | None = None

    def add(self, values, stamp_ns=None) -> None:
        v = np.abs(np.asarray(values, dtype=float))
        finite = np.isfinite(v)
        if not finite.any():
            return
        f = v[finite]
        self.count += len(f)
        self.sum_sq += float(np.sum(f * f))
        k = int(np.argmax(f))
        if self.peak is None or f[k] > self.peak:
            self.peak = float(f[k])
            self.peak_stamp_ns = int(np.asarray(stamp_ns)[finite][k]) if stamp_ns is not None else None

    @property
    def rms(self) -> float | None:
        return math.sqrt(self.sum_sq / self.count) if self.count else None


@dataclass
class Span:
    """Rows of a per-step stream: how many, first and last stamp and receive time."""
    rows: int = 0
    min_stamp_ns: int | None = None
    max_stamp_ns: int | None = None
    min_log_ns: int | None = None
    max_log_ns: int | None = None

    def add(self, stamp_ns: np.ndarray, log_ns: np.ndarray) -> None:
        if not len(stamp_ns):
            return
        self.rows += len(stamp_ns)
        lo, hi, llo, lhi = int(stamp_ns.min()), int(stamp_ns.max()), int(log_ns.min()), int(log_ns.max())
        if self.min_stamp_ns is None:
            self.min_stamp_ns, self.max_stamp_ns, self.min_log_ns, self.max_log_ns = lo, hi, llo, lhi
        else:
            self.min_stamp_ns, self.max_stamp_ns = min(self.min_stamp_ns, lo), max(self.max_stamp_ns, hi)
            self.min_log_ns, self.max_log_ns = min(self.min_log_ns, llo), max(self.max_log_ns, lhi)


@dataclass
class TrackingStats:
    """Tracking errors of one kind of machine (planar: x, y and yaw; else x, y, z and the
    rotation's angle: a hexapod's, the imperfect Delta's tilt)."""
    planar: bool
    samples: int = 0
    translation: PeakRms = field(default_factory=PeakRms)
    yaw: PeakRms = field(default_factory=PeakRms)
    rotation: PeakRms = field(default_factory=PeakRms)
    axes: list = field(init=False)                  # PeakRms per axis

    def __post_init__(self):
        self.axes = [PeakRms() for _ in range(2 if self.planar else 3)]


# ------------------------------------------------------------ per-row formulas
def tracking_error_rows(true_position, true_orientation, ref_position, ref_orientation,
                        planar: bool) -> dict:
    """Errors true pose - reference row by row: {"axes" (N, 2|3) m, "translation" (N,)
    m (norm of the axes), "yaw" (N,) rad wrapped to [-pi, pi) (planar), "rotation" (N,)
    rad, the angle of the rotation between the two orientations (otherwise)}."""
    axes = (np.asarray(true_position) - np.asarray(ref_position))[:, : 2 if planar else 3]
    out = {"axes": axes, "translation": np.linalg.norm(axes, axis=1)}
    if planar:
        out["yaw"] = wrap_angles(yaw_of(true_orientation) - yaw_of(ref_orientation))
    else:
        dot = np.abs(np.sum(np.asarray(true_orientation) * np.asarray(ref_orientation), axis=1))
        out["rotation"] = 2.0 * np.arccos(np.clip(dot, 0.0, 1.0))
    return out


def null_space_part(jac: np.ndarray, forces: np.ndarray) -> np.ndarray:
    """f - J (J^T J)^-1 J^T f for every step: ``jac`` (M, n, m), ``forces`` (M, n).

    :func:`pkm_kinematics.distribution.internal_force` vectorised; rows with a non-finite
    J or f, or a singular J^T J (the relative test of ``distribution``: |det| <=
    GRAM_RTOL |a00 a11 a22|), are NaN."""
    jac = np.asarray(jac, dtype=float)
    forces = np.asarray(forces, dtype=float)
    out = np.full(forces.shape, np.nan)
    if len(forces) == 0:
        return out
    ok = np.isfinite(jac).all(axis=(1, 2)) & np.isfinite(forces).all(axis=1)
    j, f = jac[ok], forces[ok]
    gram = np.einsum("kni,knj->kij", j, j)
    det = np.linalg.det(gram)
    diag = np.prod(np.diagonal(gram, axis1=1, axis2=2), axis=1)
    regular = np.abs(det) > GRAM_RTOL * np.abs(diag)
    y = np.linalg.solve(gram[regular], np.einsum("kni,kn->ki", j[regular], f[regular])[..., None])[..., 0]
    rows = np.flatnonzero(ok)[regular]
    out[rows] = f[regular] - np.einsum("kni,ki->kn", j[regular], y)
    return out


def drive_order(names: list, n: int, model) -> np.ndarray | None:
    """Columns of a stream's arrays in the model's leg order; None if they are not the
    model's drives."""
    legs = list(model.leg_names)
    if not names or list(names) == legs:
        return np.arange(len(legs)) if n == len(legs) else None
    if sorted(names) == sorted(legs):
        return np.array([list(names).index(leg) for leg in legs])
    return None


def internal_force_rows(cfg, forces: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """||f_int|| per row: f_int = f - J (J^T J)^-1 J^T f, the part of the drive forces f
    (M, n, in the model's leg order) in ker(J^T) (the formula of
    ``pkm_kinematics.distribution.internal_force_rows``, vectorised), J = J_m of the
    nominal model of ``cfg`` at ``poses`` (M, d) in its task coordinates ((x, y, yaw)
    planar, (x, y, z) translational, (x, y, z, a, b, c) spatial).
    NaN where J is singular or the pose unknown; zero without redundancy."""
    model = cfg.model
    dof = model.task_space.dof
    if model.n_legs <= dof:
        return np.zeros(len(forces))
    with np.errstate(all="ignore"):
        jac = model.jacobian_batch(poses) if len(poses) else np.zeros((0, model.n_legs, dof))
    return np.linalg.norm(null_space_part(jac, forces), axis=1)


def _pose_rows(block: StepBlock, info: RunInfo, cfg, idx: np.ndarray, rows: JointRows):
    """(which of the rows ``idx`` have a pose, their poses (M, d) in the machine's task
    coordinates): the true pose of the stamp if the run has a true pose, else forward
    kinematics of the encoder positions."""
    space = cfg.model.task_space
    planar, dof = space.translation_axes == 2, space.dof
    none = np.zeros(len(idx), bool), np.zeros((0, dof))
    if info.has_messages("true_pose"):
        tp = block.rows.get("true_pose")
        if tp is None:
            return none
        ok = tp.present[idx]
        pos = tp.position[idx[ok]]
        if planar:
            return ok, np.column_stack([pos[:, 0], pos[:, 1], yaw_of(tp.orientation[idx[ok]])])
        return ok, (np.column_stack([pos, rpy_of(tp.orientation[idx[ok]])]) if dof == 6 else pos)
    src, stream = (block.rows.get("state"), info.streams["state"]) if "state" in info.streams else (rows, None)
    order = drive_order(stream.names, stream.n, cfg.model) if stream is not None and stream.n is not None else None
    if src is None or order is None:
        return none
    q = src.position[idx][:, order]
    ok = src.present[idx] & np.isfinite(q).all(axis=1)
    if not ok.any():
        return none
    return ok, cfg.model.forward_kinematics_batch(q[ok])[0]


def block_internal_forces(block: StepBlock, info: RunInfo, cfg, series: str = "state"):
    """(stamps, ||f_int||) of the rows of ``series`` ("state": applied forces, or
    "command") in ``block`` that have a pose (NaN where J is singular), by
    :func:`internal_force_rows`; None if the stream has no rows here or its drives are
    not the model's. Every row without redundancy."""
    rows, stream = block.rows.get(series), info.streams.get(series)
    if rows is None or stream is None or stream.n is None:
        return None
    order = drive_order(stream.names, stream.n, cfg.model)
    if order is None:
        return None
    idx = np.flatnonzero(rows.present)
    if cfg.model.n_legs <= cfg.model.task_space.dof:
        return block.stamp_ns[idx], np.zeros(len(idx))
    ok, poses = _pose_rows(block, info, cfg, idx, rows)
    return block.stamp_ns[idx[ok]], internal_force_rows(cfg, rows.effort[idx[ok]][:, order], poses)


def internal_force_setup(info: RunInfo, cfg, series: str, rows: int) -> dict:
    """How the internal force of ``series`` is computed ({"pose_source", "redundancy"})
    or why it is not ({"error"}); ``rows``: the stream's rows in the run."""
    if series not in info.streams or rows == 0:
        return {"error": "no drive forces recorded"}
    if cfg is None:
        return {"error": "machine unknown (no run.json machine, drive names match no config)"}
    stream = info.streams[series]
    if drive_order(stream.names, stream.n, cfg.model) is None:
        return {"error": f"drives {stream.names} are not the {cfg.name} drives {list(cfg.model.leg_names)}"}
    n, dof = cfg.model.n_legs, cfg.model.task_space.dof
    if n <= dof:
        source = "none (no redundancy)"
    elif info.has_messages("true_pose"):
        source = "true_pose"
    else:
        source = "forward_kinematics(drives/state position)"
    return {"pose_source": source, "redundancy": max(0, n - dof)}


# ------------------------------------------------------------ machine
def resolve_machine(names: list, machine_name: str | None):
    """(MachineConfig or None, how it was found: "given", "drive names" or "unknown").
    By drive names only among the machines a graph runs (a recording comes from one):
    mom3_imperfect has mom3's drives but is not run yet."""
    if machine_name:
        return pkm_kinematics.load_machine(machine_name), "given"
    if not names:
        return None, "unknown"
    matches = []
    for name in pkm_kinematics.machine_names():
        try:
            cfg = pkm_kinematics.load_machine(name)
        except Exception:                         # noqa: BLE001 - a broken config is not this run's
            continue
        if cfg.kind in GRAPH_KINDS and list(cfg.model.leg_names) == list(names):
            matches.append(cfg)
    if len(matches) == 1:
        return matches[0], "drive names"
    return None, "unknown"


# ------------------------------------------------------------ trip
@dataclass
class Trip:
    """The stop that started a run's stop: ``cause`` a ``TripCause`` value ("none": the
    run did not stop; "unknown": its status names no cause; a value this version does not
    know is kept as recorded), ``reason`` the status message, ``source`` the status name
    ("controller", "sim_hw") or "estop" (an estop message and no ERROR status)."""
    cause: str = TripCause.NONE.value
    reason: str = ""
    source: str = ""
    stamp_ns: int | None = None
    topic: str = ""


def first_stop(statuses: dict, estop: bool) -> Trip:
    """The first stop of a run: of the controller statuses and the sim_hw diagnostics of
    level 2 (ERROR), the earliest by stamp (then receive time); its ``cause`` value
    (``pkm_common.causes``). Without one, an estop message that was true (cause estop)."""
    candidates = [d.first_error for name, d in statuses.items()
                  if name in ("controller", "sim_hw") and d.first_error is not None]
    if candidates:
        rec: StatusRecord = min(candidates, key=lambda r: (r.stamp_ns, r.log_ns))
        cause = rec.values.get("cause", "").strip()
        if not cause or cause == TripCause.NONE.value:
            cause = UNKNOWN_CAUSE
        return Trip(cause, rec.message, rec.name, rec.stamp_ns, rec.topic)
    if estop:
        return Trip(TripCause.ESTOP.value, "estop true", "estop")
    return Trip()


# ------------------------------------------------------------ analysis
@dataclass
class DriveForces:
    """Peak |force| per drive column of a drive stream."""
    names: list
    per_drive: list                 # PeakRms per column

    def peaks(self) -> tuple[float | None, dict | None]:
        names = self.names or [f"drive{i}" for i in range(len(self.per_drive))]
        per = {name: p.peak for name, p in zip(names, self.per_drive)}
        found = [p.peak for p in self.per_drive if p.peak is not None]
        return (max(found) if found else None), per


@dataclass
class Analysis:
    """What a run's metrics and figures are made of (:meth:`RunAnalysis.finish`)."""
    info: RunInfo
    cfg: object | None
    machine_name: str | None
    machine_source: str
    kind: str                       # the machine file's kind, or as seen in the poses ("planar",
                                    # "translational") or "unknown"
    space: object | None            # the task space (pkm_kinematics.task_space), None: unknown
    t0_ns: int | None               # time origin: the first drive state stamp (else any)
    spans: dict                     # stream key -> Span
    tracking: TrackingStats | None  # None: no true pose or no reference recorded
    forces: dict                    # "command" | "state" -> DriveForces
    internal: dict                  # {"error"} or {"norm": PeakRms, "pose_source", "redundancy"}
    internal_commanded: dict | None
    trip: Trip
    figures: FigureCurves

    @property
    def drive_names(self) -> list:
        for key in ("state", "command"):
            if key in self.info.streams:
                return list(self.info.streams[key].names)
        return []

    def figure_spec(self, machine_name: str | None = None) -> FigureSpec:
        name = self.cfg.name if self.cfg is not None else (machine_name or self.machine_name or "machine")
        internal = "error" not in self.internal and self.internal["norm"].count > 0
        return FigureSpec(label=f"{name} ({self.info.namespace or '/'})", planar=self.space is PLANAR,
                          t0_ns=self.t0_ns or 0,
                          drive_names={k: list(self.info.streams[k].names) for k in ("command", "state")
                                       if k in self.info.streams},
                          tracking=self.tracking is not None and self.tracking.samples > 0, internal=internal)


class RunAnalysis:
    """Folds a run's blocks (:meth:`add`, in stamp order) into an :class:`Analysis`
    (:meth:`finish`). ``info``: the run's RunInfo (its stream names fill in as blocks are
    read, its counts and statuses are complete when the last block has been read);
    ``machine_name``: the machine (run.json), else found from the drive names."""

    def __init__(self, info: RunInfo, machine_name: str | None = None, plot_points: int = MAX_PLOT_POINTS):
        self.info = info
        self.machine_name = machine_name
        self.figures = FigureCurves(plot_points)
        self.spans = {key: Span() for key in info.streams}
        self.tracking = {True: TrackingStats(True), False: TrackingStats(False)}
        self.forces: dict = {}
        self.z_zero = {"true_pose": True, "reference": True}     # every z == 0 so far
        self._machine = None            # (cfg, source) once resolved
        self._internal: dict = {}       # "applied" | "commanded" -> PeakRms of the norms

    # -- machine, found once the first drive states (else commands) have been read
    def _resolve(self, block: StepBlock | None) -> None:
        if self._machine is not None:
            return
        source = "state" if "state" in self.info.streams else "command"
        rows = block.rows.get(source) if block is not None else None
        if block is not None and not self.machine_name and (rows is None or not rows.present.any()):
            return
        names = self.info.streams[source].names if source in self.info.streams else []
        self._machine = resolve_machine(names, self.machine_name)

    # -- folding
    def add(self, block: StepBlock) -> None:
        """Fold one block (rows in stamp order, after those of the previous block)."""
        if not len(block):
            return
        stamps = block.stamp_ns
        for key, span in self.spans.items():
            rows = block.rows.get(key)
            if rows is not None:
                span.add(stamps[rows.present], rows.log_ns[rows.present])
        self._resolve(block)
        tp, ref = block.rows.get("true_pose"), block.rows.get("reference")
        for key, rows in (("true_pose", tp), ("reference", ref)):
            if rows is not None and rows.present.any():
                position = rows.position[rows.present]
                self.z_zero[key] = self.z_zero[key] and bool(np.all(position[:, 2] == 0.0))
                self.figures.add_pose(key, stamps[rows.present], position, yaw_of(rows.orientation[rows.present]))
        if tp is not None and ref is not None:
            self._add_tracking(stamps, tp, ref)
        for key in ("command", "state"):
            rows = block.rows.get(key)
            if rows is not None and rows.present.any():
                self._add_forces(key, stamps[rows.present], rows.effort[rows.present])
        cfg = self._machine[0] if self._machine is not None else None
        if cfg is not None:
            for key, series in (("applied", "state"), ("commanded", "command")):
                rows = block.rows.get(series)
                if rows is not None and rows.present.any():
                    self._add_internal(key, series, block, cfg)

    def _add_tracking(self, stamps, tp, ref) -> None:
        both = tp.present & ref.present
        if not both.any():
            return
        s = stamps[both]
        for planar, acc in self.tracking.items():
            e = tracking_error_rows(tp.position[both], tp.orientation[both], ref.position[both],
                                    ref.orientation[both], planar)
            acc.samples += len(s)
            acc.translation.add(e["translation"], s)
            for k, axis in enumerate(acc.axes):
                axis.add(e["axes"][:, k])
            curves = {"translation_xy" if planar else "translation_xyz": e["translation"]}
            if planar:
                acc.yaw.add(e["yaw"], s)
                curves["yaw"] = e["yaw"]
            else:
                acc.rotation.add(e["rotation"], s)
                curves.update({f"e_{axis}": e["axes"][:, k] for k, axis in enumerate("xyz")})
            self.figures.add_tracking(s, curves)

    def _add_forces(self, key: str, stamps, effort) -> None:
        forces = self.forces.get(key)
        if forces is None:
            forces = self.forces[key] = DriveForces(list(self.info.streams[key].names),
                                                    [PeakRms() for _ in range(effort.shape[1])])
        for k, peak in enumerate(forces.per_drive):
            peak.add(effort[:, k])
        self.figures.add_forces(key, stamps, effort)

    def _add_internal(self, key: str, series: str, block: StepBlock, cfg) -> None:
        found = block_internal_forces(block, self.info, cfg, series)
        if found is not None:
            stamps, norm = found
            self._internal.setdefault(key, PeakRms()).add(norm, stamps)
            self.figures.add_internal(key, stamps, norm)

    # -- result
    def finish(self) -> Analysis:
        """The analysis of the blocks folded so far (call after the last one)."""
        self._resolve(None)
        cfg, machine_source = self._machine
        kind, space = self._kind(cfg)
        tracking = None
        if "true_pose" in self.info.streams and "reference" in self.info.streams:
            tracking = self.tracking[space is PLANAR]
        forces = {k: f for k, f in self.forces.items()}
        internal = self._internal_result("applied", "state", cfg)
        commanded = None
        if "command" in self.info.streams and "error" not in internal:
            commanded = self._internal_result("commanded", "command", cfg)
        if commanded is None or "error" in commanded:
            self.figures.internal.pop("commanded", None)
        return Analysis(self.info, cfg, self.machine_name, machine_source, kind, space, self._t0(), self.spans, tracking,
                        forces, internal, commanded, first_stop(self.info.statuses, self.info.estop), self.figures)

    def _kind(self, cfg) -> tuple:
        """(kind, task space): the machine file's, or without one as the poses show it
        (in the plane z = 0: planar; else a position machine's)."""
        if cfg is not None:
            return cfg.kind, cfg.model.task_space
        key = "true_pose" if "true_pose" in self.info.streams else "reference"
        if key not in self.info.streams or self.spans[key].rows == 0:
            return "unknown", None
        return ("planar", PLANAR) if self.z_zero[key] else ("translational", POSITION)

    def _t0(self) -> int | None:
        for key in ("state", "true_pose", "command", "reference", "clock"):
            span = self.spans.get(key)
            if span is not None and span.rows:
                return span.min_stamp_ns
        return None

    def _internal_result(self, key: str, series: str, cfg) -> dict:
        span = self.spans.get(series)
        setup = internal_force_setup(self.info, cfg, series, span.rows if span is not None else 0)
        if "error" not in setup:
            setup["norm"] = self._internal.get(key, PeakRms())
        return setup


# ------------------------------------------------------------ JSON
def _parse_value(text: str):
    for conv in (int, float):
        try:
            return conv(text)
        except (TypeError, ValueError):
            pass
    return text


def _status_dict(rec: StatusRecord | None) -> dict | None:
    if rec is None:
        return None
    return {"level": rec.level, "message": rec.message, "stamp_ns": rec.stamp_ns, "topic": rec.topic,
            "values": {k: _parse_value(v) for k, v in rec.values.items()}}


def _clean(obj):
    """JSON-safe: numpy scalars to Python, non-finite floats to None."""
    if isinstance(obj, dict):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_clean(v) for v in obj]
    if isinstance(obj, (bool, np.bool_)):
        return bool(obj)
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def metrics_dict(a: Analysis, published: dict | None = None) -> dict:
    """Metrics of a run (JSON-serialisable; None where not computable).

    * ``duration_s``: sim time from the first to the last drive state stamp (else /clock,
      else commands); ``steps``: distinct state stamps.
    * ``trip_cause``: the ``pkm_common.causes.TripCause`` value of the stop that started
      the run's stop ("none" if it did not stop): of the controller statuses and sim_hw
      diagnostics of level 2, the earliest by stamp; "unknown" if that status names no
      ``cause``; "estop" for an estop message true without such a status.
      ``trip_reason``: that status's message ("" if none); ``trip_source``: "controller",
      "sim_hw", "estop" or ""; ``trip_time_s``: its stamp from the first state.
    * ``tracking_error``: e = true_pose - reference at each stamp present in both
      (deduplicated). Translation |e_xy| (planar) or |e_xyz| (translational) in m:
      ``rms_m`` = sqrt(mean |e|^2), ``max_m`` = max |e|, ``max_time_s`` its time from the
      first state; ``rms_axis_m`` per axis. Planar: yaw error wrap(yaw_true - yaw_ref)
      in rad, ``yaw_rms_rad``, ``yaw_max_rad`` (max |.|), ``yaw_max_time_s``. Otherwise
      the angle of the rotation from the reference to the true orientation,
      ``rotation_rms_rad``, ``rotation_max_rad``.
    * ``drive_force``: ``peak_commanded_n`` = max |drives/command effort|,
      ``peak_applied_n`` = max |drives/state effort|, over all drives and steps, plus per drive.
    * ``internal_force``: per step ||f_int||, f_int = f - J (J^T J)^-1 J^T f, f the applied
      forces, J = J_m of the nominal model at the true pose of the step (forward kinematics
      of the encoder positions if the run has no true pose); ``max_n``, ``rms_n`` =
      sqrt(mean ||f_int||^2); 0 without redundancy; the same of the commanded forces
      (``*_commanded_n``).
    * ``deadline_misses``: the last sim_hw diagnostics' ``deadline_misses``, else None.
    * ``timing``: over the deduplicated commands (else states), ``loop_rate_hz`` = (N - 1)
      / (last - first log time), ``sim_wall_ratio`` = (last - first stamp) / (last - first
      log time).
    * ``messages``: ``recorded`` per topic (raw, duplicates included); with ``published``
      (run.json; relative names are taken in the namespace) ``lost`` = published -
      recorded per published topic, ``lost_total`` their sum.
    * ``duplicates_dropped``: per per-step topic, messages not kept (repeats of a stamp);
      ``late_dropped``: of those, the messages of a stamp older than the look-back of the
      stream reader (topics with any only).
    * ``controller``: the last controller status (level, message, values parsed to
      numbers where possible); ``tripped`` if any controller status has level 2 or any
      estop message is true (``trip_reason`` the earliest such status's message).
    """
    info, cfg, kind = a.info, a.cfg, a.kind
    t0 = a.t0_ns
    out: dict = {"bag": str(info.bag_path), "namespace": info.namespace,
                 "machine": cfg.name if cfg is not None else a.machine_name, "machine_source": a.machine_source,
                 "kind": kind, "drives": a.drive_names}

    # duration
    span = None
    for key in ("state", "clock", "command"):
        s = a.spans.get(key)
        if s is not None and s.rows:
            span = (s.max_stamp_ns - s.min_stamp_ns) / 1e9
            break
    out["duration_s"] = span
    out["steps"] = a.spans["state"].rows if "state" in a.spans else 0
    trip = a.trip
    out["trip_cause"] = trip.cause
    out["trip_reason"] = trip.reason
    out["trip_source"] = trip.source
    out["trip_time_s"] = (trip.stamp_ns - t0) / 1e9 if trip.stamp_ns is not None and t0 is not None else None
    out["duplicates_dropped"] = {info.streams[k].topic: info.streams[k].duplicates
                                 for k in ("state", "command", "true_pose", "reference", "struts", "metrology_pose")
                                 if k in info.streams}
    out["late_dropped"] = {s.topic: s.late for s in info.streams.values() if s.late}

    # tracking
    track: dict = {"samples": 0, "rms_m": None, "max_m": None, "max_time_s": None}
    te = a.tracking
    if te is not None and te.samples:
        track.update(samples=te.samples, rms_m=te.translation.rms, max_m=te.translation.peak,
                     max_time_s=_since(te.translation.peak_stamp_ns, t0),
                     rms_axis_m=[axis.rms for axis in te.axes])
        if te.planar:
            track.update(yaw_rms_rad=te.yaw.rms, yaw_max_rad=te.yaw.peak,
                         yaw_max_time_s=_since(te.yaw.peak_stamp_ns, t0))
        else:
            track.update(rotation_rms_rad=te.rotation.rms, rotation_max_rad=te.rotation.peak)
    elif a.space is PLANAR:
        track.update(yaw_rms_rad=None, yaw_max_rad=None)
    out["tracking_error"] = track

    # drive forces
    pc, pc_per = a.forces["command"].peaks() if "command" in a.forces else (None, None)
    pa, pa_per = a.forces["state"].peaks() if "state" in a.forces else (None, None)
    out["drive_force"] = {"peak_commanded_n": pc, "peak_applied_n": pa,
                          "peak_commanded_per_drive_n": pc_per, "peak_applied_per_drive_n": pa_per}

    # internal force
    fi = a.internal
    internal: dict = {"source": "drives/state effort (applied)", "max_n": None, "rms_n": None, "samples": 0}
    if "error" in fi:
        internal["error"] = fi["error"]
    else:
        norm: PeakRms = fi["norm"]
        internal.update(model=f"nominal {cfg.name}", pose_source=fi["pose_source"], redundancy=fi["redundancy"],
                        max_n=norm.peak, rms_n=norm.rms, samples=norm.count,
                        unavailable_steps=out["steps"] - norm.count)
        fc = a.internal_commanded
        if fc is not None and "error" not in fc:
            internal.update(max_commanded_n=fc["norm"].peak, rms_commanded_n=fc["norm"].rms)
    out["internal_force"] = internal

    # sim_hw diagnostics
    sim = info.statuses.get("sim_hw")
    misses = sim.latest_values.get("deadline_misses") if sim is not None else None
    out["deadline_misses"] = _parse_value(misses) if misses is not None else None
    out["sim_hw"] = {"final_status": _status_dict(sim.last if sim else None),
                     "stopped": sim is not None and sim.first_error is not None}

    # timing
    timing = {"loop_rate_hz": None, "sim_wall_ratio": None, "wall_s": None, "sim_s": None, "source": None}
    for key, suffix in (("command", COMMAND), ("state", STATE)):
        s = a.spans.get(key)
        if s is not None and s.rows >= 2:
            wall = (s.max_log_ns - s.min_log_ns) / 1e9
            sim_s = (s.max_stamp_ns - s.min_stamp_ns) / 1e9
            timing.update(source=info.topic(suffix), wall_s=wall, sim_s=sim_s,
                          loop_rate_hz=(s.rows - 1) / wall if wall > 0 else None,
                          sim_wall_ratio=sim_s / wall if wall > 0 else None)
            break
    out["timing"] = timing

    # messages
    msgs: dict = {"recorded": dict(sorted(info.counts.items())), "published": None, "lost": None}
    if published:                                 # relative names are in the machine namespace
        published = {(t if t.startswith("/") else info.topic(t)): int(v) for t, v in published.items()}
        msgs["published"] = dict(sorted(published.items()))
        # nodes count one publication per stamp (discovery repeats of a step are not
        # counted), so the recorded side is counted the same way
        msgs["lost"] = {t: v - info.stamp_counts.get(t, info.counts.get(t, 0)) for t, v in sorted(published.items())}
        msgs["lost_total"] = sum(msgs["lost"].values())
    out["messages"] = msgs

    # controller
    ctrl = info.statuses.get("controller")
    reason = None
    if ctrl is not None and ctrl.first_error is not None:
        reason = f"controller status level 2: {ctrl.first_error.message}"
    if reason is None and info.estop:
        reason = "estop true"
    out["controller"] = {"final_status": _status_dict(ctrl.last if ctrl else None),
                         "status_messages": ctrl.count if ctrl else 0,
                         "tripped": reason is not None, "trip_reason": reason, "estop": info.estop}
    return _clean(out)


def _since(stamp_ns: int | None, t0: int | None) -> float | None:
    if stamp_ns is None or t0 is None:
        return None
    return (stamp_ns - t0) / 1e9


__all__ = ["Analysis", "PeakRms", "RunAnalysis", "Span", "Trip", "UNKNOWN_CAUSE", "block_internal_forces",
           "drive_order", "first_stop", "internal_force_rows", "internal_force_setup", "metrics_dict",
           "null_space_part", "resolve_machine", "tracking_error_rows"]
