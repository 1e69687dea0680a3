"""A per-window rate limit (pure): at most ``count`` events in each ``window_s`` of
wall-clock time, for logs and records that a stream of bad input must not flood."""

from __future__ import annotations

__all__ = ["RateLimit"]


class RateLimit:
    """``allow(now_s)``: True for at most ``count`` calls a window; the others are
    counted in ``suppressed``."""

    __slots__ = ("count", "window_s", "start_s", "used", "suppressed")

    def __init__(self, count: int, window_s: float = 1.0):
        if count < 1 or not window_s > 0.0:
            raise ValueError(f"RateLimit: count must be >= 1 and window_s > 0, got {count}, {window_s}")
        self.count, self.window_s = count, window_s
        self.start_s, self.used, self.suppressed = None, 0, 0

    def allow(self, now_s: float) -> bool:
        if self.start_s is None or now_s - self.start_s >= self.window_s:
            self.start_s, self.used = now_s, 0
        if self.used >= self.count:
            self.suppressed += 1
            return False
        self.used += 1
        return True
