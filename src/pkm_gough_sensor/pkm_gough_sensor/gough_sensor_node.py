"""Gough metrology sensor node: true tool pose in, strut readings and DKM pose out.

Thin shell over :mod:`pkm_gough_sensor.metrology` (MoM3 §4.3 readings, §6.3 DKM_GP).
Topics, relative to the node's namespace (QoS from pkm_common.qos):

  sub  platform/true_pose  PoseStamped       tool pose in world (simulation ground truth)
  pub  metrology/struts    JointState        strut1..strut6 readings (m), frame gough_base
  pub  metrology/pose      PoseStamped       DKM tool pose in world, only when it converged
  pub  diagnostics         DiagnosticArray   ERROR per refused pose / failed DKM (at most
                                             10 per second), and a periodic summary

Both outputs carry the stamp of the true pose they measure, so a lockstep partner can
pair them with the step. A refused message (NaN, non-unit quaternion, another frame)
produces no output; a reading whose DKM fails is still published on
metrology/struts (it is what the scales read) but no pose is.

Run: ``python -m pkm_gough_sensor.gough_sensor_node --ros-args -r __ns:=/pkm
-p machine:=mom3`` (defaults in config/gough_sensor.yaml).
"""

from __future__ import annotations

import time

from geometry_msgs.msg import PoseStamped
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from sensor_msgs.msg import JointState

from pkm_common import topics
from pkm_common.conversions import diagnostic_array, diagnostic_status
from pkm_common.endpoints import publisher, subscription
from pkm_common.files import reserve_file, write_summary
from pkm_common.params import declare_bool
from pkm_common.runner import main_exit, run_node
from pkm_common.timing import Cadence
from pkm_recording.node_tap import NodeTap
from pkm_gough_sensor.sensor_loop import GoughSensorLoop, declare_gough_sensor

OK, ERROR = 0, 2
ERROR_INTERVAL_S = 0.1        # immediate ERROR diagnostics: at most one per interval


class GoughSensorNode(Node):
    """The middleware around a ``sensor_loop.GoughSensorLoop`` (its ports: the
    publishers and the ERROR diagnostics)."""

    def __init__(self, context=None, **kwargs):
        super().__init__('gough_sensor', context=context, **kwargs)
        try:
            self._setup()
        except Exception:
            self.destroy_node()         # a refused configuration leaves nothing behind
            raise

    def _setup(self) -> None:
        settings = declare_gough_sensor(self)
        self.summary_path = settings.summary_path
        if self.summary_path:
            reserve_file(self.summary_path)     # a disk the bag fills cannot take the summary's place
        self.model = settings.model
        self.status_name = f'{self.get_name()}: metrology'
        self.hardware_id = f'{settings.machine} gough platform'

        self.tap = NodeTap(self, declare_bool(self, 'tap', False, 'copy the per-step streams to a recorder '
                                              'in batches (pkm_recording.tap)'))
        self.publish_struts = self.tap.wrap(publisher(self, topics.METROLOGY_STRUTS), JointState).publish
        self.publish_pose = self.tap.wrap(publisher(self, topics.METROLOGY_POSE), PoseStamped).publish
        self.pub_diag = publisher(self, topics.DIAGNOSTICS)
        self.loop = GoughSensorLoop(self.model, self)
        self.counts, self.published = self.loop.counts, self.loop.published
        # the per-step stream as bytes (pkm_common.cdr): an rclpy PoseStamped costs ~50 us
        # to take, a JointState ~13 us to publish; the bytes 1-3 us
        subscription(self, topics.TRUE_POSE, self.on_true_pose, raw=True)
        # the summary on the wall clock (in lockstep, simulated time may crawl or race),
        # after a reading's work (pkm_common.timing.Cadence: off the deadline's path),
        # on its timer only when no readings come
        self.report_cadence = Cadence(settings.diagnostics_period_s)
        self.create_timer(settings.diagnostics_period_s, lambda: self.report_cadence.on_timer() and self._report(),
                          clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._period_errors = 0
        self._last_error = ''
        self._last_error_values = {}
        self._next_error_time = 0.0
        self._max_callback_s = 0.0
        self.get_logger().info(
            f'{settings.machine}: resolution {self.model.resolution_m:g} m, noise {settings.noise_std_m:g} m, '
            f'calibration error {settings.calibration_error_m:g} m (seed {settings.seed})')

    def destroy_node(self):
        if getattr(self, 'summary_path', '') and hasattr(self, 'loop'):
            write_summary(self.summary_path, self.loop.summary(), self.get_logger().error)
        if hasattr(self, 'tap'):
            self.tap.close()
        return super().destroy_node()

    # --------------------------------------------------------------- stream
    def on_true_pose(self, buf: bytes) -> None:
        start = time.perf_counter()
        self.loop.on_true_pose(buf)
        self._max_callback_s = max(self._max_callback_s, time.perf_counter() - start)
        self.tap.after_cycle()
        if self.report_cadence.in_cycle():
            self._report()

    # ---------------------------------------------------------- diagnostics
    def error(self, message: str, values: dict) -> None:
        self._period_errors += 1
        self._last_error, self._last_error_values = message, values
        now = time.monotonic()
        if now >= self._next_error_time:     # a stream of failures must not flood the topic
            self._next_error_time = now + ERROR_INTERVAL_S
            self._publish(ERROR, message, values)
            self.get_logger().error(message)

    def _report(self) -> None:
        values = dict(self.counts)
        values['max_callback_us'] = round(self._max_callback_s * 1e6, 1)
        values['resolution_m'] = self.model.resolution_m
        if self._period_errors:
            level = ERROR
            message = f'{self._period_errors} errors in the last period; last: {self._last_error}'
            values.update(self._last_error_values)
        else:
            level, message = OK, 'measuring'
        self._period_errors = 0
        self._max_callback_s = 0.0
        self._publish(level, message, values)

    def _publish(self, level: int, message: str, values: dict) -> None:
        status = diagnostic_status(self.status_name, level, message, values, self.hardware_id)
        self.pub_diag.publish(diagnostic_array(self.get_clock().now(), [status]))


def main(args=None):
    main_exit(run_node(GoughSensorNode, args=args, name='gough_sensor', executor='events'))


if __name__ == '__main__':
    main()
