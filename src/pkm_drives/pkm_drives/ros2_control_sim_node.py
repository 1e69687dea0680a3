"""``ros2_control_sim_node``: a TEST STAND-IN for a ros2_control system, not a part of
ros2_control. It behaves towards its clients as ros2_control's standard controllers do,
on a simulated plant (sim_hw's plant parameters: pkm_sim_hw.parameters.declare_plant):

- like ``effort_controllers/JointGroupEffortController`` it takes
  ``/<controller>/commands`` (std_msgs/Float64MultiArray, one effort per joint of its
  ``joints``; a message of another length is rejected and logged, the last valid
  command holds) and writes them to the joints' effort interfaces;
- like ``joint_state_broadcaster`` it publishes ``/joint_states`` (every joint by name,
  in its own order: the machine's joints reversed, and a ``spindle_joint`` that is not
  the machine's, so that a client must map by name);
- like ``controller_manager``, one update per ``dt_s`` of wall clock (read, update,
  write), whatever its clients do; like a hardware interface whose controller is not
  commanded yet, it holds its brakes until the first command;

and, being a simulation, publishes the plant's ground truth ``platform/true_pose``.
Its summary (``summary_path``) counts the commands taken and rejected and keeps the last
one by joint name.
"""

from __future__ import annotations

import time

from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from rclpy.node import Node

from pkm_common import topics
from pkm_common.cdr import PoseStampedEncoder
from pkm_common.endpoints import publisher, system_publisher, system_subscription
from pkm_common.files import write_summary
from pkm_common.params import ParameterError, declare_str
from pkm_common.runner import main_exit, run_node
from pkm_kinematics import load_machine
from pkm_kinematics.errors import FieldError
from pkm_sim_hw.parameters import declare_plant
from pkm_sim_hw.run_record import true_pose_components

from .ros2_control import ros2_control_settings

__all__ = ["Ros2ControlSimNode", "EXTRA_JOINT"]

EXTRA_JOINT = "spindle_joint"


class Ros2ControlSimNode(Node):
    def __init__(self, context=None, **kwargs):
        super().__init__("ros2_control_sim", context=context, **kwargs)
        machine = load_machine(declare_str(self, "machine", "archi", "config/machines/<name>.yaml"))
        self.plant = declare_plant(self, machine)
        self.summary_path = declare_str(self, "summary_path", "", allow_empty=True)
        try:
            settings = ros2_control_settings(machine)
        except FieldError as exc:
            raise ParameterError(exc.name, exc.detail) from None
        self.space = machine.model.task_space
        self.joints = list(settings.joints)
        self.order = list(reversed(self.joints)) + [EXTRA_JOINT]       # the broadcaster's own order
        self.effort = [0.0] * len(self.joints)                          # the controller's, in its joints' order
        self.counts = {"commands": 0, "rejected": 0, "updates": 0}
        self.last_update_s, self.max_update_gap_s = None, 0.0     # its own loop's longest stall (a diagnostic)
        self.pub_states = system_publisher(self, JointState, settings.joint_states)
        self.pub_pose = publisher(self, topics.TRUE_POSE)
        self.pose_encoder = PoseStampedEncoder("world")
        system_subscription(self, Float64MultiArray, settings.commands, self.on_commands)
        self.create_timer(self.plant.params.dt_s, self.update)
        self.get_logger().info(f"a stand-in ros2_control system: {settings.commands}, {settings.joint_states} "
                               f"({', '.join(self.order)})")

    def on_commands(self, msg: Float64MultiArray) -> None:
        if len(msg.data) != len(self.joints):              # forward_command_controller's check
            self.counts["rejected"] += 1
            self.get_logger().error(f"command size ({len(msg.data)}) does not match number of interfaces "
                                    f"({len(self.joints)})", throttle_duration_sec=1.0)
            return
        self.effort = [float(v) for v in msg.data]
        if not self.counts["commands"]:
            self.plant.restart_clock()                      # the machine's run starts with its first command
        self.counts["commands"] += 1

    def update(self) -> None:
        """controller_manager's cycle: read the plant, publish the joints, write the efforts."""
        now = time.monotonic()
        if self.last_update_s is not None:
            self.max_update_gap_s = max(self.max_update_gap_s, now - self.last_update_s)
        self.last_update_s = now
        out = self.plant.step(self.effort, hold=not self.counts["commands"])   # brakes until commanded
        self.counts["updates"] += 1
        ns = self.plant.k * self.plant.dt_ns
        state = JointState()
        state.header.stamp.sec, state.header.stamp.nanosec = divmod(ns, 10**9)
        by_joint = {j: (p, v, f) for j, p, v, f in zip(self.joints, out.encoder_positions, out.encoder_velocities,
                                                        out.applied_forces)}
        by_joint[EXTRA_JOINT] = (0.0, 0.0, 0.0)
        state.name = self.order
        state.position, state.velocity, state.effort = ([by_joint[j][i] for j in self.order] for i in range(3))
        self.pub_states.publish(state)
        self.pub_pose.publish(self.pose_encoder.encode(ns, *true_pose_components(self.space, out)))

    def summary(self) -> dict:
        return {**self.counts, "last_command": dict(zip(self.joints, self.effort)), "steps": self.plant.k,
                "max_update_gap_ms": round(self.max_update_gap_s * 1e3, 1),
                "stopped": self.plant.stopped, "stop_reason": self.plant.stop_reason}

    def destroy_node(self):
        if self.summary_path:
            write_summary(self.summary_path, self.summary(), self.get_logger().error)
        return super().destroy_node()


def main(args=None):
    main_exit(run_node(Ros2ControlSimNode, args=args, name="ros2_control_sim", executor="events"))


if __name__ == "__main__":
    main()
