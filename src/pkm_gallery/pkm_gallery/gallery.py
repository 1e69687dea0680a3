"""``pkm-gallery``: the papers' experiments, each run from its scenario file, checked
against what the paper claims, and written to ``docs/results.md`` with its figures.

An :class:`Experiment` (:mod:`pkm_gallery.framework`; the registry:
:mod:`pkm_gallery.experiments`, one module per paper) names its paper and section and
the scenarios it runs; its ``run`` takes a :class:`Bench` and returns an :class:`Outcome`.
The gallery runs the scenarios in one process (``pkm-run --in-process``: the same
nodes in one executor, faster than a graph of processes); ``pkm-run <scenario>``
runs any of them alone. The same ``run`` is what each experiment's test calls, so the
test and ``docs/results.md`` judge the same numbers.

Exit status: 0 when every check passed, 1 when one failed (results.md says which),
2 for an unknown experiment name.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import rclpy.logging

from pkm_gallery.experiments import EXPERIMENTS, PENDING
from pkm_gallery.framework import PAPERS, Bench, Experiment, Outcome


def _cell(text) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def markdown_table(rows: list[list]) -> str:
    if not rows:
        return ""
    lines = ["| " + " | ".join(_cell(c) for c in rows[0]) + " |",
             "|" + "---|" * len(rows[0])]
    lines += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows[1:]]
    return "\n".join(lines)


def results_markdown(results: list[tuple[Experiment, Outcome, float]], figure_prefix: str = "figures",
                     pending=()) -> str:
    """docs/results.md: the summary table, then per experiment the paper's claims,
    ours and the verdicts, the measured table and the figures; ``pending``: (name,
    where in the paper, why not here) of the experiments not run yet."""
    out = ["# Results: the papers' experiments on the simulated machines", "",
           "Written by `pkm-gallery` (`pkm_gallery.gallery`) from the runs of each experiment's",
           "scenarios (`config/scenarios/`, each runs alone with `pkm-run <name>`); every check below is",
           "asserted by the experiment's test in `make test` on the same numbers. Do not edit by hand:",
           "run `pkm-gallery` again.", "",
           "| experiment | paper | checks | verdict |", "|---|---|---|---|"]
    for exp, outcome, _ in results:
        passed = sum(c.passed for c in outcome.checks)
        verdict = "reproduced" if outcome.passed else "NOT reproduced"
        out.append(f"| [{exp.name}](#{exp.name}) | {exp.paper} {exp.section} | {passed} / "
                   f"{len(outcome.checks)} | {verdict} |")
    if pending:
        out += ["", "Not reproduced here yet:", ""] + [f"- `{name}` ({where}): {why}" for name, where, why in pending]
    out += ["", "## References", ""] + [f"- **{k}**: {v}" for k, v in PAPERS.items()]
    for exp, outcome, seconds in results:
        runs = ("scenarios: " + ", ".join(f"`{s}`" for s in exp.scenarios)) if exp.scenarios else "no run"
        out += ["", f"## {exp.name}", "", f"**{exp.title}** ({exp.paper} {exp.section}; {runs}; "
                f"{seconds:.0f} s here)", ""]
        out += [markdown_table([["the paper (our criterion)", "measured", "verdict"]]
                               + [[c.claim, c.measured, "pass" if c.passed else "FAIL"] for c in outcome.checks])]
        if outcome.table:
            out += ["", markdown_table(outcome.table)]
        if outcome.notes:
            out += ["", outcome.notes.strip()]
        out += [""] + [f"![{f}]({figure_prefix}/{f})" for f in outcome.figures]
    return "\n".join(out).rstrip() + "\n"


# ------------------------------------------------------------------ command line
def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="pkm-gallery", description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="*", help=f"experiments (default: all): {', '.join(EXPERIMENTS)}")
    parser.add_argument("--docs", default="docs", help="where results.md and figures/ are written (default: docs)")
    parser.add_argument("--work", default="", help="keep the runs here (default: a temporary directory)")
    args = parser.parse_args(argv)
    unknown = [n for n in args.names if n not in EXPERIMENTS]
    if unknown:
        print(f"pkm-gallery: unknown experiment(s) {unknown}; known: {list(EXPERIMENTS)}", file=sys.stderr)
        return 2

    # the nodes run in this process: their INFO lines (configured, run complete...) would
    # bury the table; warnings and errors still show (a node's logger inherits "pkm"'s)
    rclpy.logging.set_logger_level("pkm", rclpy.logging.LoggingSeverity.WARN)
    docs = Path(args.docs)
    results = []
    with tempfile.TemporaryDirectory(prefix="pkm-gallery-") as tmp:
        work = Path(args.work) if args.work else Path(tmp)
        for name in args.names or list(EXPERIMENTS):
            exp = EXPERIMENTS[name]
            start = time.monotonic()
            outcome = exp.run(Bench(work / name, docs / "figures"))
            seconds = time.monotonic() - start
            results.append((exp, outcome, seconds))
            print(f"{name:28s} {'reproduced' if outcome.passed else 'NOT reproduced':15s} "
                  f"{sum(c.passed for c in outcome.checks)} / {len(outcome.checks)} checks  {seconds:5.1f} s")
            for c in outcome.checks:
                if not c.passed:
                    print(f"    FAIL: {c.claim}: {c.measured}")
    if len(results) == len(EXPERIMENTS):
        docs.mkdir(parents=True, exist_ok=True)
        (docs / "results.md").write_text(results_markdown(results, pending=PENDING), encoding="utf-8")
        print(f"written: {docs / 'results.md'}")
    else:                          # results.md holds every experiment or none
        print(f"{docs / 'results.md'} not written (a subset ran); figures in {docs / 'figures'}")
    return 0 if all(o.passed for _, o, _ in results) else 1


if __name__ == "__main__":
    sys.exit(main())
