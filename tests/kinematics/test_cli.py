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


# ------------------------------------------------------------------ bad input
# Every bad input: status 2 and one line "pkm-analyze: error: <field>: ..." on stderr,
# nothing on stdout, no traceback, no numpy message.
def assert_one_line_error(code, out, err, field):
    assert code == 2
    assert out == ""
    assert err.startswith(f"pkm-analyze: error: {field}") and err.count("\n") == 1, err
    assert "Traceback" not in err and "numpy" not in err


CONDITION = ["condition", "--machine", "archi", "--x", "1.0", "--y", "-0.4", "--theta-range", "-200", "200"]


BAD_ARGUMENTS = [  # argv, field, allowed range, value as printed
    (CONDITION + ["--samples", "0"], "--samples", "an integer >= 2", "0"),
    (CONDITION + ["--samples", "-3"], "--samples", "an integer >= 2", "-3"),
    (CONDITION + ["--samples", "1"], "--samples", "an integer >= 2", "1"),
    (CONDITION + ["--samples", "1e3"], "--samples", "an integer >= 2", "'1e3'"),
    (CONDITION + ["--x", "nan"], "--x", "a number in [-1000, 1000]", "nan"),
    (CONDITION + ["--y", "inf"], "--y", "a number in [-1000, 1000]", "inf"),
    (CONDITION + ["--x", "1e999"], "--x", "a number in [-1000, 1000]", "1e999"),
    (CONDITION + ["--x", "1e300"], "--x", "a number in [-1000, 1000]", "1e300"),
    (CONDITION + ["--theta-range", "nan", "200"], "--theta-range", "a finite number", "nan"),
    (CONDITION + ["--theta-range", "0", "inf"], "--theta-range", "a finite number", "inf"),
    (["resolution", "--machine", "mom3", "--points", "0"], "--points", "an integer >= 2", "0"),
    (["resolution", "--machine", "mom3", "--points", "-1"], "--points", "an integer >= 2", "-1"),
    (["orthoglide-size", "--cube", "nan", "--psi-min", "0.5", "--psi-max", "2"],
     "--cube", "a number in [1e-06, 1000]", "nan"),
    (["orthoglide-size", "--cube", "inf", "--psi-min", "0.5", "--psi-max", "2"],
     "--cube", "a number in [1e-06, 1000]", "inf"),
    (["orthoglide-size", "--cube", "-0.2", "--psi-min", "0.5", "--psi-max", "2"],
     "--cube", "a number in [1e-06, 1000]", "-0.2"),
    (["orthoglide-size", "--cube", "1e300", "--psi-min", "0.5", "--psi-max", "2"],
     "--cube", "a number in [1e-06, 1000]", "1e300"),
    (["orthoglide-size", "--cube", "0.2", "--psi-min", "nan", "--psi-max", "2"], "--psi-min", "a finite number", "nan"),
    (["orthoglide-size", "--cube", "0.2", "--psi-min", "0.5", "--psi-max", "inf"],
     "--psi-max", "a finite number", "inf"),
    (["workspace", "--machine", "archi", "--points", "0"], "--points", "an integer >= 2", "0"),
    (["workspace", "--machine", "archi", "--theta-points", "-1"], "--theta-points", "an integer >= 2", "-1"),
    (["gough-optimize", "--machine", "mom3", "--maxiter", "0"], "--maxiter", "an integer >= 1", "0"),
    (["gough-optimize", "--machine", "mom3", "--seed", "-1"], "--seed", "an integer in [0, 4294967295]", "-1"),
    (["gough-optimize", "--machine", "mom3", "--seed", str(2**32)], "--seed", "an integer in [0, 4294967295]",
     str(2**32)),
    (["report", "--points", "0"], "--points", "an integer >= 2", "0"),
    (["report", "--theta-points", "0"], "--theta-points", "an integer >= 2", "0"),
    (["report", "--resolution-points", "0"], "--resolution-points", "an integer >= 2", "0"),
]


@pytest.mark.parametrize("argv, field, allowed, got", BAD_ARGUMENTS,
                         ids=[f"{argv[0]} {field} {got}" for argv, field, _, got in BAD_ARGUMENTS])
def test_bad_argument_names_field_range_and_value(capsys, argv, field, allowed, got):
    code, out, err = run(capsys, *argv)
    assert_one_line_error(code, out, err, field)
    assert err == f"pkm-analyze: error: {field}: must be {allowed}, got {got}\n"


def test_missing_argument_is_one_line_not_usage(capsys):
    code, out, err = run(capsys, "condition", "--machine", "archi", "--y", "0", "--theta-range", "0", "1")
    assert_one_line_error(code, out, err, "the following arguments are required: --x")


@pytest.mark.parametrize("make", ["missing", "directory", "not utf-8"])
def test_unreadable_machine_file_names_machine(capsys, tmp_path, make):
    path = tmp_path / "x.yaml"
    if make == "directory":
        path.mkdir()
    elif make == "not utf-8":
        path.write_bytes(b"\xff\xfe")
    code, out, err = run(capsys, "condition", "--machine", str(path), "--x", "0", "--y", "0",
                         "--theta-range", "0", "1")
    assert_one_line_error(code, out, err, f"--machine: cannot read '{path}'")


def test_unreachable_pose_is_an_error_naming_pose_and_leg(capsys):
    code, out, err = run(capsys, "condition", "--machine", "archi", "--x", "5", "--y", "5",
                         "--theta-range", "-200", "200")
    assert_one_line_error(code, out, err, "--x, --y: pose x=5 m, y=5 m of archi is unreachable")
    assert "theta in [-200, 200] deg" in err
    assert "leg q1 platform point is 5 m from its rail, link_length is 1 m" in err
    assert "nan" not in err


def test_partly_unreachable_sweep_says_how_much(capsys):
    # y = -0.9: a platform point 0.2 m from C leaves the 1 m links' reach when |sin theta| > 0.5:
    # the open intervals (30, 150) and (-150, -30) deg hold 2 x 1199 of the 0.1 deg samples
    # (at |sin theta| = 0.5 exactly the link just reaches: reachable)
    code, out, _ = run(capsys, "condition", "--machine", "archi", "--x", "1.0", "--y", "-0.9",
                       "--theta-range", "-200", "200")
    assert code == 0 and "at 2398 of 4001 sampled angles (left out above)" in out and "nan" not in out


def test_unreachable_workspace_is_an_error(capsys, tmp_path):
    from pkm_kinematics.config import config_dir
    text = (config_dir() / "machines" / "archi.yaml").read_text()
    assert "  x: [0.6, 1.4]" in text
    path = tmp_path / "far.yaml"
    path.write_text(text.replace("  x: [0.6, 1.4]", "  x: [5.0, 6.0]"))
    for command in ("workspace", "report"):
        code, out, err = run(capsys, command, "--machine", str(path), "--points", "3", "--theta-points", "3")
        assert_one_line_error(code, out, err, "--machine: no pose of the workspace of archi")
        assert '"x": [5.0, 6.0]' in err and "27 poses sampled" in err
