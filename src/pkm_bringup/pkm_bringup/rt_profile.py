"""The realtime profile of a run (``pkm-run --rt-profile``, or ``realtime_profile: true``
in a scenario): how each node process is scheduled, and whether the OS allows it.

What each node gets (``PROFILE``; docs/decisions.md, Bringup, has the measurements):

=============  ==============  =================================================
node           scheduling      memory
=============  ==============  =================================================
controller     SCHED_FIFO 80   locked (``mlockall``, through ``MEMORY_LOCK_ENV``)
gough_sensor   SCHED_FIFO 70   locked
sim_hw         SCHED_FIFO 60   locked
trajectory     unchanged       -
recorder       unchanged       - (its ``cpu_priority``, idle by default, applies)
=============  ==============  =================================================

The order follows the deadline's critical path. sim_hw publishes the true pose first;
the Gough sensor turns it into strut readings, and the controller computes the command
from them and the drive state. What sim_hw does after that first publish (the state,
/clock, its recording tap) and the sensor's DKM after its readings (decision 22) are
off that path, and the loop needs about one core of two, so: the controller above all
(the longest stretch of the path), the sensor above the plant (its readings must not
wait for the rest of the plant's step), and sim_hw lowest (its wall timer still finds
a free core). The opposite order (the plant first, as the machine's clock) left the
sensor waiting behind the plant and the controller; CPU pinning did not help on two
cores and is not applied; the memory lock is kept although no gain showed here, with
its resident-memory cost (the measurements: docs/decisions.md, Bringup). The
trajectory node publishes its latched trajectory once; the recorder works on batches
every 0.2 s and may fall behind harmlessly (50 batches of history): both stay below
every SCHED_FIFO thread.

A policy set before ``exec`` (``preexec``) is inherited by every thread the process
creates later (DDS's receive and event threads, the executor), so the whole node runs
at its priority. ``MEMORY_LOCK_ENV`` asks ``pkm_common.runner.run_node`` for
``mlockall`` once the node is built.

Pure parts: ``PROFILE``, ``scheduling``, ``refusal`` (the one-line message from the
facts of ``Permissions``). Shell: ``probe_permissions`` (the real calls), ``preexec``
and ``applied_to_this_process`` (one process: ``pkm-run --in-process``).
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import os
import resource
import threading
import time
from dataclasses import dataclass

from pkm_common.runner import MEMORY_LOCK_ENV, lock_memory, unlock_memory
from pkm_kinematics.errors import FieldError

FIFO, OTHER = "fifo", "other"
_POLICIES = {FIFO: os.SCHED_FIFO, OTHER: os.SCHED_OTHER}
_CAP_IPC_LOCK, _CAP_SYS_NICE = 14, 23        # capability bit numbers (linux/capability.h)


@dataclass(frozen=True)
class Scheduling:
    """How one node process runs: its policy from the start (``other``: left as the
    orchestrator's, SCHED_OTHER), the SCHED_FIFO priority (1-99, 0 for ``other``),
    and whether its memory is locked."""
    policy: str = OTHER
    priority: int = 0
    lock_memory: bool = False

    def __post_init__(self):
        if self.policy not in _POLICIES:
            raise FieldError("policy", f"must be one of {list(_POLICIES)}, got {self.policy!r}")
        low, high = (1, 99) if self.policy == FIFO else (0, 0)
        if not low <= self.priority <= high:
            raise FieldError("priority", f"must be in [{low}, {high}] for {self.policy}, got {self.priority}")


PROFILE: dict[str, Scheduling] = {
    "controller": Scheduling(FIFO, 80, lock_memory=True),
    "gough_sensor": Scheduling(FIFO, 70, lock_memory=True),
    "sim_hw": Scheduling(FIFO, 60, lock_memory=True),
    "drives": Scheduling(FIFO, 60, lock_memory=True),          # the drive interface, in sim_hw's place
    "virtual_drives": Scheduling(FIFO, 60, lock_memory=True),  # the simulated machine behind the bus
    "ros2_control": Scheduling(FIFO, 60, lock_memory=True),    # the interface to a ros2_control system
    "ros2_control_sim": Scheduling(FIFO, 60, lock_memory=True),  # its stand-in in simulation
    "trajectory": Scheduling(),
    "recorder": Scheduling(),
}
# the loop's nodes composed in one process (pkm_bringup.composed_loop): one thread, at
# the loop's highest priority
PROFILE["loop"] = Scheduling(FIFO, PROFILE["controller"].priority, lock_memory=True)
# one process (--in-process): every node on one thread, at the loop's highest priority
IN_PROCESS = Scheduling(FIFO, PROFILE["controller"].priority, lock_memory=True)
HOW_TO_RUN_WITHOUT = "run without --rt-profile (scenario: realtime_profile: false)"


def scheduling(node: str, in_process: bool = False) -> Scheduling:
    """The profile's scheduling of ``node`` (a name of processes.MODULES), or of the one
    process of an in-process run."""
    if in_process:
        return IN_PROCESS
    try:
        return PROFILE[node]
    except KeyError:
        raise FieldError("node", f"must be one of {sorted(PROFILE)}, got {node!r}") from None


def highest_priority(in_process: bool = False) -> int:
    """The highest SCHED_FIFO priority the profile asks for (what the OS must allow)."""
    return IN_PROCESS.priority if in_process else max(s.priority for s in PROFILE.values())


def locks_memory(in_process: bool = False) -> bool:
    return IN_PROCESS.lock_memory if in_process else any(s.lock_memory for s in PROFILE.values())


class RealtimeProfileRefused(RuntimeError):
    """The OS does not allow the profile; the message names what is missing (one line)."""


@dataclass(frozen=True)
class Permissions:
    """What decides whether the profile can run. ``fifo_errno``: the errno of a real
    ``sched_setscheduler(SCHED_FIFO, priority)`` tried on a short-lived thread (None:
    allowed); ``mlock_errno`` the same for ``mlock`` of one page. The limits and
    capabilities name the cause in the message (None: unlimited)."""
    priority: int
    fifo_errno: int | None
    rtprio_limit: int | None
    cap_sys_nice: bool
    mlock_errno: int | None
    memlock_limit_bytes: int | None
    cap_ipc_lock: bool


def _limit(value: int | None, unit: str = "") -> str:
    if value is None:
        return "unlimited"
    return f"{value // 1024} KiB" if unit == "KiB" else str(value)


def refusal(p: Permissions, lock: bool = True) -> str | None:
    """The one-line reason the profile cannot run with permissions ``p`` (None when it
    can). ``lock``: the profile locks memory (mlockall needs CAP_IPC_LOCK, or a memlock
    limit above the process's whole mapped memory: a node maps over 1 GiB)."""
    if p.fifo_errno is not None:
        return (f"realtime profile: SCHED_FIFO priority {p.priority} not permitted "
                f"({errno.errorcode.get(p.fifo_errno, p.fifo_errno)}; needs root or CAP_SYS_NICE "
                f"(has it: {'yes' if p.cap_sys_nice else 'no'}), or an rtprio limit of at least {p.priority}: "
                f"ulimit -r is {_limit(p.rtprio_limit)}); {HOW_TO_RUN_WITHOUT}")
    if lock and p.mlock_errno is not None:
        return (f"realtime profile: memory locking not permitted "
                f"({errno.errorcode.get(p.mlock_errno, p.mlock_errno)} on mlock); {HOW_TO_RUN_WITHOUT}")
    if lock and not p.cap_ipc_lock and p.memlock_limit_bytes is not None:
        return (f"realtime profile: memory locking not permitted (mlockall needs root or CAP_IPC_LOCK, or an "
                f"unlimited memlock limit: ulimit -l is {_limit(p.memlock_limit_bytes, 'KiB')}); "
                f"{HOW_TO_RUN_WITHOUT}")
    return None


# --- shell: the real calls ---------------------------------------------------------

def _capabilities() -> int:
    """The effective capability set of this process (0 if unknown)."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("CapEff:"):
                    return int(line.split()[1], 16)
    except (OSError, ValueError):
        pass
    return 0


def _soft_limit(which: int) -> int | None:
    soft = resource.getrlimit(which)[0]
    return None if soft == resource.RLIM_INFINITY else soft


def _try_fifo(priority: int) -> int | None:
    """sched_setscheduler(SCHED_FIFO, priority) on a thread of its own, which then ends
    (a thread's policy is its own: nothing else of this process changes)."""
    result = []

    def attempt():
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            result.append(None)
        except OSError as exc:
            result.append(exc.errno or errno.EPERM)
    thread = threading.Thread(target=attempt, name="rt-profile-probe")
    thread.start()
    thread.join()
    # join returns when the Python thread is done, a moment before the kernel task of
    # that thread (SCHED_FIFO now) is gone: wait for it, so that none is left behind
    task = f"/proc/self/task/{thread.native_id}"
    deadline = time.monotonic() + 1.0
    while os.path.exists(task) and time.monotonic() < deadline:
        time.sleep(0.0005)
    return result[0]


def _try_mlock() -> int | None:
    """mlock and munlock of one page (a seccomp filter or a zero memlock limit say no)."""
    libc = ctypes.CDLL(None, use_errno=True)
    size = resource.getpagesize()
    buffer = ctypes.create_string_buffer(size)
    if libc.mlock(buffer, ctypes.c_size_t(size)) != 0:
        return ctypes.get_errno() or errno.EPERM
    libc.munlock(buffer, ctypes.c_size_t(size))
    return None


def probe_permissions(in_process: bool = False) -> Permissions:
    caps = _capabilities()
    lock = locks_memory(in_process)
    return Permissions(priority=highest_priority(in_process), fifo_errno=_try_fifo(highest_priority(in_process)),
                       rtprio_limit=_soft_limit(resource.RLIMIT_RTPRIO), cap_sys_nice=bool(caps >> _CAP_SYS_NICE & 1),
                       mlock_errno=_try_mlock() if lock else None,
                       memlock_limit_bytes=_soft_limit(resource.RLIMIT_MEMLOCK),
                       cap_ipc_lock=bool(caps >> _CAP_IPC_LOCK & 1))


def check_permitted(in_process: bool = False) -> None:
    """Raises RealtimeProfileRefused when this OS does not allow the profile."""
    message = refusal(probe_permissions(in_process), lock=locks_memory(in_process))
    if message is not None:
        raise RealtimeProfileRefused(message)


def child_environment(env: dict, s: Scheduling) -> dict:
    """``env`` for a node process of scheduling ``s``: with MEMORY_LOCK_ENV when it
    locks its memory, without it otherwise."""
    env = dict(env)
    env.pop(MEMORY_LOCK_ENV, None)
    if s.lock_memory:
        env[MEMORY_LOCK_ENV] = "1"
    return env


def set_scheduling(s: Scheduling, tid: int = 0) -> None:
    """The policy of ``s`` for thread ``tid`` (0: the calling one)."""
    os.sched_setscheduler(tid, _POLICIES[s.policy], os.sched_param(s.priority))


def preexec(s: Scheduling, before=None):
    """A ``preexec_fn`` for subprocess.Popen: ``before()`` (e.g. PR_SET_PDEATHSIG), then
    the policy of ``s`` for the child, which every thread it creates inherits. Runs in
    the child between fork and exec: an error there fails the Popen, so
    ``check_permitted`` runs first."""
    policy, param = _POLICIES[s.policy], os.sched_param(s.priority)    # made before the fork

    def apply():
        if before is not None:
            before()
        if s.policy != OTHER:
            os.sched_setscheduler(0, policy, param)
    return apply


def _threads() -> list[int]:
    try:
        return [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        return [threading.get_native_id()]


@contextlib.contextmanager
def applied_to_this_process(s: Scheduling = IN_PROCESS):
    """``s`` for every thread of this process (threads created inside inherit it from
    their creator) and its memory locked, for the block; then each thread's previous
    policy back (SCHED_OTHER for a thread made inside) and the memory unlocked.
    Raises OSError (the memory lock) before anything has changed."""
    if s.lock_memory:
        lock_memory()
    saved = {}
    try:
        for tid in _threads():
            with contextlib.suppress(OSError):            # a thread that has just ended
                saved[tid] = (os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority)
                set_scheduling(s, tid)
        yield
    finally:
        for tid in _threads():
            policy, priority = saved.get(tid, (os.SCHED_OTHER, 0))
            with contextlib.suppress(OSError):
                os.sched_setscheduler(tid, policy, os.sched_param(priority))
        if s.lock_memory:
            unlock_memory()
