"""pkm_common.domains: a domain ID per process, unique on the host while it lives."""

import os
import subprocess
import sys

import pytest

from pkm_common.domains import (DDS_PROFILE, DOMAIN_IDS, NoFreeDomain, claim_domain_id, domains_named_by_live_processes,
                                localhost_dds)

_CHILD = """
import sys, time
from pkm_common.domains import claim_domain_id
print(claim_domain_id(ids=range(int(sys.argv[1]), int(sys.argv[2])), lock_dir=sys.argv[3]), flush=True)
time.sleep(30)
"""


# IDs outside DOMAIN_IDS: no other process of this host (a parallel test worker's
# graph) names them in its environment
TEST_IDS = (150, 151, 152)


def _environment(**extra) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("PKM_TEST_ROS_DOMAIN_ID", "ROS_DOMAIN_ID")}
    return {**env, **extra}


def test_live_processes_never_share_an_id_and_a_dead_ones_id_is_free_again(tmp_path, monkeypatch):
    monkeypatch.delenv("PKM_TEST_ROS_DOMAIN_ID", raising=False)
    lo, hi = TEST_IDS[0], TEST_IDS[-1] + 1
    children = [subprocess.Popen([sys.executable, "-c", _CHILD, str(lo), str(hi), str(tmp_path)], env=_environment(),
                                 stdout=subprocess.PIPE, text=True) for _ in range(3)]
    try:
        ids = [int(c.stdout.readline()) for c in children]
        assert sorted(ids) == list(TEST_IDS)              # three live holders: all three IDs, once each
        children[1].kill()
        children[1].wait()
        # the kernel released the dead one's lock: its ID, and only it, is free again
        assert claim_domain_id(ids=TEST_IDS, lock_dir=str(tmp_path)) == ids[1]
    finally:
        for c in children:
            c.kill()
            c.wait()


def test_the_ids_map_to_valid_fast_dds_ports():
    assert 0 not in DOMAIN_IDS and max(DOMAIN_IDS) == 232 and all(i <= 101 or i >= 215 for i in DOMAIN_IDS)


def test_an_id_named_in_a_live_process_environment_is_not_claimed(tmp_path, monkeypatch):
    """A graph started by hand with ROS_DOMAIN_ID set, or the nodes of a run whose
    claiming process has ended (an orphan), hold no lock but use the domain."""
    monkeypatch.delenv("PKM_TEST_ROS_DOMAIN_ID", raising=False)
    used, free = 160, 161              # not TEST_IDS: the test above may run beside this one (xdist)
    orphan = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"],
                              env=_environment(ROS_DOMAIN_ID=str(used)))
    try:
        assert used in domains_named_by_live_processes()
        with pytest.raises(NoFreeDomain, match="named in their environment"):
            claim_domain_id(ids=[used], lock_dir=str(tmp_path), strict=True)
        assert claim_domain_id(ids=[used, free], lock_dir=str(tmp_path), strict=True) == free
    finally:
        orphan.kill()
        orphan.wait()
    assert used not in domains_named_by_live_processes()
    assert claim_domain_id(ids=[used], lock_dir=str(tmp_path), strict=True) == used


@pytest.mark.parametrize("given,expected", [
    ({}, {"range": "SYSTEM_DEFAULT", "profile": DDS_PROFILE}),                      # nothing asked: ours
    ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}, {"range": "SYSTEM_DEFAULT", "profile": DDS_PROFILE}),
    ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SYSTEM_DEFAULT", "FASTRTPS_DEFAULT_PROFILES_FILE": DDS_PROFILE},
     {"range": "SYSTEM_DEFAULT", "profile": DDS_PROFILE}),                           # ours again: unchanged
    ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}, {"range": "SUBNET", "profile": None}),   # asked: as asked
    ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SYSTEM_DEFAULT"}, {"range": "SYSTEM_DEFAULT", "profile": None}),
    ({"FASTRTPS_DEFAULT_PROFILES_FILE": "/etc/mine.xml"}, {"range": "LOCALHOST", "profile": "/etc/mine.xml"}),
    ({"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}, {"range": "LOCALHOST", "profile": None}),
    ({"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp", "ROS_AUTOMATIC_DISCOVERY_RANGE": "SYSTEM_DEFAULT",
      "FASTRTPS_DEFAULT_PROFILES_FILE": DDS_PROFILE}, {"range": "LOCALHOST", "profile": None}),   # ours inherited
    ({"ROS_LOCALHOST_ONLY": "1"}, {"range": "SYSTEM_DEFAULT", "profile": DDS_PROFILE}),   # deprecated: dropped
])
def test_a_graphs_dds_is_the_udp_localhost_profile_unless_the_user_asked_for_another(given, expected):
    env = localhost_dds({"PATH": "/bin", **given})
    assert env.get("ROS_AUTOMATIC_DISCOVERY_RANGE") == expected["range"], env
    assert env.get("FASTRTPS_DEFAULT_PROFILES_FILE") == expected["profile"], env
    assert "ROS_LOCALHOST_ONLY" not in env and env["PATH"] == "/bin"
    assert os.path.isfile(DDS_PROFILE)
