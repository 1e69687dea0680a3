"""The DDS of a graph's processes (pkm_common.domains.localhost_dds): every socket on
127.0.0.1, no Fast DDS shared-memory segment (whose port health check stalled running
loops for 333 ms whenever a process joined), and the processes still talk. Checked on
a child process from the kernel's own tables (/proc), against a child on rmw's plain
LOCALHOST range, which maps the shared memory."""

import os
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest

from pkm_bringup.processes import ros_environment
from pkm_common.domains import DDS_PROFILE

pytestmark = pytest.mark.ros

_TALKER = """
import sys, time
import rclpy
from std_msgs.msg import String
rclpy.init()
node = rclpy.create_node("dds_profile_talker")
pub = node.create_publisher(String, "/dds_profile_test", 10)
print("up", flush=True)
for k in range(int(float(sys.argv[1]) / 0.02)):
    pub.publish(String(data=f"hello {k}"))
    time.sleep(0.02)
"""


def _udp_sockets(pid: int) -> list[tuple[str, int]]:
    """(address, port) of each UDP socket the process ``pid`` holds (/proc/net/udp by inode)."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    found = []
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            fields = line.split()
            if fields[9] in inodes:
                address, port = fields[1].split(":")
                if table.endswith("6"):
                    found.append((address, int(port, 16)))          # any IPv6 socket is reported as is
                else:
                    found.append((socket.inet_ntoa(struct.pack("<I", int(address, 16))), int(port, 16)))
    return found


def _shared_memory(pid: int) -> list[str]:
    return sorted({line.split()[-1] for line in Path(f"/proc/{pid}/maps").read_text().splitlines()
                   if "/dev/shm/fastrtps" in line})


def _start_talker(env: dict, seconds: float) -> subprocess.Popen:
    talker = subprocess.Popen([sys.executable, "-c", _TALKER, str(seconds)], env=env, stdout=subprocess.PIPE, text=True)
    assert talker.stdout.readline().strip() == "up"
    time.sleep(0.5)                                     # its transports are open once discovery has run
    return talker


def test_a_graph_process_talks_over_udp_on_127_0_0_1_only_without_shared_memory(ros_graph):
    from std_msgs.msg import String

    env = ros_environment()
    assert env["FASTRTPS_DEFAULT_PROFILES_FILE"] == DDS_PROFILE and env["ROS_DOMAIN_ID"] == os.environ["ROS_DOMAIN_ID"]
    got = []
    listener = ros_graph.create_node("dds_profile_listener")
    listener.create_subscription(String, "/dds_profile_test", got.append, 10)
    talker = _start_talker(env, 6.0)
    try:
        ros_graph.spin_until(lambda: len(got) >= 5, timeout_sec=5.0)
        sockets, shm = _udp_sockets(talker.pid), _shared_memory(talker.pid)
    finally:
        talker.kill()
        talker.wait()
    assert len(got) >= 5, len(got)                        # this process (same profile) hears it
    assert sockets and all(address == "127.0.0.1" for address, _ in sockets), sockets
    assert not shm, shm


def test_rmw_s_own_localhost_range_maps_fast_dds_shared_memory():
    """The reference the test above stands against: what the profile removes is there
    without it."""
    env = {k: v for k, v in ros_environment().items() if k != "FASTRTPS_DEFAULT_PROFILES_FILE"}
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    talker = _start_talker(env, 2.0)
    try:
        shm = _shared_memory(talker.pid)
    finally:
        talker.kill()
        talker.wait()
    assert shm, "rmw_fastrtps on LOCALHOST mapped no /dev/shm/fastrtps segment"
