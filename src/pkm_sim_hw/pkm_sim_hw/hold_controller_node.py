"""``hold_controller_node``: the minimal lockstep partner of sim_hw, for tests,
benchmarks and smoke runs without the real controller.

It answers every ``drives/state`` with the drive forces that hold the platform
against gravity (nominal model: pseudo-inverse of the static wrench, ARCHI §3.4 and
§4.4.1; a hexapod's from its rigid-body model), plus a joint-space PD towards the first
state it saw, stamped with the state it answers. With ``wait_for_metrology`` it answers only once ``metrology/pose`` of the
same stamp has arrived too (the sensor in the loop, as the real controller does).
"""

from __future__ import annotations

import time

from geometry_msgs.msg import PoseStamped
from rclpy.node import Node
from sensor_msgs.msg import JointState

from pkm_common import topics
from pkm_common.conversions import stamp_to_ns
from pkm_common.endpoints import publisher, subscription
from pkm_common.files import write_summary
from pkm_common.params import declare_bool, declare_float, declare_str
from pkm_common.runner import main_exit, run_node
from pkm_common.timing import DurationHistogram, percentiles_us
from pkm_kinematics import load_machine
from pkm_kinematics.dynamics import dynamic_model, holding_forces


class HoldControllerNode(Node):
    def __init__(self, context=None, **kwargs):
        super().__init__("hold_controller", context=context, **kwargs)
        config = load_machine(declare_str(self, "machine", "archi"))
        self.model = config.model
        self.dynamics = dynamic_model(config)
        self.kp = declare_float(self, "kp_n_per_m", 2e4, 0.0, 1e9)
        self.kd = declare_float(self, "kd_ns_per_m", 500.0, 0.0, 1e7)
        self.wait_for_metrology = declare_bool(self, "wait_for_metrology", False)
        self.summary_path = declare_str(self, "summary_path", "", "JSON of answer latencies at exit",
                                        allow_empty=True)
        self.state_wall: dict[int, float] = {}       # stamp -> wall time the state arrived
        self.latencies_s = DurationHistogram()       # state arrival -> answer (metrology wait)
        self.target = None
        self.pose = None
        self.pending = None                # a state waiting for its metrology
        self.metrology_stamps: set[int] = set()
        self.answered = 0
        self.msg_command = JointState()
        self.pub = publisher(self, topics.DRIVES_COMMAND)
        subscription(self, topics.DRIVES_STATE, self.on_state)
        if self.wait_for_metrology:
            subscription(self, topics.METROLOGY_POSE, self.on_metrology)

    def on_state(self, msg: JointState) -> None:
        stamp = stamp_to_ns(msg.header.stamp)
        self.state_wall = {stamp: time.perf_counter()}
        if self.wait_for_metrology and stamp not in self.metrology_stamps:
            self.pending = msg
            return
        self.answer(msg)

    def on_metrology(self, msg: PoseStamped) -> None:
        stamp = stamp_to_ns(msg.header.stamp)
        self.metrology_stamps = {s for s in self.metrology_stamps if s > stamp - 10**9} | {stamp}
        if self.pending is not None and stamp_to_ns(self.pending.header.stamp) == stamp:
            pending, self.pending = self.pending, None
            self.answer(pending)

    def answer(self, msg: JointState) -> None:
        q = list(msg.position)
        if self.target is None:
            self.target = q
        try:                               # warm-started at the last pose (home at first)
            self.pose = list(self.model.forward_kinematics_floats(q, self.pose))
        except ValueError as exc:          # unassemblable readings: no answer, sim times out safely
            self.get_logger().error(f"drives/state not usable: {exc}")
            return
        forces = holding_forces(self.dynamics, self.model.jacobian(self.pose), self.pose).tolist()
        forces = [f + self.kp * (t - qi) - self.kd * v for f, t, qi, v in zip(forces, self.target, q, msg.velocity)]
        self.msg_command.header.stamp = msg.header.stamp
        self.msg_command.name = msg.name
        self.msg_command.effort = forces
        self.pub.publish(self.msg_command)
        self.answered += 1
        arrived = self.state_wall.get(stamp_to_ns(msg.header.stamp))
        if arrived is not None:
            self.latencies_s.add(time.perf_counter() - arrived)

    def destroy_node(self):
        if self.summary_path and self.latencies_s:
            write_summary(self.summary_path, {"answered": self.answered, **percentiles_us("latency", self.latencies_s)},
                          self.get_logger().error)
        return super().destroy_node()


def main(args=None):
    main_exit(run_node(HoldControllerNode, args=args, name="hold_controller", executor="events"))


if __name__ == "__main__":
    main()
