"""One private ROS 2 DDS domain per process (no rclpy; safe to import before it).

Test sessions (tests/conftest.py) and study workers (pkm_studies.study_engine) run
whole graphs side by side on one machine; each claims a domain ID that no other live
process on the host holds, so their runs never answer each other's states. The claim
is an exclusive ``flock`` on ``<lock dir>/<id>.lock``, held by an open file for the
life of the process and released by the kernel when it ends, even on a crash or a
``kill -9``. A process that names the ID in its environment holds it too: a graph
started by hand (``ROS_DOMAIN_ID=5 pkm-run ...``), or the nodes of a run whose
claiming process has ended (an orphan keeps its environment, not its parent's lock).
With discovery and traffic kept on localhost (:func:`localhost_dds`, applied by
:func:`use_private_domain`), processes on different hosts never meet whatever their
IDs, so the claim only needs to be unique per host.

Fast DDS on Linux maps IDs 0-101 and 215-232 to valid UDP ports (ROS 2 docs, "The
ROS_DOMAIN_ID"); 0 is everybody's default, so :data:`DOMAIN_IDS` leaves it out.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import random
import tempfile
import time

DOMAIN_IDS = tuple(range(1, 102)) + tuple(range(215, 233))
DDS_PROFILE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "fastdds_localhost_udp.xml")
PROFILE_ENV = "FASTRTPS_DEFAULT_PROFILES_FILE"     # Fast DDS 2.x (Jazzy's) reads its default profile here
RANGE_ENV = "ROS_AUTOMATIC_DISCOVERY_RANGE"
FASTDDS_RMW = "rmw_fastrtps_cpp"
LOCK_DIR = os.path.join(tempfile.gettempdir(), "pkm-ros-domain-locks")
FORCE_ENV = "PKM_TEST_ROS_DOMAIN_ID"           # forces an ID (to watch a run with a ROS tool)

_held: dict[int, int] = {}                      # domain ID -> the fd holding its lock (this process)


def domains_named_by_live_processes(proc_dir: str = "/proc") -> set[int]:
    """The ROS_DOMAIN_IDs in the environments of this host's live processes (this one
    left out; processes whose environment cannot be read are skipped). The environment
    is the one a process was started with: a child of a claiming process names the ID,
    the claiming process itself may not, and its lock covers it."""
    named, own = set(), str(os.getpid())
    try:
        pids = [p for p in os.listdir(proc_dir) if p.isdigit() and p != own]
    except OSError:
        return named
    for pid in pids:
        try:
            with open(os.path.join(proc_dir, pid, "environ"), "rb") as fh:
                environ = fh.read()
        except OSError:
            continue                             # ended meanwhile, or another user's
        for entry in environ.split(b"\0"):
            if entry.startswith(b"ROS_DOMAIN_ID="):
                with contextlib.suppress(ValueError):
                    named.add(int(entry[len(b"ROS_DOMAIN_ID="):]))
    return named


class NoFreeDomain(RuntimeError):
    """Every domain ID is held by a live process on this host (strict claims only)."""


def claim_domain_id(ids=DOMAIN_IDS, lock_dir: str = LOCK_DIR, strict: bool = False) -> int:
    """A domain ID no other live process on this host holds, locked for this process.

    IDs are tried from a random start, skipping those a live process names in its
    environment; the first whose lock file can be locked is ours. Where locking is not
    supported the first ID tried is taken unlocked; when every ID is held, one is shared
    rather than failing, unless ``strict`` (study workers: runs must never share a
    domain), which raises NoFreeDomain and ignores PKM_TEST_ROS_DOMAIN_ID."""
    forced = os.environ.get(FORCE_ENV)
    if forced and not strict:
        return int(forced)
    ids = list(ids)
    start = random.Random(os.getpid() ^ time.time_ns()).randrange(len(ids))
    ids = ids[start:] + ids[:start]
    named = domains_named_by_live_processes()
    try:
        os.makedirs(lock_dir, exist_ok=True)
        os.chmod(lock_dir, 0o1777)          # shared by all users, like /tmp
    except OSError:
        pass
    for domain_id in ids:
        if domain_id in named:
            continue                            # an unlocked user: a graph by hand, an orphan
        try:
            fd = os.open(os.path.join(lock_dir, f"{domain_id}.lock"), os.O_RDONLY | os.O_CREAT, 0o644)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            os.close(fd)
            if e.errno in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                continue                    # held by another live process
            if strict:
                raise NoFreeDomain(f"domain locks unsupported in {lock_dir}: {e}") from None
            return domain_id                # locking unsupported here: take it unlocked
        _held[domain_id] = fd
        return domain_id
    if strict:
        raise NoFreeDomain(f"all {len(ids)} ROS domain IDs are held by live processes on this host "
                           f"(locks in {lock_dir}, or named in their environment); fewer workers per host")
    return ids[0]


def localhost_dds(env: dict) -> dict:
    """The DDS settings of a graph's process, on localhost: ``env`` with them (a copy).

    With Fast DDS (Jazzy's default RMW) and no range or profile of the user's:
    :data:`DDS_PROFILE` (UDP on 127.0.0.1 only, no shared memory: the file says why) as
    Fast DDS's default profile, and ``ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT`` so
    that rmw_fastrtps takes it as it is (``LOCALHOST`` makes rmw_fastrtps add its own
    shared-memory transport). ``LOCALHOST`` asked for explicitly is taken to mean this.
    Another range asked for (a machine whose nodes run on two hosts), another RMW or a
    profile of the user's: left as asked, with ``LOCALHOST`` where no range is.
    """
    env = dict(env)
    env.pop("ROS_LOCALHOST_ONLY", None)              # deprecated in Jazzy, warns
    asked = env.get(RANGE_ENV, "")
    profile = env.get(PROFILE_ENV) or DDS_PROFILE
    fast_dds = (env.get("RMW_IMPLEMENTATION") or FASTDDS_RMW) == FASTDDS_RMW
    on_localhost = asked in ("", "LOCALHOST") or (asked == "SYSTEM_DEFAULT" and env.get(PROFILE_ENV) == DDS_PROFILE)
    if fast_dds and on_localhost and profile == DDS_PROFILE:
        env[PROFILE_ENV], env[RANGE_ENV] = DDS_PROFILE, "SYSTEM_DEFAULT"
    elif not asked or (on_localhost and env.get(PROFILE_ENV) == DDS_PROFILE):
        if env.get(PROFILE_ENV) == DDS_PROFILE:
            # ours, inherited by a process on another RMW: SYSTEM_DEFAULT would be that
            # RMW's own default (multicast on every interface), not this profile
            del env[PROFILE_ENV]
        env[RANGE_ENV] = "LOCALHOST"
    return env


def use_localhost_dds() -> None:
    """:func:`localhost_dds` applied to this process's environment (before its first
    rclpy context: Fast DDS and rcl read it then)."""
    dds = localhost_dds(os.environ)
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    os.environ.update({k: dds[k] for k in (RANGE_ENV, PROFILE_ENV) if k in dds})


def use_private_domain(ids=DOMAIN_IDS, lock_dir: str = LOCK_DIR, strict: bool = False) -> int:
    """Claim a domain for this process (once: later calls return the same ID) and set
    the environment every rclpy context and child process of it reads."""
    current = os.environ.get("ROS_DOMAIN_ID")
    if _held and current and int(current) in _held:
        return int(current)
    domain_id = claim_domain_id(ids, lock_dir, strict)
    os.environ["ROS_DOMAIN_ID"] = str(domain_id)
    os.environ.pop("ROS_STATIC_PEERS", None)
    os.environ.pop(RANGE_ENV, None)                 # a private domain is on this host: ours
    use_localhost_dds()
    return domain_id
