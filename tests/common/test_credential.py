"""pkm_common.credential: a command only the run's key holders can make, checked
against a second reader (rclpy's own deserialization and hmac recomputed here)."""

import hashlib
import hmac
import os
import stat

import pytest
from geometry_msgs.msg import PoseStamped, WrenchStamped
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import String
from trajectory_msgs.msg import MultiDOFJointTrajectory, MultiDOFJointTrajectoryPoint

from pkm_common.cdr import first_string_span
from pkm_common.conversions import signed_message
from pkm_common.credential import SCHEME, RunKey, Signer, Verifier, split_text


def _key(tmp_path, name="credential.key"):
    return RunKey.create(tmp_path / name)


def _goal(x=0.1):
    msg = PoseStamped()
    msg.header.stamp.sec = 3
    msg.pose.position.x, msg.pose.orientation.w = x, 1.0
    return msg


def _trajectory():
    msg = MultiDOFJointTrajectory()
    msg.joint_names = ["tool"]
    for k in range(3):
        point = MultiDOFJointTrajectoryPoint()
        point.time_from_start.nanosec = 1000 * k
        msg.points.append(point)
    return msg


def test_the_key_file_is_the_owners_alone_and_holds_its_key(tmp_path):
    key = _key(tmp_path)
    path = tmp_path / "credential.key"
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    again = RunKey.read(path)
    assert again.mac("goal", b"x") == key.mac("goal", b"x")
    os.chmod(path, 0o644)
    with pytest.raises(ValueError, match=r"credential_file: .* may be read by others \(mode 644\); it must be 600"):
        RunKey.read(path)
    with pytest.raises(ValueError, match="credential_file: cannot read"):
        RunKey.read(tmp_path / "missing.key")


@pytest.mark.parametrize("topic, msg", [("goal", _goal()), ("load", WrenchStamped()),
                                        ("trajectory", _trajectory())])
def test_a_signed_stamped_command_verifies_and_its_mac_is_hmac_sha256_of_the_zeroed_bytes(tmp_path, topic, msg):
    key = _key(tmp_path)
    buf = signed_message(Signer(key, "/pkm/panel", clock=lambda: 7), topic, msg)
    # second reader: rclpy deserializes the tag; HMAC recomputed over the bytes with the
    # mac's digits replaced by zeros where they are found (not re-serialized: rclpy's
    # alignment padding is not always zero, so the bytes are what is signed)
    tag = deserialize_message(buf, type(msg)).header.frame_id
    scheme, sender, seq, size, mac = tag.split(" ")
    assert (scheme, sender, seq, int(size)) == (SCHEME, "/pkm/panel", "7", len(buf))
    assert buf.count(mac.encode()) == 1
    zeroed = buf.replace(mac.encode(), b"0" * 64)
    secret = bytes.fromhex((tmp_path / "credential.key").read_text().strip())
    assert mac == hmac.new(secret, topic.encode() + b"\0" + zeroed, hashlib.sha256).hexdigest()
    # the fields survive: the message read back is the one signed, but for its frame
    back = deserialize_message(buf, type(msg))
    back.header.frame_id = msg.header.frame_id
    assert back == msg
    assert Verifier(key, clock=lambda: 0).check(topic, buf, stamped=True) == ("/pkm/panel", None)


def test_a_command_read_with_the_padding_of_the_wire_verifies_and_a_short_one_does_not(tmp_path):
    """Fast DDS hands a reader the bytes padded to a multiple of 4 (a 127-byte run/start
    arrived as 128 between two processes): the mac covers the sender's ``size``."""
    key = _key(tmp_path)
    signer = Signer(key, "/pkm/bringup_monitor")
    verifier = Verifier(key)                              # a reader exists before the command is signed
    buf = signer.text("run/start", "start")
    assert len(buf) % 4                                   # this one is padded on the wire
    assert verifier.check("run/start", buf + b"\0" * (-len(buf) % 4), False) == ("/pkm/bringup_monitor", None)
    short = signed_message(signer, "goal", _goal())[:-1]          # the last byte of orientation.w cut
    sender, why = verifier.check("goal", short, True)
    assert why.reason == f"goal: credential of /pkm/bringup_monitor for {len(short) + 1} bytes, the message has " \
        f"{len(short)}"


def test_a_string_command_carries_its_tag_as_the_first_line_and_keeps_its_body(tmp_path):
    key = _key(tmp_path)
    buf = Signer(key, "/pkm/panel").text("program", "G91 G1 X0.001\nM2")
    data = deserialize_message(buf, String).data
    tag, body = split_text(data)
    assert tag.startswith(SCHEME + " /pkm/panel ") and body == "G91 G1 X0.001\nM2"
    assert Verifier(key, clock=lambda: 0).check("program", buf, stamped=False) == ("/pkm/panel", None)
    assert split_text("G1 X1") == ("", "G1 X1")


def test_each_forgery_is_refused_with_its_reason(tmp_path):
    key = _key(tmp_path)
    signer = Signer(key, "/pkm/panel")
    verifier = Verifier(key)
    good = signer.text("controller/settings", '{"bandwidth_hz": 10}')
    # no tag at all (a rogue that names itself /pkm/panel)
    sender, why = verifier.check("controller/settings", serialize_message(String(data='{"bandwidth_hz": 10}')), False)
    assert (sender, why.reason) == ("", "controller/settings: no credential (pkm-cred/1 tag) in the message")
    # another run's key
    other = Signer(_key(tmp_path, "other.key"), "/pkm/panel").text("controller/settings", "{}")
    assert "not valid for this run (says /pkm/panel)" in verifier.check("controller/settings", other, False)[1].reason
    # altered in flight: one digit of the body
    altered = good.replace(b"10}", b"90}")
    assert altered != good and "altered" in verifier.check("controller/settings", altered, False)[1].reason
    # signed for another topic
    assert verifier.check("controller/feed_override", good, False)[1] is not None
    # a stamped message's stamp changed
    goal = signed_message(signer, "goal", _goal())
    moved = bytearray(goal)
    moved[4] ^= 1
    assert "altered" in verifier.check("goal", bytes(moved), True)[1].reason
    # the good one is taken once; sent again it is a replay
    assert verifier.check("controller/settings", good, False) == ("/pkm/panel", None)
    sender, why = verifier.check("controller/settings", good, False)
    assert sender == "/pkm/panel" and "a replayed command of /pkm/panel" in why.reason
    # a later command of the same sender is taken
    assert verifier.check("controller/settings", signer.text("controller/settings", "{}"), False)[1] is None


def test_seq_grows_with_the_clock_and_past_it(tmp_path):
    times = iter([100, 100, 50, 500])
    signer = Signer(_key(tmp_path), "/pkm/x", clock=lambda: next(times))
    assert [signer.placeholder().split(" ")[2] for _ in range(4)] == ["100", "101", "102", "500"]


def test_without_a_key_every_command_is_taken_and_a_malformed_one_raises(tmp_path):
    assert Verifier.from_file("").check("goal", b"", True) == ("", None)
    verifier = Verifier(_key(tmp_path))
    with pytest.raises(ValueError, match="not a little-endian CDR message"):
        verifier.check("goal", b"\x00\x01\x00\x00\x05", True)
    start, end = first_string_span(serialize_message(String(data="abc")), stamped=False)
    assert serialize_message(String(data="abc"))[start:end] == b"abc"


def test_refusal_names_the_sender_and_holds_a_key_holder_to_its_topics(tmp_path):
    key = _key(tmp_path)
    verifier = Verifier(key)
    allowed = frozenset({"/pkm/panel"})
    assert verifier.refusal("program", Signer(key, "/pkm/panel").text("program", "M2"), False, allowed) is None
    planner = verifier.refusal("program", Signer(key, "/pkm/trajectory").text("program", "M2"), False, allowed)
    assert planner.sender == "/pkm/trajectory" and planner.reason == \
        "program: /pkm/trajectory holds the run's credential but may not send it (only /pkm/panel)"
    assert verifier.refusal("program", serialize_message(String(data="M2")), False, allowed).sender == \
        "(no credential)"
    assert verifier.refusal("program", b"\x00\x01", False, allowed).sender == "(unreadable)"
    assert Verifier(None).refusal("program", b"", False, allowed) is None


def test_a_command_signed_before_the_reader_existed_is_a_recording_and_refused(tmp_path):
    """The same key in two runs (``pkm-run --credential``), or a controller configured
    again: what was signed before the reader was made is refused as a replay."""
    key = _key(tmp_path)
    earlier = Signer(key, "/pkm/panel").text("controller/settings", '{"bandwidth_hz": 5}')
    verifier = Verifier(key)
    sender, why = verifier.check("controller/settings", earlier, False)
    assert sender == "/pkm/panel" and "a replayed command of /pkm/panel" in why.reason
    assert verifier.check("controller/settings", Signer(key, "/pkm/panel").text("controller/settings", "{}"),
                          False) == ("/pkm/panel", None)


@pytest.mark.parametrize("forged", [
    "pkm-cred/1 /pkm/panel 12 0000000099 " + "\u00e9" * 64,      # a mac of non-ASCII: a TypeError in hmac before
    "pkm-cred/1 /pkm/panel \u00b2\u0663 0000000099 " + "a" * 64,  # digits that str.isdigit() takes
    "pkm-cred/1 /pkm/panel 12 0000000099 " + "A" * 64,            # upper-case hex
    "pkm-cred/1 /pk m/panel 12 0000000099 " + "a" * 64,           # a name with a space
    "pkm-cred/1 /pkm/p\u00e4nel 12 0000000099 " + "a" * 64,       # a name that is no ROS name
])
def test_a_malformed_tag_is_no_credential_and_never_raises(tmp_path, forged):
    buf = serialize_message(String(data=forged + "\n{}"))
    verifier = Verifier(_key(tmp_path))
    assert verifier.check("controller/settings", buf, False) == (
        "", verifier.check("controller/settings", serialize_message(String(data="{}")), False)[1])
    assert verifier.refusal("controller/settings", buf, False).sender == "(no credential)"


def test_a_sender_must_be_a_ros_node_name(tmp_path):
    with pytest.raises(ValueError, match="a full ROS node name"):
        Signer(_key(tmp_path), "/pkm/p\u00e4nel")
