"""Figures of a run report, from curves decimated while the run is streamed.

Pure module (no rclpy; matplotlib's Agg canvas, imported when drawing). A long run is
never held whole: :class:`MinMaxDecimator` keeps at most ``limit`` points of a curve
fed in order (the smallest and the largest value of every bucket of consecutive
samples, so a one-step spike is always drawn), :class:`StrideDecimator` every k-th row
of a multi-column series (the tool path, where no single value says what to keep).
:class:`FigureCurves` holds the decimators of the four figures, :func:`draw` writes
them as PNG files.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

MAX_PLOT_POINTS = 20_000
# Agg rasterizes a line in pieces of this many vertices (matplotlib's agg.path.chunksize):
# a noisy curve of MAX_PLOT_POINTS drawn whole makes Agg hold tens of MB of cells for one
# figure, in pieces only a few (at most minor artifacts at the joins of thin lines)
AGG_CHUNK_VERTICES = 2000


class MinMaxDecimator:
    """At most ~``limit`` points of a curve y(t) fed in time order by :meth:`add`: the
    samples are grouped in buckets of ``size`` consecutive samples, of which the
    smallest and the largest y are kept (NaN only where a whole bucket is NaN, so gaps
    stay gaps). When more than limit/2 buckets are held, neighbouring buckets are
    merged in pairs and ``size`` doubles, so memory is bounded whatever the length."""

    def __init__(self, limit: int = MAX_PLOT_POINTS):
        self.max_buckets = max(1, limit // 2)
        self.size = 1
        self._t = np.zeros((0, 2), np.int64)        # per bucket: its two kept points, in time order
        self._y = np.zeros((0, 2))
        self._carry_t = np.zeros(0, np.int64)       # the samples of the unfinished bucket
        self._carry_y = np.zeros(0)

    def add(self, t, y) -> None:
        t = np.concatenate([self._carry_t, np.asarray(t, dtype=np.int64)])
        y = np.concatenate([self._carry_y, np.asarray(y, dtype=float)])
        full = len(t) // self.size * self.size
        if full:
            new_t, new_y = self._extremes(t[:full].reshape(-1, self.size), y[:full].reshape(-1, self.size))
            self._t = np.concatenate([self._t, new_t])
            self._y = np.concatenate([self._y, new_y])
        self._carry_t, self._carry_y = t[full:], y[full:]
        while len(self._t) > self.max_buckets:
            self._merge()

    @staticmethod
    def _extremes(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per row of (B, k) samples: the min and max sample, in time order."""
        lo = np.argmin(np.where(np.isnan(y), np.inf, y), axis=1)
        hi = np.argmax(np.where(np.isnan(y), -np.inf, y), axis=1)
        first, second = np.minimum(lo, hi), np.maximum(lo, hi)
        rows = np.arange(len(t))
        return (np.column_stack([t[rows, first], t[rows, second]]),
                np.column_stack([y[rows, first], y[rows, second]]))

    def _merge(self) -> None:
        pairs = len(self._t) // 2 * 2
        t, y = self._extremes(self._t[:pairs].reshape(-1, 4), self._y[:pairs].reshape(-1, 4))
        self._t = np.concatenate([t, self._t[pairs:]])
        self._y = np.concatenate([y, self._y[pairs:]])
        self.size *= 2

    def curve(self) -> tuple[np.ndarray, np.ndarray]:
        """(t, y) of the kept points in time order (a bucket whose min and max are one
        sample gives one point)."""
        distinct = np.ones(self._t.shape, bool)
        distinct[:, 1] = self._t[:, 1] != self._t[:, 0]
        return (np.concatenate([self._t[distinct], self._carry_t]),
                np.concatenate([self._y[distinct], self._carry_y]))

    def __len__(self) -> int:
        return int(len(self._t) * 2 + len(self._carry_t))


class StrideDecimator:
    """Every ``stride``-th row of a series of ``columns`` fed in order, at most ``limit``
    rows (the stride doubles, dropping every other kept row, when more are held), and
    the last row fed."""

    def __init__(self, columns: int, limit: int = MAX_PLOT_POINTS):
        self.limit = max(2, limit)
        self.stride = 1
        self._seen = 0
        self._index = np.zeros(0, np.int64)
        self._rows = np.zeros((0, columns))
        self._last = None

    def add(self, rows) -> None:
        rows = np.asarray(rows, dtype=float)
        if not len(rows):
            return
        index = np.arange(self._seen, self._seen + len(rows))
        keep = index % self.stride == 0
        self._index = np.concatenate([self._index, index[keep]])
        self._rows = np.concatenate([self._rows, rows[keep]])
        self._seen += len(rows)
        self._last = (index[-1], rows[-1])
        while len(self._index) > self.limit:
            self.stride *= 2
            keep = self._index % self.stride == 0
            self._index, self._rows = self._index[keep], self._rows[keep]

    def rows(self) -> np.ndarray:
        if self._last is None:
            return self._rows
        if len(self._index) and self._index[-1] == self._last[0]:
            return self._rows
        return np.vstack([self._rows, self._last[1]])


class Unwrapper:
    """``np.unwrap`` of an angle fed in pieces: the same values as unwrapping it whole."""

    def __init__(self):
        self._raw = None            # the last raw angle fed
        self._out = None            # its unwrapped value

    def add(self, angle: np.ndarray) -> np.ndarray:
        angle = np.asarray(angle, dtype=float)
        if not len(angle):
            return angle
        if self._raw is None:
            out = np.unwrap(angle)
        else:
            out = self._out + (np.unwrap(np.concatenate([[self._raw], angle]))[1:] - self._raw)
        self._raw, self._out = float(angle[-1]), float(out[-1])
        return out


# path columns of FigureCurves.path
PATH_T, PATH_X, PATH_Y, PATH_YAW, PATH_Z = range(5)
TRACKING_CURVES = ("translation_xy", "translation_xyz", "e_x", "e_y", "e_z", "yaw")


@dataclass
class FigureCurves:
    """The decimated curves of the four figures, filled block by block (stamps in ns)."""
    limit: int = MAX_PLOT_POINTS
    path: dict = field(default_factory=dict)          # "reference" | "true_pose" -> StrideDecimator (t x y yaw z),
    path_origin_ns: int | None = None                 # t of the path rows: stamp - path_origin_ns (exact in float)
    unwrap: dict = field(default_factory=dict)        # pose stream -> Unwrapper of its yaw
    tracking: dict = field(default_factory=dict)      # TRACKING_CURVES -> MinMaxDecimator
    forces: dict = field(default_factory=dict)        # "command" | "state" -> [MinMaxDecimator per drive]
    internal: dict = field(default_factory=dict)      # "applied" | "commanded" -> MinMaxDecimator

    def add_pose(self, key: str, stamp_ns, position, yaw) -> None:
        if key not in self.path:
            self.path[key], self.unwrap[key] = StrideDecimator(5, self.limit), Unwrapper()
        if len(stamp_ns):
            if self.path_origin_ns is None:
                self.path_origin_ns = int(stamp_ns[0])
            t = (np.asarray(stamp_ns, dtype=np.int64) - self.path_origin_ns).astype(float)
            self.path[key].add(np.column_stack([t, position[:, 0], position[:, 1], self.unwrap[key].add(yaw),
                                                position[:, 2]]))

    def add_tracking(self, stamp_ns, curves: dict) -> None:
        for name, values in curves.items():
            self.tracking.setdefault(name, MinMaxDecimator(self.limit)).add(stamp_ns, values)

    def add_forces(self, key: str, stamp_ns, effort) -> None:
        drives = self.forces.setdefault(key, [MinMaxDecimator(self.limit) for _ in range(effort.shape[1])])
        for k, decimator in enumerate(drives):
            decimator.add(stamp_ns, effort[:, k])

    def add_internal(self, key: str, stamp_ns, norm) -> None:
        self.internal.setdefault(key, MinMaxDecimator(self.limit)).add(stamp_ns, norm)


@dataclass
class FigureSpec:
    """What :func:`draw` needs besides the curves."""
    label: str                      # "archi (/pkm)"
    planar: bool
    t0_ns: int
    drive_names: dict               # "command" | "state" -> names
    tracking: bool                  # the run has tracking errors
    internal: bool                  # the run has internal forces


def _figure(rows: int, height: float = 3.2):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8.0, height * rows), layout="constrained")
    axes = [fig.add_subplot(rows, 1, i + 1) for i in range(rows)]
    for ax in axes:
        ax.grid(True, alpha=0.3)
    return fig, axes


def draw(curves: FigureCurves, spec: FigureSpec, out_dir) -> list[Path]:
    """Figures of the run as PNG files in ``out_dir`` (created): ``path.png`` (tool path
    against the reference, x-y; yaw or z against time), ``tracking_error.png`` (µm,
    µrad), ``drive_forces.png`` (commanded and applied, N, one line per drive) and
    ``internal_force.png`` (norm of the null-space part, N). Figures whose data the run
    lacks are skipped."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    planar, label = spec.planar, spec.label
    files: list[Path] = []

    def seconds(stamps):
        return (np.asarray(stamps, dtype=np.int64) - spec.t0_ns) / 1e9

    def save(fig, name):
        import gc

        import matplotlib

        path = out_dir / name
        with matplotlib.rc_context({"agg.path.chunksize": AGG_CHUNK_VERTICES}):
            fig.savefig(path, dpi=110)
        files.append(path)
        fig.clear()                 # the figure's artists and canvas hold reference cycles:
        gc.collect()                # freed now, before the next figure is drawn

    # 1. path
    if curves.path:
        fig, (ax, ax2) = _figure(2, 3.6)
        for key, style, lab in (("reference", dict(ls="--", color="tab:gray"), "reference"),
                                ("true_pose", dict(color="tab:blue"), "true tool pose")):
            rows = curves.path[key].rows() if key in curves.path else np.zeros((0, 5))
            if len(rows):
                ax.plot(rows[:, PATH_X], rows[:, PATH_Y], lw=1.0, label=lab, **style)
                t = (rows[:, PATH_T] + (curves.path_origin_ns - spec.t0_ns)) / 1e9
                ax2.plot(t, np.degrees(rows[:, PATH_YAW]) if planar else rows[:, PATH_Z], lw=1.0, label=lab,
                         **style)
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
    if spec.tracking:
        fig, axes = _figure(2 if planar else 1)
        ax = axes[0]
        t, y = curves.tracking["translation_xy" if planar else "translation_xyz"].curve()
        ax.plot(seconds(t), y * 1e6, color="k", lw=1.0, label="|e| (translation)")
        for axis in "xy" if planar else "xyz":
            t, y = curves.tracking[f"e_{axis}"].curve()
            ax.plot(seconds(t), y * 1e6, lw=0.8, label=f"e_{axis}")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("tracking error (µm)")
        ax.set_title(f"Tracking error (true pose − reference), {label}")
        ax.legend(loc="best", fontsize=8)
        if planar:
            t, y = curves.tracking["yaw"].curve()
            axes[1].plot(seconds(t), y * 1e6, color="tab:red", lw=0.8)
            axes[1].set_xlabel("time (s)")
            axes[1].set_ylabel("yaw error (µrad)")
            axes[1].set_title("Orientation error")
        save(fig, "tracking_error.png")

    # 3. drive forces
    series = [(key, lab) for key, lab in (("command", "commanded (drives/command)"),
                                          ("state", "applied (drives/state)")) if curves.forces.get(key)]
    if series:
        fig, axes = _figure(len(series))
        for ax, (key, lab) in zip(axes, series):
            drives = curves.forces[key]
            names = spec.drive_names.get(key) or [f"drive {k + 1}" for k in range(len(drives))]
            for name, decimator in zip(names, drives):
                t, y = decimator.curve()
                ax.plot(seconds(t), y, lw=0.9, label=name)
            ax.set_xlabel("time (s)")
            ax.set_ylabel("drive force (N)")
            ax.set_title(f"Drive forces, {lab}, {label}")
            ax.legend(loc="best", fontsize=8, ncol=len(names))
        save(fig, "drive_forces.png")

    # 4. internal force
    if spec.internal and len(curves.internal.get("applied", ())):
        fig, (ax,) = _figure(1)
        t, y = curves.internal["applied"].curve()
        ax.plot(seconds(t), y, color="tab:purple", lw=1.0, label="applied")
        if len(curves.internal.get("commanded", ())):
            t, y = curves.internal["commanded"].curve()
            ax.plot(seconds(t), y, color="tab:orange", lw=0.8, ls="--", label="commanded")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("‖f_int‖ (N)")
        ax.set_title(f"Norm of the internal force (null space of J_mᵀ, nominal model), {label}")
        ax.legend(loc="best", fontsize=8)
        save(fig, "internal_force.png")
    return files
