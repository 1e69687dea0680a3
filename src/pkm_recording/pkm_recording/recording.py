"""What the recorder node needs from rclpy's types, without a node: message classes
by type name, the offered QoS as rosbag2 writes it, the subscription QoS that matches
every publisher, and the process's CPU priority."""

from __future__ import annotations

import os

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from pkm_recording.bag import qos_profile

_NS_MAX = 9223372036854775807


def qos_dict(qos: QoSProfile) -> dict:
    """An offered QoS profile as rosbag2 (Jazzy) writes it in ``offered_qos_profiles``
    (bag.qos_profile); an unset or infinite duration is rosbag2's infinite."""
    def ns(d):
        return d.nanoseconds if 0 < d.nanoseconds < _NS_MAX else None
    return qos_profile(qos.reliability, qos.durability, qos.depth, qos.history, ns(qos.deadline), ns(qos.lifespan),
                       qos.liveliness, ns(qos.liveliness_lease_duration), qos.avoid_ros_namespace_conventions)


def subscription_qos(offered: list[QoSProfile], depth: int) -> QoSProfile:
    """Compatible with every offered profile, deep enough not to drop at full rate."""
    reliable = all(q.reliability == ReliabilityPolicy.RELIABLE for q in offered)
    latched = all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


def normal_cpu_priority(pid: int) -> int:
    """SCHED_OTHER again for every thread of process ``pid`` (after lower_cpu_priority):
    once the loop has ended, the recorder must not wait behind everything else for its
    last messages. Best effort (another user's process, or SCHED_IDLE -> OTHER without
    CAP_SYS_NICE beyond RLIMIT_NICE, is refused): returns the threads changed."""
    changed = 0
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return 0
    for tid in tids:
        try:
            os.sched_setscheduler(int(tid), os.SCHED_OTHER, os.sched_param(0))
            changed += 1
        except (OSError, ValueError):
            pass
    return changed


def lower_cpu_priority() -> int:
    """SCHED_IDLE for every thread of this process (Linux; unprivileged): it then runs
    only on CPU time no other process wants. Threads created later inherit it.
    Returns the number of threads changed."""
    changed = 0
    for tid in os.listdir("/proc/self/task"):
        try:
            os.sched_setscheduler(int(tid), os.SCHED_IDLE, os.sched_param(0))
            changed += 1
        except (OSError, ValueError):       # a thread that has just ended
            pass
    return changed
