"""Where sim_hw's refusals go (shell): ``drives/refused``, so that the bag shows what
the plant did not apply, and the log, neither flooded by a stream of bad commands."""

from __future__ import annotations

import time

from pkm_common import topics
from pkm_common.conversions import diagnostic_array, diagnostic_status, ns_to_stamp
from pkm_common.endpoints import publisher
from pkm_common.ratelimit import RateLimit
from pkm_sim_hw.authority import Refusal

REFUSALS_PER_S = 50          # refusal records published a second at most (the rest are counted)


class RefusalReport:
    """Publishes each refusal on ``drives/refused`` (a DiagnosticArray: reason, cause,
    stamp, sender, plant step; at most REFUSALS_PER_S a second, the rest counted in
    ``counts["refusals_not_published"]``) and logs it at most once a second."""

    def __init__(self, node, counts: dict):
        self.node, self.counts = node, counts
        self.publisher = publisher(node, topics.DRIVES_REFUSED)
        self.record_limit = RateLimit(REFUSALS_PER_S)
        self.log_limit = RateLimit(1)

    def report(self, refusal: Refusal, topic: str, text: str, plant_step: int, now_ns: int) -> None:
        now = time.monotonic()
        if self.record_limit.allow(now):
            values = {"topic": topic, "reason": refusal.reason, "cause": str(refusal.cause),
                      "stamp_ns": refusal.stamp_ns, "sender": refusal.sender or "unknown",
                      "plant_step": plant_step, "stopped": refusal.stop}
            self.publisher.publish(diagnostic_array(
                ns_to_stamp(now_ns), [diagnostic_status("sim_hw/refused", 2, refusal.reason, values)]))
        else:
            self.counts["refusals_not_published"] = self.record_limit.suppressed
        if self.log_limit.allow(now):
            self.node.get_logger().error(f"{text} ({self.counts['refused_commands']} commands, "
                                         f"{self.counts['refused_loads']} loads refused so far)")
