"""The plant's per-step streams as bytes (pkm_common.cdr), without rclpy: one step's
``platform/true_pose``, ``drives/state`` and ``/clock``, all stamped t_k.

``drives/state`` carries the plant's status (pkm_common.causes.PlantStatus) in its
``header.frame_id``, in band as a drive's status word: running, the command of a
stamp applied again (realtime), or braked and why.
rclpy's message objects cost ~13 us to publish and ~30 us to take each, the bytes
1-4 us.
"""

from __future__ import annotations

from pkm_common.causes import safe_stop_status, setpoint_held_status
from pkm_common.cdr import JointStateEncoder, PoseStampedEncoder, encode_clock

from .run_record import true_pose_components

__all__ = ["StepStreams"]


class StepStreams:
    """Publishes a step of ``plant`` (a plant.Plant, or hardware with the same
    interface: pkm_drives.hardware) on three publishers, each with a ``publish(bytes)``
    (the node's, tapped for the recorder; ``pose`` unused for hardware without ground truth;
    ``clock`` None where nothing reads /clock: a direct run without a recording)."""

    def __init__(self, plant, space, pose, state, clock):
        self.plant, self.space = plant, space
        self.pose, self.state, self.clock = pose, state, clock
        self.running = JointStateEncoder(plant.names)
        self.stopped = None                        # frame_id "safe_stop:<cause>", made at the stop
        self.held = None                           # frame_id "setpoint_held:<stamp>" of this step, if held
        self.pose_encoder = PoseStampedEncoder("world")

    def hold(self, held_stamp_ns: int | None) -> None:
        """The next steps applied the command of ``held_stamp_ns`` again (None: a fresh
        one): said in the status word (~20 us, a miss only)."""
        self.held = None if held_stamp_ns is None else \
            JointStateEncoder(self.plant.names, setpoint_held_status(held_stamp_ns).word())

    def publish(self, ns: int) -> None:
        """Clock, drives/state and platform/true_pose of the plant's current step."""
        out = self.plant.output()
        # the true pose first: the sensor's work is on the critical path of the step
        # (state -> sensor -> controller), the drive state and the clock are not; real
        # drives (pkm_drives.hardware) know none
        if out.tool_pose is not None:
            self.pose.publish(self.pose_encoder.encode(ns, *true_pose_components(self.space, out)))
        encoder = self.held or self.running
        if self.plant.stopped:                     # the status word: braked, and why (also before a step)
            if self.stopped is None:
                self.stopped = JointStateEncoder(self.plant.names, safe_stop_status(self.plant.stop_cause).word())
            encoder = self.stopped
        self.state.publish(encoder.encode(ns, out.encoder_positions, out.encoder_velocities, out.applied_forces))
        if self.clock is not None:
            self.clock.publish(encode_clock(ns))
