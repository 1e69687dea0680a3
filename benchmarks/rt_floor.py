"""The machine's realtime floor: how many 1/rate deadlines a loop that does no work at
all misses on this machine, with the realtime profile's scheduling. A graph of the same
shape (rclpy over Fast DDS, one message a hop) cannot miss fewer than its chain floor,
so a miss-rate target is judged against it.

Two floors, each in processes of their own (SCHED_FIFO as pkm_bringup.rt_profile.PROFILE
says, memory locked):

- **timer**: one thread at the controller's priority sleeps to each period boundary
  (absolute times, as cyclictest) and counts the wake-ups later than one period; after
  one, it goes on at the next boundary still ahead, as an rcl timer skips the periods
  it missed (one stall, one count). This is the wake-up lateness of the machine, what
  every hop of a graph pays, not sim_hw's rule.
- **chain**: the graph's critical path without its work: a plant process (sim_hw's
  priority, a wall timer every period, publishing a 6-joint JointState as bytes), a
  sensor process (gough_sensor's priority) that forwards it, and a controller process
  (the controller's priority) that forwards that back as the command; the project's
  QoS, EventsExecutor and runner. A tick whose command did not answer the previous state
  is a miss: sim_hw's rule.

Run by benchmarks/realtime.py after each pair of graph runs. Alone:

    .venv/bin/python benchmarks/rt_floor.py [--rate 1000] [--steps 5000]

Needs SCHED_FIFO and memory locking (root, or CAP_SYS_NICE and CAP_IPC_LOCK).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

NAMES = [f"q{i}" for i in range(1, 7)]
CHAIN = ("controller", "gough_sensor", "sim_hw")     # started in this order, the plant last


@dataclass(frozen=True)
class Floor:
    steps: int
    misses: int

    @property
    def percent(self) -> float:
        return 100.0 * self.misses / self.steps if self.steps else float("nan")


def _timer(rate: float, steps: int) -> None:
    """The bare sleeper (run in a child already at its priority, memory locked)."""
    from pkm_common.runner import lock_memory
    lock_memory()
    period = round(1e9 / rate)
    late = 0
    deadline = time.clock_gettime_ns(time.CLOCK_MONOTONIC) + period
    for _ in range(steps):
        while (now := time.clock_gettime_ns(time.CLOCK_MONOTONIC)) < deadline:
            time.sleep((deadline - now) * 1e-9)
        late += now - deadline > period
        deadline += period * (1 + (now - deadline) // period)     # the next boundary ahead
    print(f"floor steps {steps} misses {late}", flush=True)


def _chain_node(role: str, rate: float, steps: int):
    """A factory for pkm_common.runner.run_node: one process of the chain."""
    import rclpy
    from rclpy.node import Node
    from sensor_msgs.msg import JointState

    from pkm_common.cdr import JointStateEncoder, stamp_ns_of
    from pkm_common.qos import STREAM_PUBLISHER_QOS, STREAM_QOS

    topics = {"gough_sensor": ("floor/state", "floor/readings"), "controller": ("floor/readings", "floor/command")}

    class Forward(Node):
        def __init__(self, context=None):
            super().__init__(f"floor_{role}", context=context)
            source, target = topics[role]
            pub = self.create_publisher(JointState, target, STREAM_PUBLISHER_QOS)
            self.create_subscription(JointState, source, pub.publish, STREAM_QOS, raw=True)

    class Plant(Node):
        def __init__(self, context=None):
            super().__init__("floor_sim_hw", context=context)
            self.pub = self.create_publisher(JointState, "floor/state", STREAM_PUBLISHER_QOS)
            self.create_subscription(JointState, "floor/command", self.on_command, STREAM_QOS, raw=True)
            self.encoder = JointStateEncoder(NAMES)
            self.dt_ns = round(1e9 / rate)
            self.k, self.started, self.answered, self.misses = 0, False, False, 0
            self.zeros = [0.0] * len(NAMES)
            self.create_timer(1.0 / rate, self.on_tick)

        def on_command(self, buf: bytes) -> None:
            if stamp_ns_of(buf) == self.k * self.dt_ns:
                self.answered = self.started = True

        def on_tick(self) -> None:
            if self.started:                   # counted from the first answer on, as sim_hw
                self.misses += not self.answered
                self.k += 1
                if self.k >= steps:
                    print(f"floor steps {steps} misses {self.misses}", flush=True)
                    rclpy.try_shutdown(context=self.context)
                    return
            self.answered = False
            self.pub.publish(self.encoder.encode(self.k * self.dt_ns, self.zeros, self.zeros, self.zeros))

    return Plant if role == "sim_hw" else Forward


def _child(role: str, rate: float, steps: int) -> int:
    if role == "timer":
        _timer(rate, steps)
        return 0
    from pkm_common.runner import run_node
    return run_node(_chain_node(role, rate, steps), args=[], executor="events", name=role)


def _start(role: str, rate: float, steps: int, log_dir: Path):
    """A child of the floor at the profile's scheduling, its output in ``log_dir``; it
    dies with this process (PR_SET_PDEATHSIG), as a graph's nodes do."""
    from pkm_bringup.processes import NodeProcess, die_with_parent
    from pkm_bringup.rt_profile import child_environment, preexec, scheduling
    s = scheduling("controller" if role == "timer" else role)
    log = log_dir / f"{role}.log"
    with log.open("w") as out:
        popen = subprocess.Popen([sys.executable, __file__, "--child", role, "--rate", str(rate), "--steps",
                                  str(steps)], env=child_environment(dict(os.environ), s), stdout=out,
                                 stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                 preexec_fn=preexec(s, before=die_with_parent))
    return NodeProcess(role, popen, log)


def _measure(roles: tuple[str, ...], rate: float, steps: int) -> Floor:
    """Start ``roles`` in order; the last one counts and prints. Fails (RuntimeError,
    with the output) when a child exits early or the count does not end in time;
    every child is stopped however it ends."""
    from pkm_bringup.processes import stop_nodes
    with tempfile.TemporaryDirectory(prefix="rt_floor_") as tmp:
        children = []
        try:
            for role in roles:
                children.append(_start(role, rate, steps, Path(tmp)))
            counter, deadline = children[-1], time.monotonic() + steps / rate + 120
            while counter.running():
                early = [c for c in children[:-1] if not c.running()]
                if early or time.monotonic() > deadline:
                    what = f"{early[0].name} exited ({early[0].popen.returncode})" if early else "timed out"
                    raise RuntimeError(f"floor {'/'.join(roles)}: {what}:\n" + _output(children))
                time.sleep(0.05)
        finally:
            stop_nodes(children, timeout_s=10.0, together=True)
        lines = [line for line in counter.log.read_text(errors="replace").splitlines()
                 if line.startswith("floor steps")]
        if counter.popen.returncode != 0 or not lines:
            raise RuntimeError(f"floor {counter.name} exited {counter.popen.returncode}:\n" + _output(children))
        words = lines[-1].split()                 # "floor steps S misses M"
        return Floor(int(words[2]), int(words[4]))


def _output(children) -> str:
    return "\n".join(f"--- {c.name}\n{c.log.read_text(errors='replace')[-2000:]}" for c in children)


def timer_floor(rate: float, steps: int) -> Floor:
    return _measure(("timer",), rate, steps)


def chain_floor(rate: float, steps: int) -> Floor:
    """The three processes in a DDS domain this process holds (pkm_common.domains),
    discovery on this host only."""
    from pkm_common.domains import use_private_domain
    use_private_domain()
    return _measure(CHAIN, rate, steps)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rate", type=float, default=1000.0, help="loop rate in Hz (default 1000)")
    parser.add_argument("--steps", type=int, default=5000, help="periods counted (default 5000)")
    parser.add_argument("--child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        return _child(args.child, args.rate, args.steps)
    from pkm_bringup.rt_profile import RealtimeProfileRefused, check_permitted
    try:
        check_permitted()
    except RealtimeProfileRefused as exc:
        print(f"realtime floor skipped: {exc}")
        return 0
    for name, measure in (("timer", timer_floor), ("chain", chain_floor)):
        floor = measure(args.rate, args.steps)
        print(f"{args.rate:.0f} Hz {name:>5} floor: {floor.misses} of {floor.steps} deadlines missed "
              f"({floor.percent:.2f} %)", flush=True)
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    sys.exit(main())
