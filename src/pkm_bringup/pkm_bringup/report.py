"""Run reports: metrics and figures from a recorded run (rosbag2 + MCAP).

Pure module (no rclpy): the bag is read with ``rosbags`` (``AnyReader``, message
definitions from the bag, ``Stores.ROS2_JAZZY`` as fallback), the internal force is
computed with ``pkm_kinematics``, the figures are drawn with matplotlib's Agg canvas.

A run directory is ``<run_dir>/bag/`` (metadata.yaml + .mcap) plus an optional
``<run_dir>/run.json`` (``machine``, ``namespace``, ``published`` counts, ``scenario``).

* :func:`load_run`      bag -> :class:`RunData` (numpy arrays per topic, deduplicated by stamp)
* :func:`metrics`       RunData -> JSON-serialisable dict (definitions in the docstring)
* :func:`plot`          RunData -> PNG files (path, tracking error, drive forces, internal force)
* :func:`write_report`  run directory -> ``report/metrics.json`` + PNGs
* :func:`main`          ``pkm-report <run_dir> [--out DIR]``
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

NS_PER_S = 1_000_000_000
DEFAULT_NAMESPACE = "/pkm"
MAX_PLOT_POINTS = 20_000

# topics relative to the machine namespace (DESIGN.md, "The graph")
STATE, COMMAND = "drives/state", "drives/command"
TRUE_POSE, REFERENCE = "platform/true_pose", "controller/reference"
STRUTS, METROLOGY_POSE = "metrology/struts", "metrology/pose"
STATUS, DIAGNOSTICS = "controller/status", "diagnostics"
TRAJECTORY, LOAD, ESTOP = "trajectory", "load", "estop"
KNOWN_SUFFIXES = (STATE, COMMAND, TRUE_POSE, REFERENCE, STRUTS, METROLOGY_POSE, STATUS,
                  DIAGNOSTICS, TRAJECTORY, LOAD, ESTOP)

class NoBagError(FileNotFoundError):
    """The given directory holds no rosbag2 recording."""


# ------------------------------------------------------------------ data
@dataclass
class JointSeries:
    """A JointState stream, deduplicated by header stamp (the last message of a stamp
    is kept), sorted by stamp. Missing fields are NaN."""
    names: list
    stamp_ns: np.ndarray            # (N,) int64
    log_ns: np.ndarray              # (N,) int64, recorder receive time of the kept message
    position: np.ndarray            # (N, n)
    velocity: np.ndarray            # (N, n)
    effort: np.ndarray              # (N, n)
    recorded: int                   # messages in the bag (before deduplication)

    @property
    def duplicates(self) -> int:
        return self.recorded - len(self.stamp_ns)


@dataclass
class PoseSeries:
    """A PoseStamped stream, deduplicated by stamp like :class:`JointSeries`."""
    stamp_ns: np.ndarray
    log_ns: np.ndarray
    position: np.ndarray            # (N, 3) m
    orientation: np.ndarray         # (N, 4) quaternion (x, y, z, w)
    recorded: int

    @property
    def duplicates(self) -> int:
        return self.recorded - len(self.stamp_ns)

    @property
    def yaw(self) -> np.ndarray:
        """Rotation about z (rad, in (-pi, pi]) of each orientation."""
        x, y, z, w = self.orientation.T
        return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


@dataclass
class StatusRecord:
    stamp_ns: int
    log_ns: int
    topic: str
    name: str
    level: int
    message: str
    values: dict                    # key -> value string, as published


@dataclass
class RunData:
    bag_path: Path
    namespace: str
    topics: dict                    # topic -> message type
    counts: dict                    # topic -> messages recorded (raw)
    clock_ns: np.ndarray            # /clock values
    clock_log_ns: np.ndarray
    state: JointSeries | None = None
    command: JointSeries | None = None
    true_pose: PoseSeries | None = None
    reference: PoseSeries | None = None
    struts: JointSeries | None = None
    metrology_pose: PoseSeries | None = None
    stamp_counts: dict = field(default_factory=dict)   # topic -> messages with a new stamp
    statuses: dict = field(default_factory=dict)   # status name -> [StatusRecord] (bag order)
    estop_log_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    estop: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    load_stamp_ns: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    load_force: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    load_torque: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    trajectory_time_s: np.ndarray | None = None     # the last trajectory message's points
    trajectory_position: np.ndarray | None = None   # (P, 3)
    trajectory_yaw: np.ndarray | None = None        # (P,)

    def topic(self, suffix: str) -> str:
        return f"{self.namespace}/{suffix}"

    def t0_ns(self) -> int | None:
        """Sim time origin of the plots: the first state (else any) stamp."""
        for series in (self.state, self.true_pose, self.command, self.reference):
            if series is not None and len(series.stamp_ns):
                return int(series.stamp_ns[0])
        return int(self.clock_ns[0]) if len(self.clock_ns) else None


# --------------------------------------------------------------- reading
def find_bag(path) -> Path:
    """The rosbag2 directory (or lone .mcap file) of a run directory or a bag path."""
    path = Path(path)
    if path.is_file() and path.suffix == ".mcap":
        return path
    for candidate in (path, path / "bag"):
        if (candidate / "metadata.yaml").is_file():
            return candidate
    for candidate in (path / "bag", path):        # a recorder that died before metadata.yaml
        mcaps = sorted(candidate.glob("*.mcap")) if candidate.is_dir() else []
        if len(mcaps) == 1:
            return mcaps[0]
    raise NoBagError(f"{path}: no rosbag2 recording (metadata.yaml + .mcap) in {path} or {path / 'bag'}")


def _dedupe_last(stamps: np.ndarray) -> np.ndarray:
    """Indices keeping the last message of every stamp, sorted by stamp."""
    if len(stamps) == 0:
        return np.zeros(0, dtype=np.int64)
    rev = stamps[::-1]
    _, first_in_rev = np.unique(rev, return_index=True)
    return (len(stamps) - 1 - first_in_rev).astype(np.int64)



def _joint_series(msgs: list) -> JointSeries | None:
    if not msgs:
        return None
    names = next((list(m.name) for _, m in msgs if len(m.name)), [])
    n = len(names) or max(max(len(m.position), len(m.velocity), len(m.effort)) for _, m in msgs)
    stamps = np.array([_stamp_time(m.header.stamp) for _, m in msgs], dtype=np.int64)
    logs = np.array([t for t, _ in msgs], dtype=np.int64)
    arrays = {k: np.full((len(msgs), n), np.nan) for k in ("position", "velocity", "effort")}
    for i, (_, m) in enumerate(msgs):
        order = None
        if names and len(m.name) and list(m.name) != names and sorted(m.name) == sorted(names):
            order = [list(m.name).index(name) for name in names]
        for key, arr in arrays.items():
            values = np.asarray(getattr(m, key), dtype=float)
            if len(values) == n:
                arr[i] = values if order is None else values[order]
    keep = _dedupe_last(stamps)
    return JointSeries(names, stamps[keep], logs[keep], arrays["position"][keep], arrays["velocity"][keep],
                       arrays["effort"][keep], len(msgs))


def _pose_series(msgs: list) -> PoseSeries | None:
    if not msgs:
        return None
    stamps = np.array([_stamp_time(m.header.stamp) for _, m in msgs], dtype=np.int64)
    logs = np.array([t for t, _ in msgs], dtype=np.int64)
    pos = np.array([(m.pose.position.x, m.pose.position.y, m.pose.position.z) for _, m in msgs], dtype=float)
    ori = np.array([(m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w)
                    for _, m in msgs], dtype=float)
    keep = _dedupe_last(stamps)
    return PoseSeries(stamps[keep], logs[keep], pos[keep], ori[keep], len(msgs))


def _infer_namespace(topics) -> str:
    found = set()
    for topic in topics:
        for suffix in KNOWN_SUFFIXES:
            if topic.endswith("/" + suffix):
                found.add(topic[: -len(suffix) - 1])
    if len(found) > 1:
        raise ValueError(f"the bag holds several machine namespaces {sorted(found)}: pass namespace=")
    return found.pop() if found else DEFAULT_NAMESPACE


def load_run(run_dir_or_bag, namespace: str | None = None) -> RunData:
    """Read a recorded run into numpy arrays.

    ``run_dir_or_bag``: a run directory (holding ``bag/``), a rosbag2 directory or an
    .mcap file. ``namespace``: the machine namespace (``/pkm``); inferred from the topic
    names when None. Per-step streams (drive state and command, true pose, reference,
    metrology) are deduplicated by header stamp, keeping the last message of a stamp
    (the state of step 0 may be republished while the graph comes up).
    Raises :class:`NoBagError` (a FileNotFoundError) if there is no recording.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    bag = find_bag(run_dir_or_bag)
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        topics = {c.topic: c.msgtype for c in reader.connections}
        if namespace is None:
            namespace = _infer_namespace(topics)
        namespace = namespace.rstrip("/")
        if namespace and not namespace.startswith("/"):
            namespace = "/" + namespace
        wanted = {f"{namespace}/{s}": s for s in KNOWN_SUFFIXES}
        wanted["/clock"] = "clock"
        counts = {t: 0 for t in topics}
        stamp_counts = {t: 0 for t in topics}
        last_stamp = {}
        msgs = {s: [] for s in wanted.values()}
        for conn, log_ns, raw in reader.messages():
            counts[conn.topic] += 1
            if raw[4:12] != last_stamp.get(conn.topic):     # as recorder_node counts: a new stamp
                last_stamp[conn.topic] = raw[4:12]
                stamp_counts[conn.topic] += 1
            suffix = wanted.get(conn.topic)
            if suffix is not None:
                msgs[suffix].append((log_ns, reader.deserialize(raw, conn.msgtype)))

    run = RunData(bag_path=bag, namespace=namespace, topics=topics, counts=counts, stamp_counts=stamp_counts,
                  clock_ns=np.array([_stamp_time(m.clock) for _, m in msgs["clock"]], dtype=np.int64),
                  clock_log_ns=np.array([t for t, _ in msgs["clock"]], dtype=np.int64))
    run.state, run.command = _joint_series(msgs[STATE]), _joint_series(msgs[COMMAND])
    run.struts = _joint_series(msgs[STRUTS])
    run.true_pose, run.reference = _pose_series(msgs[TRUE_POSE]), _pose_series(msgs[REFERENCE])
    run.metrology_pose = _pose_series(msgs[METROLOGY_POSE])
    for suffix in (STATUS, DIAGNOSTICS):
        topic = f"{namespace}/{suffix}"
        for log_ns, m in msgs[suffix]:
            for s in m.status:
                name = s.name.rsplit("/", 1)[-1].strip()
                level = int.from_bytes(s.level, "little") if isinstance(s.level, (bytes, bytearray)) else int(s.level)
                run.statuses.setdefault(name, []).append(StatusRecord(
                    _stamp_time(m.header.stamp), int(log_ns), topic, name, level, s.message,
                    {kv.key: kv.value for kv in s.values}))
    if msgs[ESTOP]:
        run.estop_log_ns = np.array([t for t, _ in msgs[ESTOP]], dtype=np.int64)
        run.estop = np.array([bool(m.data) for _, m in msgs[ESTOP]])
    if msgs[LOAD]:
        run.load_stamp_ns = np.array([_stamp_time(m.header.stamp) for _, m in msgs[LOAD]], dtype=np.int64)
        run.load_force = np.array([(m.wrench.force.x, m.wrench.force.y, m.wrench.force.z) for _, m in msgs[LOAD]])
        run.load_torque = np.array([(m.wrench.torque.x, m.wrench.torque.y, m.wrench.torque.z)
                                    for _, m in msgs[LOAD]])
    if msgs[TRAJECTORY]:
        points = msgs[TRAJECTORY][-1][1].points
        tfs = [p.transforms[0] if len(p.transforms) else None for p in points]
        run.trajectory_time_s = np.array([_stamp_time(p.time_from_start) / 1e9 for p in points])
        run.trajectory_position = np.array([(t.translation.x, t.translation.y, t.translation.z) if t else
                                            (np.nan,) * 3 for t in tfs]).reshape(-1, 3)
        run.trajectory_yaw = np.array([math.atan2(2.0 * (t.rotation.w * t.rotation.z + t.rotation.x * t.rotation.y),
                                                  1.0 - 2.0 * (t.rotation.y ** 2 + t.rotation.z ** 2))
                                       if t else np.nan for t in tfs])
    return run


def _stamp_time(t) -> int:
    return int(t.sec) * NS_PER_S + int(t.nanosec)


# --------------------------------------------------------------- metrics
def _resolve_machine(run: RunData, machine_name: str | None):
    """(MachineConfig or None, how it was found)."""
    import pkm_kinematics

    if machine_name:
        return pkm_kinematics.load_machine(machine_name), "given"
    names = run.state.names if run.state is not None else (run.command.names if run.command is not None else [])
    if not names:
        return None, "unknown"
    matches = []
    for name in pkm_kinematics.machine_names():
        try:
            cfg = pkm_kinematics.load_machine(name)
        except Exception:                         # noqa: BLE001 - a broken config is not this run's
            continue
        if list(cfg.model.leg_names) == list(names):
            matches.append(cfg)
    if len(matches) == 1:
        return matches[0], "drive names"
    return None, "unknown"


def _kind(run: RunData, cfg) -> str:
    if cfg is not None:
        return cfg.kind
    pose = run.true_pose or run.reference
    if pose is None or len(pose.stamp_ns) == 0:
        return "unknown"
    return "planar" if np.all(pose.position[:, 2] == 0.0) else "translational"


def _match(a_stamps: np.ndarray, b_stamps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    _, ia, ib = np.intersect1d(a_stamps, b_stamps, assume_unique=True, return_indices=True)
    return ia, ib


def _wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def _rms(x: np.ndarray) -> float | None:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x * x))) if len(x) else None


def _max_abs(x: np.ndarray) -> float | None:
    x = x[np.isfinite(x)]
    return float(np.max(np.abs(x))) if len(x) else None


def tracking_errors(run: RunData, kind: str) -> dict | None:
    """Errors true pose - reference at the stamps both have: {"stamp_ns", "axes" (N, 2|3)
    m, "translation" (N,) m, "yaw" (N,) rad wrapped to [-pi, pi) (planar only)}."""
    if run.true_pose is None or run.reference is None:
        return None
    it, ir = _match(run.true_pose.stamp_ns, run.reference.stamp_ns)
    planar = kind == "planar"
    axes = (run.true_pose.position[it] - run.reference.position[ir])[:, : 2 if planar else 3]
    out = {"stamp_ns": run.true_pose.stamp_ns[it], "axes": axes, "translation": np.linalg.norm(axes, axis=1)}
    if planar:
        out["yaw"] = _wrap(run.true_pose.yaw[it] - run.reference.yaw[ir])
    return out


def _drive_order(series: JointSeries, model) -> np.ndarray | None:
    names = list(model.leg_names)
    if not series.names or series.names == names:
        return np.arange(len(names)) if series.effort.shape[1] == len(names) else None
    if sorted(series.names) == sorted(names):
        return np.array([series.names.index(n) for n in names])
    return None


def null_space_part(jac: np.ndarray, forces: np.ndarray) -> np.ndarray:
    """f - J (J^T J)^-1 J^T f for every step: ``jac`` (M, n, m), ``forces`` (M, n).

    :func:`pkm_kinematics.distribution.internal_force` vectorised; rows with a non-finite
    J or f, or a singular J^T J (the relative test of ``distribution``: |det| <=
    1e-13 |a00 a11 a22|), are NaN."""
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
    regular = np.abs(det) > 1e-13 * np.abs(diag)
    y = np.linalg.solve(gram[regular], np.einsum("kni,kn->ki", j[regular], f[regular])[..., None])[..., 0]
    rows = np.flatnonzero(ok)[regular]
    out[rows] = f[regular] - np.einsum("kni,ki->kn", j[regular], y)
    return out


def internal_forces(run: RunData, cfg, series: JointSeries | None = None) -> dict:
    """Per-step internal force of drive forces (default: the applied ones, drives/state
    effort): the component f - J (J^T J)^-1 J^T f of f in ker(J^T)
    (the formula of ``pkm_kinematics.distribution.internal_force_rows``, which the plant
    and the controller use, vectorised over the steps), with J = J_m of the *nominal* model of ``cfg`` at the true
    pose of the same stamp (forward kinematics of the encoder positions if the run has
    no true pose). Zero without redundancy (n drives == 3 DOF).

    Returns {"stamp_ns", "norm" (N,) N (NaN where J is singular or the pose unknown),
    "pose_source", "redundancy"} or {"error": reason}."""
    series = run.state if series is None else series
    if series is None or len(series.stamp_ns) == 0:
        return {"error": "no drive forces recorded"}
    if cfg is None:
        return {"error": "machine unknown (no run.json machine, drive names match no config)"}
    model = cfg.model
    order = _drive_order(series, model)
    if order is None:
        return {"error": f"drives {series.names} are not the {cfg.name} drives {list(model.leg_names)}"}
    forces = series.effort[:, order]
    n, dof = model.n_legs, 3
    if n <= dof:
        return {"stamp_ns": series.stamp_ns, "norm": np.zeros(len(series.stamp_ns)),
                "pose_source": "none (no redundancy)", "redundancy": 0}
    planar = cfg.kind == "planar"
    if run.true_pose is not None and len(run.true_pose.stamp_ns):
        i_s, i_p = _match(series.stamp_ns, run.true_pose.stamp_ns)
        pos = run.true_pose.position[i_p]
        poses = np.column_stack([pos[:, 0], pos[:, 1], run.true_pose.yaw[i_p]]) if planar else pos
        source = "true_pose"
    else:
        src = run.state if run.state is not None else series
        i_s, i_q = _match(series.stamp_ns, src.stamp_ns)
        q = src.position[i_q][:, order]
        finite = np.isfinite(q).all(axis=1)
        i_s, q = i_s[finite], q[finite]
        poses, _ = model.forward_kinematics_batch(q)
        source = "forward_kinematics(drives/state position)"
    with np.errstate(all="ignore"):
        jac = model.jacobian_batch(poses) if len(i_s) else np.zeros((0, n, dof))
    norm = np.linalg.norm(null_space_part(jac, forces[i_s]), axis=1)
    return {"stamp_ns": series.stamp_ns[i_s], "norm": norm, "pose_source": source, "redundancy": n - dof}


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


def _peak(series: JointSeries | None) -> tuple[float | None, dict | None]:
    if series is None or len(series.stamp_ns) == 0:
        return None, None
    names = series.names or [f"drive{i}" for i in range(series.effort.shape[1])]
    per = {name: _max_abs(series.effort[:, i]) for i, name in enumerate(names)}
    return _max_abs(series.effort.ravel()), per


def analyse(run: RunData, machine_name: str | None = None) -> dict:
    """What both ``metrics`` and ``plot`` derive from a run, computed once: the machine
    (``cfg``, ``machine_source``), ``kind``, the tracking errors (``err``) and the
    internal forces of the applied (``fi``) and commanded (``fc``, or None) forces."""
    cfg, machine_source = _resolve_machine(run, machine_name)
    kind = _kind(run, cfg)
    fi = internal_forces(run, cfg)
    fc = internal_forces(run, cfg, run.command) if run.command is not None and "error" not in fi else None
    return {"cfg": cfg, "machine_source": machine_source, "kind": kind, "err": tracking_errors(run, kind),
            "fi": fi, "fc": fc}


def metrics(run: RunData, machine_name: str | None = None, published: dict | None = None,
            analysis: dict | None = None) -> dict:
    """Metrics of a run (JSON-serialisable; None where not computable).

    * ``duration_s``: sim time from the first to the last drive state stamp (else /clock,
      else commands); ``steps``: distinct state stamps.
    * ``tracking_error``: e = true_pose - reference at each stamp present in both
      (deduplicated). Translation |e_xy| (planar) or |e_xyz| (translational) in m:
      ``rms_m`` = sqrt(mean |e|^2), ``max_m`` = max |e|, ``max_time_s`` its time from the
      first state; ``rms_axis_m`` per axis. Planar: yaw error wrap(yaw_true - yaw_ref)
      in rad, ``yaw_rms_rad``, ``yaw_max_rad`` (max |.|), ``yaw_max_time_s``.
    * ``drive_force``: ``peak_commanded_n`` = max |drives/command effort|,
      ``peak_applied_n`` = max |drives/state effort|, over all drives and steps, plus per drive.
    * ``internal_force``: per step ||f_int||, f_int = f - J (J^T J)^-1 J^T f, f the applied
      forces, J = J_m of the nominal model at the true pose of the step (see
      :func:`internal_forces`); ``max_n``, ``rms_n`` = sqrt(mean ||f_int||^2); 0 without
      redundancy; the same of the commanded forces (``*_commanded_n``).
    * ``deadline_misses``: the last sim_hw diagnostics' ``deadline_misses``, else None.
    * ``timing``: over the deduplicated commands, ``loop_rate_hz`` = (N - 1) / (last - first
      log time), ``sim_wall_ratio`` = (last - first stamp) / (last - first log time).
    * ``messages``: ``recorded`` per topic (raw, duplicates included); with ``published``
      (run.json; relative names are taken in the namespace) ``lost`` = published -
      recorded per published topic, ``lost_total`` their sum.
    * ``controller``: the last controller status (level, message, values parsed to
      numbers where possible); ``tripped`` if any controller status has level 2 or any
      estop message is true (``trip_reason`` the first such message).
    """
    a = analysis or analyse(run, machine_name)
    cfg, machine_source, kind = a["cfg"], a["machine_source"], a["kind"]
    t0 = run.t0_ns()
    out: dict = {"bag": str(run.bag_path), "namespace": run.namespace,
                 "machine": cfg.name if cfg is not None else machine_name, "machine_source": machine_source,
                 "kind": kind,
                 "drives": (run.state.names if run.state is not None
                            else run.command.names if run.command is not None else [])}

    # duration
    span = None
    for stamps in ((run.state.stamp_ns if run.state is not None else None), run.clock_ns,
                   (run.command.stamp_ns if run.command is not None else None)):
        if stamps is not None and len(stamps):
            span = (int(stamps.max()) - int(stamps.min())) / 1e9
            break
    out["duration_s"] = span
    out["steps"] = len(run.state.stamp_ns) if run.state is not None else 0
    out["duplicates_dropped"] = {run.topic(s): getattr(run, a).duplicates
                                 for s, a in ((STATE, "state"), (COMMAND, "command"), (TRUE_POSE, "true_pose"),
                                              (REFERENCE, "reference"), (STRUTS, "struts"),
                                              (METROLOGY_POSE, "metrology_pose"))
                                 if getattr(run, a) is not None}

    # tracking
    err = a["err"]
    track: dict = {"samples": 0, "rms_m": None, "max_m": None, "max_time_s": None}
    if err is not None and len(err["stamp_ns"]):
        e = err["translation"]
        k = int(np.nanargmax(e))
        track.update(samples=len(e), rms_m=_rms(e), max_m=float(e[k]), max_time_s=(int(err["stamp_ns"][k]) - t0) / 1e9,
                     rms_axis_m=[_rms(err["axes"][:, i]) for i in range(err["axes"].shape[1])])
        if "yaw" in err:
            y = np.abs(err["yaw"])
            ky = int(np.nanargmax(y))
            track.update(yaw_rms_rad=_rms(y), yaw_max_rad=float(y[ky]),
                         yaw_max_time_s=(int(err["stamp_ns"][ky]) - t0) / 1e9)
    elif kind == "planar":
        track.update(yaw_rms_rad=None, yaw_max_rad=None)
    out["tracking_error"] = track

    # drive forces
    pc, pc_per = _peak(run.command)
    pa, pa_per = _peak(run.state)
    out["drive_force"] = {"peak_commanded_n": pc, "peak_applied_n": pa,
                          "peak_commanded_per_drive_n": pc_per, "peak_applied_per_drive_n": pa_per}

    # internal force
    fi = a["fi"]
    internal: dict = {"source": "drives/state effort (applied)", "max_n": None, "rms_n": None, "samples": 0}
    if "error" in fi:
        internal["error"] = fi["error"]
    else:
        norm = fi["norm"]
        internal.update(model=f"nominal {cfg.name}", pose_source=fi["pose_source"], redundancy=fi["redundancy"],
                        max_n=_max_abs(norm), rms_n=_rms(norm), samples=int(np.isfinite(norm).sum()),
                        unavailable_steps=int(len(run.state.stamp_ns) - np.isfinite(norm).sum()))
        fc = a["fc"]
        if fc is not None and "error" not in fc:
            internal.update(max_commanded_n=_max_abs(fc["norm"]), rms_commanded_n=_rms(fc["norm"]))
    out["internal_force"] = internal

    # sim_hw diagnostics
    sim = run.statuses.get("sim_hw", [])
    misses = None
    for rec in reversed(sim):
        if "deadline_misses" in rec.values:
            misses = _parse_value(rec.values["deadline_misses"])
            break
    out["deadline_misses"] = misses
    out["sim_hw"] = {"final_status": _status_dict(sim[-1] if sim else None),
                     "stopped": any(r.level >= 2 for r in sim)}

    # timing
    timing = {"loop_rate_hz": None, "sim_wall_ratio": None, "wall_s": None, "sim_s": None, "source": None}
    for name, series in ((COMMAND, run.command), (STATE, run.state)):
        if series is not None and len(series.stamp_ns) >= 2:
            order = np.argsort(series.log_ns, kind="stable")
            wall = (int(series.log_ns[order[-1]]) - int(series.log_ns[order[0]])) / 1e9
            sim_s = (int(series.stamp_ns.max()) - int(series.stamp_ns.min())) / 1e9
            timing.update(source=run.topic(name), wall_s=wall, sim_s=sim_s,
                          loop_rate_hz=(len(series.stamp_ns) - 1) / wall if wall > 0 else None,
                          sim_wall_ratio=sim_s / wall if wall > 0 else None)
            break
    out["timing"] = timing

    # messages
    msgs: dict = {"recorded": dict(sorted(run.counts.items())), "published": None, "lost": None}
    if published:                                 # relative names are in the machine namespace
        published = {(t if t.startswith("/") else run.topic(t)): int(v) for t, v in published.items()}
        msgs["published"] = dict(sorted(published.items()))
        # nodes count one publication per stamp (discovery repeats of a step are not
        # counted), so the recorded side is counted the same way
        msgs["lost"] = {t: v - run.stamp_counts.get(t, run.counts.get(t, 0)) for t, v in sorted(published.items())}
        msgs["lost_total"] = sum(msgs["lost"].values())
    out["messages"] = msgs

    # controller
    ctrl = run.statuses.get("controller", [])
    reason = None
    for rec in ctrl:
        if rec.level >= 2:
            reason = f"controller status level 2: {rec.message}"
            break
    estop_on = bool(run.estop.any()) if len(run.estop) else False
    if reason is None and estop_on:
        reason = "estop true"
    out["controller"] = {"final_status": _status_dict(ctrl[-1] if ctrl else None), "status_messages": len(ctrl),
                         "tripped": reason is not None, "trip_reason": reason, "estop": estop_on}
    return _clean(out)


# ------------------------------------------------------------------ plots
def _pick(n: int, y: np.ndarray | None = None, limit: int = MAX_PLOT_POINTS) -> np.ndarray:
    """Indices to plot: all if n <= limit; else the min and max of ``y`` in each of
    limit/2 buckets (spikes survive), or every k-th point."""
    if n <= limit:
        return np.arange(n)
    if y is None or not np.isfinite(y).any():
        return np.unique(np.append(np.arange(0, n, math.ceil(n / limit)), n - 1))
    y = np.where(np.isfinite(y), y, np.nanmean(y))
    size = math.ceil(n / (limit // 2))             # bucket length
    full = (n // size) * size
    blocks = y[:full].reshape(-1, size)
    starts = np.arange(0, full, size)
    idx = [starts + np.argmin(blocks, axis=1), starts + np.argmax(blocks, axis=1), [0, n - 1]]
    if full < n:
        tail = y[full:]
        idx.append([full + int(np.argmin(tail)), full + int(np.argmax(tail))])
    idx = np.concatenate([np.asarray(i, dtype=np.int64) for i in idx])
    return np.unique(idx)


def _figure(rows: int, height: float = 3.2):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8.0, height * rows), layout="constrained")
    axes = [fig.add_subplot(rows, 1, i + 1) for i in range(rows)]
    for ax in axes:
        ax.grid(True, alpha=0.3)
    return fig, axes


def plot(run: RunData, out_dir, machine_name: str | None = None, analysis: dict | None = None) -> list[Path]:
    """Figures of the run as PNG files in ``out_dir`` (created): ``path.png`` (tool path
    against the reference, x-y; yaw or z against time), ``tracking_error.png`` (µm, µrad),
    ``drive_forces.png`` (commanded and applied, N, one line per drive) and
    ``internal_force.png`` (norm of the null-space part, N). Figures whose data the run
    lacks are skipped. Long runs are decimated to ~20k points (min/max per bucket)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    a = analysis or analyse(run, machine_name)
    cfg, kind = a["cfg"], a["kind"]
    planar = kind == "planar"
    t0 = run.t0_ns() or 0
    label = f"{cfg.name if cfg is not None else (machine_name or 'machine')} ({run.namespace or '/'})"
    files: list[Path] = []

    def t_of(stamps):
        return (stamps.astype(np.int64) - t0) / 1e9

    def save(fig, name):
        path = out_dir / name
        fig.savefig(path, dpi=110)
        files.append(path)

    # 1. path
    if run.true_pose is not None or run.reference is not None:
        fig, (ax, ax2) = _figure(2, 3.6)
        for series, style, lab in ((run.reference, dict(ls="--", color="tab:gray"), "reference"),
                                   (run.true_pose, dict(color="tab:blue"), "true tool pose")):
            if series is not None and len(series.stamp_ns):
                i = _pick(len(series.stamp_ns))
                ax.plot(series.position[i, 0], series.position[i, 1], lw=1.0, label=lab, **style)
                t = t_of(series.stamp_ns[i])
                if planar:
                    ax2.plot(t, np.degrees(np.unwrap(series.yaw)[i]), lw=1.0, label=lab, **style)
                else:
                    ax2.plot(t, series.position[i, 2], lw=1.0, label=lab, **style)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(f"Tool path, {label}")
        ax.legend(loc="best", fontsize=8)
        ax2.set_xlabel("time (s)")
        ax2.set_ylabel("yaw θ (deg)" if planar else "z (m)")
        ax2.set_title("Tool orientation" if planar else "Tool height")
        ax2.legend(loc="best", fontsize=8)
        save(fig, "path.png")

    # 2. tracking error
    err = a["err"]
    if err is not None and len(err["stamp_ns"]):
        fig, axes = _figure(2 if planar else 1)
        i = _pick(len(err["stamp_ns"]), err["translation"])
        t = t_of(err["stamp_ns"][i])
        ax = axes[0]
        ax.plot(t, err["translation"][i] * 1e6, color="k", lw=1.0, label="|e| (translation)")
        for k, axis in enumerate("xyz"[: err["axes"].shape[1]]):
            ax.plot(t, err["axes"][i, k] * 1e6, lw=0.8, label=f"e_{axis}")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("tracking error (µm)")
        ax.set_title(f"Tracking error (true pose − reference), {label}")
        ax.legend(loc="best", fontsize=8)
        if planar:
            axes[1].plot(t, err["yaw"][i] * 1e6, color="tab:red", lw=0.8)
            axes[1].set_xlabel("time (s)")
            axes[1].set_ylabel("yaw error (µrad)")
            axes[1].set_title("Orientation error")
        save(fig, "tracking_error.png")

    # 3. drive forces
    series_list = [(s, lab) for s, lab in ((run.command, "commanded (drives/command)"),
                                           (run.state, "applied (drives/state)")) if s is not None and len(s.stamp_ns)]
    if series_list:
        fig, axes = _figure(len(series_list))
        for ax, (s, lab) in zip(axes, series_list):
            i = _pick(len(s.stamp_ns))
            t = t_of(s.stamp_ns[i])
            names = s.names or [f"drive {k + 1}" for k in range(s.effort.shape[1])]
            for k, name in enumerate(names):
                ax.plot(t, s.effort[i, k], lw=0.9, label=name)
            ax.set_xlabel("time (s)")
            ax.set_ylabel("drive force (N)")
            ax.set_title(f"Drive forces, {lab}, {label}")
            ax.legend(loc="best", fontsize=8, ncol=len(names))
        save(fig, "drive_forces.png")

    # 4. internal force
    fi = a["fi"]
    if "error" not in fi and len(fi["stamp_ns"]):
        fig, (ax,) = _figure(1)
        i = _pick(len(fi["stamp_ns"]), fi["norm"])
        ax.plot(t_of(fi["stamp_ns"][i]), fi["norm"][i], color="tab:purple", lw=1.0, label="applied")
        fc = a["fc"]
        if fc is not None:
            if "error" not in fc and len(fc["stamp_ns"]):
                j = _pick(len(fc["stamp_ns"]), fc["norm"])
                ax.plot(t_of(fc["stamp_ns"][j]), fc["norm"][j], color="tab:orange", lw=0.8, ls="--",
                        label="commanded")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("‖f_int‖ (N)")
        ax.set_title(f"Norm of the internal force (null space of J_mᵀ, nominal model), {label}")
        ax.legend(loc="best", fontsize=8)
        save(fig, "internal_force.png")
    return files


# ----------------------------------------------------------------- report
def read_run_json(run_dir) -> dict:
    path = Path(run_dir) / "run.json"
    if not path.is_file():
        return {}
    with open(path, encoding="utf-8") as fh:
        data = json.load(fh)
    return data if isinstance(data, dict) else {}


def write_report(run_dir, out_dir=None) -> dict:
    """Metrics and figures of a run directory: reads ``run.json`` if present (machine,
    namespace, published counts), writes ``<out_dir>/metrics.json`` (default
    ``<run_dir>/report``) and the PNGs; returns the metrics (with ``scenario``,
    ``run_dir`` and the ``plots`` file names added)."""
    run_dir = Path(run_dir)
    info = read_run_json(run_dir)
    run = load_run(run_dir, namespace=info.get("namespace"))
    out_dir = Path(out_dir) if out_dir is not None else run_dir / "report"
    out_dir.mkdir(parents=True, exist_ok=True)
    analysis = analyse(run, info.get("machine"))
    result = metrics(run, info.get("machine"), info.get("published"), analysis)
    result = {"scenario": info.get("scenario"), "run_dir": str(run_dir), **result}
    files = plot(run, out_dir, result.get("machine"), analysis)
    result["plots"] = [f.name for f in files]
    with open(out_dir / "metrics.json", "w", encoding="utf-8") as fh:
        json.dump(result, fh, indent=2, allow_nan=False)
        fh.write("\n")
    return result


def _fmt(value, scale: float = 1.0, digits: int = 1, unit: str = "") -> str:
    if value is None:
        return "n/a"
    return f"{value * scale:.{digits}f}{(' ' + unit) if unit else ''}"


def summary(m: dict) -> str:
    """A short human-readable table of the metrics."""
    te, df, fi, tm = m["tracking_error"], m["drive_force"], m["internal_force"], m["timing"]
    rows = [("run", f"{m.get('scenario') or '-'}  machine {m.get('machine') or '?'} ({m['kind']}), "
                    f"namespace {m['namespace'] or '/'}"),
            ("duration", f"{_fmt(m['duration_s'], digits=3, unit='s')} sim, {m['steps']} steps"),
            ("timing", f"{_fmt(tm['loop_rate_hz'], unit='Hz')} loop, {_fmt(tm['sim_wall_ratio'], digits=3)} x real "
                       f"time ({_fmt(tm['wall_s'], digits=2, unit='s')} wall)"),
            ("tracking error", f"RMS {_fmt(te['rms_m'], 1e6, unit='µm')}, max {_fmt(te['max_m'], 1e6, unit='µm')}"
                               + (f" at {te['max_time_s']:.3f} s" if te.get("max_time_s") is not None else ""))]
    if m["kind"] == "planar":
        rows.append(("yaw error", f"RMS {_fmt(te.get('yaw_rms_rad'), 1e6, unit='µrad')}, "
                                  f"max {_fmt(te.get('yaw_max_rad'), 1e6, unit='µrad')}"))
    rows += [("peak drive force", f"commanded {_fmt(df['peak_commanded_n'], unit='N')}, "
                                  f"applied {_fmt(df['peak_applied_n'], unit='N')}"),
             ("internal force", f"max {_fmt(fi['max_n'], unit='N')}, RMS {_fmt(fi['rms_n'], unit='N')}"
                                + (f"  ({fi['error']})" if fi.get("error") else "")),
             ("deadline misses", "n/a" if m["deadline_misses"] is None else str(m["deadline_misses"]))]
    lost = m["messages"].get("lost")
    if lost is None:
        rows.append(("messages", f"{sum(m['messages']['recorded'].values())} recorded (no published counts)"))
    else:
        bad = {t: n for t, n in lost.items() if n}
        rows.append(("messages lost", ", ".join(f"{t} {n}" for t, n in bad.items()) if bad else "none"))
    c = m["controller"]
    final = c["final_status"]
    state = "n/a" if final is None else f"level {final['level']} '{final['message']}'"
    rows.append(("controller", f"{state}; " + (f"TRIPPED ({c['trip_reason']})" if c["tripped"] else "not tripped")))
    if m.get("plots") is not None:
        rows.append(("figures", ", ".join(m["plots"]) or "none"))
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="pkm-report", description="Metrics and figures of a recorded PKM run.")
    parser.add_argument("run_dir", help="run directory (with bag/ and run.json) or a rosbag2 directory")
    parser.add_argument("--out", help="output directory (default <run_dir>/report)")
    args = parser.parse_args(argv)
    try:
        result = write_report(args.run_dir, args.out)
    except (NoBagError, ValueError) as exc:       # ValueError: e.g. ambiguous namespace, unknown machine
        print(f"pkm-report: error: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else Path(args.run_dir) / "report"
    print(summary(result))
    print(f"{'written':<16}  {out / 'metrics.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
