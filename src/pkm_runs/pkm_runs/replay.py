"""``pkm-replay``: offline determinism check of a recorded run (no ROS graph).

The recorded sensor data — ``drives/state`` and, for the metrology strategies,
``metrology/struts`` / ``metrology/pose`` of the same stamp — and the recorded
``trajectory`` are fed into a fresh :class:`ControllerCore` built from the run's own
``params/controller.yaml``, in the order the controller answered them (one recorded
``drives/command`` per answered state). Every recomputed force must equal the
recorded one bit for bit: the control law is a pure function of its inputs, and a
difference means hidden state, wall-clock dependence or a changed law. In real time
under missed deadlines a state can come before the reading of the one before: the
node prepared that one and left it (no command answers it), and so does the replay;
and a command is kept until its inputs are in (the recorder may log a reading it
received itself after the command that answered it).

What an operator did while the run went on — a program or jog (``trajectory``), the
feed override, a strategy or gain change — is replayed from ``controller/events``: the
controller applied each right after answering a state and recorded which
(pkm_controller.operator_actions), and the replay applies it after the same state.

An ``estop`` the controller obeyed is in ``controller/events`` too, after the state
it followed, and so is every safe stop of the controller (``safe_stop``: the only
record of a wall-clock watchdog's); both are replayed there. A recording made before
those events cannot replay a stop from outside the sensor data: with an ``estop`` in
it only the commands before it are compared. A missing state or metrology message
ends the comparison there. Either is said in the result's note.

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

from pkm_recording.bag import IncompleteBagError
from pkm_runs.report import incomplete_hint, recover_for_command
from pkm_runs.report_data import BagReadError, NoBagError, open_bag, read_messages
from pkm_common.causes import plant_stop_cause, setpoint_held
from pkm_common.conversions import pose_from_msg, stamp_to_ns
from pkm_controller.controller import ControllerConfig, ControllerCore
from pkm_controller.operator_actions import Action, apply_action, recorded_payload
from pkm_controller.reference import reference_from_msg
from pkm_kinematics import load_machine


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


def controller_config(run_dir: Path) -> tuple[str, ControllerConfig]:
    params = yaml.safe_load((run_dir / "params" / "controller.yaml").read_text(encoding="utf-8"))
    params = params["/**"]["ros__parameters"]
    names = {f.name for f in fields(ControllerConfig)}
    return params["machine"], ControllerConfig(**{k: v for k, v in params.items() if k in names})


LOOP_TOPICS = ("drives/state", "drives/command", "metrology/struts", "metrology/pose", "estop")
MAX_WAITING = 2000              # recorded commands a missing input may lag behind (2 s at 1 kHz)


def recorded_messages(bag_dir: Path, namespace: str, topics=LOOP_TOPICS):
    """(topic without the namespace, log time ns, message) of ``topics``, in log time
    order (a command is logged after the state and metrology it answers). Raises
    ``IncompleteBagError`` for a bag its recorder did not finish and ``BagReadError``
    for one rosbags cannot read."""
    ns = namespace.rstrip("/")
    wanted = {f"{ns}/{t}": t for t in topics}
    with open_bag(bag_dir) as reader:
        connections = [c for c in reader.connections if c.topic in wanted]
        if not connections:                   # (rosbags reads every connection for an empty list)
            return
        for connection, log_ns, raw in read_messages(reader, bag_dir, connections):
            yield wanted[connection.topic], log_ns, reader.deserialize(raw, connection.msgtype)


class _Replay:
    """The comparison, fed one recorded message at a time: memory stays bounded by the
    states and readings not answered yet, however long the run."""

    def __init__(self, core: ControllerCore, metrology: str | None):
        self.core, self.metrology = core, metrology
        self.inputs = {"drives/state": {}, "metrology/struts": {}, "metrology/pose": {}}
        # recorded commands whose inputs are not in yet: a stream the recorder receives
        # itself (not through a tap) is logged when it gets it, which under load can be
        # after the command that answered it
        self.waiting: collections.deque = collections.deque()
        self.commands = self.compared = self.identical = 0
        self.max_diff, self.first, self.note = 0.0, None, ""
        self.stopped = False             # an estop, or an input missing: nothing compared after it
        self.stops_recorded = False      # the controller recorded its stops: replayed, an estop is no cut
        self.trajectory_seen = False
        self.actions: dict[int, list] = collections.defaultdict(list)   # after_ns -> [(Action, payload, event)]

    def operator_events(self, events: list, trajectories) -> None:
        """The recorded controller/events; ``trajectories``: the recorded trajectory
        messages in order (one per trajectory event). Those of before the first state
        are applied now, the others after the answer of their state."""
        for event in events:
            action = Action(event["kind"])
            if "intruder" in event and action != Action.TRAJECTORY:
                continue                           # refused for its sender: nothing was applied
            payload = recorded_payload(event)
            self.stops_recorded |= action in (Action.ESTOP, Action.SAFE_STOP)
            if action == Action.TRAJECTORY:
                msg = next(trajectories, None)
                if msg is None:
                    self.note = self.note or "a trajectory event without its recorded trajectory: replay incomplete"
                    continue
                if "points" not in event:          # the node could not read it, or refused its
                    continue                       # sender (an intruder): nothing was applied
                payload = reference_from_msg(msg, self.core.model.task_space)
                self.trajectory_seen = True
            if event["after_ns"] is None:
                self._apply(action, payload, event)
            else:
                self.actions[event["after_ns"]].append((action, payload, event))

    def _apply(self, action: Action, payload, event: dict) -> None:
        replayed = apply_action(self.core, action, payload)
        if replayed["ok"] != event["ok"] and not self.note:
            self.note = (f"{action.value} after {event['after_ns']} ns: recorded "
                         f"{'applied' if event['ok'] else 'refused'}, replayed "
                         f"{'applied' if replayed['ok'] else 'refused: ' + replayed['message']}")

    def add(self, topic: str, msg) -> None:
        if topic == "trajectory":
            if not self.trajectory_seen:
                self.trajectory_seen = True
                self.core.set_trajectory(reference_from_msg(msg, self.core.model.task_space), None)
        elif topic == "estop":
            if msg.data and not self.stopped and not self.stops_recorded:   # not replayable: the cut
                self.stopped = True
                self.note = f"estop recorded: the {self.commands} commands before it are compared"
        elif topic == "drives/command":
            self.waiting.append((self.commands, msg))
            self.commands += 1
            self._drain()
        elif not self.stopped:                    # after a stop nothing is compared: nothing kept
            self.inputs[topic].setdefault(stamp_to_ns(msg.header.stamp), msg)
            self._drain()

    def _missing(self, stamp: int) -> str:
        """The input of ``stamp`` not recorded (yet), or ""."""
        if stamp not in self.inputs["drives/state"]:
            return "drives/state"
        return self.metrology if self.metrology and stamp not in self.inputs[self.metrology] else ""

    def _drain(self, end: bool = False) -> None:
        """Compare the waiting commands in order while their inputs are in; a command
        still missing one after MAX_WAITING later ones (or at the end) ends the
        comparison there."""
        while self.waiting and not self.stopped:
            i, command = self.waiting[0]
            stamp = stamp_to_ns(command.header.stamp)
            missing = self._missing(stamp)
            if missing and (end or len(self.waiting) > MAX_WAITING):
                self.note = f"command {i}: no recorded {missing} of stamp {stamp} ns; compared up to it"
                self.stopped = True
            if missing:
                return
            self.waiting.popleft()
            self.command(i, command)

    def command(self, i: int, command) -> None:
        """Recompute recorded command ``i`` (its inputs are in) and compare."""
        stamp = stamp_to_ns(command.header.stamp)
        state = self.inputs["drives/state"][stamp]
        metrology = self.inputs[self.metrology] if self.metrology else {}
        struts = pose = None
        if self.metrology == "metrology/struts":
            struts = list(metrology[stamp].position)
        elif self.metrology == "metrology/pose":
            position, rotation = pose_from_msg(metrology[stamp])
            pose = (position.tolist(), rotation)
        states = self.inputs["drives/state"]
        for older in sorted(t for t in states if t < stamp and self.metrology):
            # a state the node prepared and then left: the next one came before its
            # reading (realtime under missed deadlines). Preparing moved the core on.
            # Without a metrology reading to wait for the node answers every state it
            # takes: a recorded state without its command never reached it (realtime:
            # seen while a long callback, a 1000-point trajectory, held the node)
            self._prepare(states[older], older)
        if self._prepare(state, stamp):
            forces = self.core.complete(struts=struts, metrology_pose=pose)
        else:                                     # stopped: the node answers the last command (zeros)
            forces = list(self.core.last_command)
        for inputs in self.inputs.values():       # answered: older stamps are never asked for again
            for old in [t for t in inputs if t <= stamp]:
                del inputs[old]
        for action, payload, event in self.actions.pop(stamp, ()):
            self._apply(action, payload, event)     # what the operator did after this answer
        recorded = [float(f) for f in command.effort]
        self.compared += 1
        if forces == recorded:
            self.identical += 1
        elif self.first is None:
            self.first = i
        self.max_diff = max(self.max_diff, max((abs(a - b) for a, b in zip(forces, recorded)), default=0.0))


    def _prepare(self, state, stamp: int) -> bool:
        """What controller_node does on a drive state: the plant's status word, then the
        first half of the cycle (ControllerCore.prepare)."""
        frame_id = state.header.frame_id
        plant_cause = plant_stop_cause(frame_id)
        if plant_cause is not None and not self.core.stopped:
            self.core.plant_stopped(plant_cause)  # the node does so on the drives' status word
        return self.core.prepare(stamp * 1e-9, list(state.position), list(state.velocity), list(state.effort),
                                 held=setpoint_held(frame_id))


def replay_controller(run_dir: str | Path) -> ReplayResult:
    """Recompute every recorded command of ``run_dir`` and compare (see module doc),
    streaming the bag."""
    run_dir = Path(run_dir)
    run = json.loads((run_dir / "run.json").read_text(encoding="utf-8")) if (run_dir / "run.json").exists() else {}
    machine, config = controller_config(run_dir)
    core = ControllerCore(load_machine(machine), config)
    metrology = core.strategy.metrology_topic or None
    replay = _Replay(core, metrology)
    namespace = run.get("namespace", "/pkm")
    events = [json.loads(msg.data) for _, _, msg in
              recorded_messages(run_dir / "bag", namespace, ("controller/events",))]
    if events:
        replay.operator_events(events, (msg for _, _, msg in
                                        recorded_messages(run_dir / "bag", namespace, ("trajectory",))))
    else:
        # a recording without events (made before they existed): its first trajectory,
        # which the controller had before its first answer
        for topic, _, msg in recorded_messages(run_dir / "bag", namespace, ("trajectory",)):
            replay.add(topic, msg)
            break
    for topic, _, msg in recorded_messages(run_dir / "bag", namespace):
        replay.add(topic, msg)
    replay._drain(end=True)
    note = replay.note
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
