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
from pkm_common.cdr import JointStateEncoder, PoseStampedEncoder, decode_pose_stamped
from pkm_common.conversions import diagnostic_array, diagnostic_status
from pkm_common.endpoints import publisher, subscription
from pkm_common.files import reserve_file, write_summary
from pkm_common.params import ParameterError, declare_bool, declare_float, declare_int, declare_str
from pkm_common.poses import pose_components, pose_from_components
from pkm_common.runner import main_exit, run_node
from pkm_common.timing import Cadence
from pkm_recording.node_tap import NodeTap
from pkm_gough_sensor.metrology import MAX_RESOLUTION_M, STRUT_NAMES, GoughSensorModel
from pkm_kinematics import load_machine, machine_names

OK, ERROR = 0, 2
ERROR_INTERVAL_S = 0.1        # immediate ERROR diagnostics: at most one per interval
ACCEPTED_FRAMES = ('world', '')


class GoughSensorNode(Node):
    def __init__(self, context=None, **kwargs):
        super().__init__('gough_sensor', context=context, **kwargs)
        try:
            self._setup()
        except Exception:
            self.destroy_node()         # a refused configuration leaves nothing behind
            raise

    def _setup(self) -> None:
        machine = declare_str(self, 'machine', 'mom3', 'machine file with a metrology section',
                              choices=machine_names())
        noise = declare_float(self, 'noise_std_m', 0.0, 0.0, 1e-3,
                              'std of the Gaussian noise on each strut reading', unit='m')
        seed = declare_int(self, 'seed', 0, 0, 2**31 - 1, 'seeds the calibration error and the noise')
        calibration = declare_float(self, 'calibration_error_m', 0.0, 0.0, 0.01,
                                    'std of the per-axis error of the true joint centres', unit='m')
        resolution = declare_float(self, 'resolution_m', 0.0, 0.0, MAX_RESOLUTION_M,
                                   "scale resolution; 0: the machine file's encoder_resolution", unit='m')
        period = declare_float(self, 'diagnostics_period_s', 1.0, 0.01, 60.0,
                               'period of the summary diagnostic', unit='s')
        self.summary_path = declare_str(self, 'summary_path', '', 'write a JSON summary here at exit',
                                        allow_empty=True)
        if self.summary_path:
            reserve_file(self.summary_path)     # a disk the bag fills cannot take the summary's place
        config = load_machine(machine)
        if config.metrology is None:
            with_metrology = [n for n in machine_names() if _has_metrology(n)]
            raise ParameterError('machine', f'must name a machine with a metrology section, one of '
                                 f'{with_metrology}; {machine!r} has none')
        self.model = GoughSensorModel(config.metrology, noise, seed, calibration, resolution or None)
        self.status_name = f'{self.get_name()}: metrology'
        self.hardware_id = f'{machine} gough platform'

        self.tap = NodeTap(self, declare_bool(self, 'tap', False, 'copy the per-step streams to a recorder '
                                              'in batches (pkm_recording.tap)'))
        self.pub_struts = self.tap.wrap(publisher(self, topics.METROLOGY_STRUTS), JointState)
        self.pub_pose = self.tap.wrap(publisher(self, topics.METROLOGY_POSE), PoseStamped)
        self.pub_diag = publisher(self, topics.DIAGNOSTICS)
        # the per-step stream as bytes (pkm_common.cdr): an rclpy PoseStamped costs ~50 us
        # to take, a JointState ~13 us to publish; the bytes 1-3 us
        subscription(self, topics.TRUE_POSE, self.on_true_pose, raw=True)
        self._struts_encoder = JointStateEncoder(STRUT_NAMES, 'gough_base', fields=('position',))
        self._pose_encoder = PoseStampedEncoder('world')
        # the summary on the wall clock (in lockstep, simulated time may crawl or race),
        # after a reading's work (pkm_common.timing.Cadence: off the deadline's path),
        # on its timer only when no readings come
        self.report_cadence = Cadence(period)
        self.create_timer(period, lambda: self.report_cadence.on_timer() and self._report(),
                          clock=Clock(clock_type=ClockType.STEADY_TIME))

        self.counts = dict(received=0, measured=0, solved=0, failed=0, refused=0)
        self.published = {'metrology/pose': 0, 'metrology/struts': 0}   # distinct stamps
        self._last_stamp_ns = -1
        self._period_errors = 0
        self._last_error = ''
        self._last_error_values = {}
        self._next_error_time = 0.0
        self._max_callback_s = 0.0
        self.get_logger().info(
            f'{machine}: resolution {self.model.resolution_m:g} m, noise {noise:g} m, '
            f'calibration error {calibration:g} m (seed {seed})')

    def destroy_node(self):
        if getattr(self, 'summary_path', '') and hasattr(self, 'published'):
            write_summary(self.summary_path, {**self.counts, 'published': self.published},
                          self.get_logger().error)
        if hasattr(self, 'tap'):
            self.tap.close()
        return super().destroy_node()

    # --------------------------------------------------------------- stream
    def on_true_pose(self, buf: bytes) -> None:
        start = time.perf_counter()
        self.counts['received'] += 1
        ns = -1
        try:
            msg = decode_pose_stamped(buf, 'platform/true_pose')
            ns = msg.stamp_ns
            if msg.frame_id not in ACCEPTED_FRAMES:
                raise ValueError(f"header.frame_id: must be 'world', got {msg.frame_id!r}")
            position, rotation = pose_from_components(msg.position, msg.orientation)
            lengths = self.model.measure(position, rotation)
        except ValueError as exc:
            self.counts['refused'] += 1
            self._error(f'true pose refused: {exc}', {'stamp_ns': ns})
            return
        self.counts['measured'] += 1
        published = self.published
        new_step = ns != self._last_stamp_ns      # counted once per step (not the discovery repeats)
        self._last_stamp_ns = ns
        # the readings first: a sensor-space controller waits for them, and the DKM
        # (~20 us) is then off its critical path; a measured-space one waits for the pose
        lengths = lengths.tolist()
        self.pub_struts.publish(self._struts_encoder.encode(ns, position=lengths))
        published['metrology/struts'] += new_step
        est_p, est_r, result = self.model.estimate(lengths)
        if result.converged:
            published['metrology/pose'] += new_step
            self.counts['solved'] += 1
            self.pub_pose.publish(self._pose_encoder.encode(ns, *pose_components(est_p, est_r)))
        else:
            self.counts['failed'] += 1
            self._error(f'DKM failed: {result.reason}', {
                'stamp_ns': ns, 'iterations': result.iterations,
                'residual_m': result.residual_m, 'lengths_m': lengths})
        self._max_callback_s = max(self._max_callback_s, time.perf_counter() - start)
        self.tap.after_cycle()
        if self.report_cadence.in_cycle():
            self._report()

    # ---------------------------------------------------------- diagnostics
    def _error(self, message: str, values: dict) -> None:
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


def _has_metrology(name: str) -> bool:
    try:
        return load_machine(name).metrology is not None
    except ValueError:
        return False


def main(args=None):
    main_exit(run_node(GoughSensorNode, args=args, name='gough_sensor', executor='events'))


if __name__ == '__main__':
    main()
