"""The graph's live data in Foxglove: what ``foxglove_bridge`` serves over the Foxglove
WebSocket protocol (the ``foxglove-sdk`` package's server; no rclpy here).

Open Foxglove (app or foxglove.dev) -> "Open connection" -> ``ws://127.0.0.1:8765``.
Channels (the run's namespace, ``/pkm`` by default, before each; log time = the
step's simulated stamp):

==================  ====================  =========================================
channel             schema                what
==================  ====================  =========================================
drives/state        JSON                  ``name``, ``position`` (m), ``velocity``,
                                          ``effort`` (N) per drive, ``status`` word
metrology/struts    JSON                  the Gough strut lengths, named
tool/true_pose      foxglove.PoseInFrame  the simulated tool pose (frame ``world``)
tool/reference      foxglove.PoseInFrame  the controller's reference
machine             foxglove.SceneUpdate  the legs (and struts) as lines, from
                                          ``markers``
controller/status   JSON                  the controller's diagnostic values
==================  ====================  =========================================

Suggested layout: a 3D panel with ``machine``, ``tool/true_pose`` and
``tool/reference``; a Plot panel of ``drives/state.effort[:]`` and of
``tool/true_pose.pose.position.x`` against ``tool/reference.pose.position.x``; a Raw
Messages panel on ``controller/status``. Each stream is sent at most ``rate_hz`` times
per second of simulated time (a 1-2 kHz loop is more than a viewer needs).
"""

from __future__ import annotations

import math

from pkm_kinematics.errors import FieldError

STREAMS = ("drives/state", "metrology/struts", "tool/true_pose", "tool/reference", "machine", "controller/status")


class Decimator:
    """Lets a stream through at most ``rate_hz`` per second of its own stamps."""

    def __init__(self, rate_hz: float):
        if not (math.isfinite(rate_hz) and 0.1 <= rate_hz <= 1000.0):
            raise FieldError("rate_hz", f"must be in [0.1, 1000] Hz, got {rate_hz}")
        self.period_ns = int(1e9 / rate_hz)
        self.last: dict[str, int] = {}

    def due(self, stream: str, stamp_ns: int) -> bool:
        last = self.last.get(stream)
        if last is not None and 0 <= stamp_ns - last < self.period_ns:
            return False
        self.last[stream] = stamp_ns
        return True


def joint_json(names, position, velocity, effort, status: str = "") -> dict:
    """A JointState as the JSON message of drives/state and metrology/struts."""
    return {"name": list(names), "position": list(position), "velocity": list(velocity),
            "effort": list(effort), "status": status}


def pose_in_frame(position, orientation, stamp_ns: int):
    """A pose (x, y, z; quaternion x, y, z, w) as foxglove.PoseInFrame in ``world``."""
    from foxglove.messages import Pose, PoseInFrame, Quaternion, Timestamp, Vector3
    return PoseInFrame(timestamp=Timestamp(stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000), frame_id="world",
                       pose=Pose(position=Vector3(x=position[0], y=position[1], z=position[2]),
                                 orientation=Quaternion(x=orientation[0], y=orientation[1], z=orientation[2],
                                                        w=orientation[3])))


def machine_scene(points, stamp_ns: int, thickness_m: float = 0.01):
    """Segments (pairs of consecutive 3-D points, a LINE_LIST) as a foxglove.SceneUpdate."""
    from foxglove.messages import (Color, LinePrimitive, LinePrimitiveLineType, Point3, SceneEntity, SceneUpdate,
                                   Timestamp)
    line = LinePrimitive(type=LinePrimitiveLineType.LineList, thickness=thickness_m,
                         points=[Point3(x=p[0], y=p[1], z=p[2]) for p in points],
                         color=Color(r=0.2, g=0.5, b=0.9, a=1.0))
    entity = SceneEntity(timestamp=Timestamp(stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000),
                         frame_id="world", id="legs", lines=[line])
    return SceneUpdate(entities=[entity])


class LiveChannels:
    """The channels of one namespace on a Foxglove WebSocket server of its own
    (``port`` 0: any free one, ``server.port`` says which)."""

    def __init__(self, namespace: str = "/pkm", host: str = "127.0.0.1", port: int = 8765, rate_hz: float = 30.0):
        import foxglove
        from foxglove.channels import PoseInFrameChannel, SceneUpdateChannel
        if not 0 <= port <= 65535:
            raise FieldError("port", f"must be in [0, 65535], got {port}")
        self.decimator = Decimator(rate_hz)
        self.context = foxglove.Context()
        ns = namespace.rstrip("/")
        json_schema = {"type": "object"}
        self.channels = {
            "drives/state": foxglove.Channel(f"{ns}/drives/state", schema=json_schema, context=self.context),
            "metrology/struts": foxglove.Channel(f"{ns}/metrology/struts", schema=json_schema, context=self.context),
            "controller/status": foxglove.Channel(f"{ns}/controller/status", schema=json_schema,
                                                  context=self.context),
            "tool/true_pose": PoseInFrameChannel(f"{ns}/tool/true_pose", context=self.context),
            "tool/reference": PoseInFrameChannel(f"{ns}/tool/reference", context=self.context),
            "machine": SceneUpdateChannel(f"{ns}/machine", context=self.context),
        }
        self.server = foxglove.start_server(name=f"pkm {ns}", host=host, port=port, context=self.context)
        self.sent = dict.fromkeys(self.channels, 0)

    def log(self, stream: str, message, stamp_ns: int, decimate: bool = True) -> bool:
        """``message`` on ``stream`` if it is due (``decimate``); True when sent."""
        if decimate and not self.decimator.due(stream, stamp_ns):
            return False
        self.channels[stream].log(message, log_time=stamp_ns)
        self.sent[stream] += 1
        return True

    def close(self) -> None:
        self.server.stop()
