"""recorder_node in a test process: discovery pace and the in-process tap hand-over."""

from __future__ import annotations

from rclpy.parameter import Parameter

from pkm_bringup.recorder_node import RecorderNode


def _recorder(ctx, tmp_path, name, **params):
    overrides = [Parameter(k, value=v) for k, v in {"output": str(tmp_path / name), **params}.items()]
    return RecorderNode(context=ctx, namespace="/rec_test", parameter_overrides=overrides)


def test_discovery_slows_down_once_the_recorder_is_ready(ros_context, tmp_path):
    waiting = _recorder(ros_context, tmp_path, "a", expect_topics="never/published")
    ready = _recorder(ros_context, tmp_path, "b", running_discovery_period_s=2.5)
    try:
        assert not waiting.ready and waiting.discovery_timer.timer_period_ns == 100_000_000
        assert ready.ready and ready.discovery_timer.timer_period_ns == 2_500_000_000
    finally:
        waiting.destroy_node()
        ready.destroy_node()


def test_records_handed_over_are_written_and_refused_once_destroyed(ros_context, tmp_path):
    node = _recorder(ros_context, tmp_path, "c")
    clock = b"\x00\x01\x00\x00" + (7).to_bytes(4, "little") + (0).to_bytes(4, "little")
    try:
        assert node.write_records([("/clock", "rosgraph_msgs/msg/Clock", 7_000_000_000, clock)]) is True
        assert node.writer.counts["/clock"] == 1 and node.steps["/clock"] == 1
    finally:
        node.destroy_node()
    assert node.write_records([("/clock", "rosgraph_msgs/msg/Clock", 8_000_000_000, clock)]) is False
