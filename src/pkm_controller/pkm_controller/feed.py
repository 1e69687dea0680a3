"""Feed override and feed hold: the trajectory's own time under a speed scale (pure core).

The reference is sampled at tau, the trajectory's time, which advances by s per
second of machine time; s is the feed override (LinuxCNC's feed override; s = 0 is a
feed hold). By the chain rule the reference the laws see is

    x_d = x(tau),  v_d = s v(tau),  a_d = s^2 a(tau) + (ds/dt) v(tau)

and s follows the operator's target at a bounded rate (``MAX_RATE_PER_S``), so that
neither a change nor a hold ever asks the drives for a velocity step: from full speed
a hold brakes along the path in 1 / MAX_RATE_PER_S seconds, at a deceleration of
MAX_RATE_PER_S v (5 m/s^2 at 0.5 m/s: the default planner limits). The path itself is
the planned one whatever s is; its velocity limits hold for s <= 1 (an override above
1 is refused), its acceleration limits where s^2 a + (ds/dt) v stays within them. At s = 1 with no override since the trajectory started, tau = t - t0
exactly, so a run without an override samples bit for bit as it always did.
"""

from __future__ import annotations

from pkm_kinematics.errors import FieldError

MAX_RATE_PER_S = 10.0         # |ds/dt|: from full speed to a hold in 0.1 s
MAX_OVERRIDE = 1.0            # the planner's limits hold up to the planned feed


def check_override(value) -> float:
    """The feed override as a float in [0, MAX_OVERRIDE]; ValueError naming the range."""
    try:
        s = float(value)
    except (TypeError, ValueError):
        raise FieldError("feed_override", f"must be a number in [0, {MAX_OVERRIDE:g}], got {value!r}") from None
    if not 0.0 <= s <= MAX_OVERRIDE:        # (False for NaN)
        raise FieldError("feed_override", f"must be in [0, {MAX_OVERRIDE:g}] (0: feed hold), got {value!r}")
    return s


class FeedClock:
    """tau(t) of the running trajectory under a feed override (module doc)."""

    def __init__(self):
        self.target = 1.0          # what the operator asked for
        self.scale = 1.0           # s of the last cycle
        self.restart(0.0)

    @property
    def nominal(self) -> bool:
        """No override in force: tau = t - t0."""
        return self.scale == 1.0 and self.target == 1.0

    def restart(self, t0: float) -> None:
        """A new trajectory starts at machine time ``t0`` (the override stays)."""
        self.t0 = t0
        self.last_t, self.last_tau = t0, 0.0

    def set_target(self, s: float) -> None:
        """The operator's override (check_override first); s ramps to it from the next cycle."""
        self.target = check_override(s)

    def peek(self, t: float) -> float:
        """tau at ``t`` without advancing (the start check of a new trajectory)."""
        if self.nominal:
            return t - self.t0
        return self.last_tau + self.scale * max(t - self.last_t, 0.0)

    def advance(self, t: float) -> tuple[float, float, float]:
        """(tau, s, ds/dt) at the cycle of machine time ``t``."""
        if self.nominal:
            self.last_t = t
            self.last_tau = tau = t - self.t0
            return tau, 1.0, 0.0
        dt = max(t - self.last_t, 0.0)
        s0 = self.scale
        step = MAX_RATE_PER_S * dt
        s1 = min(self.target, s0 + step) if self.target > s0 else max(self.target, s0 - step)
        tau = self.last_tau + 0.5 * (s0 + s1) * dt       # trapezoid: exact for the linear ramp
        sdot = (s1 - s0) / dt if dt > 0.0 else 0.0
        self.scale, self.last_t, self.last_tau = s1, t, tau
        if self.nominal:                 # back at full feed: tau = t - t0 again from here
            self.t0 = t - tau
        return tau, s1, sdot


def scaled_reference(sample, s: float, sdot: float) -> tuple[list, list, list]:
    """(x_d, v_d, a_d) of a reference sample (x, v, a) at trajectory time tau under the
    feed scale s and its rate: v_d = s v, a_d = s^2 a + (ds/dt) v (chain rule)."""
    x, v, a = sample
    if s == 1.0 and sdot == 0.0:
        return x, v, a
    return x, [s * vi for vi in v], [s * s * ai + sdot * vi for ai, vi in zip(a, v)]
