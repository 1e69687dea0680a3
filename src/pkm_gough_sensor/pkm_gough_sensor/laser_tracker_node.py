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
from pkm_common.endpoints import publisher, subscription
from pkm_common.files import reserve_file, write_summary
from pkm_common.params import declare_bool
from pkm_common.runner import main_exit, run_node
from pkm_gough_sensor.sensor_loop import LaserLoop, declare_laser_tracker
from pkm_recording.node_tap import NodeTap


class LaserTrackerNode(Node):
    """The middleware around a ``sensor_loop.LaserLoop``."""

    def __init__(self, context=None, **kwargs):
        super().__init__('laser_tracker', context=context, **kwargs)
        try:
            self._setup()
        except Exception:
            self.destroy_node()
            raise

    def _setup(self) -> None:
        settings = declare_laser_tracker(self)
        self.summary_path = settings.summary_path
        if self.summary_path:
            reserve_file(self.summary_path)
        self.model = settings.model
        self.tap = NodeTap(self, declare_bool(self, 'tap', False, 'copy the per-step streams to a recorder '
                                              'in batches (pkm_recording.tap)'))
        publish = self.tap.wrap(publisher(self, topics.LASER_POINT), PoseStamped).publish
        self.loop = LaserLoop(self.model, publish, lambda text: self.get_logger().error(
            text, throttle_duration_sec=1.0), topics.LASER_POINT)
        self.counts, self.published = self.loop.counts, self.loop.published
        subscription(self, topics.TRUE_POSE, self.on_true_pose, raw=True)
        self.get_logger().info(f'tool {settings.tool} m, sigma {settings.sigma_m:g} m (seed {settings.seed}), '
                               f'frame at {settings.frame_position} m, {settings.frame_rpy_deg} deg')

    def destroy_node(self):
        if getattr(self, 'summary_path', '') and hasattr(self, 'loop'):
            write_summary(self.summary_path, self.loop.summary(), self.get_logger().error)
        if hasattr(self, 'tap'):
            self.tap.close()
        return super().destroy_node()

    def on_true_pose(self, buf: bytes) -> None:
        self.loop.on_true_pose(buf)
        self.tap.after_cycle()


def main(args=None):
    main_exit(run_node(LaserTrackerNode, args=args, name='laser_tracker', executor='events'))


if __name__ == '__main__':
    main()
