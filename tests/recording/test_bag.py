"""pkm_recording.bag: rosbag2-compatible MCAP writer, kill -9 recovery, counting.

Pure Python (no ROS graph): messages are serialized with rosbags' Jazzy typestore and
read back with rosbags' AnyReader and with mcap + mcap_ros2, which must agree with each
other, with BagWriter.counts and with metadata.yaml.
"""

import io
import json
import os
import shutil
import signal
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from pkm_recording.tap import StreamTap, split_batch
from pkm_recording.bag import (
    INFINITE_DURATION,
    BagWriter,
    IncompleteBagError,
    check_complete,
    qos_profile,
    qos_profiles_yaml,
    read_counts,
    recorded_stamps,
    recover,
    recover_bag,
)

T0 = 1_700_000_000_000_000_000  # log times (ns since the epoch)
JS, POSE, DIAG, TRAJ, CLOCK = ('sensor_msgs/msg/JointState', 'geometry_msgs/msg/PoseStamped',
                               'diagnostic_msgs/msg/DiagnosticArray',
                               'trajectory_msgs/msg/MultiDOFJointTrajectory', 'rosgraph_msgs/msg/Clock')
TOPICS = {  # topic -> (type, message count, QoS offered)
    '/joint_states': (JS, 2000, qos_profile('reliable', 'volatile', 10)),
    '/platform_pose': (POSE, 600, qos_profile('best_effort', 'volatile', 5)),
    '/diagnostics': (DIAG, 120, qos_profile('reliable', 'volatile', 100)),
    '/trajectory': (TRAJ, 30, qos_profile('reliable', 'transient_local', 1)),
    '/clock': (CLOCK, 400, qos_profile('best_effort', 'volatile', 1)),
}


@pytest.fixture(scope='module')
def ts():
    return get_typestore(Stores.ROS2_JAZZY)


# --- test messages ---------------------------------------------------------------------

def _time(ts, i):
    return ts.types['builtin_interfaces/msg/Time'](sec=1000 + i // 1000, nanosec=(i % 1000) * 1_000_000)


def _header(ts, i, frame):
    return ts.types['std_msgs/msg/Header'](stamp=_time(ts, i), frame_id=frame)


def make_msg(ts, msgtype, i):
    """The i-th test message of msgtype (content depends on i)."""
    T = ts.types
    if msgtype == JS:
        return T[JS](header=_header(ts, i, 'base'), name=['q1', 'q2', 'q3'],
                     position=np.array([float(i), i + 0.25, -0.5 * i]),
                     velocity=np.array([0.1 * i, 0.0, 1.0]), effort=np.zeros(0))
    if msgtype == POSE:
        pose = T['geometry_msgs/msg/Pose'](
            position=T['geometry_msgs/msg/Point'](x=0.001 * i, y=-0.002 * i, z=0.5),
            orientation=T['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=np.sin(i * 1e-3), w=np.cos(i * 1e-3)))
        return T[POSE](header=_header(ts, i, 'world'), pose=pose)
    if msgtype == DIAG:
        status = [T['diagnostic_msgs/msg/DiagnosticStatus'](
            level=i % 4, name=f'node{k}', message=f'cycle {i}', hardware_id='pkm',
            values=[T['diagnostic_msgs/msg/KeyValue'](key='i', value=str(i)),
                    T['diagnostic_msgs/msg/KeyValue'](key='k', value=str(k))]) for k in range(2)]
        return T[DIAG](header=_header(ts, i, ''), status=status)
    if msgtype == TRAJ:
        points = []
        for k in range(3):
            tf = T['geometry_msgs/msg/Transform'](
                translation=T['geometry_msgs/msg/Vector3'](x=float(i), y=float(k), z=0.1 * k),
                rotation=T['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0))
            points.append(T['trajectory_msgs/msg/MultiDOFJointTrajectoryPoint'](
                transforms=[tf], velocities=[], accelerations=[],
                time_from_start=T['builtin_interfaces/msg/Duration'](sec=k, nanosec=500)))
        return T[TRAJ](header=_header(ts, i, 'world'), joint_names=['platform'], points=points)
    if msgtype == CLOCK:
        return T[CLOCK](clock=_time(ts, i))
    raise AssertionError(msgtype)


def _f(values):
    return [float(v) for v in values]


def _stamp(h):
    return (int(h.stamp.sec), int(h.stamp.nanosec), h.frame_id)


def key_fields(msgtype, m):
    """Decoded field values, comparable between rosbags and mcap_ros2 objects."""
    if msgtype == JS:
        return (_stamp(m.header), list(m.name), _f(m.position), _f(m.velocity), _f(m.effort))
    if msgtype == POSE:
        p, q = m.pose.position, m.pose.orientation
        return (_stamp(m.header), _f([p.x, p.y, p.z, q.x, q.y, q.z, q.w]))
    if msgtype == DIAG:
        def level(v):
            return v[0] if isinstance(v, (bytes, bytearray)) else int(v)
        return (_stamp(m.header), [(level(s.level), s.name, s.message, s.hardware_id,
                                    [(kv.key, kv.value) for kv in s.values]) for s in m.status])
    if msgtype == TRAJ:
        return (_stamp(m.header), list(m.joint_names),
                [([_f([t.translation.x, t.translation.y, t.translation.z,
                       t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w]) for t in p.transforms],
                  len(p.velocities), len(p.accelerations),
                  (int(p.time_from_start.sec), int(p.time_from_start.nanosec))) for p in m.points])
    if msgtype == CLOCK:
        return (int(m.clock.sec), int(m.clock.nanosec))
    raise AssertionError(msgtype)


def write_test_bag(ts, path, chunk_size=16 * 1024, compression='zstd', flush_every=250, scale=1.0):
    """Interleaved messages on all TOPICS (counts times ``scale``); returns
    (writer, expected {topic: [(log time, fields)]})."""
    expected = {topic: [] for topic in TOPICS}
    schedule = []
    for topic, (msgtype, n, _) in TOPICS.items():
        n = max(1, round(n * scale))
        period = 2_000_000_000 // n  # all topics span ~2 s
        schedule += [(T0 + k * period + len(schedule) % 7, topic, k) for k in range(n)]
    schedule.sort()
    with BagWriter(path, chunk_size=chunk_size, compression=compression) as writer:
        ids = {topic: writer.add_topic(topic, msgtype, [qos])
               for topic, (msgtype, _, qos) in TOPICS.items()}
        for j, (t, topic, k) in enumerate(schedule):
            msgtype = TOPICS[topic][0]
            msg = make_msg(ts, msgtype, k)
            writer.write(ids[topic], t, ts.serialize_cdr(msg, msgtype), publish_time_ns=t - 1000)
            expected[topic].append((t, key_fields(msgtype, msg)))
            if j % flush_every == 0:
                writer.flush()
    return writer, expected


def anyreader_messages(ts, path):
    """{topic: [(log time, fields)]} and {topic: msgcount} via rosbags' AnyReader."""
    got, counts = {}, {}
    with AnyReader([Path(path)], default_typestore=ts) as reader:
        for conn in reader.connections:
            counts[conn.topic] = conn.msgcount
            got.setdefault(conn.topic, [])
        for conn, t, raw in reader.messages():
            got[conn.topic].append((t, key_fields(conn.msgtype, reader.deserialize(raw, conn.msgtype))))
    return got, counts


def mcap_ros2_messages(mcap_path):
    """{topic: [(log time, fields)]} via mcap + mcap_ros2's decoder."""
    got = {}
    with open(mcap_path, 'rb') as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            got.setdefault(channel.topic, []).append((message.log_time, key_fields(schema.name, decoded)))
    return got


def metadata_yaml(path):
    return yaml.safe_load((Path(path) / 'metadata.yaml').read_text())['rosbag2_bagfile_information']


def yaml_counts(info):
    return {t['topic_metadata']['name']: t['message_count'] for t in info['topics_with_message_count']}


# --- round trip -----------------------------------------------------------------------------

@pytest.mark.parametrize('compression', ['zstd', 'none'])
def test_round_trip_rosbags_and_mcap_ros2_agree(ts, tmp_path, compression):
    bag = tmp_path / 'run1'
    writer, expected = write_test_bag(ts, bag, compression=compression)
    n_expected = {topic: n for topic, (_, n, _) in TOPICS.items()}
    assert writer.counts == n_expected
    assert sum(n_expected.values()) > 3000

    got_rosbags, rosbags_counts = anyreader_messages(ts, bag)
    got_mcap = mcap_ros2_messages(writer.mcap_path)
    info = metadata_yaml(bag)
    for topic, messages in expected.items():
        assert got_rosbags[topic] == messages, topic
        assert got_mcap[topic] == messages, topic
    assert rosbags_counts == n_expected
    assert yaml_counts(info) == n_expected
    assert info['message_count'] == sum(n_expected.values())
    assert read_counts(bag) == n_expected
    assert read_counts(writer.mcap_path) == n_expected
    with open(writer.mcap_path, 'rb') as fh:
        stats = make_reader(fh).get_summary().statistics
    assert stats.message_count == sum(n_expected.values())
    assert stats.chunk_count > 10  # small chunks: the test crosses many chunk boundaries

    times = [t for messages in expected.values() for t, _ in messages]
    assert info['starting_time']['nanoseconds_since_epoch'] == min(times)
    assert info['duration']['nanoseconds'] == max(times) - min(times)


def test_sequence_and_publish_time(ts, tmp_path):
    with BagWriter(tmp_path / 'b') as writer:
        a = writer.add_topic('/a', CLOCK)
        b = writer.add_topic('/b', CLOCK)
        data = ts.serialize_cdr(make_msg(ts, CLOCK, 1), CLOCK)
        for i in range(5):
            writer.write(a, T0 + i, data, publish_time_ns=T0 + i - 7)
            writer.write(b, T0 + i, bytearray(data))
        writer.write(b, T0 + 9, memoryview(data))
    with open(writer.mcap_path, 'rb') as fh:
        msgs = [(c.topic, m.sequence, m.log_time, m.publish_time)
                for _, c, m in make_reader(fh).iter_messages(log_time_order=False)]
    assert [s for topic, s, _, _ in msgs if topic == '/a'] == [1, 2, 3, 4, 5]
    assert [s for topic, s, _, _ in msgs if topic == '/b'] == [1, 2, 3, 4, 5, 6]
    assert all(p == t - 7 for topic, _, t, p in msgs if topic == '/a')
    assert all(p == t for topic, _, t, p in msgs if topic == '/b')


def _tap_region(records):
    """The records region of a recording-tap batch (pkm_recording.tap) and its count."""
    tap = StreamTap()
    for topic, time_ns, data in records:
        tap.add(topic, CLOCK, data, time_ns)
    topics, region, count = split_batch(tap.take_payload())
    return [t for t, _ in topics], region, count


@pytest.mark.parametrize("chunk_size", [1 << 20, 150])
def test_tap_records_write_what_the_same_writes_one_by_one_would(ts, tmp_path, chunk_size):
    """write_tap_records (one compiled pass per batch) against write() per message:
    the same file, byte for byte, chunk ends included; a topic mapped to -1 is skipped."""
    data = [ts.serialize_cdr(make_msg(ts, CLOCK, i), CLOCK) for i in range(8)]
    records = [('/a', T0 + 3, data[0]), ('/b', T0 + 1, data[1]), ('/skip', T0, data[6]), ('/a', T0 + 5, data[2]),
               ('/b', T0 + 2, data[3]), ('/a', T0 + 4, data[4]), ('/skip', T0, data[7]), ('/b', T0 + 9, data[5])]
    files = []
    for name, packed in (("one", False), ("packed", True)):
        (tmp_path / name).mkdir()
        with BagWriter(tmp_path / name / "bag", chunk_size=chunk_size) as writer:     # the same file name
            ids = {'/a': writer.add_topic('/a', CLOCK), '/b': writer.add_topic('/b', CLOCK), '/skip': -1}
            if packed:
                stamps = []
                for part in (records[:3], records[3:]):
                    topics, region, count = _tap_region(part)
                    written, stamp = writer.write_tap_records(region, count, [ids[t] for t in topics])
                    assert written.tolist() == [ids[t] for t, _, _ in part if t != '/skip']
                    stamps += stamp.tolist()
                assert stamps == [int.from_bytes(d[4:12], 'little', signed=True)
                                  for t, _, d in records if t != '/skip']
            else:
                for topic, t, d in records:
                    if topic != '/skip':
                        writer.write(ids[topic], t, d)
        files.append(writer.mcap_path.read_bytes())
        info = yaml.safe_load((tmp_path / name / 'bag' / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
        assert info['starting_time']['nanoseconds_since_epoch'] == T0 + 1
        assert info['duration']['nanoseconds'] == 8
        assert {t['topic_metadata']['name']: t['message_count'] for t in info['topics_with_message_count']} \
            == {'/a': 3, '/b': 3}
    assert files[0] == files[1]
    assert [(topic, seq, t, p) for topic, seq, t, p, _ in _messages_of(files[1])] == [
        ('/a', 1, T0 + 3, T0 + 3), ('/b', 1, T0 + 1, T0 + 1), ('/a', 2, T0 + 5, T0 + 5),
        ('/b', 2, T0 + 2, T0 + 2), ('/a', 3, T0 + 4, T0 + 4), ('/b', 3, T0 + 9, T0 + 9)]


def _messages_of(data: bytes) -> list:
    return [(c.topic, m.sequence, m.log_time, m.publish_time, bytes(m.data))
            for _, c, m in make_reader(io.BytesIO(data)).iter_messages(log_time_order=False)]


def test_a_malformed_tap_batch_is_refused_whole(ts, tmp_path):
    data = ts.serialize_cdr(make_msg(ts, CLOCK, 3), CLOCK)
    with BagWriter(tmp_path / 'b') as writer:
        cid = writer.add_topic('/clock', CLOCK)
        topics, region, count = _tap_region([('/clock', T0, data), ('/clock', T0 + 1, data)])
        assert writer.write_tap_records(region, count, [cid])[0].tolist() == [cid, cid]
        negative = bytearray(region)
        negative[14 + len(data) + 2:14 + len(data) + 10] = (-5).to_bytes(8, 'little', signed=True)
        bad_index = bytearray(region)
        bad_index[0:2] = (1).to_bytes(2, 'little')
        for args, match in (((region[:-1], count, [cid]), 'record 1 runs past the end'),
                            ((region, count + 1, [cid]), 'record 2 runs past the end'),
                            ((bad_index, count, [cid]), 'record 0 names a topic index'),
                            ((negative, count, [cid]), 'record 1 has a negative publish time'),
                            ((region, count, [99]), 'unknown channel id 99')):
            with pytest.raises(ValueError, match=match):
                writer.write_tap_records(*args)
        assert writer.counts == {'/clock': 2}
    with pytest.raises(ValueError, match='closed'):
        writer.write_tap_records(region, count, [cid])
    got, counts = anyreader_messages(ts, tmp_path / 'b')
    assert counts == {'/clock': 2} and [t for t, _ in got['/clock']] == [T0, T0 + 1]


# --- schemas, channels, metadata --------------------------------------------------------------

def test_schemas_channels_and_metadata(ts, tmp_path):
    bag = tmp_path / 'layout'
    writer, _ = write_test_bag(ts, bag)
    assert sorted(p.name for p in bag.iterdir()) == ['layout_0.mcap', 'metadata.yaml']
    with open(writer.mcap_path, 'rb') as fh:
        reader = make_reader(fh)
        header = reader.get_header()
        summary = reader.get_summary()
        records = list(reader.iter_metadata())
    assert header.profile == 'ros2' and 'pkm' in header.library
    schemas = {s.name: s for s in summary.schemas.values()}
    assert sorted(schemas) == sorted(t for t, _, _ in TOPICS.values())
    for name, schema in schemas.items():
        assert schema.encoding == 'ros2msg'
        assert schema.data.decode() == ts.generate_msgdef(name, ros_version=2)[0]
    js = schemas[JS].data.decode()
    assert js.startswith('std_msgs/Header header\nstring[] name\nfloat64[] position')
    assert '=' * 80 + '\nMSG: std_msgs/Header\n' in js
    assert '=' * 80 + '\nMSG: builtin_interfaces/Time\n' in js
    traj = schemas[TRAJ].data.decode()
    for dep in ('trajectory_msgs/MultiDOFJointTrajectoryPoint', 'geometry_msgs/Transform',
                'geometry_msgs/Twist', 'builtin_interfaces/Duration'):
        assert f'\nMSG: {dep}\n' in traj

    assert len(summary.channels) == len(TOPICS)
    for channel in summary.channels.values():
        msgtype, _, qos = TOPICS[channel.topic]
        assert channel.message_encoding == 'cdr'
        assert summary.schemas[channel.schema_id].name == msgtype
        assert set(channel.metadata) == {'offered_qos_profiles', 'topic_type_hash'}
        assert channel.metadata['topic_type_hash'] == ts.hash_rihs01(msgtype)
        [offered] = yaml.safe_load(channel.metadata['offered_qos_profiles'])
        assert offered == qos
        assert (offered['reliability'], offered['durability'], offered['depth']) == (
            qos['reliability'], qos['durability'], qos['depth'])

    info = metadata_yaml(bag)
    assert info['version'] == 9
    assert info['storage_identifier'] == 'mcap'
    assert info['relative_file_paths'] == ['layout_0.mcap']
    assert info['compression_format'] == '' and info['compression_mode'] == ''
    assert info['ros_distro'] == 'jazzy'
    assert info['custom_data'] is None
    [file_info] = info['files']
    assert file_info['path'] == 'layout_0.mcap'
    assert file_info['message_count'] == info['message_count']
    for entry in info['topics_with_message_count']:
        meta = entry['topic_metadata']
        msgtype, _, qos = TOPICS[meta['name']]
        assert meta['type'] == msgtype and meta['serialization_format'] == 'cdr'
        assert meta['offered_qos_profiles'] == [qos]
        assert meta['type_description_hash'] == ts.hash_rihs01(msgtype)

    # rosbag2's MCAP plugin reads the format version (and so the QoS format) from here
    [record] = [r for r in records if r.name == 'rosbag2']
    assert yaml.safe_load(record.metadata['serialized_metadata']) == info


def test_layout_matches_rosbags_writer(ts, tmp_path):
    """Same messages through rosbags' own Writer: same metadata and records, bar the
    documented differences (file name, ros_distro, topic_type_hash, sequence numbers)."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.metadata import parse_qos

    topics = [('/joint_states', JS, [qos_profile('reliable', 'volatile', 10)]),
              ('/tf_like', POSE, [qos_profile('best_effort', 'transient_local', 3)]),
              ('/clock', CLOCK, [])]
    ref, ours = tmp_path / 'ref', tmp_path / 'ours'
    with Writer(ref, version=9, storage_plugin=StoragePlugin.MCAP) as rw, BagWriter(ours) as bw:
        for topic, msgtype, qos in topics:
            conn = rw.add_connection(topic, msgtype, typestore=ts,
                                     offered_qos_profiles=parse_qos(qos_profiles_yaml(qos)))
            cid = bw.add_topic(topic, msgtype, qos)
            for i in range(7 if msgtype != CLOCK else 0):
                data = ts.serialize_cdr(make_msg(ts, msgtype, i), msgtype)
                rw.write(conn, T0 + 10 * i, data)
                bw.write(cid, T0 + 10 * i, data)

    ref_info, our_info = metadata_yaml(ref), metadata_yaml(ours)
    assert ref_info['relative_file_paths'] == ['ref.mcap']     # rosbags: <name>.mcap
    assert our_info['relative_file_paths'] == ['ours_0.mcap']  # rosbag2: <name>_0.mcap
    assert ref_info['ros_distro'] == 'rosbags' and our_info['ros_distro'] == 'jazzy'
    for info in (ref_info, our_info):
        info.pop('relative_file_paths'), info.pop('ros_distro')
        info['files'][0].pop('path')
    assert our_info == ref_info

    def records(path):
        with open(path, 'rb') as fh:
            summary = make_reader(fh).get_summary()
        schemas = {i: (s.name, s.encoding, s.data) for i, s in summary.schemas.items()}
        channels = {i: (c.topic, c.message_encoding, schemas[c.schema_id],
                        yaml.safe_load(c.metadata['offered_qos_profiles']))
                    for i, c in summary.channels.items()}
        return schemas, channels, summary.statistics.message_count

    assert records(ref / 'ref.mcap') == records(ours / 'ours_0.mcap')
    with open(ref / 'ref.mcap', 'rb') as fa, open(ours / 'ours_0.mcap', 'rb') as fb:
        ma = [(c.topic, m.log_time, m.data) for _, c, m in make_reader(fa).iter_messages()]
        mb = [(c.topic, m.log_time, m.data) for _, c, m in make_reader(fb).iter_messages()]
    assert ma == mb


def test_qos_profiles_yaml_is_rosbag2s_format():
    text = qos_profiles_yaml([qos_profile('best_effort', 'transient_local', 5)])
    assert text == textwrap.dedent('''\
        - history: keep_last
          depth: 5
          reliability: best_effort
          durability: transient_local
          deadline:
            sec: 9223372036
            nsec: 854775807
          lifespan:
            sec: 9223372036
            nsec: 854775807
          liveliness: automatic
          liveliness_lease_duration:
            sec: 9223372036
            nsec: 854775807
          avoid_ros_namespace_conventions: false''')
    assert qos_profiles_yaml([]) == '[]'
    two = yaml.safe_load(qos_profiles_yaml([qos_profile(), qos_profile(depth=1, deadline=1_500_000_000)]))
    assert [p['depth'] for p in two] == [10, 1]
    assert two[1]['deadline'] == {'sec': 1, 'nsec': 500_000_000}
    assert two[0]['deadline'] == INFINITE_DURATION
    assert qos_profile('RELIABLE', 'Volatile')['reliability'] == 'reliable'
    for bad in ({'reliability': 'sometimes'}, {'durability': 'persistent'}, {'depth': -1},
                {'depth': 2.5}, {'deadline': 'soon'}, {'history': 'keep_some'}):
        with pytest.raises(ValueError):
            qos_profile(**bad)
    with pytest.raises(ValueError, match='unknown keys'):
        qos_profiles_yaml([{'reliability': 'reliable', 'colour': 'blue'}])


# --- topics ------------------------------------------------------------------------------------

def test_add_topic_twice(ts, tmp_path):
    with BagWriter(tmp_path / 'b') as writer:
        a = writer.add_topic('/a', JS)
        assert writer.add_topic('/a', JS) == a
        b = writer.add_topic('/b', JS)  # same type: schema shared
        assert b != a
        with pytest.raises(ValueError, match=r"'/a' already recorded as 'sensor_msgs/msg/JointState'"):
            writer.add_topic('/a', POSE)
    with open(writer.mcap_path, 'rb') as fh:
        summary = make_reader(fh).get_summary()
    assert [s.name for s in summary.schemas.values()] == [JS]
    assert sorted(c.topic for c in summary.channels.values()) == ['/a', '/b']
    assert writer.counts == {'/a': 0, '/b': 0}


def test_project_type_with_explicit_definition(ts, tmp_path):
    """A type the Jazzy typestore does not know: definition passed in; both readers
    decode it from the schema alone."""
    from rosbags.typesys import get_types_from_msg

    msgdef = 'std_msgs/Header header\nuint8 level\nstring text\nfloat64[] values\n'
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg(msgdef, 'pkm_msgs/msg/Status'))
    Status = store.types['pkm_msgs/msg/Status']
    full, _ = store.generate_msgdef('pkm_msgs/msg/Status', ros_version=2)
    with BagWriter(tmp_path / 'b') as writer:
        cid = writer.add_topic('/status', 'pkm_msgs/msg/Status', msgdef=full)
        for i in range(3):
            msg = Status(header=_header(store, i, 'x'), level=i, text=f'n{i}', values=np.array([i, 2.0 * i]))
            writer.write(cid, T0 + i, store.serialize_cdr(msg, 'pkm_msgs/msg/Status'))
    with open(writer.mcap_path, 'rb') as fh:
        decoded = [(d.level, d.text, list(d.values)) for _, _, _, d in
                   make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages()]
    assert decoded == [(i, f'n{i}', [float(i), 2.0 * i]) for i in range(3)]
    with AnyReader([tmp_path / 'b'], default_typestore=ts) as reader:
        texts = [reader.deserialize(raw, conn.msgtype).text for conn, _, raw in reader.messages()]
    assert texts == ['n0', 'n1', 'n2']


# --- bad input -------------------------------------------------------------------------------------

def test_unknown_message_type(tmp_path):
    with BagWriter(tmp_path / 'b') as writer:
        with pytest.raises(ValueError, match=r"'/foo'.*unknown message type 'pkm_msgs/msg/Nope'"):
            writer.add_topic('/foo', 'pkm_msgs/msg/Nope')
        with pytest.raises(ValueError, match=r"'/foo'.*'sensor_msgs/JointState'.*pkg/msg/Type"):
            writer.add_topic('/foo', 'sensor_msgs/JointState')
        with pytest.raises(ValueError, match='fully qualified'):
            writer.add_topic('joint_states', JS)
        with pytest.raises(ValueError, match='reliability'):
            writer.add_topic('/foo', JS, [{'reliability': 'maybe'}])
        assert writer.counts == {}


def test_existing_directory(tmp_path):
    busy = tmp_path / 'busy'
    busy.mkdir()
    (busy / 'notes.txt').write_text('keep me')
    with pytest.raises(ValueError, match='exists and is not empty'):
        BagWriter(busy)
    assert os.listdir(busy) == ['notes.txt']
    afile = tmp_path / 'afile'
    afile.write_text('x')
    with pytest.raises(ValueError, match='not a directory'):
        BagWriter(afile)
    empty = tmp_path / 'empty'
    empty.mkdir()
    with BagWriter(empty) as writer:  # an empty directory is fine
        pass
    assert writer.mcap_path == empty / 'empty_0.mcap'
    with pytest.raises(ValueError, match='compression'):
        BagWriter(tmp_path / 'c', compression='bz2')
    with pytest.raises(ValueError, match='storage_id'):
        BagWriter(tmp_path / 'c', storage_id='sqlite3')
    assert not (tmp_path / 'c').exists()  # arguments are checked before anything is created


def test_bad_writes_leave_the_bag_intact(ts, tmp_path):
    bag = tmp_path / 'b'
    data = ts.serialize_cdr(make_msg(ts, CLOCK, 3), CLOCK)
    with BagWriter(bag) as writer:
        cid = writer.add_topic('/clock', CLOCK)
        writer.write(cid, T0, data)
        with pytest.raises(ValueError, match=r'unknown channel id 99'):
            writer.write(99, T0, data)
        with pytest.raises(ValueError, match='integer nanoseconds'):
            writer.write(cid, T0 + 0.5, data)
        with pytest.raises(ValueError, match='out of range'):
            writer.write(cid, -1, data)
        with pytest.raises(ValueError, match='bytes-like'):
            writer.write(cid, T0, 'not bytes')
        writer.write(cid, np.int64(T0 + 1), data)
    with pytest.raises(ValueError, match='closed'):
        writer.write(cid, T0 + 2, data)
    with pytest.raises(ValueError, match='closed'):
        writer.add_topic('/x', CLOCK)
    assert writer.counts == {'/clock': 2}
    got, counts = anyreader_messages(ts, bag)
    assert counts == {'/clock': 2}
    assert [t for t, _ in got['/clock']] == [T0, T0 + 1]


# --- close, empty bags ----------------------------------------------------------------------------------

def test_close_twice_and_empty_bags(ts, tmp_path):
    writer = BagWriter(tmp_path / 'empty', compression='lz4')
    cid = writer.add_topic('/joint_states', JS, [qos_profile()])
    writer.flush()
    writer.close()
    size = writer.mcap_path.stat().st_size
    writer.close()
    writer.flush()
    assert writer.closed and writer.mcap_path.stat().st_size == size
    assert cid == 1 and writer.counts == {'/joint_states': 0}

    got, counts = anyreader_messages(ts, tmp_path / 'empty')
    assert counts == {'/joint_states': 0} and got == {'/joint_states': []}
    info = metadata_yaml(tmp_path / 'empty')
    assert info['message_count'] == 0 and yaml_counts(info) == {'/joint_states': 0}
    assert info['starting_time']['nanoseconds_since_epoch'] == 2**63 - 1  # as rosbag2 and rosbags
    assert info['duration']['nanoseconds'] == 0
    assert read_counts(tmp_path / 'empty') == {'/joint_states': 0}
    assert mcap_ros2_messages(writer.mcap_path) == {}

    with BagWriter(tmp_path / 'no_topics'):
        pass
    _, counts = anyreader_messages(ts, tmp_path / 'no_topics')
    assert counts == {}
    assert metadata_yaml(tmp_path / 'no_topics')['topics_with_message_count'] == []


def test_context_manager_closes_on_error(ts, tmp_path):
    data = ts.serialize_cdr(make_msg(ts, CLOCK, 0), CLOCK)
    with pytest.raises(RuntimeError, match='boom'):
        with BagWriter(tmp_path / 'b') as writer:
            writer.write(writer.add_topic('/clock', CLOCK), T0, data)
            raise RuntimeError('boom')
    assert writer.closed
    assert anyreader_messages(ts, tmp_path / 'b')[1] == {'/clock': 1}


def test_concurrent_writers_and_flusher(ts, tmp_path):
    data = ts.serialize_cdr(make_msg(ts, JS, 1), JS)
    with BagWriter(tmp_path / 'b', chunk_size=4096) as writer:
        ids = [writer.add_topic(f'/t{k}', JS) for k in range(4)]
        stop = threading.Event()

        def produce(cid):
            for i in range(2000):
                writer.write(cid, T0 + i, data)

        def flusher():
            while not stop.is_set():
                writer.flush()

        threads = [threading.Thread(target=produce, args=(cid,)) for cid in ids]
        flush_thread = threading.Thread(target=flusher)
        flush_thread.start()
        for th in threads:
            th.start()
        for th in threads:
            th.join()
        stop.set()
        flush_thread.join()
    expected = {f'/t{k}': 2000 for k in range(4)}
    assert writer.counts == expected
    assert anyreader_messages(ts, tmp_path / 'b')[1] == expected
    assert read_counts(tmp_path / 'b') == expected


# --- crash: truncation and recovery -------------------------------------------------------------------------

def _copy_truncated(src_bag, dst_bag, cut, garbage=b''):
    """A bag dir as a killed writer leaves it: the mcap cut at byte ``cut``, no metadata."""
    dst_bag.mkdir()
    src = next(src_bag.glob('*.mcap'))
    data = src.read_bytes()[:cut] + garbage
    (dst_bag / src.name).write_bytes(data)
    return dst_bag / src.name


def test_truncated_at_any_byte_is_read_and_recovered(ts, tmp_path):
    src = tmp_path / 'full'
    writer, expected = write_test_bag(ts, src, chunk_size=4 * 1024, flush_every=10**9, scale=0.2)
    size = writer.mcap_path.stat().st_size
    previous = -1
    cuts = sorted({0, 5, 8, 20, 40, 100} | set(range(200, size, max(1, size // 25))) | {size - 1})
    for n, cut in enumerate(cuts):
        bag = tmp_path / f'cut{n}'
        _copy_truncated(src, bag, cut, garbage=b'\x00' * 64 if n % 2 else b'')
        counts = read_counts(bag)
        total = sum(counts.values())
        assert total >= previous, cut  # more bytes never read fewer messages
        previous = total
        assert recover(bag) == counts
        assert yaml_counts(metadata_yaml(bag)) == counts
        if n % 4 and cut != cuts[-1]:
            continue  # AnyReader (slow YAML) on a quarter of the cuts
        got, reader_counts = anyreader_messages(ts, bag)
        assert reader_counts == counts
        for topic, messages in got.items():  # exactly a prefix of what was written
            assert messages == expected[topic][:len(messages)], (cut, topic)
    assert previous > 0.9 * sum(len(m) for m in expected.values())


def test_recover_is_idempotent_and_keeps_the_original(ts, tmp_path):
    src = tmp_path / 'full'
    writer, expected = write_test_bag(ts, src, chunk_size=8 * 1024)
    bag = tmp_path / 'killed'
    mcap = _copy_truncated(src, bag, writer.mcap_path.stat().st_size * 6 // 10)
    original = mcap.read_bytes()
    with pytest.raises(Exception):  # not readable as is: no footer, no metadata.yaml
        anyreader_messages(ts, bag)
    counts = recover(bag)
    assert 0 < sum(counts.values()) < sum(len(m) for m in expected.values())
    assert (bag / (mcap.name + '.truncated')).read_bytes() == original
    assert recover(bag) == counts          # second run: nothing to do
    assert read_counts(bag) == counts
    assert yaml_counts(metadata_yaml(bag)) == counts

    # metadata.yaml lost but the mcap complete (killed between the two): rebuilt
    (bag / 'metadata.yaml').unlink()
    assert recover(bag) == counts
    assert anyreader_messages(ts, bag)[1] == counts

    # complete bag straight from BagWriter: untouched
    before = writer.mcap_path.read_bytes()
    assert recover(src) == {topic: len(m) for topic, m in expected.items()}
    assert writer.mcap_path.read_bytes() == before and not list(src.glob('*.truncated'))


def test_check_complete_and_what_recover_bag_says(ts, tmp_path):
    src = tmp_path / 'full'
    writer, expected = write_test_bag(ts, src, chunk_size=8 * 1024)
    total = sum(len(m) for m in expected.values())
    check_complete(src)
    check_complete(writer.mcap_path)
    complete = recover_bag(src)
    assert not complete.rewritten and not complete.metadata_rebuilt and complete.lost is None
    assert complete.describe() == f'complete bag, nothing to recover ({total} messages on {len(TOPICS)} topics)'

    killed = tmp_path / 'killed'                    # cut, no metadata.yaml: the loss is not known
    size = writer.mcap_path.stat().st_size
    _copy_truncated(src, killed, size // 2)
    with pytest.raises(IncompleteBagError, match='no metadata.yaml'):
        check_complete(killed)
    with pytest.raises(IncompleteBagError, match='without an MCAP footer'):
        check_complete(next(killed.glob('*.mcap')))
    recovery = recover_bag(killed)
    kept = sum(recovery.counts.values())
    assert recovery.rewritten and recovery.listed is None and recovery.lost is None and 0 < kept < total
    assert 0 < recovery.dropped_bytes < size // 2
    assert recovery.describe().startswith(f'recovered {kept} messages on ')
    check_complete(killed)

    cut_copy = tmp_path / 'cut_copy'                # cut, metadata.yaml kept: the loss is counted
    _copy_truncated(src, cut_copy, size * 7 // 10)
    shutil.copy(src / 'metadata.yaml', cut_copy / 'metadata.yaml')
    with pytest.raises(IncompleteBagError, match='without an MCAP footer'):
        check_complete(cut_copy)
    recovery = recover_bag(cut_copy)
    assert recovery.listed == {topic: len(m) for topic, m in expected.items()}
    assert recovery.lost == total - sum(recovery.counts.values()) > 0
    assert f'{recovery.lost} of the {total} messages its metadata.yaml listed are lost' in recovery.describe()

    no_metadata = tmp_path / 'no_metadata'          # killed between the footer and metadata.yaml
    _copy_truncated(src, no_metadata, size)
    recovery = recover_bag(no_metadata)
    assert not recovery.rewritten and recovery.metadata_rebuilt and sum(recovery.counts.values()) == total
    assert 'nothing lost' in recovery.describe()
    check_complete(no_metadata)


_CHILD = textwrap.dedent('''\
    import json, os, signal, sys
    from rosbags.typesys import Stores, get_typestore
    from pkm_recording.bag import BagWriter, qos_profile

    bag, status, chunk_size = sys.argv[1], sys.argv[2], int(sys.argv[3])
    ts = get_typestore(Stores.ROS2_JAZZY)
    T = ts.types

    def time(i):
        return T['builtin_interfaces/msg/Time'](sec=i // 1000, nanosec=(i % 1000) * 1000000)

    def js(i):
        import numpy as np
        h = T['std_msgs/msg/Header'](stamp=time(i), frame_id='base')
        return ts.serialize_cdr(T['sensor_msgs/msg/JointState'](
            header=h, name=['q1', 'q2', 'q3'], position=np.array([float(i), 0.0, 0.0]),
            velocity=np.zeros(3), effort=np.zeros(0)), 'sensor_msgs/msg/JointState')

    def clock(i):
        return ts.serialize_cdr(T['rosgraph_msgs/msg/Clock'](clock=time(i)), 'rosgraph_msgs/msg/Clock')

    writer = BagWriter(bag, chunk_size=chunk_size)
    ids = {'/joint_states': writer.add_topic('/joint_states', 'sensor_msgs/msg/JointState',
                                             [qos_profile('reliable', 'volatile', 10)]),
           '/clock': writer.add_topic('/clock', 'rosgraph_msgs/msg/Clock',
                                      [qos_profile('best_effort', 'volatile', 1)])}
    flushed = None
    for i in range(6000):
        writer.write(ids['/joint_states'], 10**18 + i * 1000, js(i))
        if i % 4 == 0:
            writer.write(ids['/clock'], 10**18 + i * 1000, clock(i))
        if i % 1000 == 999 and i < 5000:
            writer.flush()
            flushed = writer.counts
    # messages after the last flush (i = 5000..5999) are in flight: kill -9 now
    with open(status + '.tmp', 'w') as fh:
        json.dump({'flushed': flushed, 'written': writer.counts}, fh)
    os.replace(status + '.tmp', status)
    os.kill(os.getpid(), signal.SIGKILL)
''')


@pytest.mark.slow
@pytest.mark.parametrize('chunk_size', [1 << 20, 8 * 1024])
def test_kill_9_loses_at_most_the_open_chunk(ts, tmp_path, chunk_size):
    bag, status = tmp_path / 'killed', tmp_path / 'status.json'
    proc = subprocess.run([sys.executable, '-c', _CHILD, str(bag), str(status), str(chunk_size)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == -signal.SIGKILL, proc.stderr
    progress = json.loads(status.read_text())
    flushed, written = progress['flushed'], progress['written']
    assert flushed == {'/joint_states': 5000, '/clock': 1250}
    assert written == {'/joint_states': 6000, '/clock': 1500}
    assert sorted(p.name for p in bag.iterdir()) == ['killed_0.mcap']  # no metadata.yaml

    # the truncated file, read linearly with mcap's StreamReader: no footer at the end
    seen = {}
    with open(bag / 'killed_0.mcap', 'rb') as fh:
        with pytest.raises(Exception):
            for record in StreamReader(fh).records:
                seen[type(record).__name__] = seen.get(type(record).__name__, 0) + 1
    assert seen.get('Message', 0) >= sum(flushed.values())
    assert 'Footer' not in seen

    counts = read_counts(bag)
    for topic in flushed:
        assert flushed[topic] <= counts[topic] <= written[topic]
    if chunk_size == 1 << 20:   # the open chunk never filled up: exactly the flushed messages
        assert counts == flushed
    else:                       # chunks that filled up after the last flush reached the OS too
        assert counts['/joint_states'] > flushed['/joint_states']

    assert recover(bag) == counts
    got, reader_counts = anyreader_messages(ts, bag)
    assert reader_counts == counts
    assert yaml_counts(metadata_yaml(bag)) == counts
    positions = [fields[2][0] for _, fields in got['/joint_states']]
    assert positions == [float(i) for i in range(counts['/joint_states'])]
    assert (bag / 'killed_0.mcap.truncated').exists()
    shutil.rmtree(bag)


def test_recorded_stamps_count_new_stamps_as_the_recorder_does(ts, tmp_path):
    """A killed recorder's summary is rebuilt from its recovered bag: per topic, the
    number of new header stamps in log-time order (a message sent again with its
    stamp, as sim_hw repeats a state, counts once), against rosbags' reader and the
    messages' deserialized stamps."""
    with BagWriter(tmp_path / 'b') as writer:
        state = writer.add_topic('/pkm/drives/state', JS, [qos_profile('reliable', 'volatile', 10)])
        pose = writer.add_topic('/pkm/platform/true_pose', POSE, [qos_profile('reliable', 'volatile', 10)])
        t = T0
        for k in range(300):
            for _ in range(1 + (k % 7 == 0)):                 # every seventh state repeated
                t += 1000
                writer.write(state, t, ts.serialize_cdr(make_msg(ts, JS, k), JS))
            t += 1000
            writer.write(pose, t, ts.serialize_cdr(make_msg(ts, POSE, k), POSE))
    expected: dict = {}
    with AnyReader([tmp_path / 'b'], default_typestore=ts) as reader:
        last = {}
        for conn, _, raw in reader.messages():
            stamp = reader.deserialize(raw, conn.msgtype).header.stamp
            stamp = (stamp.sec, stamp.nanosec)
            if last.get(conn.topic) != stamp:
                last[conn.topic] = stamp
                expected[conn.topic] = expected.get(conn.topic, 0) + 1
    assert recorded_stamps(tmp_path / 'b') == expected == {'/pkm/drives/state': 300, '/pkm/platform/true_pose': 300}
