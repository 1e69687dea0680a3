"""``pkm-run``: run a scenario end to end — every node, recording, summary, report.

Multi-process (default): recorder, sim_hw, gough_sensor, controller and
trajectory_node as processes, started together (processes.py), parameters from the
scenario (scenario.py) written to ``<run_dir>/params/<node>.yaml``. The run starts
only when the graph is connected (every stream of the scenario has its publisher and
subscriber, the recorder is subscribed to all of them, the planner is up): then
pkm-run publishes the start signal, and the controller (told to wait for it, and with
a program for its trajectory) answers the first state and the lockstep begins; in
realtime mode trajectory_node runs all the same, for the goals and programs of an
operator (pkm-panel). The run ends
when sim_hw reaches ``duration_s``; the nodes are then stopped in order, the recorder
last. A node that exits early is a crash: reported with its last output, everything
else stopped. Ctrl-C / SIGTERM stop everything the same way (the bag is finalized).

In-process (``--in-process``): the same nodes and parameters in one executor, for fast
tests; in lockstep both modes compute the same run (tests/bringup).

Direct (``--engine direct``): the same loops without a transport, in one process
(direct.py): a lockstep scenario on the simulated machine, the graph's run byte for
byte (tests/bringup/test_direct_engine.py), several times faster; studies use it.

Realtime profile (``--rt-profile``, or the scenario's ``realtime_profile: true``):
SCHED_FIFO and locked memory for the loop's nodes (rt_profile.py), set as each
process starts; in one process, for the whole process during the run. Refused (exit
2, nothing started) where the OS does not allow it.

Every command that can move the machine carries the run's credential (pkm_common.credential):
pkm-run makes a key per run (``credential.key``, mode 600) or takes one (``--credential``:
a panel's, a script's), gives its path to the nodes, and signs its start signal.

Run directory::

    runs/<date>-<time>_<scenario>/
      credential.key  scenario.yaml  params/<node>.yaml  logs/<node>.log  summaries/<node>.json
      bag/ (rosbag2: metadata.yaml + .mcap)  run.json  report/ (metrics.json, *.png)

The graph's side (rclpy: the checks before the start, the nodes as processes) is
graph.py, the nodes in one executor in_process.py; this module sequences a run around
them: the run directory, the run lock, run.json, a dead recorder's bag recovered, the
report.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import signal
import sys
import time
from pathlib import Path

from pkm_bringup import run_cli
from pkm_bringup.engines import ENGINES
from pkm_bringup.graph import Progress, RunFailed, StopSignals, run_processes
from pkm_bringup.processes import use_ros_environment
from pkm_bringup.rt_profile import RealtimeProfileRefused, applied_to_this_process, check_permitted
from pkm_bringup.run_files import DiskReserve
from pkm_bringup.scenario import (Scenario, ScenarioError, laser_tracker_parameters, load_scenario, node_parameters,
                                  params_file_text)
from pkm_common.causes import TripCause, parse_cause, run_status
from pkm_common.credential import KEY_FILE, RunKey
from pkm_common.files import disk_full, durable, write_json
from pkm_recording.bag import recorded_stamps, recover
from pkm_recording.memory import MAX_SECONDS
from pkm_runs.report import analyse_recording, summary, write_report
from pkm_runs.report_metrics import metrics_dict


# pkm-run's exit code per run status (2: the scenario or the arguments were refused)
EXIT_CODES = {"completed": 0, "failed": 1, "tripped": 3}


def run_cause(summaries: dict, failure: TripCause = TripCause.NONE, error: str = "") -> tuple[TripCause, str]:
    """The cause that started the run's stop and its reason (trip_cause), but a node
    that died (``failure``) when the machine did not stop before, or stopped only as a
    consequence: its inputs went silent (watchdog), its plant braked."""
    cause, reason = trip_cause(summaries)
    if failure != TripCause.NONE and cause in (TripCause.NONE, TripCause.WATCHDOG, TripCause.PLANT_SAFE_STOP):
        return failure, error.split("; its last output")[0]
    return cause, reason


def make_run_dir(s: Scenario, root: Path) -> Path:
    run_dir = root / f"{time.strftime('%Y%m%d-%H%M%S')}_{s.name}"
    suffix = 1
    while run_dir.exists():
        suffix += 1
        run_dir = root / f"{time.strftime('%Y%m%d-%H%M%S')}_{s.name}_{suffix}"
    return run_dir


LOCK_DIR = Path(os.environ.get("PKM_RUN_LOCK_DIR", "/tmp/pkm-run-locks"))


class RunLock:
    """One run per DDS domain and namespace on this machine: an exclusive ``flock`` on
    ``LOCK_DIR/domain-<id><namespace>.lock``, held for the run and released by the
    kernel when the process ends (however it ends). Discovery is kept on localhost,
    so this covers every run that could cross-talk, without waiting for discovery."""

    def __init__(self, namespace: str):
        domain = os.environ.get("ROS_DOMAIN_ID", "0")
        self.path = LOCK_DIR / f"domain-{domain}{namespace.replace('/', '_')}.lock"
        self.domain, self.namespace, self.fh = domain, namespace, None

    def __enter__(self):
        LOCK_DIR.mkdir(parents=True, exist_ok=True)
        self.fh = open(self.path, "a+", encoding="utf-8")
        try:
            fcntl.flock(self.fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self.fh.seek(0)
            holder = self.fh.read().strip() or "another process"
            self.fh.close()
            raise RunFailed(f"another run is active in ROS_DOMAIN_ID={self.domain}, namespace {self.namespace} "
                            f"({holder}); use another domain (export ROS_DOMAIN_ID=...) or namespace") from None
        self.fh.seek(0)
        self.fh.truncate()
        self.fh.write(f"pid {os.getpid()}")
        self.fh.flush()
        return self

    def __exit__(self, *exc):
        self.fh.close()                       # closing releases the lock


def _in_process_profile(s: Scenario, in_process: bool):
    """One process with the realtime profile: the whole orchestrator at the loop's
    priority with its memory locked for the run (the recorder, on the loop's thread,
    with it), then as before; a no-op otherwise."""
    if not (in_process and s.realtime_profile):
        return contextlib.nullcontext()
    return applied_to_this_process()


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}


def trip_cause(summaries: dict) -> tuple[TripCause, str]:
    """The cause that started the run's stop, and its reason: the controller's (it takes
    the plant's when the plant braked first: then in the plant's own words, which name
    what stopped it, a drive and its error code), else the plant's."""
    machine = summaries.get("sim_hw") or summaries.get("drives") or summaries.get("ros2_control") or {}
    for node in ("controller", "sim_hw", "drives", "ros2_control"):
        summary = summaries.get(node, {})
        if summary.get("stopped"):
            try:
                cause = parse_cause(summary.get("cause", "none"))
            except ValueError:
                continue
            if cause != TripCause.NONE:
                reason = summary.get("stop_reason") or summary.get("message", "")
                if node == "controller" and machine.get("stopped") and machine.get("cause") == cause.value:
                    reason = machine.get("stop_reason") or reason
                return cause, reason
    return TripCause.NONE, ""


def collect(s: Scenario, run_dir: Path, mode: str, wall_s: float, codes: dict, error: str = "",
            failure: TripCause = TripCause.NONE) -> dict:
    """run.json: node summaries, published vs recorded per topic, exit codes; ``failure``:
    the cause of the RunFailed that ended it (run_cause)."""
    summaries = {p.stem: _read_json(p) for p in sorted((run_dir / "summaries").glob("*.json"))}
    published = {}
    for node in (s.machine_node, "controller", "gough_sensor", "laser_tracker"):
        for topic, count in summaries.get(node, {}).get("published", {}).items():
            if topic == "platform/true_pose" and node != "sim_hw":
                continue                     # the drive interface has no ground truth (the virtual drives do)
            published[s.topic(topic)] = count
    recorded = summaries.get("recorder", {}).get("recorded_stamps", {})
    lost = {t: n - recorded.get(t, 0) for t, n in published.items()} if s.record else {}
    refused = [f for f in str(summaries.get("controller", {}).get("faults", "")).split("; ")
               if f.startswith("trajectory refused")]
    if s.program is not None and s.mode == "lockstep" and refused and not error:
        error = f"the program did not run: the controller {refused[0]}"     # it held still: not a completed run
    if any(v < 0 for v in lost.values()) and not error:
        error = (f"more messages recorded than published on {[t for t, v in lost.items() if v < 0]}: "
                 "another graph publishes in this domain and namespace")
    cause, reason = run_cause(summaries, failure, error)
    # DDS delivery to the sensor is not a recording loss, but a true pose it never
    # measured is a step the metrology missed: stated, not silent
    sensor, sim = summaries.get("gough_sensor", {}), summaries.get(s.machine_node, {})
    sensor_missed = max(0, sim.get("published", {}).get("platform/true_pose", 0)
                        - sensor.get("published", {}).get("metrology/struts", 0)) if sensor and sim else 0
    run = {"scenario": s.name, "machine": s.machine, "model": s.controller_machine,
           "laser_tracker": laser_tracker_parameters(s), "namespace": s.namespace,
           "mode": mode,
           "strategy": s.strategy, "distribution": s.controller.get("distribution"),
           "metrology": s.metrology, "realtime_profile": s.realtime_profile, "duration_s": s.duration_s,
           "wall_s": wall_s,
           "status": run_status(error, cause), "error": error, "cause": str(cause), "trip_reason": reason,
           "sensor_missed_steps": sensor_missed, "exit_codes": codes,
           "published": published, "recorded": recorded, "lost": lost, "summaries": summaries}
    _write_run(run_dir, run)
    return run


def _write_run(run_dir: Path, run: dict) -> None:
    """run.json, whole (run_files.write_json); a disk too full even for it is said on
    stderr and in the returned record, never a traceback."""
    try:
        write_json(run_dir / "run.json", run)
    except OSError as exc:
        run["status"], run["error"] = "failed", run.get("error") or f"run.json not written: {exc}"
        print(f"pkm-run: run.json not written: {exc}", file=sys.stderr)


def run_scenario(s: Scenario, run_dir: Path, in_process: bool = False, progress: bool = True,
                 report: bool = True, credential: Path | None = None, engine: str = "graph",
                 recording=None) -> dict:
    """Run ``s`` into ``run_dir`` (created); returns run.json's content (status
    ``completed`` or ``failed`` with ``error``), with ``metrics`` when recorded.
    ``credential``: the key file the run's commands are signed with (a panel's, a
    script's: pkm_common.credential); by default a new one in the run directory.
    ``engine``: "graph" (the ROS 2 nodes, as processes or ``in_process``) or "direct"
    (the same loops without a transport, pkm_bringup.direct; a scenario it cannot run
    fails with the reason, nothing started). ``recording``: a
    pkm_recording.memory.MemoryRecording for a recorded scenario in the direct engine of
    at most memory.MAX_SECONDS: its messages are kept there instead of a bag, and the
    metrics (``metrics``, no report files) are taken from them (a study's run whose
    bag would be removed once read); a failed run's are written as its bag.
    Raises rt_profile.RealtimeProfileRefused, before anything is made or started,
    when the scenario asks for the realtime profile and the OS does not allow it."""
    if engine not in ENGINES:
        raise ValueError(f"engine: must be one of {ENGINES}, got {engine!r}")
    direct = engine == "direct"
    if recording is not None and not (direct and s.record and s.duration_s <= MAX_SECONDS):
        raise ValueError(f"recording: in memory only for a recorded run of at most {MAX_SECONDS:g} s in the direct "
                         f"engine (engine {engine}, record {s.record}, duration_s {s.duration_s:g})")
    if s.realtime_profile and not direct:
        check_permitted(in_process)
    mode = "direct" if direct else "in_process" if in_process else "processes"
    reserves = []
    try:                                       # nothing started yet: a full disk is said, not a traceback
        for sub in ("params", "logs", "summaries"):
            (run_dir / sub).mkdir(parents=True, exist_ok=True)
        # the end of the run's space, kept from the start: the nodes' summaries, then run.json
        # (none for a directory thrown away once read: files.scratch)
        reserves = [DiskReserve(run_dir, "nodes"), DiskReserve(run_dir, "end")] if durable() else []
        for reserve in reserves:
            if not reserve.held:
                raise OSError(reserve.error)
        for stale in (run_dir / "summaries").glob("*.json"):     # a run directory used again
            stale.unlink()
        if direct:
            from pkm_bringup.direct import refusal      # (without rclpy's graph: imported for this engine only)
            if refusal(s):
                raise ValueError(refusal(s))
        if credential is None:
            RunKey.create(run_dir / KEY_FILE)
        params = node_parameters(s, run_dir, credential)
        for name, values in params.items():
            (run_dir / "params" / f"{name}.yaml").write_text(params_file_text(values), encoding="utf-8")
        (run_dir / "scenario.yaml").write_text(s.source.read_text(encoding="utf-8"), encoding="utf-8")
        if credential is not None:
            RunKey.read(credential)                # a key others may read, or none: said before anything starts
    except BaseException as exc:
        for reserve in reserves:
            reserve.release()
        if isinstance(exc, ValueError):
            return collect(s, run_dir, mode, 0.0, {}, f"{exc}; nothing started")
        if not isinstance(exc, OSError):
            raise
        return collect(s, run_dir, mode, 0.0, {}, f"the run directory cannot be written, nothing started: {exc}")
    if not direct:                                  # no transport, nothing to cross-talk with
        use_ros_environment()
    start = time.monotonic()
    error, codes, interruption, failure = "", {}, _Interruption(), TripCause.NONE
    try:
        if direct:
            from pkm_bringup.direct import run_direct as run
        elif in_process:       # (imported for this mode only: it loads every node's module, seconds)
            from pkm_bringup.in_process import run_in_process as run
        else:
            run = run_processes
        with interruption, RunLock(s.namespace) if not direct else contextlib.nullcontext(), \
                _in_process_profile(s, in_process and not direct):
            run(s, run_dir, params, Progress(s.duration_s, enabled=progress), codes, interruption,
                reserves[0] if reserves else None,
                *(() if recording is None else (recording,)))
    except RunFailed as exc:
        error, failure = str(exc), exc.cause
    except KeyboardInterrupt:
        error = INTERRUPTED
    except Exception as exc:                      # noqa: BLE001 - reported in run.json, never a traceback
        # a signal's KeyboardInterrupt raised while rclpy's executor converts a message
        # for a callback comes out of pybind11 as RuntimeError("Unable to convert call
        # argument ..."): the run was interrupted all the same
        error = INTERRUPTED if interruption.signalled else f"{type(exc).__name__}: {exc}"
    for reserve in reserves:                       # (the first: a runner that failed before its loop)
        reserve.release()
    recovered = _recover_bag(s, run_dir)
    result = collect(s, run_dir, mode, time.monotonic() - start, codes, error, failure)
    if recovered:
        result["recovered"] = recovered
        _write_run(run_dir, result)
    if recording is not None and len(recording) and result["status"] == "failed":
        try:                                       # kept for pkm-report and pkm-replay on the failure
            recording.write_bag(run_dir / "bag")
        except (OSError, ValueError) as exc:
            result["report_error"] = f"the failed run's bag not written: {exc}"
    if recording is not None and len(recording):
        try:
            result["metrics"] = metrics_dict(analyse_recording(recording, namespace=result.get("namespace"),
                                                               machine_name=result.get("machine")),
                                             result.get("published"))
        except ValueError as exc:                  # messages the analysis cannot read: said, no traceback
            result["report_error"] = str(exc)
    elif report and s.record and (run_dir / "bag" / "metadata.yaml").exists():
        try:
            result["metrics"] = write_report(run_dir)
        except (ValueError, OSError) as exc:      # an unreadable bag (IncompleteBagError, ...): said, no traceback
            result["report_error"] = str(exc)
            if disk_full(exc):                     # the run's record is incomplete: the run failed
                result["status"], result["error"] = "failed", result["error"] or f"report: the disk is full: {exc}"
                _write_run(run_dir, result)
    return result


def _recover_bag(s: Scenario, run_dir: Path) -> dict:
    """A bag whose recorder died (no metadata.yaml): made readable up to its last
    complete chunk (bag.recover); the recorder's summary then holds what was saved, so
    that run.json states the loss. {} when there was nothing to recover."""
    bag = run_dir / "bag"
    if not s.record or not bag.is_dir() or (bag / "metadata.yaml").exists() or not any(bag.glob("*.mcap")):
        return {}
    try:
        counts = recover(bag)
    except (OSError, ValueError) as exc:
        return {"error": f"bag could not be recovered: {exc}"}
    summary_path = run_dir / "summaries" / "recorder.json"
    if not _read_json(summary_path):          # the recorder was killed (its reserved file holds zeros): the bag's count
        write_json(summary_path, {"recorded_stamps": recorded_stamps(bag), "recovered": True})
    return {"messages": sum(counts.values()) if isinstance(counts, dict) else counts}


def format_summary(run: dict, run_dir: Path) -> str:
    sims = run["summaries"].get("sim_hw") or run["summaries"].get("drives") or run["summaries"].get("ros2_control", {})
    ctrl = run["summaries"].get("controller", {})
    lines = [f"scenario {run['scenario']} ({run['machine']}, {run['strategy']}"
             f"{', ' + run['distribution'] if run.get('distribution') else ''}, {run['mode']}"
             f"{', realtime profile' if run.get('realtime_profile') else ''}): {run['status']}"]
    if run.get("model", run["machine"]) != run["machine"]:
        lines.append(f"  the controller's model: {run['model']}")
    if run["error"]:
        lines.append(f"  error: {run['error']}")
    if run.get("cause", "none") != "none":
        lines.append(f"  stopped by {run['cause']}: {run.get('trip_reason', '')}")
    if run.get("sensor_missed_steps"):
        lines.append(f"  gough_sensor: {run['sensor_missed_steps']} true poses not measured")
    if run.get("recovered"):
        lines.append(f"  the recorder did not finish: bag recovered up to its last chunk ({run['recovered']})")
    if sims:
        rate = sims.get("steps_per_s")
        lines.append(f"  steps {sims.get('steps')}  sim {sims.get('sim_time_s', 0):.3f} s  wall {run['wall_s']:.1f} s"
                     f"  loop {rate:.0f} steps/s" if rate else f"  steps {sims.get('steps')}")
        if sims.get("stopped"):
            lines.append(f"  plant stopped: {sims.get('stop_reason')}")
    if ctrl:
        lines.append(f"  controller: {ctrl.get('message')}  compute p50 {ctrl.get('compute_us_p50', 0):.0f} us"
                     f"  p99 {ctrl.get('compute_us_p99', 0):.0f} us")
    if run.get("report_error"):
        lines.append(f"  no report: {run['report_error']}")
    if run.get("metrics"):
        lines.append("  " + summary(run["metrics"]).replace("\n", "\n  "))
    lines.append(f"  run directory: {run_dir}")
    return "\n".join(lines)


INTERRUPTED = "interrupted (Ctrl-C / SIGTERM)"


def _interrupt(*_):
    raise KeyboardInterrupt


class _Interruption(StopSignals):
    """Ctrl-C and SIGTERM raise KeyboardInterrupt inside the block, as
    ``signalled`` records (main thread only; elsewhere the handlers stay as they are
    and nothing is recorded)."""

    signalled = False

    def __init__(self):
        super().__init__(self._raise)

    def _raise(self, *_):
        if self.signalled:                 # a second signal (a panel's SIGTERM after a Ctrl-C, ...):
            return                         # the ordered stop of the first one is running
        self.signalled = True
        raise KeyboardInterrupt


def main(argv=None) -> int:
    """pkm-run (its console script is run_cli.main: the same, its arguments read first)."""
    return run_command(run_cli.parser().parse_args(argv))


def run_command(args) -> int:
    """pkm-run with its parsed arguments (run_cli.parser)."""
    overrides = {**({"record": False} if args.no_record else {}),
                 **({"realtime_profile": True} if args.rt_profile else {})}
    try:
        s = load_scenario(args.scenario, overrides)
    except ScenarioError as exc:
        print(f"pkm-run: {exc}", file=sys.stderr)
        return 2
    direct = args.engine == "direct"
    if direct:
        from pkm_bringup.direct import refusal
        if refusal(s) or args.in_process:
            print(f"pkm-run: --engine direct: {refusal(s) or 'the engine is one process already (no --in-process)'}",
                  file=sys.stderr)
            return 2
    elif s.realtime_profile:                  # refused before anything is made or started
        try:
            check_permitted(args.in_process)
        except RealtimeProfileRefused as exc:
            print(f"pkm-run: {exc}", file=sys.stderr)
            return 2
    run_dir = (Path(args.run_dir) if args.run_dir else make_run_dir(s, Path(args.runs))).resolve()
    if run_dir.exists() and any(run_dir.iterdir()):
        print(f"pkm-run: run directory {run_dir} exists and is not empty", file=sys.stderr)
        return 2
    signal.signal(signal.SIGTERM, _interrupt)
    where = "the direct engine" if direct else \
        f"ROS_DOMAIN_ID={use_ros_environment()['ROS_DOMAIN_ID']}"     # this shell's, or one claimed: said, to join it
    print(f"running {s.name}: {s.description or s.machine} ({s.duration_s:.3f} s simulated, {where})", flush=True)
    credential = Path(args.credential).resolve() if args.credential else None
    print(f"commands need the credential in {credential or run_dir / KEY_FILE}", flush=True)
    run = run_scenario(s, run_dir, in_process=args.in_process, progress=not args.no_progress,
                       credential=credential, engine=args.engine)
    print(format_summary(run, run_dir), flush=True)
    return EXIT_CODES[run["status"]]


if __name__ == "__main__":
    sys.exit(main())
