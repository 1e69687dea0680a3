"""``ros2_control_node``: the drive interface on a ros2_control system (hardware:
ros2_control): sim_hw's loop (pkm_sim_hw.sim_loop, real time only) stepping
ros2_control.Ros2ControlHardware, which sends ``drives/command``'s efforts to the effort
controller (``/<controller>/commands``, std_msgs/Float64MultiArray, in its joints'
order) and reads ``/joint_states`` by joint name (the machine file's
``drives.ros2_control``). The controller sees ``drives/state`` as from sim_hw.

At start it waits (``boot_timeout_s``) for a joint_states sample with the machine's
joints: a system that has none is refused naming what is missing.
"""

from __future__ import annotations

import dataclasses

from rclpy.wait_for_message import wait_for_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from pkm_common.endpoints import system_publisher, system_subscription
from pkm_common.params import ParameterError, declare_float, declare_str
from pkm_common.runner import main_exit, run_node
from pkm_kinematics import load_machine
from pkm_kinematics.errors import FieldError
from pkm_sim_hw.parameters import declare_loop
from pkm_sim_hw.sim_hw_node import SimHwNode

from .ros2_control import Ros2ControlHardware, ros2_control_settings


class Ros2ControlNode(SimHwNode):
    simulated = False

    def __init__(self, context=None, **kwargs):
        super().__init__(context=context, node_name="ros2_control", **kwargs)

    def make_settings(self):
        machine = load_machine(declare_str(self, "machine", "archi", "config/machines/<name>.yaml"))
        dt_s = declare_float(self, "dt_s", 0.004, 1e-5, 0.1, "the interface's cycle", unit="s")
        timeout_s = declare_float(self, "boot_timeout_s", 10.0, 0.0, 600.0, "how long to wait for the first "
                                  "joint_states", lo_open=True, unit="s")
        try:
            settings = ros2_control_settings(machine)
        except FieldError as exc:
            raise ParameterError(exc.name, exc.detail) from None
        self.command_pub = system_publisher(self, Float64MultiArray, settings.commands)
        message = Float64MultiArray()

        def send(efforts) -> None:
            message.data = efforts
            self.command_pub.publish(message)
        self.hardware = Ros2ControlHardware(settings, machine.model.leg_names, dt_s, send)
        system_subscription(self, JointState, settings.joint_states, self.on_joint_states)
        ok, msg = wait_for_message(JointState, self, settings.joint_states, time_to_wait=timeout_s)
        if ok:
            self.on_joint_states(msg)
        try:
            self.hardware.start()
        except FieldError as exc:
            raise ParameterError(exc.name, exc.detail + f" within {timeout_s:g} s") from None
        loop = declare_loop(self, machine, self.hardware, dt_s)
        if loop.lockstep:
            raise ParameterError("mode", "must be realtime: a ros2_control system runs its own real-time loop")
        return dataclasses.replace(loop, publish_markers=False)

    def on_joint_states(self, msg: JointState) -> None:
        self.hardware.on_joint_states(list(msg.name), msg.position, msg.velocity, msg.effort)


def main(args=None):
    main_exit(run_node(Ros2ControlNode, args=args, name="ros2_control", executor="events"))


if __name__ == "__main__":
    main()
