"""pkm-report and pkm-replay on a bag its recorder did not finish: no ROS graph.

A small run is recorded with the project's BagWriter (small chunks, flushed like the
recorder), then its .mcap is cut in the middle, as a kill -9 of the recorder (no
metadata.yaml) or a cut copy (metadata.yaml kept) leaves it. Both commands must say
in one line that the bag is incomplete and how to recover it, and with ``--recover``
make it readable (pkm_recording.bag.recover) and go on."""

import json
import math

import pytest
import yaml

from pkm_runs import replay, report
from pkm_recording.bag import BagWriter, IncompleteBagError, check_complete, recover_bag
from pkm_common.cdr import JointStateEncoder, PoseStampedEncoder, encode_clock

NS = "/pkm"
STEPS = 1500
DT_NS = 1_000_000
WALL0 = 1_700_000_000 * 10**9
DRIVES = ["q1", "q2", "q3", "q4"]


def record_run(run_dir):
    """ARCHI-like per-step streams for STEPS steps, flushed every 100 steps into 16 KiB
    chunks; run.json and the controller parameters beside the bag."""
    state, command = JointStateEncoder(DRIVES), JointStateEncoder(DRIVES, fields=("effort",))
    pose = PoseStampedEncoder("world")
    with BagWriter(run_dir / "bag", chunk_size=16 * 1024) as writer:
        ids = {topic: writer.add_topic(topic, msgtype) for topic, msgtype in (
            ("/clock", "rosgraph_msgs/msg/Clock"), (f"{NS}/drives/state", "sensor_msgs/msg/JointState"),
            (f"{NS}/platform/true_pose", "geometry_msgs/msg/PoseStamped"),
            (f"{NS}/drives/command", "sensor_msgs/msg/JointState"),
            (f"{NS}/controller/reference", "geometry_msgs/msg/PoseStamped"))}
        for k in range(STEPS):
            stamp, wall = k * DT_NS, WALL0 + 2 * k * DT_NS
            x, y, yaw = 1.0 + 0.01 * math.sin(k / 200), -0.4, 0.785
            orientation = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
            forces = [100.0 * math.sin(k / 100 + j) for j in range(4)]
            writer.write(ids["/clock"], wall, encode_clock(stamp))
            writer.write(ids[f"{NS}/drives/state"], wall + 1000, state.encode(stamp, [0.5] * 4, [0.0] * 4, forces))
            writer.write(ids[f"{NS}/platform/true_pose"], wall + 2000, pose.encode(stamp, (x, y, 0.0), orientation))
            writer.write(ids[f"{NS}/drives/command"], wall + 3000, command.encode(stamp, effort=forces))
            writer.write(ids[f"{NS}/controller/reference"], wall + 4000,
                         pose.encode(stamp, (x + 1e-5, y, 0.0), orientation))
            if k % 100 == 99:
                writer.flush()
    (run_dir / "run.json").write_text(json.dumps({"scenario": "cut", "machine": "archi", "namespace": NS}))
    (run_dir / "params").mkdir()
    (run_dir / "params" / "controller.yaml").write_text(yaml.safe_dump(
        {"/**": {"ros__parameters": {"machine": "archi", "strategy": "computed_torque"}}}))
    return run_dir


def cut(run_dir, keep_metadata: bool):
    """The .mcap cut at 60 % (metadata.yaml removed unless ``keep_metadata``)."""
    (mcap,) = (run_dir / "bag").glob("*.mcap")
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) * 6 // 10])
    if not keep_metadata:
        (run_dir / "bag" / "metadata.yaml").unlink()
    return mcap


@pytest.fixture
def killed(tmp_path):
    """A run whose recorder was killed: the .mcap cut, no metadata.yaml."""
    run_dir = record_run(tmp_path / "killed")
    cut(run_dir, keep_metadata=False)
    return run_dir


def _one_line_error(err: str, prog: str, run_dir) -> None:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert "Traceback" not in err
    assert lines[0].startswith(f"{prog}: error: incomplete bag")
    assert f"{prog} --recover {run_dir}" in lines[0]


@pytest.mark.parametrize("keep_metadata", [False, True], ids=["killed", "cut_copy"])
def test_report_of_an_incomplete_bag_says_how_to_recover(tmp_path, capsys, keep_metadata):
    run_dir = record_run(tmp_path / "run")
    cut(run_dir, keep_metadata)
    with pytest.raises(IncompleteBagError):
        check_complete(run_dir / "bag")
    assert report.main([str(run_dir)]) == 2
    _one_line_error(capsys.readouterr().err, "pkm-report", run_dir)
    assert not (run_dir / "report" / "metrics.json").exists()


def test_report_recover_then_report(killed, capsys):
    assert report.main([str(killed), "--recover"]) == 0
    out = capsys.readouterr().out
    first = out.splitlines()[0]
    assert first.startswith(f"pkm-report: {killed / 'bag'}: recovered ") and "unfinished chunk are lost" in first
    m = json.loads((killed / "report" / "metrics.json").read_text())
    assert 0 < m["steps"] < STEPS and m["machine"] == "archi"
    assert m["tracking_error"]["max_m"] == pytest.approx(1e-5, rel=1e-6)
    assert sorted(p.name for p in (killed / "bag").iterdir()) == ["bag_0.mcap", "bag_0.mcap.truncated",
                                                                  "metadata.yaml"]
    # recovered once: the bag is complete, the report reads it as it is
    assert report.main([str(killed)]) == 0
    assert report.main([str(killed), "--recover"]) == 0
    assert "complete bag, nothing to recover" in capsys.readouterr().out


def test_recovery_of_a_cut_copy_counts_what_is_lost(tmp_path):
    run_dir = record_run(tmp_path / "run")
    cut(run_dir, keep_metadata=True)
    recovery = recover_bag(run_dir / "bag")
    total = 5 * STEPS
    assert recovery.rewritten and recovery.listed is not None and sum(recovery.listed.values()) == total
    assert 0 < recovery.lost < total and recovery.lost == total - sum(recovery.counts.values())
    assert f"{recovery.lost} of the {total} messages its metadata.yaml listed are lost" in recovery.describe()
    check_complete(run_dir / "bag")


def test_replay_of_an_incomplete_bag_says_how_to_recover(killed, capsys):
    assert replay.main([str(killed)]) == 2
    _one_line_error(capsys.readouterr().err, "pkm-replay", killed)


def test_replay_recover_then_replay(killed, capsys):
    code = replay.main([str(killed), "--recover"])
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err
    lines = captured.out.splitlines()
    assert lines[0].startswith(f"pkm-replay: {killed / 'bag'}: recovered ")
    assert "recorded commands recomputed" in lines[1]      # the replay went on over the recovered bag
    assert code in (0, 1)
