"""pkm_common.cdr against rclpy's own (de)serialization (rmw_fastrtps typesupport): the
independent reference for the bytes."""

import math

import pytest
from geometry_msgs.msg import PoseStamped
from hypothesis import given, settings
from hypothesis import strategies as st
from rclpy.serialization import deserialize_message, serialize_message
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from pkm_common.cdr import (JointStateData, JointStateDecoder, JointStateEncoder, PoseStampedEncoder,
                            decode_joint_state, decode_pose_stamped, encode_clock, in_order, stamp_ns_of)

texts = st.text(st.characters(blacklist_characters='\x00', blacklist_categories=('Cs',)), max_size=12)  # C strings
doubles = st.floats(allow_nan=False, width=64)
stamps = st.integers(0, 2**31 * 10**9 - 1)


@st.composite
def joint_states(draw):
    names = draw(st.lists(texts, max_size=7))
    n = len(names)
    arrays = [draw(st.one_of(st.just([]), st.lists(doubles, min_size=n, max_size=n),
                             st.lists(doubles, max_size=9)))         # any length: a malformed command
              for _ in range(3)]
    msg = JointState(name=names, position=arrays[0], velocity=arrays[1], effort=arrays[2])
    msg.header.frame_id = draw(texts)
    stamp = draw(stamps)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
    return msg, stamp


def fields(msg: JointState):
    return (list(msg.name), list(msg.position), list(msg.velocity), list(msg.effort))


@settings(max_examples=300, deadline=None)
@given(joint_states())
def test_decode_joint_state_reads_what_rclpy_serialized(case):
    msg, stamp = case
    data = decode_joint_state(serialize_message(msg))
    assert data.stamp_ns == stamp and data.frame_id == msg.header.frame_id
    assert (list(data.name), list(data.position), list(data.velocity), list(data.effort)) == fields(msg)


@settings(max_examples=300, deadline=None)
@given(st.lists(texts, max_size=7), texts, st.sets(st.sampled_from(JointStateEncoder.FIELDS)), stamps,
       st.randoms(use_true_random=False))
def test_joint_state_encoder_writes_what_rclpy_reads(names, frame, chosen, stamp, rnd):
    encoder = JointStateEncoder(names, frame, chosen)
    arrays = {f: [rnd.uniform(-1e3, 1e3) for _ in names] if f in chosen else [] for f in JointStateEncoder.FIELDS}
    buf = encoder.encode(stamp, **arrays)
    msg = deserialize_message(buf, JointState)
    assert (msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec, msg.header.frame_id) == (stamp, frame)
    assert fields(msg) == (names, arrays["position"], arrays["velocity"], arrays["effort"])
    # byte-identical to rclpy's serialization up to its (uninitialised) padding and trailing bytes
    assert len(buf) == encoder.size and deserialize_message(serialize_message(msg), JointState) == msg
    assert decode_joint_state(buf) == decode_joint_state(serialize_message(msg))


def test_joint_state_decoder_switches_layouts_and_matches_the_general_reader():
    a = JointStateEncoder(["d1", "d2", "d3", "d4"]).encode(10, [1.0] * 4, [2.0] * 4, [3.0] * 4)
    b = JointStateEncoder(["d1", "d2", "d3", "d4"], fields=("effort",)).encode(11, effort=[4.0, 5.0, 6.0, 7.0])
    c = serialize_message(JointState(name=["d1", "d2", "d3"], effort=[1.0, 2.0, 3.0]))
    odd = serialize_message(JointState(name=["d1", "d2"], effort=[1.0]))          # uncacheable layout
    decoder = JointStateDecoder()
    for buf in (a, a, b, b, a, c, odd, odd, c, b, a):
        assert decoder.decode(buf) == decode_joint_state(buf)
    # same layout, other values: read from the bytes, not remembered
    other = JointStateEncoder(["d1", "d2", "d3", "d4"]).encode(12, [9.0] * 4, [8.0] * 4, [7.0] * 4)
    assert decoder.decode(a).position == (1.0,) * 4 and decoder.decode(other).position == (9.0,) * 4


@settings(max_examples=200, deadline=None)
@given(texts, stamps, st.lists(doubles, min_size=7, max_size=7))
def test_pose_stamped_both_ways(frame, stamp, values):
    buf = PoseStampedEncoder(frame).encode(stamp, values[:3], values[3:])
    msg = deserialize_message(buf, PoseStamped)
    p, q = msg.pose.position, msg.pose.orientation
    assert [p.x, p.y, p.z, q.x, q.y, q.z, q.w] == values and msg.header.frame_id == frame
    data = decode_pose_stamped(serialize_message(msg))
    assert data.stamp_ns == stamp and data.frame_id == frame
    assert list(data.position) + list(data.orientation) == values


def test_clock_and_stamp_of_any_stamped_message():
    msg = deserialize_message(encode_clock(3_000_000_001), Clock)
    assert (msg.clock.sec, msg.clock.nanosec) == (3, 1)
    assert stamp_ns_of(encode_clock(42)) == 42
    assert stamp_ns_of(PoseStampedEncoder().encode(7, (0, 0, 0), (0, 0, 0, 1))) == 7


def test_nan_and_infinity_pass_through_unchanged():
    """Checking values is the node's rule (it refuses NaN by name), not the codec's."""
    buf = JointStateEncoder(["a", "b"], fields=("effort",)).encode(0, effort=[math.nan, math.inf])
    effort = decode_joint_state(buf).effort
    assert math.isnan(effort[0]) and effort[1] == math.inf


@pytest.mark.parametrize("cut", [0, 3, 11, 14, 20, 30, 45, 60])
def test_truncated_joint_state_is_refused_naming_the_field(cut):
    buf = JointStateEncoder(["d1", "d2"], "base").encode(5, [1.0, 2.0], [3.0, 4.0], [5.0, 6.0])
    with pytest.raises(ValueError, match=r"drives/state: "):
        decode_joint_state(buf[:cut], "drives/state")
    with pytest.raises(ValueError, match=r"drives/state: "):
        JointStateDecoder("drives/state").decode(buf[:cut])


def test_malformed_bytes_are_refused():
    good = serialize_message(JointState(name=["a"]))
    with pytest.raises(ValueError, match="not a little-endian CDR"):
        decode_joint_state(b"\x00\x00\x00\x00" + good[4:])
    broken = bytearray(good)
    broken[20:24] = (10**6).to_bytes(4, "little")           # the name count
    with pytest.raises(ValueError, match="name count"):
        decode_joint_state(bytes(broken))
    unterminated = bytearray(good)
    unterminated[29] = ord("x")                             # the NUL of name[0]
    with pytest.raises(ValueError, match=r"name\[0\] is not a NUL-terminated string"):
        decode_joint_state(bytes(unterminated))
    with pytest.raises(ValueError, match="pose runs past the end"):
        decode_pose_stamped(PoseStampedEncoder().encode(0, (0, 0, 0), (0, 0, 0, 1))[:40])


def test_encoder_refuses_bad_input_naming_it():
    encoder = JointStateEncoder(["a", "b"], fields=("effort",))
    with pytest.raises(ValueError, match="effort: expected 2 values"):
        encoder.encode(0, effort=[1.0])
    with pytest.raises(ValueError, match="must hold numbers"):
        encoder.encode(0, effort=[1.0, "x"])
    with pytest.raises(ValueError, match="stamp: must be in"):
        encoder.encode(-1, effort=[1.0, 2.0])
    with pytest.raises(ValueError, match="fields: must be among"):
        JointStateEncoder(["a"], fields=("torque",))


def test_in_order_reorders_every_array_of_a_permuted_message():
    msg = JointStateData(5, "", ("q2", "q1", "q3"), (2.0, 1.0, 3.0), (20.0, 10.0, 30.0), (0.2,))
    out = in_order(msg, ["q1", "q2", "q3"], "drives/state")
    assert out.name == ("q1", "q2", "q3") and out.position == (1.0, 2.0, 3.0)
    assert out.velocity == (10.0, 20.0, 30.0) and out.effort == (0.2,)      # wrong length: left for the caller
    unnamed = msg._replace(name=())
    assert in_order(unnamed, ["q1", "q2", "q3"]) is unnamed
    with pytest.raises(ValueError, match=r"drives/state: names \['q2', 'q1', 'q3'\] are not \['q1', 'q2', 'q4'\]"):
        in_order(msg, ["q1", "q2", "q4"], "drives/state")


# ------------------------------------------------------- MultiDOFJointTrajectory
@st.composite
def trajectories(draw):
    """Any joint count and frame (so every alignment of the points), points with or
    without velocities and accelerations: the fast path and the field-by-field one."""
    from geometry_msgs.msg import Transform, Twist
    from trajectory_msgs.msg import MultiDOFJointTrajectory, MultiDOFJointTrajectoryPoint
    joints = draw(st.lists(texts, min_size=0, max_size=3))
    msg = MultiDOFJointTrajectory(joint_names=joints)
    msg.header.frame_id = draw(texts)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(draw(stamps), 10**9)
    for _ in range(draw(st.integers(0, 6))):
        values = iter(draw(st.lists(doubles, min_size=19 * len(joints), max_size=19 * len(joints))))
        tfs, vels, accs = [], [], []
        for _ in joints:
            tf = Transform()
            tf.translation.x, tf.translation.y, tf.translation.z = next(values), next(values), next(values)
            tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w = (next(values) for _ in range(4))
            tfs.append(tf)
            for out in (vels, accs):
                tw = Twist()
                tw.linear.x, tw.linear.y, tw.linear.z = next(values), next(values), next(values)
                tw.angular.x, tw.angular.y, tw.angular.z = next(values), next(values), next(values)
                out.append(tw)
        point = MultiDOFJointTrajectoryPoint(transforms=tfs, velocities=vels if draw(st.booleans()) else [],
                                             accelerations=accs if draw(st.booleans()) else [])
        point.time_from_start.sec = draw(st.integers(-2**31, 2**31 - 1))
        point.time_from_start.nanosec = draw(st.integers(0, 999_999_999))
        msg.points.append(point)
    return msg


@settings(max_examples=300, deadline=None)
@given(trajectories())
def test_a_trajectory_reads_as_rclpy_reads_it(msg):
    from pkm_common.cdr import decode_multidof_trajectory
    data = decode_multidof_trajectory(serialize_message(msg))
    stamp = msg.header.stamp
    assert (data.stamp_ns, data.frame_id, data.joint_names) == \
        (stamp.sec * 10**9 + stamp.nanosec, msg.header.frame_id, tuple(msg.joint_names))
    assert data.transform.shape == (len(msg.points), len(msg.joint_names), 7)
    for k, p in enumerate(msg.points):
        assert data.time_s[k] == p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec
        for j, tf in enumerate(p.transforms):
            r, t = tf.rotation, tf.translation
            assert data.transform[k, j].tolist() == [t.x, t.y, t.z, r.x, r.y, r.z, r.w]
        for out, twists in ((data.velocity, p.velocities), (data.acceleration, p.accelerations)):
            expected = [[w.linear.x, w.linear.y, w.linear.z, w.angular.x, w.angular.y, w.angular.z]
                        for w in twists] or [[0.0] * 6] * len(msg.joint_names)
            assert out[k].tolist() == expected


def test_a_malformed_trajectory_is_refused_naming_the_point_and_field():
    from geometry_msgs.msg import Transform, Twist
    from trajectory_msgs.msg import MultiDOFJointTrajectory, MultiDOFJointTrajectoryPoint

    from pkm_common.cdr import decode_multidof_trajectory
    point = MultiDOFJointTrajectoryPoint(transforms=[Transform()], velocities=[Twist()], accelerations=[Twist()])
    good = MultiDOFJointTrajectory(joint_names=["tool"], points=[point] * 5)
    buf = serialize_message(good)
    with pytest.raises(ValueError, match=r"trajectory: points\[4\].time_from_start runs past the end"):
        decode_multidof_trajectory(buf[:-4])
    two = MultiDOFJointTrajectoryPoint(transforms=[Transform()] * 2)
    bad = MultiDOFJointTrajectory(joint_names=["tool"], points=[point] * 3 + [two])
    with pytest.raises(ValueError, match=r"points\[3\].transforms: expected 1 \(one per joint\), got 2"):
        decode_multidof_trajectory(serialize_message(bad))
    with pytest.raises(ValueError, match="not a little-endian CDR message"):
        decode_multidof_trajectory(b"\x00\x00\x00\x00" + buf[4:])


def test_a_stamp_before_1970_is_refused_by_both_readers():
    """Every reader of a stamped message: the general one and the decoder's cached layout."""
    import pytest
    from pkm_common.cdr import JointStateDecoder, decode_pose_stamped
    from geometry_msgs.msg import PoseStamped
    good = JointState(name=["d1", "d2"], position=[1.0, 2.0])
    bad = JointState(name=["d1", "d2"], position=[1.0, 2.0])
    bad.header.stamp.sec = -1
    decoder = JointStateDecoder("drives/state")
    decoder.decode(serialize_message(good))              # its layout is now cached
    for decode in (decoder.decode, decode_joint_state):
        with pytest.raises(ValueError, match=r"header.stamp must be at or after 0 s .* got sec -1"):
            decode(serialize_message(bad))
    pose = PoseStamped()
    pose.header.stamp.sec = -3
    with pytest.raises(ValueError, match="got sec -3"):
        decode_pose_stamped(serialize_message(pose))


def test_a_viewer_drops_what_it_cannot_read_and_reports_the_first():
    from pkm_common.cdr import ShownReader, decode_pose_stamped
    reports = []
    read = ShownReader(reports.append)
    assert read(decode_pose_stamped, b"\x00\x01\x00\x00") is None and read(decode_pose_stamped, b"") is None
    assert read.dropped == 2 and len(reports) == 1 and reports[0].startswith("not shown: ")


def test_decode_bool_reads_what_rclpy_serialized_and_refuses_other_bytes():
    from std_msgs.msg import Bool

    from pkm_common.cdr import decode_bool
    assert decode_bool(serialize_message(Bool(data=True))) is True
    assert decode_bool(serialize_message(Bool(data=False))) is False
    for bad in (b"", b"\x00\x01\x00\x00", b"\x01\x00\x00\x00\x01"):        # empty, cut, big-endian
        with pytest.raises(ValueError, match="estop: not a little-endian CDR std_msgs/Bool"):
            decode_bool(bad, "estop")


def test_a_trajectory_encoded_as_records_is_the_message_rclpy_reads():
    """cdr.encode_multidof_trajectory (through conversions.trajectory_bytes) against
    rclpy: its bytes deserialize to the message conversions.trajectory_msg builds, and
    have its size, for planar and spatial samples, 0, 1, 2 and 7 points, and frame ids
    whose lengths put the first point 4 or 8 past an alignment; our decoder reads them
    back. (rclpy's padding bytes are not initialised: the bytes are compared as messages.)"""
    import numpy as np
    from rclpy.serialization import deserialize_message, serialize_message
    from trajectory_msgs.msg import MultiDOFJointTrajectory
    from pkm_common.cdr import decode_multidof_trajectory
    from pkm_common.conversions import trajectory_bytes, trajectory_msg
    from pkm_kinematics.task_space import PLANAR, SPATIAL
    rng = np.random.default_rng(7)
    offsets = set()
    for space in (PLANAR, SPATIAL):
        for n in (0, 1, 2, 7):
            t = np.cumsum(rng.uniform(0.0, 0.01, n))
            x, v, a = (rng.normal(size=(n, space.dof)) for _ in range(3))
            for frame in ("world", "w", "worl", "a-longer-frame-id"):
                msg = trajectory_msg(space, t, x, v, a)
                msg.header.frame_id, msg.header.stamp.sec, msg.header.stamp.nanosec = frame, 12, 345
                data = trajectory_bytes(space, t, x, v, a, 12 * 10**9 + 345, frame_id=frame)
                assert deserialize_message(data, MultiDOFJointTrajectory) == msg, (space, n, frame)
                assert len(data) == len(serialize_message(msg))
                back = decode_multidof_trajectory(data)
                np.testing.assert_array_equal(back.time_s, [p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec
                                                            for p in msg.points])
                offsets.add((len(frame) + 1) % 8)
    assert len(offsets) > 1


@settings(max_examples=200, deadline=None)
@given(stamps, texts, st.lists(st.tuples(st.integers(0, 3), texts, texts, texts,
                                         st.lists(st.tuples(texts, texts), max_size=5)), max_size=4))
def test_a_diagnostic_array_is_the_message_rclpy_serializes(stamp, frame, statuses):
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from pkm_common.cdr import encode_diagnostic_array
    msg = DiagnosticArray()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
    msg.header.frame_id = frame
    msg.status = [DiagnosticStatus(level=bytes((level,)), name=name, message=message, hardware_id=hardware,
                                   values=[KeyValue(key=k, value=v) for k, v in values])
                  for level, name, message, hardware, values in statuses]
    # compared as rclpy reads them: its padding bytes are not zeroed (uninitialised memory)
    assert deserialize_message(encode_diagnostic_array(stamp, statuses, frame), DiagnosticArray) == msg


def test_diagnostic_bytes_are_the_message_the_nodes_publish():
    from diagnostic_msgs.msg import DiagnosticArray
    from pkm_common.conversions import diagnostic_array, diagnostic_bytes, diagnostic_status, ns_to_stamp
    values = {"mode": "tracking", "error_m": 1.5e-6, "cycles": 12, "ratio": 0.1 + 0.2, "unicode": "µm"}
    for level in (0, 1, 2, 3, b"\x02"):
        expected = diagnostic_array(ns_to_stamp(7_000_000_123), [diagnostic_status("controller", level, "ok", values)])
        assert deserialize_message(diagnostic_bytes(7_000_000_123, "controller", level, "ok", values),
                                   DiagnosticArray) == expected
    msg = deserialize_message(diagnostic_bytes(5, "n", 1, "m", {}), DiagnosticArray)
    assert msg.status[0].level == b"\x01" and msg.status[0].values == []
    with pytest.raises(ValueError, match="level"):
        diagnostic_bytes(5, "n", 4, "m")
