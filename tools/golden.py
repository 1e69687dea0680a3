"""Golden outputs: what the project computes, recorded before a restructuring and
compared after each of its steps (issue 41: "behaviour unchanged").

    .venv/bin/python tools/golden.py record            # writes tests/golden/golden.json
    .venv/bin/python tools/golden.py compare           # exit 1 and the differences, if any
    .venv/bin/python tools/golden.py compare --only archi_demo mom3_square

For every lockstep scenario of config/scenarios, run in one process and recorded:
- the commands (drives/command: stamp and efforts, in stamp order) and the true poses
  (platform/true_pose) as SHA-256 digests of their float64 bytes, with their counts:
  bit-identical or not;
- the report's metrics, flattened, without the fields that measure the machine it ran
  on (wall time, rates, compute and response times: ``VOLATILE``), numbers to 9
  significant digits;
- whether pkm-replay recomputes every recorded command bit for bit, and how many.
And pkm-analyze's JSON: ``report`` of every machine file, ``dosr``.
A scenario's realtime runs (the panel's) are not deterministic and are left out.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import struct
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = ROOT / "tests" / "golden" / "golden.json"
# what measures the machine it ran on, counts what a wall-clock timer published, or
# counts the plant's repeats of its first state while the graph connects; paths
VOLATILE = re.compile(r"wall|rate_hz|compute|response|_us(_|$)|steps_per_s|real_time|loop_rate|sim_wall|run_dir|"
                      r"rosout|diagnostics|markers|sim_hw\.final_status|duplicates_dropped|messages\.(recorded|lost)|"
                      r"(^|\.)bag$")
DIGITS = 9


def _number(value):
    if isinstance(value, float):
        return float(f"{value:.{DIGITS}g}")
    return value


def _flat(tree, prefix: str = "") -> dict:
    """{"a.b.c": leaf} of a JSON tree, the VOLATILE paths left out."""
    out = {}
    items = tree.items() if isinstance(tree, dict) else enumerate(tree) if isinstance(tree, list) else None
    if items is None:
        return {} if VOLATILE.search(prefix) else {prefix: _number(tree)}
    for key, value in items:
        out.update(_flat(value, f"{prefix}.{key}" if prefix else str(key)))
    return out


def _digest(messages, fields) -> dict:
    """SHA-256 of (stamp, fields...) float64 bytes of each stamp's first message, in
    stamp order (the plant repeats its first state until the graph is connected: how
    many times depends on the machine's load)."""
    first = {}
    for m in messages:
        first.setdefault(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec, fields(m))
    rows = sorted(first.items())
    h = hashlib.sha256()
    for stamp, values in rows:
        h.update(struct.pack(f"<q{len(values)}d", stamp, *values))
    return {"count": len(rows), "sha256": h.hexdigest()}


def scenario_outputs(name: str, work: Path, engine: str = "graph") -> dict:
    from pkm_bringup.orchestrator import run_scenario
    from pkm_runs.replay import recorded_messages, replay_controller
    from pkm_bringup.scenario import load_scenario
    s = load_scenario(name)
    run_dir = work / name
    run = run_scenario(s, run_dir, in_process=True, progress=False, engine=engine)
    bag, ns = run_dir / "bag", s.namespace
    commands = _digest((m for _, _, m in recorded_messages(bag, ns, ("drives/command",))), lambda m: list(m.effort))
    poses = _digest((m for _, _, m in recorded_messages(bag, ns, ("platform/true_pose",))),
                    lambda m: [m.pose.position.x, m.pose.position.y, m.pose.position.z, m.pose.orientation.x,
                               m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w])
    replayed = replay_controller(run_dir)
    return {"status": run["status"], "cause": run.get("cause"), "commands": commands, "true_poses": poses,
            "replay": {"ok": bool(replayed.ok), "compared": replayed.compared, "identical": replayed.identical},
            "metrics": _flat(run.get("metrics", {}))}


def analyze_outputs() -> dict:
    out = {}
    machines = sorted(p.stem for p in (ROOT / "config" / "machines").glob("*.yaml"))
    for args in [["report", "--machine", m] for m in machines] + [["dosr"]]:
        proc = subprocess.run([sys.executable, "-m", "pkm_kinematics.cli", "--json", *args], capture_output=True,
                              text=True, timeout=600, cwd=ROOT)
        out[" ".join(args)] = _flat(json.loads(proc.stdout)) if proc.returncode == 0 else \
            {"exit": proc.returncode, "stderr": proc.stderr[-500:]}
    return out


def lockstep_scenarios() -> list[str]:
    from pkm_bringup.scenario import load_scenario
    names = sorted(p.stem for p in (ROOT / "config" / "scenarios").glob("*.yaml"))
    return [n for n in names if load_scenario(n).mode == "lockstep"]


def outputs(only: list[str] | None, analyze: bool, engine: str = "graph") -> dict:
    out = {"scenarios": {}, "analyze": analyze_outputs() if analyze else {}}
    with tempfile.TemporaryDirectory(prefix="golden-") as work:
        for name in only or lockstep_scenarios():
            if engine == "direct":
                from pkm_bringup.direct import refusal
                from pkm_bringup.scenario import load_scenario
                if refusal(load_scenario(name)):
                    print(f"golden: {name}: {refusal(load_scenario(name))}", file=sys.stderr, flush=True)
                    continue
            print(f"golden: {name}", file=sys.stderr, flush=True)
            out["scenarios"][name] = scenario_outputs(name, Path(work), engine)
    return out


def differences(golden: dict, now: dict) -> list[str]:
    """What differs, one line each (scenarios and analyses ``now`` has)."""
    lines = []
    for section in ("scenarios", "analyze"):
        for name, got in now[section].items():
            want = golden.get(section, {}).get(name)
            if want is None:
                lines.append(f"{section} {name}: not in the golden outputs")
                continue
            flat_want, flat_got = _flat(want), _flat(got)
            for key in sorted(set(flat_want) | set(flat_got)):
                if flat_want.get(key, "(none)") != flat_got.get(key, "(none)"):
                    lines.append(f"{section} {name} {key}: {flat_want.get(key, '(none)')!r} -> "
                                 f"{flat_got.get(key, '(none)')!r}")
    return lines


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("action", choices=("record", "compare"))
    parser.add_argument("--golden", type=Path, default=GOLDEN)
    parser.add_argument("--only", nargs="+", metavar="SCENARIO", help="these scenarios (and no pkm-analyze)")
    parser.add_argument("--engine", choices=("graph", "direct"), default="graph",
                        help="direct: the direct engine's runs against the golden outputs (recorded by the graph)")
    args = parser.parse_args(argv)
    if args.engine == "direct" and args.action == "record":
        parser.error("the golden outputs are recorded by the graph (compare --engine direct checks the engine)")
    now = outputs(args.only, analyze=not args.only, engine=args.engine)
    if args.action == "record":
        if args.only and args.golden.exists():        # add to what was recorded
            now = {**json.loads(args.golden.read_text()), "scenarios": {
                **json.loads(args.golden.read_text())["scenarios"], **now["scenarios"]}}
        args.golden.parent.mkdir(parents=True, exist_ok=True)
        args.golden.write_text(json.dumps(now, indent=1, sort_keys=True) + "\n", encoding="utf-8")
        print(f"golden: {len(now['scenarios'])} scenarios, {len(now['analyze'])} analyses -> {args.golden}")
        return 0
    lines = differences(json.loads(args.golden.read_text()), now)
    for line in lines:
        print(line)
    bad_replays = [n for n, o in now["scenarios"].items() if not o["replay"]["ok"]]
    print(f"golden: {len(now['scenarios'])} scenarios compared, {len(lines)} differences"
          + (f"; replay not exact: {bad_replays}" if bad_replays else ""))
    return 1 if lines or bad_replays else 0


if __name__ == "__main__":
    sys.exit(main())
