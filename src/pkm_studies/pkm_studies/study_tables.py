"""A study's outputs from its rows (``<out>/results/<key>.json``): the table as Parquet
(through pyarrow) and CSV, the summary per group, and the plots. Pure pandas and
matplotlib; every file is written to a temporary name and renamed (atomic).

- ``results.parquet``, ``results.csv``: one row per run of the study as it is now
  (rows of runs no longer in the study, after an edit, are left out), ordered by run
  index; a list-valued parameter (``size`` > 1) is a list column in Parquet and JSON
  text in CSV.
- ``summary.csv``: per group (``group_by``): ``runs``, ``completed``, ``tripped``,
  ``failed``, then for each of ``metrics`` present: count, mean, std, min, median, max
  over the runs that did not fail.
- plots: ``<metric>.png``, the distribution of a metric per group (box plot with the
  runs drawn over it); ``<metric>_vs_<parameter>.png``, a metric against each sampled
  parameter (a list-valued one by its RMS), coloured by group.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

from pkm_common.files import atomic_write
from pkm_studies.study import Study

STATUSES = ("completed", "tripped", "failed")


def read_rows(out_dir: Path, runs) -> pd.DataFrame:
    """The rows of ``runs`` that have a result, as a DataFrame ordered by run index."""
    rows = []
    for run in runs:
        path = out_dir / "results" / f"{run.key}.json"
        try:
            rows.append(json.loads(path.read_text(encoding="utf-8")))
        except (OSError, ValueError):            # missing, or unreadable (study_engine.done_keys removes it)
            continue
    frame = pd.DataFrame(rows)
    return frame.sort_values("index").reset_index(drop=True) if len(frame) else frame


def group_labels(frame: pd.DataFrame, keys: list[str]) -> pd.Series:
    """One text label per row from its ``keys`` values ("all" without keys)."""
    if not keys or not len(frame):
        return pd.Series(["all"] * len(frame), index=frame.index)
    return frame[keys].apply(lambda row: ", ".join(f"{k.split('.')[-1]}={_text(row[k])}" for k in keys), axis=1)


def _text(value) -> str:
    if isinstance(value, float):
        return f"{value:.4g}"
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_text(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_text(v)}" for k, v in value.items()) + "}"
    return str(value)


def _plain(value):
    """A table cell as the row had it: numpy scalars and arrays as Python numbers and lists."""
    if isinstance(value, np.ndarray):
        return [_plain(v) for v in value.tolist()]
    if isinstance(value, np.generic):
        return value.item()
    return value


def rows_from_table(out_dir: Path) -> dict[str, dict]:
    """{key: row} of ``<out>/results.parquet`` (none without one): the rows as they were
    written (a cell left empty by its row, NaN in the table, left out again), floats to
    the bit. The table is what a study keeps of its rows where its ``results/`` is not
    kept (a long study carried on over several machines or clean checkouts)."""
    path = out_dir / "results.parquet"
    if not path.exists():
        return {}
    rows = {}
    for record in pd.read_parquet(path, engine="pyarrow").to_dict("records"):
        row = {k: _plain(v) for k, v in record.items()
               if not (isinstance(v, float) and math.isnan(v)) and v is not None}
        rows[str(row["key"])] = row
    return rows


TAIL_PERCENTILES = (95, 99)


def summarise(study: Study, frame: pd.DataFrame) -> pd.DataFrame:
    """The summary table: a row per group, in the order the groups first appear."""
    if not len(frame):
        return pd.DataFrame()
    labels = group_labels(frame, study.group_by)
    status = frame.get("run.status", pd.Series(["failed"] * len(frame), index=frame.index))
    rows = []
    for label in dict.fromkeys(labels):
        members = frame[labels == label]
        ok = members[status[labels == label] != "failed"]
        row = {"group": label, "runs": len(members)}
        row.update({s: int((status[labels == label] == s).sum()) for s in STATUSES})
        for m in study.metrics:
            if m not in frame:
                continue
            values = pd.to_numeric(ok[m], errors="coerce").dropna()
            row.update({f"{m}.count": len(values), f"{m}.mean": values.mean(), f"{m}.std": values.std(),
                        f"{m}.min": values.min(), f"{m}.median": values.median(),
                        # a Monte Carlo's tails (linear interpolation between order statistics)
                        **{f"{m}.p{q}": values.quantile(q / 100) for q in TAIL_PERCENTILES},
                        f"{m}.max": values.max()})
        rows.append(row)
    return pd.DataFrame(rows)


def write_outputs(study: Study, out_dir: Path, runs) -> pd.DataFrame:
    """results.parquet, results.csv, summary.csv and the plots; returns the table."""
    frame = read_rows(out_dir, runs)
    frame = frame[study.row_columns(frame.columns)]         # rows written before a study's ``rows`` changed
    if len(frame):
        atomic_write(out_dir / "results.parquet", lambda p: frame.to_parquet(p, engine="pyarrow", index=False))
        as_text = frame.copy()
        for col in as_text.columns:
            if as_text[col].map(lambda v: isinstance(v, (list, tuple))).any():
                as_text[col] = as_text[col].map(json.dumps)
        atomic_write(out_dir / "results.csv", lambda p: as_text.to_csv(p, index=False))
        summary = summarise(study, frame)
        atomic_write(out_dir / "summary.csv", lambda p: summary.to_csv(p, index=False))
        draw_plots(study, frame, out_dir)
    return frame


def format_summary(study: Study, frame: pd.DataFrame) -> str:
    """The summary as a text table: per group, the runs by status and each metric's
    mean, std, 99th percentile and max."""
    summary = summarise(study, frame)
    if not len(summary):
        return "no results"
    lines = []
    metrics = [m for m in study.metrics if f"{m}.mean" in summary]
    width = min(100, max(5, *(len(str(g)) for g in summary["group"])))
    head = f"{'group':{width}s} {'runs':>5s} {'done':>5s} {'trip':>5s} {'fail':>5s}"
    for m in metrics:
        head += f"  {m + ' mean/std/p99/max':>52s}"
    lines.append(head)
    for _, row in summary.iterrows():
        line = f"{str(row['group'])[:width]:{width}s} {row['runs']:5d} {row['completed']:5d} {row['tripped']:5d} " \
               f"{row['failed']:5d}"
        for m in metrics:
            line += "  " + (f"{_num(row[m + '.mean'])} / {_num(row[m + '.std'])} / {_num(row[m + '.p99'])} / "
                            f"{_num(row[m + '.max'])}").rjust(52)
        lines.append(line)
    return "\n".join(lines)


def _num(value) -> str:
    return "n/a" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.4g}"


# ------------------------------------------------------------------ plots
def _scalar(values: pd.Series) -> tuple[np.ndarray, str]:
    """A parameter's values as numbers: a list-valued one by its RMS."""
    first = values.iloc[0]
    if isinstance(first, (list, tuple, np.ndarray)):
        return np.array([math.sqrt(np.mean(np.square(v))) for v in values]), "rms"
    return pd.to_numeric(values, errors="coerce").to_numpy(dtype=float), ""


def draw_plots(study: Study, frame: pd.DataFrame, out_dir: Path) -> list[Path]:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    labels = group_labels(frame, study.group_by)
    ok = frame.get("run.status", pd.Series(["failed"] * len(frame))) != "failed"
    groups = list(dict.fromkeys(labels))
    files = []
    for m in (m for m in study.metrics if m in frame):
        values = pd.to_numeric(frame[m], errors="coerce")
        per_group = [values[(labels == g) & ok].dropna().to_numpy() for g in groups]
        if not any(len(v) for v in per_group):
            continue
        fig, ax = plt.subplots(figsize=(max(5.0, 1.6 * len(groups)), 4.0))
        ax.boxplot([v if len(v) else [np.nan] for v in per_group], showfliers=False)
        for i, v in enumerate(per_group, start=1):
            ax.plot(np.full(len(v), i) + np.linspace(-0.12, 0.12, len(v)) if len(v) > 1 else [i] * len(v), v, ".",
                    alpha=0.6)
        # one line per key, the value under its name: long strategy names do not overlap
        ax.set_xticks(range(1, len(groups) + 1), [g.replace(", ", "\n").replace("=", "=\n") for g in groups],
                      fontsize=7)
        ax.set_ylabel(m)
        ax.set_title(f"{study.name}: {m} per group ({int(ok.sum())} runs)", fontsize=9)
        fig.tight_layout()
        files.append(_save(fig, out_dir / f"{m}.png"))
        plt.close(fig)
        for d in study.draws:
            if d.path not in frame:
                continue
            x, how = _scalar(frame[d.path])
            fig, ax = plt.subplots(figsize=(5.5, 4.0))
            for g in groups:
                sel = ((labels == g) & ok).to_numpy()
                ax.plot(x[sel], values.to_numpy()[sel], ".", label=g)
            ax.set_xlabel(f"{how}({d.path})" if how else d.path)
            ax.set_ylabel(m)
            if len(groups) > 1:
                ax.legend(fontsize=7)
            ax.set_title(f"{study.name}: {m}\nagainst {d.path}", fontsize=9)
            fig.tight_layout()
            files.append(_save(fig, out_dir / f"{m}_vs_{d.path}.png"))
            plt.close(fig)
    return files


def _save(fig, path: Path) -> Path:
    atomic_write(path, lambda p: fig.savefig(p, dpi=110, format="png"))
    return path
