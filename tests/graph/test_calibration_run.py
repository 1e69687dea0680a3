"""Calibrating a machine in three commands, end to end through pkm-calibrate's CLI: the
shipped ARCHI program is what `plan` writes today; a short MoM3 program planned here
(12 poses) run in the graph on mom3_calibration's Delta as built, `identify
--instrument gough` on its recording writes the calibrated file, whose lengths and
zeros are the plant's, and which the controller then loads as its model. A run of
another machine, without the instrument's stream, with dwells outside the workspace
or without dwells (of the length asked) is refused by name. (ARCHI's own calibration
run, and every model on its machine: pkm-gallery's archi_calibration, in make test.)"""

import numpy as np
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


@pytest.fixture(scope="module")
def miscalibrated_gough_run(calibration):
    """The same program, the Gough's own joints off by 0.2 mm (per axis, std)."""
    root, _ = calibration
    scenario = load_scenario("mom3_calibration", {"program": str(root / "mom3_short.nc"),
                                                  "sensor": {"calibration_error_m": 2e-4, "seed": 3}})
    run = run_scenario(scenario, root / "gough_off", in_process=True, progress=False, report=False)
    assert run["status"] == "completed", run["error"]
    return root / "gough_off"


def _identified(out):
    data = yaml.safe_load(out.read_text())
    return data, data["calibration"]["parameters"]


def test_a_miscalibrated_gough_read_strut_by_strut_is_identified_with_the_machine(miscalibrated_gough_run, capsys):
    """Its pose (the sensor's forward kinematics on its nominal joints) carries the
    joints' errors into the machine's model; its struts, with its joints identified
    too, explain every reading. The encoders' zeros then share one offset: the datum
    (where the tool is against the Gough's held joints), the rest within their std."""
    run_dir, out = miscalibrated_gough_run, miscalibrated_gough_run / "pose.yaml"
    assert main(["identify", "mom3", str(run_dir), "--instrument", "gough", "--out", str(out)]) == 0
    pose_fit = capsys.readouterr().out
    out = run_dir / "struts.yaml"
    assert main(["identify", "mom3", str(run_dir), "--instrument", "gough-struts", "--out", str(out)]) == 0
    struts_fit = capsys.readouterr().out
    assert "its own joints identified too" in struts_fit and "gough.plate.1.x" in struts_fit
    after = [float(text.split("residual RMS ")[1].split(" -> ")[1].split(" um")[0]) for text in (pose_fit, struts_fit)]
    assert after[0] > 10.0 and after[1] < 1.0, after               # um: what each model leaves unexplained
    data, parameters = _identified(out)
    nominal = load_machine("mom3").data["legs"]
    zeros = []
    for k, leg in enumerate(data["legs"]):
        name = leg["name"]
        length, std = leg["link_length"] - nominal[k]["link_length"], parameters[f"length.{name}"]["std"]
        assert abs(length - LENGTH_ERRORS[k] * nominal[k]["link_length"]) < max(3 * std, 2e-6), (name, length, std)
        zeros.append((leg["rail_origin"][2] - nominal[k]["rail_origin"][2] - ZERO_ERRORS[k],
                      parameters[f"zero.{name}"]["std"]))
    datum = np.mean([z for z, _ in zeros])
    assert all(abs(z - datum) < 3 * std for z, std in zeros), (datum, zeros)
    assert abs(datum) < 3 * 2e-4, datum
    offsets = data["metrology"]["geometry"]["joint_offsets"]
    assert np.abs(offsets["base"]).max() > 1e-4 and np.abs(offsets["plate"]).max() == 0.0   # plate: held
    assert load_machine(out).metrology.platform.base_points.shape == (6, 3)


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
