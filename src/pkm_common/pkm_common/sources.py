"""Who may publish on a topic a node acts on (pure, no rclpy).

DDS gives no sender per message: a node that acts on a stream (the plant on
``drives/command``, the controller on ``drives/state`` and its metrology) asks the
graph who publishes it (``get_publishers_info_by_topic``, full node names) and counts
the publishers matched to its subscription (the ``matched`` event comes before a new
publisher's first message). The source is the node it was told (a ``*_source``
parameter) or, with none, the one publisher there is at the first message; any other
publisher, or a second one under the source's name (an orphan of an earlier run), is
an intruder.

A command (a trajectory, a goal, a program, a setting, the feed override, the start)
may come from any of the nodes a run names (``AllowedSenders``: the run's planner, the
operator's panel, pkm-run itself): a publisher of another name is an intruder. DDS
gives no sender per message, so while an intruder publishes on a commanding topic no
message of it is taken, from anyone. Names are what the graph says: a process that
names its node like an allowed one is not caught by them; the run's credential
(pkm_common.credential) catches it, and ``CommandGuard`` asks both, names first (an
intruder the graph knows is named).
"""

from __future__ import annotations

from dataclasses import dataclass

from pkm_common.credential import COMMAND_TOPICS, Verifier

__all__ = ["AllowedSenders", "CommandGuard", "Intrusion", "SourceGate", "node_names"]


@dataclass(frozen=True)
class Intrusion:
    """Another publisher on the topic: why, and who (node names, when known)."""

    reason: str
    sender: str = ""
    by_credential: bool = False          # the message's credential was refused (not the graph's names)


class SourceGate:
    """The one source of ``topic`` (``expected``: a full node name, or "" for the one
    publisher at the first message; ``parameter``: the parameter that names it, for
    the message)."""

    def __init__(self, topic: str, expected: str = "", parameter: str = "source"):
        self.topic, self.expected, self.parameter = topic, expected, parameter
        self.source = expected               # the node, once known

    def check(self, publishers: list[str], matched: int = 1) -> Intrusion | None:
        """The nodes publishing ``topic``, one name per publisher: any other than the
        source is an intruder, named; more publishers ``matched`` to the subscription
        than the graph names yet is one too, counted (its name comes with a later
        check). Before the source is known nothing is decided."""
        if not self.source:
            return None
        others = sorted({p for p in publishers if p != self.source})
        if publishers.count(self.source) > 1:
            others.append(f"a second {self.source}")
        if others:
            return Intrusion(f"{', '.join(others)} publishes on {self.topic} (only {self.source} may)",
                             ", ".join(others))
        if matched > max(1, len(publishers)):
            return Intrusion(f"{matched} publishers on {self.topic} (only {self.source} may)")
        return None

    def connect(self, publishers: list[str], matched: int = 1) -> Intrusion | None:
        """At the first message: the source is the expected node, or else the one
        publisher there is; two publishers (``matched`` to the subscription, named or
        not yet) and no expected node are refused."""
        if not self.source and matched > 1:
            return Intrusion(f"{matched} publishers on {self.topic}: set {self.parameter} to the node name of its "
                             "source", ", ".join(sorted(set(publishers))))
        if not self.source:
            distinct = sorted(set(publishers))
            if len(distinct) > 1:
                return Intrusion(f"{len(distinct)} publishers on {self.topic} ({', '.join(distinct)}): set "
                                 f"{self.parameter} to the node name of its source", ", ".join(distinct))
            if distinct:
                self.source = distinct[0]
        return self.check(publishers, matched)


def node_names(text: str) -> frozenset:
    """Full node names from a comma-separated parameter ("/pkm/panel, /pkm/x")."""
    return frozenset(name.strip() for name in text.split(",") if name.strip())


class AllowedSenders:
    """Who may command through ``topic``: the nodes ``allowed`` (full names; empty:
    anyone, a node started by hand without a run); ``parameter`` names the setting
    that lists them, for the message."""

    def __init__(self, topic: str, allowed, parameter: str = "sources"):
        self.topic, self.parameter = topic, parameter
        self.allowed = frozenset(allowed)

    def check(self, publishers: list[str]) -> Intrusion | None:
        """The nodes publishing ``topic`` (named: conversions.graph_senders): any not
        allowed is an intruder, named. An endpoint the graph knows no node of is not
        counted: at start-up a legitimate node's endpoints are seen before its name, and
        refusing them lost a run's latched trajectory under load (a DDS writer that never
        names a node, like a spoofed name, is what a credential would catch)."""
        if not self.allowed:
            return None
        others = sorted({p for p in publishers if p not in self.allowed})
        if not others:
            return None
        return Intrusion(f"{', '.join(others)} publishes on {self.topic} (only {', '.join(sorted(self.allowed))} "
                         f"may: {self.parameter})", ", ".join(others))


class CommandGuard:
    """Whether a command on a topic may be taken: every publisher the graph names is
    allowed (``names``), then the message carries the run's credential of an allowed
    sender (``verifier``; none required without a key). One rule for the controller,
    the planner and the plant."""

    def __init__(self, names: AllowedSenders, verifier: Verifier):
        self.names, self.verifier = names, verifier
        self.topic, self.stamped = names.topic, COMMAND_TOPICS[names.topic]

    @property
    def watched(self) -> bool:
        """Anything to check: named senders or a key."""
        return bool(self.names.allowed) or self.verifier.required

    def refused(self, senders, buf=b"") -> Intrusion | None:
        """Why the command ``buf`` is not taken (None: taken); ``senders()``: the
        graph's node names on the topic, asked only when the run names its senders.
        Without ``buf`` only the names are checked (a check of the graph)."""
        found = self.names.check(senders()) if self.names.allowed else None
        if found is None and buf:
            why = self.verifier.refusal(self.topic, buf, self.stamped, self.names.allowed)
            if why is not None:
                found = Intrusion(why.reason, why.sender, by_credential=True)
        return found

    def authentic(self, buf) -> bool:
        """The message carries a valid credential (or none is required): what it says
        of itself (a trajectory's stamp) can be believed."""
        return self.verifier.refusal(self.topic, buf, self.stamped) is None
