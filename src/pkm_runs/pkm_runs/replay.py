"""``pkm-replay``: offline determinism check of a recorded run (no ROS graph).

The controller node's own loop (:class:`pkm_controller.node_loop.ControllerLoop`,
the same object controller_node drives) is built from the run's
``params/controller.yaml`` and given the recorded bytes: ``drives/state`` and, for
the metrology strategies, ``metrology/struts`` / ``metrology/pose`` of the same
stamp, in the order the controller answered them (one recorded ``drives/command``
per answered state). Its ports (:class:`ReplayPorts`) keep what it sends out. Every
recomputed command must equal the recorded one bit for bit: the loop is a pure
function of its inputs, and a difference means hidden state, wall-clock dependence
or a changed law. In real time under missed deadlines a state can come before the
reading of the one before: the node prepared that one and left it (no command
answers it), and so does the replay; and a command is kept until its inputs are in
(the recorder may log a reading it received itself after the command that answered
it).

What an operator did while the run went on (a program or jog on ``trajectory``, the
feed override, a strategy or gain change) is replayed from ``controller/events``: the
controller recorded after which answered state it applied each
(pkm_controller.operator_actions). The replay hands the loop the same action before
that state (a trajectory as its recorded bytes, through the loop's own reading and
checks), and the loop applies it after its answer, as the node did.

An ``estop`` the controller obeyed is in ``controller/events`` too, after the state
it followed, and so is every safe stop of the controller (``safe_stop``: the only
record of a wall-clock watchdog's); the replay gives the loop both after the same
answer. A recording made before those events cannot replay a stop from outside the
sensor data: with an ``estop`` in it only the commands before it are compared. A
missing state or metrology message ends the comparison there. Either is said in the
result's note.

A bag its recorder did not finish (killed, cut) is refused with one line saying so;
``--recover`` first makes it readable up to its last complete chunk
(``pkm_recording.bag.recover``).
"""

from __future__ import annotations

import argparse
import collections
import json
import sys
from dataclasses import dataclass, fields
from pathlib import Path

import yaml

from pkm_common import topics
from pkm_common.cdr import JointStateDecoder, decode_bool, decode_string, stamp_ns_of
from pkm_common.causes import TripCause
from pkm_controller.configuration import NODE_PARAMETERS, core_from_parameters
from pkm_controller.config import ControllerConfig
from pkm_controller.node_loop import ControllerLoop
from pkm_controller.operator_actions import Action, recorded_payload
from pkm_recording.bag import IncompleteBagError
from pkm_runs.report import incomplete_hint, recover_for_command
from pkm_runs.report_data import BagReadError, NoBagError, open_bag, read_messages


@dataclass
class ReplayResult:
    commands: int             # recorded commands
    compared: int             # commands recomputed
    identical: int            # bit-identical
    max_abs_diff_n: float
    first_mismatch: int | None   # index of the first differing command
    note: str = ""

    @property
    def ok(self) -> bool:
        return self.compared > 0 and self.identical == self.compared


def controller_parameters(run_dir: Path) -> dict:
    """The controller node's parameters of the run (``params/controller.yaml``)."""
    params = yaml.safe_load((run_dir / "params" / "controller.yaml").read_text(encoding="utf-8"))
    return params["/**"]["ros__parameters"]


def controller_config(run_dir: Path) -> tuple[str, ControllerConfig]:
    params = controller_parameters(run_dir)
    names = {f.name for f in fields(ControllerConfig)}
    return params["machine"], ControllerConfig(**{k: v for k, v in params.items() if k in names})


LOOP_TOPICS = (topics.DRIVES_STATE, topics.DRIVES_COMMAND, topics.METROLOGY_STRUTS, topics.METROLOGY_POSE, topics.ESTOP)
MAX_WAITING = 2000              # recorded commands a missing input may lag behind (2 s at 1 kHz)
# applied by the loop between a state and its answer (its inbox): handed to it before that state
BEFORE_ANSWER = (Action.TRAJECTORY, Action.FEED_OVERRIDE, Action.SETTINGS)


def recorded_bytes(bag_dir: Path, namespace: str, topics=LOOP_TOPICS):
    """(topic without the namespace, log time ns, serialized message) of ``topics``, in
    log time order (a command is logged after the state and metrology it answers).
    Raises ``IncompleteBagError`` for a bag its recorder did not finish and
    ``BagReadError`` for one rosbags cannot read."""
    ns = namespace.rstrip("/")
    wanted = {f"{ns}/{t}": t for t in topics}
    with open_bag(bag_dir) as reader:
        connections = [c for c in reader.connections if c.topic in wanted]
        if not connections:                   # (rosbags reads every connection for an empty list)
            return
        for connection, log_ns, raw in read_messages(reader, bag_dir, connections):
            yield wanted[connection.topic], log_ns, raw


def recorded_messages(bag_dir: Path, namespace: str, topics=LOOP_TOPICS):
    """:func:`recorded_bytes` as message objects (rosbags' deserialization)."""
    ns = namespace.rstrip("/")
    wanted = {f"{ns}/{t}": t for t in topics}
    with open_bag(bag_dir) as reader:
        connections = [c for c in reader.connections if c.topic in wanted]
        if not connections:
            return
        for connection, log_ns, raw in read_messages(reader, bag_dir, connections):
            yield wanted[connection.topic], log_ns, reader.deserialize(raw, connection.msgtype)


class ReplayPorts:
    """The loop's ports (node_loop.ControllerPorts) for a replay: the commands it
    publishes and the events it records are kept; the rest goes nowhere. The graph
    has one node per input, the source the run named."""

    def __init__(self):
        self.commands: list[bytes] = []
        self.events: list[dict] = []

    def publish_command(self, command: bytes) -> None:
        self.commands.append(command)

    def resend_command(self, command: bytes) -> None:
        pass

    def publish_reference_bytes(self, reference: bytes) -> None:
        pass

    def publish_status(self, stamp_ns: int, level: int, message: str, values: dict) -> None:
        pass

    def publish_event(self, text: str) -> None:
        self.events.append(json.loads(text))

    def publish_estop(self) -> None:
        pass

    def after_cycle(self) -> None:
        pass

    def input_publishers(self, topic: str) -> list[str]:
        return ["/replay"]

    def topic_senders(self, topic: str) -> list[str]:
        return []

    def log_info(self, text: str) -> None:
        pass

    def log_error(self, text: str) -> None:
        pass


def replay_loop(run_dir: Path) -> tuple[ControllerLoop, ReplayPorts]:
    """The run's controller loop as the node configured it, with replay ports: every
    input from the one recorded source, no key (the recorded commands were checked
    when they came), no waiting for a start (the recording begins with it)."""
    params = controller_parameters(run_dir)
    machine, config = controller_config(run_dir)
    values = {**NODE_PARAMETERS, **{k: params[k] for k in NODE_PARAMETERS if k in params},
              "wait_for_trajectory": False, "wait_for_start": False, "state_source": "", "metrology_source": "",
              "trajectory_source": "", "operator_sources": "", "credential_file": ""}
    ports = ReplayPorts()
    loop = ControllerLoop(core_from_parameters(machine, config), values, ports)
    loop.active = True
    return loop, ports


class _Replay:
    """The comparison, fed one recorded message at a time: memory stays bounded by the
    states and readings not answered yet, however long the run."""

    def __init__(self, loop: ControllerLoop, ports: ReplayPorts):
        self.loop, self.ports = loop, ports
        strategy = loop.core.strategy
        self.metrology = strategy.metrology_topic or None
        self.inputs = {"drives/state": {}, "metrology/struts": {}, "metrology/pose": {}}
        # recorded commands whose inputs are not in yet: a stream the recorder receives
        # itself (not through a tap) is logged when it gets it, which under load can be
        # after the command that answered it
        self.waiting: collections.deque = collections.deque()
        self.command_decoder = JointStateDecoder("drives/command")
        self.commands = self.compared = self.identical = 0
        self.max_diff, self.first, self.note = 0.0, None, ""
        self.stopped = False             # an estop, or an input missing: nothing compared after it
        self.stops_recorded = False      # the controller recorded its stops: replayed, an estop is no cut
        self.trajectory_seen = False
        # after_ns -> [(Action, payload, recorded event)]: handed over before the state
        # of that stamp (BEFORE_ANSWER) or after its answer (stops, refusals)
        self.before: dict[int, list] = collections.defaultdict(list)
        self.after: dict[int, list] = collections.defaultdict(list)
        self.outcomes: list[tuple[dict, int]] = []      # (recorded event, index of the replayed one)

    def operator_events(self, events: list, trajectories) -> None:
        """The recorded controller/events; ``trajectories``: the recorded trajectory
        messages' bytes in order (one per trajectory event). Those of before the first
        state are handed over now, the others around the answer of their state."""
        for event in events:
            action = Action(event["kind"])
            if "intruder" in event and action != Action.TRAJECTORY:
                continue                           # refused for its sender: nothing was applied
            payload = recorded_payload(event)
            self.stops_recorded |= action in (Action.ESTOP, Action.SAFE_STOP)
            if action == Action.TRAJECTORY:
                payload = next(trajectories, None)
                if payload is None:
                    self.note = self.note or "a trajectory event without its recorded trajectory: replay incomplete"
                    continue
                if "intruder" in event:            # refused for its sender: nothing was applied
                    continue
                self.trajectory_seen |= event["ok"]
            when = event["after_ns"]
            # a trajectory the node could not read or refused as inconsistent (no points
            # counted) was refused as it came, not in the loop's inbox
            queued = action in BEFORE_ANSWER and (action != Action.TRAJECTORY or "points" in event)
            if when is None:
                self._hand_over(action, payload, event)
            elif queued:
                self.before[when].append((action, payload, event))
            else:                                  # stops, and trajectories refused as they came
                self.after[when].append((action, payload, event))

    def _hand_over(self, action: Action, payload, event: dict) -> None:
        """Give the loop one recorded action, by the way the node gave it."""
        loop = self.loop
        self.outcomes.append((event, len(self.ports.events)))
        if action == Action.TRAJECTORY:
            loop.on_trajectory(payload)
        elif action == Action.ESTOP:
            loop.on_estop(True)
        elif action == Action.SAFE_STOP:
            if not loop.core.stopped:              # else the replayed loop stopped by itself
                loop.safe_stop(payload["reason"], TripCause(payload["cause"]))
        else:
            loop.operator(action, payload)

    def _hand_over_all(self, actions) -> None:
        for action, payload, event in actions:
            self._hand_over(action, payload, event)

    def add(self, topic: str, raw: bytes) -> None:
        if topic == "estop":
            if decode_bool(raw, "estop") and not self.stopped and not self.stops_recorded:   # the cut
                self.stopped = True
                self.note = f"estop recorded: the {self.commands} commands before it are compared"
        elif topic == "drives/command":
            self.waiting.append((self.commands, raw))
            self.commands += 1
            self.drain()
        elif not self.stopped:                    # after a stop nothing is compared: nothing kept
            self.inputs[topic].setdefault(stamp_ns_of(raw), raw)
            self.drain()

    def _missing(self, stamp: int) -> str:
        """The input of ``stamp`` not recorded (yet), or ""."""
        if stamp not in self.inputs["drives/state"]:
            return "drives/state"
        return self.metrology if self.metrology and stamp not in self.inputs[self.metrology] else ""

    def drain(self, end: bool = False) -> None:
        """Compare the waiting commands in order while their inputs are in; a command
        still missing one after MAX_WAITING later ones (or at the end) ends the
        comparison there."""
        while self.waiting and not self.stopped:
            i, command = self.waiting[0]
            stamp = stamp_ns_of(command)
            missing = self._missing(stamp)
            if missing and (end or len(self.waiting) > MAX_WAITING):
                self.note = f"command {i}: no recorded {missing} of stamp {stamp} ns; compared up to it"
                self.stopped = True
            if missing:
                return
            self.waiting.popleft()
            self.command(i, command, stamp)

    def command(self, i: int, command: bytes, stamp: int) -> None:
        """The loop's answer to the state of recorded command ``i`` (its inputs are in),
        compared with it."""
        loop, states = self.loop, self.inputs["drives/state"]
        # the operator's actions applied after this answer reached the node after the
        # answer before it: with a metrology strategy possibly between this state and
        # its reading (after the first state, which moves the core's clock), which
        # the replay takes as the one case
        before = self.before.pop(stamp, ())
        if not self.metrology or loop.core.stopped:
            self._hand_over_all(before)
            before = ()
        if self.metrology:
            # a state the node prepared and then left: the next one came before its
            # reading (realtime under missed deadlines). Preparing moved the core on.
            # Without a metrology reading to wait for the node answers every state it
            # takes: a recorded state without its command never reached it (realtime:
            # seen while a long callback, a 1000-point trajectory, held the node)
            for older in sorted(t for t in states if t < stamp):
                loop.on_state(states[older])
        answers = len(self.ports.commands)
        loop.on_state(states[stamp])
        self._hand_over_all(before)
        if self.metrology and len(self.ports.commands) == answers:
            loop.on_metrology(self.inputs[self.metrology][stamp])
        for inputs in self.inputs.values():       # answered: older stamps are never asked for again
            for old in [t for t in inputs if t <= stamp]:
                del inputs[old]
        self._hand_over_all(self.after.pop(stamp, ()))
        recorded = self.command_decoder.decode(command).effort
        replayed = self.command_decoder.decode(self.ports.commands[-1]).effort \
            if len(self.ports.commands) > answers else ()
        self.ports.commands.clear()
        self.compared += 1
        if replayed == recorded:
            self.identical += 1
        else:
            if self.first is None:
                self.first = i
            diffs = [abs(a - b) for a, b in zip(replayed, recorded)] if replayed else [float("inf")]
            self.max_diff = max(self.max_diff, max(diffs, default=0.0))

    def verdicts(self) -> str:
        """The first recorded action whose replayed outcome (applied or refused) differs, or ""."""
        replayed = [e for e in self.ports.events if e["kind"] in {a.value for a in BEFORE_ANSWER}]
        recorded = [e for e, _ in self.outcomes if Action(e["kind"]) in BEFORE_ANSWER]
        for was, now in zip(recorded, replayed):
            if was["ok"] != now["ok"]:
                return (f"{was['kind']} after {was['after_ns']} ns: recorded "
                        f"{'applied' if was['ok'] else 'refused'}, replayed "
                        f"{'applied' if now['ok'] else 'refused: ' + now['message']}")
        return ""


def replay_controller(run_dir: str | Path) -> ReplayResult:
    """Recompute every recorded command of ``run_dir`` through the controller's loop and
    compare (see module doc), streaming the bag."""
    run_dir = Path(run_dir)
    run = json.loads((run_dir / "run.json").read_text(encoding="utf-8")) if (run_dir / "run.json").exists() else {}
    replay = _Replay(*replay_loop(run_dir))
    namespace = run.get("namespace", "/pkm")
    events = [json.loads(decode_string(raw, "controller/events"))
              for _, _, raw in recorded_bytes(run_dir / "bag", namespace, (topics.CONTROLLER_EVENTS,))]
    trajectories = (raw for _, _, raw in recorded_bytes(run_dir / "bag", namespace, (topics.TRAJECTORY,)))
    if events:
        replay.operator_events(events, trajectories)
    else:
        # a recording without events (made before they existed): its first trajectory,
        # which the controller had before its first answer
        first = next(trajectories, None)
        if first is not None:
            replay.trajectory_seen = True
            replay.loop.on_trajectory(first)
    for topic, _, raw in recorded_bytes(run_dir / "bag", namespace):
        replay.add(topic, raw)
    replay.drain(end=True)
    note = replay.note or replay.verdicts()
    if not replay.trajectory_seen and not note:
        note = "no trajectory in the recording (the run ended before it started?)"
    return ReplayResult(replay.commands, replay.compared, replay.identical, replay.max_diff, replay.first, note)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="pkm-replay", description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", help="a run directory of pkm-run (with bag/ and params/controller.yaml)")
    parser.add_argument("--recover", action="store_true",
                        help="first make a bag whose recorder was killed readable up to its last complete chunk "
                             "(pkm_recording.bag.recover; the original .mcap is kept as .mcap.truncated)")
    args = parser.parse_args(argv)
    run_dir = Path(args.run_dir)
    if not (run_dir / "bag").is_dir() or not (run_dir / "params" / "controller.yaml").exists():
        print(f"pkm-replay: {run_dir} has no bag/ or params/controller.yaml", file=sys.stderr)
        return 2
    try:
        if args.recover:
            recover_for_command("pkm-replay", run_dir)
    except (NoBagError, ValueError) as exc:       # ValueError: not an MCAP file, several files, ...
        print(f"pkm-replay: error: {run_dir / 'bag'} cannot be recovered: {exc}", file=sys.stderr)
        return 2
    try:
        result = replay_controller(run_dir)
    except (NoBagError, IncompleteBagError, BagReadError) as exc:
        print(incomplete_hint("pkm-replay", run_dir, exc), file=sys.stderr)
        return 2
    print(f"{result.compared} of {result.commands} recorded commands recomputed, {result.identical} identical, "
          f"max |difference| {result.max_abs_diff_n:.3g} N"
          + (f", first mismatch at command {result.first_mismatch}" if result.first_mismatch is not None else "")
          + (f" ({result.note})" if result.note else ""))
    return 0 if result.ok else 1


if __name__ == "__main__":
    sys.exit(main())
