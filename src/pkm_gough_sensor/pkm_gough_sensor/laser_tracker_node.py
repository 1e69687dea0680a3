"""Laser tracker node: the simulated plant's true tool point plus noise, the external
instrument of a calibration run (pkm-calibrate identify --instrument laser).

Thin shell over :mod:`pkm_gough_sensor.laser`. Topics, relative to the namespace:

  sub  platform/true_pose  PoseStamped   tool pose in world (simulation ground truth)
  pub  instrument/laser    PoseStamped   the tool point read in the tracker's frame
                                         (frame laser_tracker; orientation: identity,
                                         a tracker reads a point), the true pose's stamp

A refused true pose (NaN, non-unit quaternion, another frame) gives no reading.

Run: ``python -m pkm_gough_sensor.laser_tracker_node --ros-args -r __ns:=/pkm
--params-file config/laser_tracker.yaml``.
"""

from __future__ import annotations

from geometry_msgs.msg import PoseStamped
from rclpy.node import Node

from pkm_common import topics
from pkm_common.cdr import PoseStampedEncoder, decode_pose_stamped
from pkm_common.endpoints import publisher, subscription
from pkm_common.files import reserve_file, write_summary
from pkm_common.params import declare_bool, declare_float, declare_float_list, declare_int, declare_str
from pkm_common.poses import pose_from_components
from pkm_common.runner import main_exit, run_node
from pkm_gough_sensor.laser import MAX_SIGMA_M, LaserTracker
from pkm_recording.node_tap import NodeTap

ACCEPTED_FRAMES = ('world', '')
IDENTITY = (0.0, 0.0, 0.0, 1.0)


class LaserTrackerNode(Node):
    def __init__(self, context=None, **kwargs):
        super().__init__('laser_tracker', context=context, **kwargs)
        try:
            self._setup()
        except Exception:
            self.destroy_node()
            raise

    def _setup(self) -> None:
        tool = declare_float_list(self, 'tool', [0.0, 0.0, 0.0], 'the point measured, platform frame', length=3,
                                  lo=-10.0, hi=10.0, unit='m')
        sigma = declare_float(self, 'sigma_m', 2e-6, 0.0, MAX_SIGMA_M, "the noise's std per axis", unit='m')
        seed = declare_int(self, 'seed', 0, 0, 2**31 - 1, 'seeds the noise')
        position = declare_float_list(self, 'frame_position', [0.0, 0.0, 0.0], "the tracker's frame in the world",
                                      length=3, lo=-100.0, hi=100.0, unit='m')
        rpy = declare_float_list(self, 'frame_rpy_deg', [0.0, 0.0, 0.0], "the tracker frame's roll, pitch, yaw",
                                 length=3, lo=-360.0, hi=360.0, unit='deg')
        self.summary_path = declare_str(self, 'summary_path', '', 'write a JSON summary here at exit',
                                        allow_empty=True)
        if self.summary_path:
            reserve_file(self.summary_path)
        self.model = LaserTracker(tool, sigma, seed, position, rpy)
        self.tap = NodeTap(self, declare_bool(self, 'tap', False, 'copy the per-step streams to a recorder '
                                              'in batches (pkm_recording.tap)'))
        self.pub = self.tap.wrap(publisher(self, topics.LASER_POINT), PoseStamped)
        self._encoder = PoseStampedEncoder('laser_tracker')
        subscription(self, topics.TRUE_POSE, self.on_true_pose, raw=True)
        self.counts = dict(received=0, refused=0)
        self.published = {topics.LASER_POINT: 0}
        self._last_stamp_ns = -1
        self.get_logger().info(f'tool {tool} m, sigma {sigma:g} m (seed {seed}), frame at {position} m, {rpy} deg')

    def destroy_node(self):
        if getattr(self, 'summary_path', '') and hasattr(self, 'published'):
            write_summary(self.summary_path, {**self.counts, 'published': self.published}, self.get_logger().error)
        if hasattr(self, 'tap'):
            self.tap.close()
        return super().destroy_node()

    def on_true_pose(self, buf: bytes) -> None:
        self.counts['received'] += 1
        try:
            msg = decode_pose_stamped(buf, 'platform/true_pose')
            if msg.frame_id not in ACCEPTED_FRAMES:
                raise ValueError(f"header.frame_id: must be 'world', got {msg.frame_id!r}")
            position, rotation = pose_from_components(msg.position, msg.orientation)
        except ValueError as exc:
            self.counts['refused'] += 1
            self.get_logger().error(f'true pose refused: {exc}', throttle_duration_sec=1.0)
            return
        point = self.model.measure(position, rotation)
        self.pub.publish(self._encoder.encode(msg.stamp_ns, tuple(point.tolist()), IDENTITY))
        self.published[topics.LASER_POINT] += msg.stamp_ns != self._last_stamp_ns
        self._last_stamp_ns = msg.stamp_ns
        self.tap.after_cycle()


def main(args=None):
    main_exit(run_node(LaserTrackerNode, args=args, name='laser_tracker', executor='events'))


if __name__ == '__main__':
    main()
