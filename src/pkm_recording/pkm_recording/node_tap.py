"""A node's recording tap (the rclpy side of pkm_recording.tap).

``NodeTap(node, enabled)``: with ``enabled`` the node's per-step publishers wrapped by
``wrap`` copy every message into a StreamTap, published on ``TAP_TOPIC`` every
``period_s`` (``TAP_PERIOD_S``) and by ``flush()``: from ``after_cycle()``, which the
node calls right after its answer in a cycle (``pkm_common.timing.Cadence``: off the
deadline's path), and from a timer when no cycle runs; ``close()`` is the last flush (call it before the
context goes down). Disabled,
``wrap`` returns the publisher itself: nothing is added to the loop.

``sink``: a recorder in the same process (the orchestrator's in-process mode) sets it
to its ``write_records`` (False: not recorded, counted as ``dropped`` like a batch
that cannot be published); the batch payloads then go to it directly, without a
message (no publishing and taking of ~60 kB every 0.2 s per node, on the loop's own
thread). The tap publisher still exists: the recorder's readiness check
looks for it.
"""

from __future__ import annotations

import time

from rclpy.duration import Duration
from std_msgs.msg import UInt8MultiArray

from pkm_common.qos import TAP_QOS
from pkm_recording.tap import TAP_TOPIC, StreamTap, TappedPublisher, message_type_name
from pkm_common.timing import Cadence

# A batch every 0.2 s: most of a batch's cost is per batch (its message, the recorder's
# callback, topic table and calls), not per record. Measured on archi_demo (~60 kB a
# batch at 1 kHz): the recorder process's CPU 3.9-5.6 -> 1.6-2.1 us a message from 50
# ms to 0.2 s; in one process the batches' cost on the loop's thread 10-13.5 -> 3.8-5.2
# us a step, in pauses of ~400 instead of ~250 us. A node killed with -9 loses at most
# its last 0.2 s of records (counted).
TAP_PERIOD_S = 0.2


class NodeTap:
    def __init__(self, node, enabled: bool, period_s: float = TAP_PERIOD_S):
        self.tap = StreamTap() if enabled else None
        self.batches = 0
        self.dropped = 0
        self.sink = None
        self.cadence = Cadence(period_s)
        if enabled:
            self.publisher = node.create_publisher(UInt8MultiArray, TAP_TOPIC, TAP_QOS)
            node.create_timer(period_s, self._on_timer)

    def after_cycle(self) -> None:
        """A batch if one is due (call right after the node's answer of a cycle)."""
        if self.tap is not None and self.cadence.in_cycle():
            self.flush()

    def _on_timer(self) -> None:
        if self.cadence.on_timer():
            self.flush()

    def wrap(self, publisher, msg_class):
        """``publisher`` (of CDR bytes), tapped when enabled."""
        if self.tap is None:
            return publisher
        return TappedPublisher(publisher, self.tap, message_type_name(msg_class), time.time_ns)

    def flush(self) -> None:
        """Publish what was recorded since the last batch. At the end of a node whose
        context is already down the batch cannot go out: it is dropped (the recorder's
        published-vs-recorded count shows it), never raised into the teardown."""
        if self.tap is None:
            return
        if self.sink is not None:
            payload = self.tap.take_payload()
            if payload is None:
                return
            try:
                delivered = self.sink(payload) is not False      # False: the recorder is gone
            except Exception:              # noqa: BLE001 - never raised into the loop or the teardown
                delivered = False
            if delivered:
                self.batches += 1
            else:
                self.dropped += 1
            return
        batch = self.tap.take_batch()
        if batch is None:
            return
        try:
            self.publisher.publish(batch)
            self.batches += 1
        except Exception:                  # noqa: BLE001 - rclpy's RCLError on a dead context
            self.dropped += 1

    def close(self, linger_s: float = 2.0) -> None:
        """The last flush, before the node goes down: the batch, then up to
        ``linger_s`` for the recorder to acknowledge it (at once when it is there). A
        reliable writer that is destroyed right after publishing cannot resend what a
        busy (idle-priority) reader has not taken yet: an interrupted run lost the
        controller's last batch that way, and with the suite on two workers a whole run
        lost the sensor's last two steps after 0.25 s."""
        before = self.batches
        self.flush()
        if self.batches > before and self.sink is None:
            try:
                self.publisher.wait_for_all_acked(Duration(nanoseconds=int(linger_s * 1e9)))
            except Exception:              # noqa: BLE001 - a context going down: nothing to wait for
                pass
