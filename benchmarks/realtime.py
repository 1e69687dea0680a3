"""Realtime benchmark: missed deadlines of ``mode: realtime`` runs without and with
pkm-run's realtime profile (``--rt-profile``: SCHED_FIFO and locked memory for the
loop's nodes, pkm_bringup/rt_profile.py; with it the loop's nodes also run composed in
one process by default, ``loop_process: composed``, pkm_bringup/composed_loop.py, and
without it each in its own).

The scenario (archi_demo by default: ARCHI test motion, Gough in the loop, sensor
space + inf-norm, recorded) runs as processes in real time: sim_hw steps on a wall
timer every dt, and a step whose command did not answer the previous state is a
deadline miss (sim_hw's summary ``deadline_misses``). Runs come in pairs, without the
profile then with it, back to back (A B A B ...), so that a slow phase of this VM
falls on both sides of a pair. Printed per pair: steps, misses without and with, the
ratio with / without, the hypervisor's CPU steal of each run; per rate: the median
ratio and the pooled miss rates (all misses over all steps). Rates: 1 kHz (dt 1 ms) and
2 kHz (dt 0.5 ms).

After each pair, the machine's floor in the same minutes (benchmarks/rt_floor.py, with
the profile's scheduling, as many periods as the graph's run steps): ``timer``, the
wake-ups of a bare SCHED_FIFO sleeper more than a period late, and ``chain``, the
misses of the graph's three-process path (plant -> sensor -> controller -> plant)
forwarding messages with no work (as processes only). A graph of processes cannot do
better than its chain floor: judge a target against it (``--no-floor`` leaves it out).

Each run is the scenario's program (archi_demo: ~5 s of motion, plus ~15 s of start-up
and shutdown), and the floors take ~20 s a pair: ``--pairs 3`` (default) and both rates
take ~6 minutes.

Usage: python benchmarks/realtime.py [--pairs 3] [--rates 1000,2000] [--scenario archi_demo]
       [--duration-s 0] [--in-process] [--no-floor]

Needs what the profile needs (root, or CAP_SYS_NICE and CAP_IPC_LOCK); where the OS
refuses it the benchmark says why and exits 0 (``make bench`` goes on).
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from hoststat import CpuSteal  # noqa: E402  (benchmarks/hoststat.py)
from rt_floor import Floor, chain_floor, timer_floor  # noqa: E402  (benchmarks/rt_floor.py)


@dataclass(frozen=True)
class RunResult:
    profile: bool
    steps: int
    misses: int
    status: str
    steal_percent: float | None

    @property
    def miss_rate(self) -> float:
        return self.misses / self.steps if self.steps else math.nan


def run_once(scenario: str, dt_s: float, profile: bool, duration_s: float, in_process: bool) -> RunResult:
    from pkm_bringup.orchestrator import run_scenario
    from pkm_bringup.scenario import load_scenario
    # the drives' sync error counter off: it brakes the machine on a burst of misses
    # (cause deadline_missed), and the benchmark counts the misses of whole runs
    plant = {**load_scenario(scenario).plant, "sync_error_limit": 0}
    overrides = {"mode": "realtime", "dt_s": dt_s, "realtime_profile": profile, "plant": plant}
    if duration_s:
        overrides["duration_s"] = duration_s
    s = load_scenario(scenario, overrides)
    with tempfile.TemporaryDirectory() as tmp, CpuSteal() as steal:
        run = run_scenario(s, Path(tmp) / "run", in_process=in_process, progress=False, report=False)
    if run["status"] == "failed":
        raise RuntimeError(f"run failed: {run['error']}")
    sim = run["summaries"]["sim_hw"]
    # a run may end "tripped" (a supervisor stops the machine after a burst of misses):
    # its misses still count; sim_hw runs to the end with the machine held
    return RunResult(profile, int(sim["steps"]), int(sim["deadline_misses"]), run["status"], steal.percent)


def ratio(with_profile: RunResult, without: RunResult) -> float:
    """Miss rate with the profile over the rate without (nan when neither missed)."""
    a, b = without.miss_rate, with_profile.miss_rate
    if a == 0:
        return math.nan if b == 0 else math.inf
    return b / a


def _pct(misses: int, steps: int) -> str:
    return f"{misses:5d} ({100.0 * misses / steps:6.2f} %)" if steps else "-"


def _steal(r: RunResult) -> str:
    return "n/a" if r.steal_percent is None else f"{r.steal_percent:.1f}"


def _status(r: RunResult, label: str) -> str:
    return "" if r.status == "completed" else f"  ({label} {r.status})"


def _floor(f: Floor | None) -> str:
    return "-" if f is None else _pct(f.misses, f.steps)


def _pooled(results: list) -> str:
    """All misses over all steps of ``results`` (RunResult or Floor; None: not measured)."""
    results = [r for r in results if r is not None]
    misses, steps = sum(r.misses for r in results), sum(r.steps for r in results)
    return f"{misses} / {steps} = {100.0 * misses / steps:5.2f} %" if steps else "-"


def measure_floors(rate: float, steps: int, args) -> tuple[Floor | None, Floor | None]:
    """The machine's floors over ``steps`` periods, right after a pair: the bare timer,
    and the three-process chain (a graph of processes only; None: not measured)."""
    if args.no_floor:
        return None, None
    return timer_floor(rate, steps), None if args.in_process else chain_floor(rate, steps)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", type=int, default=3, help="pairs (without, with) per rate (default 3)")
    parser.add_argument("--rates", default="1000,2000", help="loop rates in Hz, comma-separated")
    parser.add_argument("--scenario", default="archi_demo")
    parser.add_argument("--duration-s", type=float, default=0.0, help="simulated time (0: the program's)")
    parser.add_argument("--in-process", action="store_true", help="one process (the profile on all of it)")
    parser.add_argument("--no-floor", action="store_true", help="leave out the machine's floor (rt_floor.py)")
    args = parser.parse_args(argv)
    from pkm_bringup.rt_profile import RealtimeProfileRefused, check_permitted
    try:
        check_permitted(args.in_process)
    except RealtimeProfileRefused as exc:
        print(f"realtime benchmark skipped: {exc}")
        return 0
    rates = [float(r) for r in args.rates.split(",") if r.strip()]
    mode = "in one process" if args.in_process else "as processes"
    print(f"{args.scenario}, mode: realtime, {mode}; {args.pairs} pairs per rate (without, then with the profile)")
    header = (f"{'rate':>6} {'pair':>4} {'steps':>6} {'floor: timer':>14} {'floor: chain':>14}"
              f" {'misses without':>17} {'misses with':>17} {'ratio':>6}   steal % (without, with)")
    print(header)
    print("-" * len(header))
    summaries = []
    start = time.monotonic()
    for rate in rates:
        pairs, floor_pairs = [], []
        for k in range(args.pairs):
            without = run_once(args.scenario, 1.0 / rate, False, args.duration_s, args.in_process)
            with_profile = run_once(args.scenario, 1.0 / rate, True, args.duration_s, args.in_process)
            floors = measure_floors(rate, max(without.steps, with_profile.steps), args)
            pairs.append((without, with_profile))
            floor_pairs.append(floors)
            r = ratio(with_profile, without)
            print(f"{rate:6.0f} {k + 1:4d} {without.steps:6d} {_floor(floors[0]):>14} {_floor(floors[1]):>14}"
                  f" {_pct(without.misses, without.steps):>17}"
                  f" {_pct(with_profile.misses, with_profile.steps):>17} {r:6.3f}   "
                  f"{_steal(without)}, {_steal(with_profile)}{_status(without, 'without:')}"
                  f"{_status(with_profile, 'with:')}",
                  flush=True)
        ratios = [ratio(b, a) for a, b in pairs]
        finite = [r for r in ratios if not math.isnan(r)]
        summaries.append((rate, statistics.median(finite) if finite else math.nan,
                          _pooled([a for a, _ in pairs]), _pooled([b for _, b in pairs]),
                          _pooled([f[0] for f in floor_pairs]), _pooled([f[1] for f in floor_pairs])))
    print()
    print(f"{'rate':>6} {'median ratio':>12} {'pooled without':>24} {'pooled with':>24}"
          f" {'floor: timer':>24} {'floor: chain':>24}")
    for rate, median, *pooled in summaries:
        print(f"{rate:6.0f} {median:12.3f} " + " ".join(f"{p:>24}" for p in pooled))
    print(f"({time.monotonic() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
