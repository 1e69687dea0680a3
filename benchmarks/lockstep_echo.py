"""Zero-work lockstep floor: two processes ping-pong a 3-joint JointState over DDS
with the project's runner (EventsExecutor) and QoS. Run by benchmarks/plant.py as
the reference for its rates; alone:

    .venv/bin/python benchmarks/lockstep_echo.py answer --ros-args ... &   (then)
    .venv/bin/python benchmarks/lockstep_echo.py lead STEPS --ros-args ...

The lead prints ``steps/s <rate>`` after STEPS round trips and exits. Without
arguments (``make bench``) it runs both processes itself and prints the rate.
"""

import sys
import time

import rclpy
from rclpy.node import Node
from sensor_msgs.msg import JointState

from pkm_common.qos import STREAM_QOS
from pkm_common.runner import run_node

ROLE = sys.argv[1] if len(sys.argv) > 1 else ""
STEPS = int(sys.argv[2]) if ROLE == "lead" else 0


class Echo(Node):
    def __init__(self, context=None):
        super().__init__(f"echo_{ROLE}", context=context)
        self.msg = JointState(name=["a", "b", "c"], position=[1.0, 2.0, 3.0])
        if ROLE == "lead":
            self.pub = self.create_publisher(JointState, "echo/state", STREAM_QOS)
            self.create_subscription(JointState, "echo/command", self.on_answer, STREAM_QOS)
            self.count, self.start = 0, None
            self.create_timer(0.1, self.kick)          # until the partner is discovered
        else:
            self.pub = self.create_publisher(JointState, "echo/command", STREAM_QOS)
            self.create_subscription(JointState, "echo/state", self.pub.publish, STREAM_QOS)

    def kick(self):
        if self.start is None:
            self.pub.publish(self.msg)

    def on_answer(self, _msg):
        if self.start is None:
            self.start = time.perf_counter()
        self.count += 1
        if self.count >= STEPS:
            print(f"steps/s {STEPS / (time.perf_counter() - self.start):.1f}", flush=True)
            rclpy.try_shutdown(context=self.context)
            return
        self.msg.header.stamp.nanosec = self.count
        self.pub.publish(self.msg)


if __name__ == "__main__":
    if ROLE not in ("lead", "answer"):
        sys.path.insert(0, str(__import__("pathlib").Path(__file__).parent))
        from plant import echo_floor
        print(f"zero-work lockstep echo, 2 processes: {echo_floor():,.0f} steps/s")
        sys.exit(0)
    sys.exit(run_node(Echo, args=sys.argv, executor="events"))
