"""The direct engine's bag writers (pkm_bringup.direct_recording): the writer in a
process of its own writes the bag the in-process one writes, byte for byte, and its
failures reach the run's process as the in-process writer's would."""

from __future__ import annotations

import errno
import os
import signal
import threading

import pytest

from pkm_bringup import direct_recording
from pkm_bringup.direct_recording import Recorder, RecorderProcess, RecordingFailed, _portable, bag_recorder
from pkm_common import topics
from pkm_common.cdr import JointStateEncoder
from pkm_common.files import disk_full

STEPS = 650                  # three whole batches of 200 and a last one at the close


def _record(recorder) -> dict:
    """Two topics' messages through the recorder's tap, a batch every 200 steps."""
    state = recorder.index("/pkm/drives/state", topics.DRIVES_STATE)
    recorder.start()                             # the writer forked once the run is wired
    command = recorder.index("/pkm/drives/command", topics.DRIVES_COMMAND)     # a topic after the start
    states, commands = JointStateEncoder(["a", "b", "c"]), JointStateEncoder(["a", "b", "c"], fields=("effort",))
    for k in range(STEPS):
        stamp = k * 1_000_000
        recorder.tap.add_indexed(state, states.encode(stamp, [k * 1e-3, 0.5, -0.5], [0.1, 0.2, 0.3], [1.0, 2.0, 3.0]),
                                 1_000_000_000 + 2 * k)
        if k % 3:                                # a repeated stamp is not a new one (the summary counts them)
            recorder.tap.add_indexed(command, commands.encode(stamp, effort=[float(k), 0.0, -1.0]),
                                     1_000_000_001 + 2 * k)
        if k % 200 == 199:
            recorder.flush()
    return recorder.close()


def test_the_writer_process_writes_the_bag_the_run_s_process_writes(tmp_path):
    summaries, files = [], []
    for name, make in (("here", Recorder), ("process", RecorderProcess)):
        output = tmp_path / name / "bag"
        summaries.append(_record(make(str(output), "lz4")))
        files.append({path.name: path.read_bytes() for path in output.iterdir()})
    here, process = files
    assert sorted(here) == sorted(process) and any(name.endswith(".mcap") for name in here), (sorted(here),
                                                                                              sorted(process))
    for name in here:
        assert here[name] == process[name], f"{name}: {len(here[name])} bytes here, {len(process[name])} by the process"
    assert summaries[0] == summaries[1], summaries
    assert summaries[1]["recorded"] == {"/pkm/drives/state": STEPS, "/pkm/drives/command": 433}, summaries[1]


def test_a_refused_bag_path_is_a_value_error_of_the_run_and_no_process_is_left(tmp_path):
    taken = tmp_path / "bag"
    taken.mkdir()
    (taken / "other.txt").write_text("someone's file")
    recorder = RecorderProcess(str(taken), "lz4")
    recorder.index("/pkm/drives/state", topics.DRIVES_STATE)
    with pytest.raises(ValueError, match="exists and is not empty"):
        recorder.start()
    with pytest.raises(ChildProcessError):
        os.waitpid(-1, os.WNOHANG)               # the writer was reaped: no child of this process left


def test_a_writer_that_died_fails_the_next_batch(tmp_path):
    recorder = RecorderProcess(str(tmp_path / "bag"), "lz4")
    index = recorder.index("/pkm/drives/state", topics.DRIVES_STATE)
    recorder.start()
    os.kill(recorder.pid, signal.SIGKILL)
    assert recorder.conn.poll(10.0), "the writer's end of the pipe did not close"
    recorder.tap.add_indexed(index, JointStateEncoder(["a"]).encode(0, [0.0], [0.0], [0.0]), 1)
    with pytest.raises(RecordingFailed, match="the bag's writer ended"):
        recorder.flush()
    recorder.abandon()                           # already reaped: nothing to wait for
    assert recorder.closed


def test_the_writer_s_errors_keep_what_the_run_tells_by():
    full = _portable(OSError(errno.ENOSPC, "No space left on device", "/runs/x/bag/x_0.mcap"))
    assert isinstance(full, OSError) and disk_full(full) and "bag's writer" in str(full), full
    assert type(_portable(ValueError("bag directory taken"))) is ValueError
    other = _portable(KeyError("channel"))
    assert isinstance(other, RecordingFailed) and "KeyError" in str(other), other


def test_a_process_with_threads_writes_its_bag_itself(tmp_path, monkeypatch):
    """A fork copies only the calling thread (a Dask worker has several; so has pytest
    here): the bag is then written in the run's process."""
    stop = threading.Event()
    other = threading.Thread(target=stop.wait)
    other.start()
    try:
        assert not direct_recording.may_fork()
        recorder = bag_recorder(str(tmp_path / "threads"), "lz4")
    finally:
        stop.set()
        other.join()
    assert isinstance(recorder, Recorder), recorder
    recorder.start()
    recorder.close()
    monkeypatch.setattr(threading, "active_count", lambda: 1)      # pkm-run's process: one thread
    alone = bag_recorder(str(tmp_path / "alone"), "lz4")
    assert isinstance(alone, RecorderProcess), alone
    alone.start()
    alone.close()


def test_the_writer_outlives_signals_to_the_run_s_group_and_ends_with_the_run(tmp_path):
    """A terminal's Ctrl-C or a kill of the run's process group reaches the writer too:
    it ignores them, and the run's process, which decides, closes the bag through it."""
    recorder = RecorderProcess(str(tmp_path / "bag"), "lz4")
    index = recorder.index("/pkm/drives/state", topics.DRIVES_STATE)
    recorder.start()
    for number in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        os.kill(recorder.pid, number)
    recorder.tap.add_indexed(index, JointStateEncoder(["a"]).encode(5, [1.0], [0.0], [0.0]), 1)
    assert recorder.close()["recorded"] == {"/pkm/drives/state": 1}
