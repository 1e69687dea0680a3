"""Foxglove live (pkm_operator.foxglove_live, foxglove_bridge_node): a WebSocket client
speaking the Foxglove protocol subscribes to the bridge's channels while sim_hw and a
holding controller run, and decodes what it receives."""

from __future__ import annotations

import json
import struct
import time

import pytest
from rclpy.parameter import Parameter

from pkm_operator.foxglove_live import Decimator
from pkm_operator.foxglove_bridge_node import FoxgloveBridgeNode
from pkm_sim_hw.hold_controller_node import HoldControllerNode
from pkm_sim_hw.sim_hw_node import SimHwNode

pytestmark = pytest.mark.ros


def overrides(**values):
    return [Parameter(k, value=v) for k, v in values.items()]


def test_the_decimator_lets_a_stream_through_at_its_rate_of_simulated_time():
    d = Decimator(100.0)                          # one per 10 ms of stamps
    passed = [t for t in range(0, 100_000_000, 1_000_000) if d.due("s", t)]
    assert passed == list(range(0, 100_000_000, 10_000_000))
    assert d.due("other", 1_000_000)              # each stream on its own
    with pytest.raises(ValueError, match=r"rate_hz: must be in \[0.1, 1000\] Hz"):
        Decimator(0.0)


def test_a_foxglove_client_sees_the_live_drive_state_pose_and_machine(ros_graph):
    from websockets.sync.client import connect
    sim = ros_graph.add_node(SimHwNode(context=ros_graph.context, namespace="/pkm", parameter_overrides=overrides(
        machine="mom3", publish_markers=True)))
    ros_graph.add_node(HoldControllerNode(context=ros_graph.context, namespace="/pkm",
                                          parameter_overrides=overrides(machine="mom3")))
    bridge = ros_graph.add_node(FoxgloveBridgeNode(context=ros_graph.context, namespace="/pkm",
                                                   parameter_overrides=overrides(port=0, rate_hz=50.0)))
    ros_graph.start()
    try:
        with connect(f"ws://127.0.0.1:{bridge.port}", subprotocols=["foxglove.sdk.v1"], open_timeout=10) as ws:
            channels, deadline = {}, time.monotonic() + 10.0
            while len(channels) < 6 and time.monotonic() < deadline:
                msg = ws.recv(timeout=5.0)
                if isinstance(msg, str) and json.loads(msg).get("op") == "advertise":
                    channels.update({c["topic"]: c for c in json.loads(msg)["channels"]})
            assert {"/pkm/drives/state", "/pkm/tool/true_pose", "/pkm/machine"} <= set(channels)
            assert channels["/pkm/tool/true_pose"]["schemaName"] == "foxglove.PoseInFrame"
            assert channels["/pkm/machine"]["schemaName"] == "foxglove.SceneUpdate"
            wanted = {1: "/pkm/drives/state", 2: "/pkm/tool/true_pose", 3: "/pkm/machine"}
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                {"id": i, "channelId": channels[t]["id"]} for i, t in wanted.items()]}))
            got: dict = {}
            deadline = time.monotonic() + 15.0
            while len(got.get(1, [])) < 5 or 2 not in got or 3 not in got:
                assert time.monotonic() < deadline, f"messages received: { {k: len(v) for k, v in got.items()} }"
                msg = ws.recv(timeout=5.0)
                if isinstance(msg, bytes) and msg[0] == 1:          # messageData
                    sub, log_time = struct.unpack_from("<IQ", msg, 1)
                    got.setdefault(sub, []).append((log_time, msg[13:]))
    finally:
        ros_graph.stop()
    states = [(t, json.loads(payload)) for t, payload in got[1]]
    assert states[0][1]["name"] == sim.plant.names and len(states[0][1]["position"]) == 3
    times = [t for t, _ in states]
    # the state's simulated stamp is the log time, at most 50 per simulated second
    assert times == sorted(times) and min(b - a for a, b in zip(times, times[1:])) >= 20_000_000
    assert all(abs(s["position"][0] - states[0][1]["position"][0]) < 1e-3 for _, s in states)   # held in place
    assert len(got[2][0][1]) > 0 and len(got[3][0][1]) > 0               # protobuf pose and scene
