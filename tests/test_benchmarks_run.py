"""Every benchmark of ``make bench`` runs: each is started as ``make bench`` starts it,
with its smallest sizes, and must exit 0 and print its table. A benchmark that no
longer matches the code it measures (a callback that now takes bytes, a renamed
function) fails here instead of in the next ``make bench`` (issue 20: one did).
The figures themselves are not checked: speed targets live in benchmarks/."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from pkm_bringup.processes import ros_environment
from pkm_common.domains import DDS_PROFILE, NoFreeDomain, claim_domain_id

ROOT = Path(__file__).resolve().parents[1]

# benchmark -> (arguments that make it small, a line its output must have)
SMALL = {
    "kinematics.py": (["--repeat", "1"], "benchmark"),
    "drives.py": (["--cycles", "50"], "| archi | 4 |"),
    "drive_limited.py": (["--segments", "60"], "| genhexkins tilt"),
    "calibration.py": (["--poses", "20", "--repeat", "1"], "| genhexkins, laser tracker"),
    "hexapod.py": (["--repeat", "1", "--readings", "200"], "| genhexkins hexapod | ours, compiled stream"),
    "gough_sensor.py": (["--repeat", "1", "--cycles", "50"], "node callback"),
    "trajectory.py": (["--lines", "40", "--repeat", "1"], "ARCHI test motion"),
    "controller.py": (["--cycles", "40", "--graph-duration", "0.3"], "| mom3 | measured_space"),
    "plant.py": (["--duration", "0.05"], "steps/s"),
    "hexapod_graph.py": (["--pairs", "1", "--duration-s", "0.3", "--in-process"], "median ratio hexapod / ARCHI"),
    "lockstep_echo.py": ([], "steps/s"),
    "report_memory.py": (["--seconds", "0.5"], "MiB"),
    "realtime.py": (["--pairs", "1", "--rates", "1000", "--duration-s", "0.3", "--in-process"], "ratio"),
    "rt_floor.py": (["--steps", "200"], "chain floor:"),
    "study.py": (["--runs", "3", "--direct-runs", "3", "--duration-s", "0.2", "--variants", "2000", "--workers", "1"],
                 "Pareto front"),
    "engine.py": (["--repeat", "1", "--duration-s", "0.2"], "| direct |"),
    "startup.py": (["--repeat", "1", "--modes", "in-process"], "pkm-run --help"),
    "bringup.py": (["--windows-only", "--window-modes", "in-process", "--window-runs", "1",
                    "--window-length-s", "6"], "in-process"),
}


def test_every_benchmark_is_listed():
    found = {p.name for p in (ROOT / "benchmarks").glob("*.py")} - {"hoststat.py", "baseline.py"}
    assert found == set(SMALL), found ^ set(SMALL)


def test_a_baseline_checkout_runs_its_own_code_or_is_refused(tmp_path, monkeypatch):
    """benchmarks/baseline.py (--baseline DIR): the child imports the checkout's packages
    first; a directory whose src/ lacks them would have measured this checkout's code
    through its editable install: refused, naming where it came from."""
    monkeypatch.syspath_prepend(str(ROOT / "benchmarks"))
    from baseline import run_baseline
    code = 'import json, pkm_bringup; print(json.dumps({"at": pkm_bringup.__file__}))'
    assert run_baseline(ROOT, code)["at"].startswith(str(ROOT / "src"))
    (tmp_path / "src" / "pkm_other").mkdir(parents=True)
    with pytest.raises(SystemExit, match="imported pkm_bringup from .*, not the checkout"):
        run_baseline(tmp_path, code)


def test_a_benchmark_graph_runs_in_a_domain_it_holds_apart_from_the_test_that_starts_it():
    """plant.py and controller.py picked a random unlocked ROS_DOMAIN_ID in 40-101: started
    here, one landed in the other xdist worker's domain, and its /pkm/sim_hw and
    /pkm/hold_controller met that worker's gallery run (the intruder guards stopped it)."""
    env = ros_environment(own_domain=True)
    domain = int(env["ROS_DOMAIN_ID"])
    assert domain != int(os.environ["ROS_DOMAIN_ID"])            # not this worker's
    assert env["FASTRTPS_DEFAULT_PROFILES_FILE"] == DDS_PROFILE               # on localhost (localhost_dds)
    assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "SYSTEM_DEFAULT"
    with pytest.raises(NoFreeDomain):                             # held: nobody else claims it
        claim_domain_id(ids=[domain], strict=True)
    # and no benchmark names a domain of its own choosing
    for path in (ROOT / "benchmarks").glob("*.py"):
        assert not re.search(r"ROS_DOMAIN_ID\s*=|domain_id\s*=\s*\d|randint", path.read_text()), path.name


# SCHED_FIFO loops (the realtime profile): alone on the machine (conftest.realtime_loop_alone)
REALTIME = {"realtime.py", "rt_floor.py"}


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(set(SMALL) - REALTIME))
def test_the_benchmark_runs(name):
    _runs(name)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(REALTIME))
def test_the_realtime_benchmark_runs(name, realtime_loop_alone):
    _runs(name)


def _runs(name):
    args, expected = SMALL[name]
    out = subprocess.run([sys.executable, str(ROOT / "benchmarks" / name), *args], cwd=ROOT, capture_output=True,
                         text=True, timeout=240)
    assert out.returncode == 0, f"{name} exited {out.returncode}:\n{out.stdout[-2000:]}\n{out.stderr[-3000:]}"
    assert expected in out.stdout, out.stdout[-2000:]
