"""pkm_common.domains: a domain ID per process, unique on the host while it lives."""

import os
import subprocess
import sys

from pkm_common.domains import DOMAIN_IDS, claim_domain_id

_CHILD = """
import sys, time
from pkm_common.domains import claim_domain_id
print(claim_domain_id(ids=range(int(sys.argv[1]), int(sys.argv[2])), lock_dir=sys.argv[3]), flush=True)
time.sleep(30)
"""


def test_live_processes_never_share_an_id_and_a_dead_ones_id_is_free_again(tmp_path, monkeypatch):
    monkeypatch.delenv("PKM_TEST_ROS_DOMAIN_ID", raising=False)
    env = {k: v for k, v in os.environ.items() if k != "PKM_TEST_ROS_DOMAIN_ID"}
    children = [subprocess.Popen([sys.executable, "-c", _CHILD, "1", "4", str(tmp_path)], env=env,
                                 stdout=subprocess.PIPE, text=True) for _ in range(3)]
    try:
        ids = [int(c.stdout.readline()) for c in children]
        assert sorted(ids) == [1, 2, 3]                  # three live holders: all three IDs, once each
        children[1].kill()
        children[1].wait()
        # the kernel released the dead one's lock: its ID, and only it, is free again
        assert claim_domain_id(ids=range(1, 4), lock_dir=str(tmp_path)) == ids[1]
    finally:
        for c in children:
            c.kill()
            c.wait()


def test_the_ids_map_to_valid_fast_dds_ports():
    assert 0 not in DOMAIN_IDS and max(DOMAIN_IDS) == 232 and all(i <= 101 or i >= 215 for i in DOMAIN_IDS)
