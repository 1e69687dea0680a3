"""``pkm-replay``: offline determinism check of a recorded run (no ROS graph).

The recorded sensor data — ``drives/state`` and, for the metrology strategies,
``metrology/struts`` / ``metrology/pose`` of the same stamp — and the recorded
``trajectory`` are fed into a fresh :class:`ControllerCore` built from the run's own
``params/controller.yaml``, in the order the controller answered them (one recorded
``drives/command`` per answered state). Every recomputed force must equal the
recorded one bit for bit: the control law is a pure function of its inputs, and a
difference means hidden state, wall-clock dependence or a changed law.

Stops from outside the sensor data (``estop`` from another node, wall-clock
watchdogs) cannot be replayed: with an ``estop`` in the recording only the commands
before it are compared; a missing state or metrology message ends the comparison
there. Either is said in the result's note.

A bag its recorder did not finish (killed, cut) is refused with one line saying so;
``--recover`` first makes it readable up to its last complete chunk
(``pkm_bringup.bag.recover``).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass, fields
from pathlib import Path

import yaml

from pkm_bringup.bag import IncompleteBagError
from pkm_bringup.report import incomplete_hint, recover_for_command
from pkm_bringup.report_data import BagReadError, NoBagError, open_bag, read_messages
from pkm_common.conversions import pose_from_msg, stamp_to_ns
from pkm_controller.controller import ControllerConfig, ControllerCore
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


def read_streams(bag_dir: Path, namespace: str) -> dict:
    """First message per stamp of the loop's topics, the commands in order, the trajectory.
    Raises ``IncompleteBagError`` for a bag its recorder did not finish and
    ``BagReadError`` for one rosbags cannot read."""
    ns = namespace.rstrip("/")
    wanted = {f"{ns}/{t}": t for t in ("drives/state", "drives/command", "metrology/struts", "metrology/pose",
                                      "trajectory", "estop")}
    streams = {t: {} for t in wanted.values() if t not in ("trajectory", "drives/command", "estop")}
    commands, trajectory, estop_log_ns = [], None, None
    with open_bag(bag_dir) as reader:
        connections = [c for c in reader.connections if c.topic in wanted]
        for connection, log_ns, raw in read_messages(reader, bag_dir, connections):
            topic = wanted[connection.topic]
            msg = reader.deserialize(raw, connection.msgtype)
            if topic == "trajectory":
                trajectory = trajectory or msg
            elif topic == "drives/command":
                commands.append((log_ns, msg))
            elif topic == "estop":
                if msg.data and estop_log_ns is None:
                    estop_log_ns = log_ns
            else:
                streams[topic].setdefault(stamp_to_ns(msg.header.stamp), msg)
    return {"commands": commands, "trajectory": trajectory, "estop_log_ns": estop_log_ns, **streams}


def controller_config(run_dir: Path) -> tuple[str, ControllerConfig]:
    params = yaml.safe_load((run_dir / "params" / "controller.yaml").read_text(encoding="utf-8"))
    params = params["/**"]["ros__parameters"]
    names = {f.name for f in fields(ControllerConfig)}
    return params["machine"], ControllerConfig(**{k: v for k, v in params.items() if k in names})


def replay_controller(run_dir: str | Path) -> ReplayResult:
    """Recompute every recorded command of ``run_dir`` and compare (see module doc)."""
    run_dir = Path(run_dir)
    run = json.loads((run_dir / "run.json").read_text(encoding="utf-8")) if (run_dir / "run.json").exists() else {}
    machine, config = controller_config(run_dir)
    data = read_streams(run_dir / "bag", run.get("namespace", "/pkm"))
    core = ControllerCore(load_machine(machine), config)
    if data["trajectory"] is not None:
        core.set_trajectory(reference_from_msg(data["trajectory"], core.planar), None)
    compared = identical = 0
    max_diff, first, note = 0.0, None, ""
    if data["trajectory"] is None:
        note = "no trajectory in the recording (the run ended before it started?)"
    commands = data["commands"]
    if data["estop_log_ns"] is not None:      # a stop from outside the sensor data: not replayable
        commands = [(t, c) for t, c in commands if t < data["estop_log_ns"]]
        note = f"estop recorded: the {len(commands)} commands before it are compared"
    metrology = {"sensor_space": "metrology/struts", "measured_space": "metrology/pose"}.get(config.strategy)
    for i, (_, command) in enumerate(commands):
        stamp = stamp_to_ns(command.header.stamp)
        state = data["drives/state"].get(stamp)
        if state is None or (metrology and stamp not in data[metrology]):
            missing = "drives/state" if state is None else metrology
            note = f"command {i}: no recorded {missing} of stamp {stamp} ns; compared up to it"
            break
        struts = pose = None
        if metrology == "metrology/struts":
            struts = list(data[metrology][stamp].position)
        elif metrology == "metrology/pose":
            position, rotation = pose_from_msg(data[metrology][stamp])
            pose = (position.tolist(), rotation)
        forces = core.update(stamp * 1e-9, list(state.position), list(state.velocity), list(state.effort),
                             struts=struts, metrology_pose=pose)
        recorded = [float(f) for f in command.effort]
        compared += 1
        diff = max((abs(a - b) for a, b in zip(forces, recorded)), default=0.0)
        if forces == recorded:
            identical += 1
        elif first is None:
            first = i
        max_diff = max(max_diff, diff)
    return ReplayResult(len(data["commands"]), compared, identical, max_diff, first, note)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="pkm-replay", description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", help="a run directory of pkm-run (with bag/ and params/controller.yaml)")
    parser.add_argument("--recover", action="store_true",
                        help="first make a bag whose recorder was killed readable up to its last complete chunk "
                             "(pkm_bringup.bag.recover; the original .mcap is kept as .mcap.truncated)")
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
