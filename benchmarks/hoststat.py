"""What the host did to a benchmark run: CPU time the hypervisor took ("steal").

This VM's rates move by +-30 % between minutes for the same code. /proc/stat's steal
column (time a virtual CPU was ready to run but the hypervisor ran something else)
explains much of it: a graph run at 395 steps/s saw 14.9 % steal, one at 843 steps/s
2.8 %. The benchmarks print it next to each run so a slow run can be told from a slow
change.

    with CpuSteal() as steal:
        ...
    steal.percent    # share of all CPU time over the block, or None without /proc/stat
"""

from __future__ import annotations


def _cpu_times() -> list[int] | None:
    try:
        with open("/proc/stat", encoding="ascii") as fh:
            fields = fh.readline().split()
    except OSError:
        return None
    if not fields or fields[0] != "cpu" or len(fields) < 9:
        return None
    return [int(v) for v in fields[1:]]


class CpuSteal:
    """Steal as a percentage of all CPU time (every core) between enter and exit."""

    def __init__(self) -> None:
        self.percent: float | None = None
        self._start: list[int] | None = None

    def __enter__(self) -> "CpuSteal":
        self._start = _cpu_times()
        return self

    def __exit__(self, *exc) -> None:
        end = _cpu_times()
        if self._start is None or end is None:
            return
        delta = [b - a for a, b in zip(self._start, end)]
        total = sum(delta[:8])              # user nice system idle iowait irq softirq steal
        self.percent = 100.0 * delta[7] / total if total > 0 else None

    def __str__(self) -> str:
        return "n/a" if self.percent is None else f"{self.percent:.1f} %"
