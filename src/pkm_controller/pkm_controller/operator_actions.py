"""An operator's actions on a running controller, applied between two cycles (pure core).

A trajectory (a program, a jog), the feed override (feed hold at 0), an E-stop, and the
settings an operator may change while running (ControllerCore.change_settings: strategy,
distribution, gains) reach the controller node as messages at any moment. The node
applies them right after answering a state, never between the two halves of a cycle,
and records each as an event (JSON on ``controller/events``) that says after which
answered state it was applied and what came of it. ``pkm-replay`` applies the same
events after the same states, so a run driven from a panel recomputes bit for bit.
"""

from __future__ import annotations

import json
from enum import Enum

from pkm_common.causes import TripCause

from .feed import check_override


class Action(str, Enum):
    TRAJECTORY = "trajectory"        # payload: a reference.Reference
    FEED_OVERRIDE = "feed_override"  # payload: s in [0, 1]
    SETTINGS = "settings"            # payload: {name: value} (JSON text or a dict)
    ESTOP = "estop"                  # payload: None; applied at once (never deferred), recorded
    # the controller's own safe stop, whatever started it: payload {"reason", "cause"}. Its
    # data reproduce most (a trip of the law, the plant's status word); a wall-clock
    # watchdog's only this record does, and with it every stop of a run is replayable
    SAFE_STOP = "safe_stop"


LAST_CYCLE = object()      # apply_action's default after_ns: the core's last cycle


def apply_action(core, action: Action, payload, after_ns=LAST_CYCLE) -> dict:
    """Apply one action to ``core`` (a ControllerCore) now; the event that records it:
    kind, after_ns (the stamp of the last state answered, None before the first;
    ``after_ns`` given: that one (None: before the first answer), for an action applied
    between a state and its answer), ok, message (why it was refused) and what was
    applied. A ValueError as the payload: the message could not be read; refused with
    its message."""
    if after_ns is LAST_CYCLE:
        after_ns = core.last_stamp_ns
    after = after_ns
    event = {"kind": action.value, "after_ns": after, "ok": True, "message": ""}
    if isinstance(payload, ValueError):          # the message itself could not be read
        event.update(ok=False, message=str(payload))
        return event
    try:
        if action == Action.TRAJECTORY:
            now = None if core.last_time_s is None else core.last_time_s + core.config.dt_s
            event.update(duration_s=payload.duration_s, points=payload.points)
            if getattr(payload, "stamp_ns", None) is not None:     # the message's header stamp: its name
                event["stamp_ns"] = payload.stamp_ns
            approach = core.set_trajectory(payload, now)
            if approach is not None:
                event["approach"] = approach
        elif action == Action.ESTOP:
            core.trip("estop", TripCause.ESTOP)
        elif action == Action.SAFE_STOP:
            event.update(reason=str(payload["reason"]), cause=TripCause(payload["cause"]).value)
            core.trip(event["reason"], TripCause(event["cause"]))      # the first stop's cause is kept
        elif action == Action.FEED_OVERRIDE:
            event["value"] = check_override(payload)
            core.feed.set_target(event["value"])
        else:
            changes = json.loads(payload) if isinstance(payload, (str, bytes)) else payload
            event["changes"] = changes
            core.change_settings(changes)
    except json.JSONDecodeError as exc:
        event.update(ok=False, message=f"settings: not JSON ({exc})")
    except ValueError as exc:
        event.update(ok=False, message=str(exc))
    return event


def recorded_payload(event: dict):
    """The payload to apply a recorded event again (pkm-replay); a trajectory's is its
    recorded message, which the caller reads."""
    if event["kind"] == Action.SAFE_STOP.value:
        return {"reason": event["reason"], "cause": event["cause"]}
    return event.get("value", event.get("changes"))


def event_json(event: dict) -> str:
    return json.dumps(event, sort_keys=True)


def event_summary(event: dict) -> str:
    """One log line for an applied or refused action."""
    if not event["ok"]:
        return f"{event['kind']} refused: {event['message']}"
    if event["kind"] == Action.TRAJECTORY.value:
        approach = event.get("approach")
        after = "" if approach is None else (f", after an approach of {approach['distance_m'] * 1e3:.3f} mm / "
                                             f"{approach['angle_rad']:.4f} rad in {approach['duration_s']:.3f} s")
        return f"trajectory accepted: {event['duration_s']:.3f} s, {event['points']} points{after}"
    return f"{event['kind']} applied: " + ", ".join(
        f"{k}={v}" for k, v in event.items() if k not in ("kind", "ok", "message"))


class OperatorInbox:
    """The actions that arrived since the last answer: ``add`` applies one at once
    when the controller has not cycled yet, else keeps it; ``drain`` applies the kept
    ones (right after an answer). Both return the events made."""

    def __init__(self):
        self.pending: list = []

    def add(self, core, action: Action, payload) -> list[dict]:
        self.pending.append((action, payload))
        return self.drain(core) if core.last_time_s is None else []

    def drain(self, core) -> list[dict]:
        actions, self.pending = self.pending, []
        return [apply_action(core, action, payload) for action, payload in actions]
