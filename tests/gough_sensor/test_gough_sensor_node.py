"""Gough sensor node: true poses in, strut readings and DKM poses out, same stamps.

In-process tests run the node on the test's own context (both executors); the slow
test starts it as a process the way a user does and stops it with a signal.
Expected readings come from the test's own world-frame strut lengths; the pose error
bound is MoM3's worst-case resolution (``gough_resolution``, §5.5).
"""

import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from pkm_kinematics import load_machine
from pkm_kinematics.analysis import gough_resolution
from pkm_kinematics.rotations import log_so3, rotation_from_rpy

pytestmark = pytest.mark.ros

REPO = Path(__file__).resolve().parents[2]
MET = load_machine('mom3').metrology
RES = MET.encoder_resolution_m
BOUND = gough_resolution(MET.platform, RES, MET.tool_box, MET.workspace_center, MET.workspace_size_m)
NS = '/pkm'
TOOL_CENTER = np.array([0.0, 0.0, 0.882])      # mom3 workspace centre (Delta platform = tool)


def expected_lengths(p_t, r_t):
    """|B_i - A_i| in world: A_i = p_wb + R_wb a_i, B_i = p_t + R_t (p_tp + R_tp b_i)."""
    a = MET.base_position + MET.platform.base_points @ MET.base_rotation.T
    b = p_t + (MET.plate_position_in_tool + MET.platform.plate_points @ MET.plate_rotation_in_tool.T) @ r_t.T
    return np.linalg.norm(b - a, axis=1)


def path(n):
    """Tool poses along a circle in the mom3 workspace with small tilts."""
    out = []
    for k in range(n):
        t = 2 * math.pi * k / n
        p = TOOL_CENTER + [0.1 * math.cos(t), 0.1 * math.sin(t), 0.05 * math.sin(2 * t)]
        out.append((p, rotation_from_rpy(1e-3 * math.sin(t), -1e-3 * math.cos(t), 2e-3 * math.sin(t))))
    return out


class Probe:
    """The test's side of the graph: publishes true poses, collects the outputs."""

    def __init__(self, graph, params=()):
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseStamped
        from rclpy.parameter import Parameter
        from sensor_msgs.msg import JointState

        from pkm_common.qos import STREAM_QOS
        from pkm_gough_sensor.gough_sensor_node import GoughSensorNode

        self.graph = graph
        overrides = [Parameter('diagnostics_period_s', value=0.1)] + [Parameter(k, value=v) for k, v in params]
        self.sensor = graph.add_node(GoughSensorNode(
            context=graph.context, namespace=NS, parameter_overrides=overrides))
        node = graph.create_node('probe', namespace=NS)
        self.pub = node.create_publisher(PoseStamped, 'platform/true_pose', STREAM_QOS)
        self.struts, self.poses, self.statuses = {}, {}, []
        node.create_subscription(JointState, 'metrology/struts', self._on_struts, STREAM_QOS)
        node.create_subscription(PoseStamped, 'metrology/pose', self._on_pose, STREAM_QOS)
        node.create_subscription(DiagnosticArray, 'diagnostics',
                                 lambda m: self.statuses.extend(m.status), STREAM_QOS)
        self.node = node

    def _on_struts(self, msg):
        self.struts[msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec] = msg

    def _on_pose(self, msg):
        self.poses[msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec] = msg

    def wait_connected(self, timeout=10.0):
        assert self.graph.spin_until(
            lambda: self.pub.get_subscription_count() >= 1
            and self.node.count_publishers(f'{NS}/metrology/pose') >= 1
            and self.node.count_publishers(f'{NS}/metrology/struts') >= 1, timeout_sec=timeout)

    def send(self, stamp_ns, position, rotation=None, quat=None, frame='world'):
        from pkm_common.conversions import pose_msg
        msg = pose_msg(position if np.isfinite(position).all() else [0.0, 0.0, 0.0],
                       np.eye(3) if rotation is None else rotation, stamp_ns, frame)
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in position)
        if quat is not None:
            o = msg.pose.orientation
            o.x, o.y, o.z, o.w = quat
        self.pub.publish(msg)

    def errors(self):
        from diagnostic_msgs.msg import DiagnosticStatus
        return [s for s in self.statuses if s.level == DiagnosticStatus.ERROR]


def values(status):
    return {kv.key: kv.value for kv in status.values}


@pytest.mark.parametrize('ros_graph', ['single', 'events'], indirect=True)
def test_every_true_pose_gets_struts_and_a_pose_with_its_stamp(ros_graph):
    probe = Probe(ros_graph)
    probe.wait_connected()
    poses = path(40)
    for k, (p, rot) in enumerate(poses):
        stamp = 1_000_000_000 + k * 500_000          # 2 kHz steps
        probe.send(stamp, p, rot)
        assert ros_graph.spin_until(lambda: stamp in probe.struts and stamp in probe.poses, 5.0), k
    assert len(probe.struts) == len(probe.poses) == len(poses)

    from pkm_common.conversions import pose_from_msg
    for k, (p, rot) in enumerate(poses):
        stamp = 1_000_000_000 + k * 500_000
        struts = probe.struts[stamp]
        assert list(struts.name) == [f'strut{i}' for i in range(1, 7)]
        assert struts.header.frame_id == 'gough_base'
        measured = np.array(struts.position)
        np.testing.assert_allclose(measured / RES, np.round(measured / RES), atol=1e-6)
        assert np.abs(measured - expected_lengths(p, rot)).max() <= RES / 2 + 1e-12
        pose = probe.poses[stamp]
        assert pose.header.frame_id == 'world'
        est_p, est_r = pose_from_msg(pose)
        assert np.linalg.norm(log_so3(est_r @ rot.T)) <= BOUND.orientation_rad
        # tool 0.1 m above the plate: plate position error + lever x rotation error
        assert np.linalg.norm(est_p - p) <= BOUND.position_m + 0.1 * BOUND.orientation_rad
    assert not probe.errors()

    def summary():
        ok = [values(s) for s in probe.statuses if s.level == b'\x00']
        return ok and ok[-1]['solved'] == '40' and ok[-1]
    assert ros_graph.spin_until(summary, 5.0), probe.statuses
    last = summary()
    assert (last['measured'], last['failed'], last['refused']) == ('40', '0', '0')
    assert float(last['resolution_m']) == RES
    assert probe.statuses[-1].name == 'gough_sensor: metrology'


@pytest.mark.parametrize('bad,field', [
    (dict(position=[math.nan, 0.0, 0.9]), 'pose.position.x'),
    (dict(position=[0.0, 0.0, 0.882], quat=(0.0, 0.0, 0.0, 2.0)), 'pose.orientation: must be a unit quaternion'),
    (dict(position=[0.0, 0.0, 0.882], frame='map'), "header.frame_id: must be 'world'"),
])
def test_an_invalid_true_pose_is_refused_with_an_error(ros_graph, bad, field):
    probe = Probe(ros_graph)
    probe.wait_connected()
    probe.send(1_000, **bad)
    probe.send(2_000, TOOL_CENTER, np.eye(3))
    assert ros_graph.spin_until(lambda: 2_000 in probe.poses and probe.errors(), 5.0)
    assert 1_000 not in probe.struts and 1_000 not in probe.poses
    error = probe.errors()[0]
    assert 'true pose refused' in error.message and field in error.message
    assert values(error)['stamp_ns'] == '1000'
    assert probe.poses[2_000].pose.position.z == pytest.approx(TOOL_CENTER[2], abs=1e-5)


def test_unmeasurable_pose_reports_the_dkm_failure_and_publishes_no_pose(ros_graph):
    probe = Probe(ros_graph)
    probe.wait_connected()
    probe.send(1_000, TOOL_CENTER, np.eye(3))
    probe.send(2_000, [1.5, 0.0, 0.9], np.eye(3))      # struts far beyond their travel
    probe.send(3_000, TOOL_CENTER + [0.01, 0.0, 0.0], np.eye(3))
    assert ros_graph.spin_until(lambda: 3_000 in probe.poses and probe.errors(), 5.0)
    assert 1_000 in probe.poses and 2_000 not in probe.poses
    assert 2_000 in probe.struts                       # the scales' readings still go out
    error = probe.errors()[0]
    assert error.message.startswith('DKM failed: strut') and 'outside the strut travel' in error.message
    v = values(error)
    assert v['stamp_ns'] == '2000' and v['iterations'] == '0'
    # the summary stays ERROR for the period with the failure
    assert ros_graph.spin_until(
        lambda: any(s.level == b'\x02' and values(s).get('failed') == '1' and 'errors in the last period'
                    in s.message for s in probe.statuses), 5.0)


def test_bad_parameter_stops_the_node_with_a_clear_error(ros_context):
    from rclpy.parameter import Parameter

    from pkm_common.params import ParameterError
    from pkm_gough_sensor.gough_sensor_node import GoughSensorNode
    with pytest.raises(ParameterError, match=r"parameter 'calibration_error_m': must be a number in \[0, 0.01\] m"):
        GoughSensorNode(context=ros_context, parameter_overrides=[Parameter('calibration_error_m', value=-1.0)])
    with pytest.raises(ParameterError, match="parameter 'machine': must name a machine with a metrology section"):
        GoughSensorNode(context=ros_context, parameter_overrides=[Parameter('machine', value='sliding_star')])


# ------------------------------------------------------------ multi-process
def _start(tmp_path, *extra):
    log = open(tmp_path / 'node.log', 'w')
    cmd = [sys.executable, '-m', 'pkm_gough_sensor.gough_sensor_node', '--ros-args', '-r', f'__ns:={NS}',
           '--params-file', str(REPO / 'config' / 'gough_sensor.yaml'), *extra]
    env = dict(os.environ, PYTHONUNBUFFERED='1')       # ROS_DOMAIN_ID: the session's own
    return subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env, cwd=tmp_path), log


@pytest.mark.slow
@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
def test_node_process_exchanges_poses_and_exits_cleanly_on_a_signal(ros_graph, tmp_path, sig):
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import JointState

    from pkm_common.conversions import pose_msg, stamp_to_ns
    from pkm_common.qos import STREAM_QOS

    proc, log = _start(tmp_path, '-p', 'diagnostics_period_s:=0.2')
    try:
        node = ros_graph.create_node('probe', namespace=NS)
        pub = node.create_publisher(PoseStamped, 'platform/true_pose', STREAM_QOS)
        got = {'struts': {}, 'pose': {}, 'diag': []}
        node.create_subscription(JointState, 'metrology/struts',
                                 lambda m: got['struts'].update({stamp_to_ns(m.header.stamp): m}), STREAM_QOS)
        node.create_subscription(PoseStamped, 'metrology/pose',
                                 lambda m: got['pose'].update({stamp_to_ns(m.header.stamp): m}), STREAM_QOS)
        node.create_subscription(DiagnosticArray, 'diagnostics', lambda m: got['diag'].extend(m.status), STREAM_QOS)
        # the first summary proves the node is up and its publishers matched ours
        assert ros_graph.spin_until(lambda: got['diag'] and pub.get_subscription_count() >= 1, 30.0), (
            (tmp_path / 'node.log').read_text())
        for k, (p, rot) in enumerate(path(5)):
            stamp = 10**9 * (k + 1)
            pub.publish(pose_msg(p, rot, stamp, 'world'))
            assert ros_graph.spin_until(lambda: stamp in got['pose'] and stamp in got['struts'], 10.0), k
            est = got['pose'][stamp].pose.position
            assert np.linalg.norm([est.x - p[0], est.y - p[1], est.z - p[2]]) <= (
                BOUND.position_m + 0.1 * BOUND.orientation_rad)
        assert got['diag'][0].name == 'gough_sensor: metrology'
        start = time.monotonic()
        proc.send_signal(sig)
        code = proc.wait(timeout=5.0)
        assert code == 0, (tmp_path / 'node.log').read_text()
        assert time.monotonic() - start < 5.0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        log.close()
    text = (tmp_path / 'node.log').read_text()
    assert 'mom3: resolution 1e-06 m' in text and 'Traceback' not in text and 'FATAL' not in text


@pytest.mark.slow
@pytest.mark.parametrize('override,message', [
    ('noise_std_m:=-1.0', "parameter 'noise_std_m': must be a number in [0, 0.001] m, got -1.0"),
    ('machine:=sliding_star', "parameter 'machine': must name a machine with a metrology section, one of "
     "['archi', 'hexapod8', 'mom3', 'mom3_imperfect']"),
])
def test_node_process_refuses_a_bad_parameter_with_status_2(tmp_path, override, message):
    proc, log = _start(tmp_path, '-p', override)
    try:
        code = proc.wait(timeout=30.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        log.close()
    text = (tmp_path / 'node.log').read_text()
    assert code == 2, text
    assert message in text
