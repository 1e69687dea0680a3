"""Run reports: metrics and figures from a recorded run (rosbag2 + MCAP).

Pure module (no rclpy). A run directory is ``<run_dir>/bag/`` (metadata.yaml + .mcap)
plus an optional ``<run_dir>/run.json`` (``machine``, ``namespace``, ``published``
counts, ``scenario``). The report streams the bag: its memory does not grow with the
length of the run (``benchmarks/report_memory.py`` measures it). One module per concern:

* ``report_data``     reading: :class:`RunReader` (the bag as blocks of per-step columns,
  deduplicated and joined by stamp), :func:`load_run` (a whole run in memory)
* ``report_metrics``  :class:`RunAnalysis` (blocks -> running statistics), the per-row
  formulas, :func:`metrics_dict` (definitions of every metric)
* ``report_plots``    decimated curves and the figures
* this module         :func:`write_report` (run directory -> ``report/metrics.json`` +
  PNGs), :func:`summary`, the in-memory helpers (:func:`metrics`, :func:`plot`,
  :func:`tracking_errors`, :func:`internal_forces` of a :class:`RunData`) and
  :func:`main`: ``pkm-report <run_dir> [--out DIR] [--recover]``
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pkm_recording import bag as bagfile
from pkm_recording.bag import IncompleteBagError
from pkm_runs.report_data import (BLOCK_ROWS, COMMAND, DEFAULT_NAMESPACE, DIAGNOSTICS, ESTOP, KNOWN_SUFFIXES, LOAD,
                                     METROLOGY_POSE, NS_PER_S, REFERENCE, STATE, STATUS, STRUTS, TRAJECTORY,
                                     TRUE_POSE, BagReadError, JointSeries, NoBagError, PoseSeries, RunData, RunInfo,
                                     RunReader, StatusRecord, StepBlock, find_bag, load_run)
from pkm_runs.report_metrics import (Analysis, RunAnalysis, block_internal_forces, internal_force_setup,
                                        metrics_dict, null_space_part, tracking_error_rows)
from pkm_runs.report_plots import MAX_PLOT_POINTS, MinMaxDecimator, draw
from pkm_kinematics.task_space import PLANAR

__all__ = ["Analysis", "BagReadError", "IncompleteBagError", "JointSeries", "MAX_PLOT_POINTS", "MinMaxDecimator",
           "NoBagError", "PoseSeries", "RunData", "RunInfo", "RunReader", "StatusRecord", "StepBlock", "analyse",
           "analyse_bag", "analyse_recording", "find_bag", "internal_forces", "load_run", "main", "metrics",
           "null_space_part", "plot", "read_run_json", "summary", "tracking_errors", "write_report", "COMMAND",
           "DEFAULT_NAMESPACE", "DIAGNOSTICS", "ESTOP", "KNOWN_SUFFIXES", "LOAD", "METROLOGY_POSE", "NS_PER_S",
           "REFERENCE", "STATE",
           "STATUS", "STRUTS", "TRAJECTORY", "TRUE_POSE"]


# ------------------------------------------------------------ analysis
def analyse_bag(run_dir_or_bag, namespace: str | None = None, machine_name: str | None = None,
                plot_points: int = MAX_PLOT_POINTS) -> Analysis:
    """Stream a recorded run through :class:`RunAnalysis` (memory independent of its length)."""
    return _analyse(RunReader(run_dir_or_bag, namespace), machine_name, plot_points)


def analyse_recording(recording, namespace: str | None = None, machine_name: str | None = None,
                      plot_points: int = MAX_PLOT_POINTS) -> Analysis:
    """:func:`analyse_bag` of a run's messages kept in memory instead of a bag
    (pkm_recording.memory.MemoryRecording, a direct run's): the same analysis."""
    return _analyse(RunReader("memory", namespace, source=recording), machine_name, plot_points)


def _analyse(reader: RunReader, machine_name: str | None, plot_points: int) -> Analysis:
    with reader:
        analysis = RunAnalysis(reader.info, machine_name, plot_points)
        for block in reader.blocks():
            analysis.add(block)
        return analysis.finish()


def analyse(run: RunData, machine_name: str | None = None, plot_points: int = MAX_PLOT_POINTS) -> Analysis:
    """:class:`RunAnalysis` of a run in memory (its steps folded block by block, as a
    streamed run is)."""
    analysis = RunAnalysis(run.info, machine_name, plot_points)
    for start in range(0, len(run.steps), BLOCK_ROWS):
        analysis.add(run.steps.take(slice(start, start + BLOCK_ROWS)))
    return analysis.finish()


def metrics(run: RunData, machine_name: str | None = None, published: dict | None = None,
            analysis: Analysis | None = None) -> dict:
    """Metrics of a run in memory (:func:`pkm_runs.report_metrics.metrics_dict` says
    what each one is)."""
    return metrics_dict(analysis or analyse(run, machine_name), published)


def plot(run: RunData, out_dir, machine_name: str | None = None, analysis: Analysis | None = None) -> list[Path]:
    """Figures of a run in memory as PNG files in ``out_dir`` (see
    :func:`pkm_runs.report_plots.draw`)."""
    a = analysis or analyse(run, machine_name)
    return draw(a.figures, a.figure_spec(machine_name), out_dir)


def tracking_errors(run: RunData, space) -> dict | None:
    """Errors true pose - reference at the stamps both have: {"stamp_ns", "axes" (N, 2|3)
    m, "translation" (N,) m, "yaw" (N,) rad wrapped to [-pi, pi) (planar only)}; None
    without a true pose or a reference."""
    tp, ref = run.steps.rows.get("true_pose"), run.steps.rows.get("reference")
    if tp is None or ref is None:
        return None
    both = tp.present & ref.present
    out = tracking_error_rows(tp.position[both], tp.orientation[both], ref.position[both], ref.orientation[both],
                              space is PLANAR)
    return {"stamp_ns": run.steps.stamp_ns[both], **out}


def internal_forces(run: RunData, cfg, series: str = "state") -> dict:
    """Per-step internal force of the drive forces of ``series`` ("state": the applied
    ones, drives/state effort; or "command"): the component f - J (J^T J)^-1 J^T f of f in
    ker(J^T), J = J_m of the *nominal* model of ``cfg`` at the true pose of the same stamp
    (forward kinematics of the encoder positions if the run has no true pose); zero
    without redundancy (``report_metrics.internal_force_rows``).

    Returns {"stamp_ns", "norm" (N,) N (NaN where J is singular), "pose_source",
    "redundancy"} over the stamps with a pose, or {"error": reason}."""
    rows = run.steps.rows.get(series)
    setup = internal_force_setup(run.info, cfg, series, int(rows.present.sum()) if rows is not None else 0)
    if "error" in setup:
        return setup
    stamps, norm = block_internal_forces(run.steps, run.info, cfg, series)
    return {"stamp_ns": stamps, "norm": norm, **setup}


# ------------------------------------------------------------ report
def read_run_json(run_dir) -> dict:
    path = Path(run_dir) / "run.json"
    if not path.is_file():
        return {}
    with open(path, encoding="utf-8") as fh:
        data = json.load(fh)
    return data if isinstance(data, dict) else {}


def write_report(run_dir, out_dir=None) -> dict:
    """Metrics and figures of a run directory, streaming its bag: reads ``run.json`` if
    present (machine, namespace, published counts), writes ``<out_dir>/metrics.json``
    (default ``<run_dir>/report``) and the PNGs; returns the metrics (with ``scenario``,
    ``run_dir`` and the ``plots`` file names added). Raises :class:`NoBagError`,
    ``IncompleteBagError`` (``pkm_recording.bag.recover`` makes the bag readable) or
    :class:`BagReadError`."""
    run_dir = Path(run_dir)
    info = read_run_json(run_dir)
    analysis = analyse_bag(run_dir, namespace=info.get("namespace"), machine_name=info.get("machine"))
    out_dir = Path(out_dir) if out_dir is not None else run_dir / "report"
    out_dir.mkdir(parents=True, exist_ok=True)
    result = metrics_dict(analysis, info.get("published"))
    result = {"scenario": info.get("scenario"), "run_dir": str(run_dir), **result}
    # the controller's model when it is not the machine's file (a calibrated one)
    result["model"] = info["model"] if info.get("model") not in (None, info.get("machine")) else None
    files = draw(analysis.figures, analysis.figure_spec(result.get("machine")), out_dir)
    result["plots"] = [f.name for f in files]
    with open(out_dir / "metrics.json", "w", encoding="utf-8") as fh:
        json.dump(result, fh, indent=2, allow_nan=False)
        fh.write("\n")
    return result


def _fmt(value, scale: float = 1.0, digits: int = 1, unit: str = "") -> str:
    if value is None:
        return "n/a"
    return f"{value * scale:.{digits}f}{(' ' + unit) if unit else ''}"


def stop_line(m: dict) -> str:
    """The run's stop in a few words: its cause, when and who said it."""
    cause = m.get("trip_cause", "none")
    if cause in (None, "none"):
        return "none"
    when = f" at {m['trip_time_s']:.3f} s" if m.get("trip_time_s") is not None else ""
    said = f" ({m['trip_source']}: {m['trip_reason']})" if m.get("trip_source") else ""
    return f"{cause}{when}{said}"


def summary(m: dict) -> str:
    """A short human-readable table of the metrics."""
    te, df, fi, tm = m["tracking_error"], m["drive_force"], m["internal_force"], m["timing"]
    rows = [("run", f"{m.get('scenario') or '-'}  machine {m.get('machine') or '?'} ({m['kind']}), "
                    f"namespace {m['namespace'] or '/'}"),
            ("controller's model", m.get("model") or "the machine's file"),
            ("duration", f"{_fmt(m['duration_s'], digits=3, unit='s')} sim, {m['steps']} steps"),
            ("stopped by", stop_line(m)),
            ("timing", f"{_fmt(tm['loop_rate_hz'], unit='Hz')} loop, {_fmt(tm['sim_wall_ratio'], digits=3)} x real "
                       f"time ({_fmt(tm['wall_s'], digits=2, unit='s')} wall)"),
            ("tracking error", f"RMS {_fmt(te['rms_m'], 1e6, unit='µm')}, max {_fmt(te['max_m'], 1e6, unit='µm')}"
                               + (f" at {te['max_time_s']:.3f} s" if te.get("max_time_s") is not None else ""))]
    if "yaw_rms_rad" in te:                    # a planar machine's
        rows.append(("yaw error", f"RMS {_fmt(te.get('yaw_rms_rad'), 1e6, unit='µrad')}, "
                                  f"max {_fmt(te.get('yaw_max_rad'), 1e6, unit='µrad')}"))
    elif te.get("rotation_max_rad"):           # a tool that turns (a hexapod), or tilts (the imperfect Delta)
        rows.append(("rotation error", f"RMS {_fmt(te.get('rotation_rms_rad'), 1e6, unit='µrad')}, "
                                       f"max {_fmt(te.get('rotation_max_rad'), 1e6, unit='µrad')}"))
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


def recover_for_command(prog: str, path) -> None:
    """``--recover`` of pkm-report and pkm-replay: ``bag.recover_bag`` of the run's bag,
    what it kept and lost printed on one line."""
    bag_dir = find_bag(path)
    recovery = bagfile.recover_bag(bag_dir)
    print(f"{prog}: {bag_dir}: {recovery.describe()}")


def incomplete_hint(prog: str, path, exc: Exception) -> str:
    """The one line pkm-report and pkm-replay print for a bag they cannot read."""
    if isinstance(exc, IncompleteBagError):
        return (f"{prog}: error: incomplete bag: {exc}. The recorder was killed or the file cut; "
                f"`{prog} --recover {path}` makes it readable up to its last complete chunk "
                f"(the original .mcap is kept as .mcap.truncated)")
    return f"{prog}: error: {exc}"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="pkm-report", description="Metrics and figures of a recorded PKM run.")
    parser.add_argument("run_dir", help="run directory (with bag/ and run.json) or a rosbag2 directory")
    parser.add_argument("--out", help="output directory (default <run_dir>/report)")
    parser.add_argument("--recover", action="store_true",
                        help="first make a bag whose recorder was killed readable up to its last complete chunk "
                             "(pkm_recording.bag.recover; the original .mcap is kept as .mcap.truncated)")
    args = parser.parse_args(argv)
    try:
        if args.recover:
            recover_for_command("pkm-report", args.run_dir)
        result = write_report(args.run_dir, args.out)
    except (NoBagError, IncompleteBagError, BagReadError, ValueError) as exc:   # ValueError: e.g. ambiguous
        print(incomplete_hint("pkm-report", args.run_dir, exc), file=sys.stderr)  # namespace, unknown machine
        return 2
    out = Path(args.out) if args.out else Path(args.run_dir) / "report"
    print(summary(result))
    print(f"{'written':<16}  {out / 'metrics.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
