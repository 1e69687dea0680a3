"""pkm-analyze: every documented command prints a table and valid JSON."""

import json

import pytest

from pkm_kinematics.cli import main


def run(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_condition_table_and_json(capsys):
    code, out, _ = run(capsys, "condition", "--machine", "archi", "--x", "1.0", "--y", "-0.4",
                       "--theta-range", "-200", "200")
    assert code == 0
    assert "J_124 singular at (deg)  -150.0000, 19.4712" in out
    code, out, _ = run(capsys, "--json", "condition", "--machine", "archi", "--x", "1.0", "--y", "-0.4",
                       "--theta-range", "-200", "200")
    data = json.loads(out)
    assert data["full_machine"]["condition_max"] == pytest.approx(11.4564, abs=1e-3)
    assert len(data["sub_machines"]) == 4


def test_resolution(capsys):
    code, out, _ = run(capsys, "--json", "resolution", "--machine", "mom3")
    data = json.loads(out)
    assert code == 0 and 5.5e-6 < data["position_m"] < 6.5e-6 and data["struts_within_limits"]


def test_orthoglide_size(capsys):
    code, out, _ = run(capsys, "orthoglide-size", "--cube", "0.2", "--psi-min", "0.5", "--psi-max", "2.0")
    assert code == 0 and "310.58 mm" in out and "256.99 mm" in out


@pytest.mark.parametrize("machine", ["archi", "sliding_star", "mom3", "orthoglide"])
def test_workspace_and_report(capsys, machine):
    code, out, _ = run(capsys, "--json", "workspace", "--machine", machine, "--points", "5", "--theta-points", "5")
    assert code == 0 and json.loads(out)["reachable_fraction"] == 1.0
    code, out, _ = run(capsys, "report", "--machine", machine, "--points", "5", "--theta-points", "5",
                       "--resolution-points", "3")
    assert code == 0 and f"Machine {machine}" in out


def test_errors_exit_2_with_the_field(capsys):
    code, _, err = run(capsys, "condition", "--machine", "mom3", "--x", "0", "--y", "0", "--theta-range", "0", "1")
    assert code == 2 and "--machine" in err
    code, _, err = run(capsys, "condition", "--machine", "archi", "--x", "0", "--y", "0", "--theta-range", "5", "1")
    assert code == 2 and "--theta-range" in err
    code, _, err = run(capsys, "orthoglide-size", "--cube", "0.2", "--psi-min", "2", "--psi-max", "3")
    assert code == 2 and "psi bounds" in err


def test_gough_optimize_runs(capsys):
    code, out, _ = run(capsys, "--json", "gough-optimize", "--machine", "mom3", "--maxiter", "2")
    data = json.loads(out)
    assert code == 0 and 0.0 < data["criterion_m"] < 1e-4
    assert 0.634 - 1e-6 <= data["strut_range"][0] and data["strut_range"][1] <= 1.080 + 1e-6
