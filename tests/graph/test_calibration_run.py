"""Calibrating a machine in three commands, end to end through pkm-calibrate's CLI: the
shipped ARCHI program is what `plan` writes today; a short MoM3 program planned here
(12 poses) run in the graph on mom3_calibration's Delta as built, `identify
--instrument gough` on its recording writes the calibrated file, whose lengths and
zeros are the plant's, and which the controller then loads as its model. A run of
another machine, without the instrument's stream, with dwells outside the workspace
or without dwells (of the length asked) is refused by name. (ARCHI's own calibration
run, and every model on its machine: pkm-gallery's archi_calibration, in make test.)"""

import pytest
import yaml

from pkm_bringup.orchestrator import run_scenario
from pkm_bringup.scenario import load_scenario
from pkm_calibration.cli import main
from pkm_calibration.recorded import read_calibration_run
from pkm_kinematics import load_machine
from pkm_kinematics.config import config_dir, load_machine_data

LENGTH_ERRORS = (0.002, -0.0015, 0.001)          # config/scenarios/mom3_calibration.yaml's plant
ZERO_ERRORS = (0.0005, -0.0008, 0.0003)


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    root = tmp_path_factory.mktemp("calibration")
    program = root / "mom3_short.nc"
    assert main(["plan", "mom3", "--instrument", "gough", "--poses", "12", "--candidates", "200", "--dwell-s", "0.3",
                 "--feed", "18000", "--out", str(program)]) == 0
    run = run_scenario(load_scenario("mom3_calibration", {"program": str(program)}), root / "run", in_process=True,
                       progress=False, report=False)
    return root, run


def test_the_shipped_program_is_what_plan_writes(tmp_path):
    out = tmp_path / "plan.nc"
    assert main(["plan", "archi", "--poses", "30", "--angle-half-range-deg", "180", "--dwell-s", "0.6",
                 "--feed", "30000", "--out", str(out)]) == 0
    shipped = (config_dir() / "programs" / "archi_calibration.nc").read_text()
    assert out.read_text() == shipped


def test_identify_writes_the_plants_geometry_and_the_controller_loads_it(calibration, capsys):
    root, run = calibration
    assert run["status"] == "completed", run["error"]
    out = root / "mom3.calibrated.yaml"
    assert main(["identify", "mom3", str(root / "run"), "--instrument", "gough", "--out", str(out),
                 "--label", "test"]) == 0
    printed = capsys.readouterr().out
    assert "the Gough metrology's tool pose" in printed and "held at nominal: b.z.q1, b.z.q2, b.z.q3" in printed, \
        printed
    data = yaml.safe_load(out.read_text())
    nominal = load_machine("mom3").data["legs"]
    parameters = data["calibration"]["parameters"]
    for k, leg in enumerate(data["legs"]):
        name = leg["name"]
        length, std = leg["link_length"] - nominal[k]["link_length"], parameters[f"length.{name}"]["std"]
        assert abs(length - LENGTH_ERRORS[k] * nominal[k]["link_length"]) < max(3 * std, 2e-6), (name, length, std)
        zero, std = leg["rail_origin"][2] - nominal[k]["rail_origin"][2], parameters[f"zero.{name}"]["std"]
        assert abs(zero - ZERO_ERRORS[k]) < max(3 * std, 2e-6), (name, zero, std)
    config = load_machine(out)
    assert config.model_label == "mom3 (calibrated: test)"
    fig19 = load_scenario("mom3_fig19", {"model": str(out)})
    assert fig19.controller_machine == str(out)


def test_runs_that_are_not_this_machines_calibration_are_refused(calibration, capsys):
    root, _ = calibration
    assert main(["identify", "archi", str(root / "run")]) == 2
    assert "a run of mom3, not of archi" in capsys.readouterr().err        # its run.json says so
    assert main(["identify", "mom3", str(root / "run"), "--instrument", "laser"]) == 2
    assert "the run recorded no laser readings (stream instrument)" in capsys.readouterr().err
    narrow = dict(load_machine("mom3").data, workspace={"center": [0.0, 0.0, 0.882], "size": 0.02})
    with pytest.raises(ValueError, match=r"is outside mom3's workspace \[.*\]: not a calibration of this machine"):
        read_calibration_run(root / "run", load_machine_data(narrow))
    assert main(["identify", "mom3", str(root / "run"), "--instrument", "gough", "--min-dwell-s", "5"]) == 2
    assert "0 dwells of at least 5 s found, 8 needed (is it a calibration program's run?)" in \
        capsys.readouterr().err
