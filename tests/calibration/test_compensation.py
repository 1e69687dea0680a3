"""Drive compensation tables: the interpolation and its slope against the closed form of
a piecewise-linear function, LinuxCNC comp files written and read back, a screw error
recovered from readings made here (compensation_fit), bad tables refused by name, and
the controller reading true positions through them."""

import numpy as np
import pytest

from pkm_calibration.compensation_fit import fit_table, fit_tables
from pkm_kinematics import load_machine
from pkm_kinematics.compensation import Compensation, DriveTable, comp_file_text, compensation_of, read_comp_file
from pkm_kinematics.config import load_machine_data
from pkm_kinematics.errors import ConfigError


def test_a_table_interpolates_and_holds_its_ends():
    table = DriveTable([0.0, 0.1, 0.3], [1e-5, -2e-5, 0.0])
    assert np.allclose(table.correction([0.05, 0.2, -1.0, 1.0]), [-0.5e-5, -1e-5, 1e-5, 0.0], atol=1e-15)
    assert np.allclose(table.slope([0.05, 0.2, -1.0, 1.0]), [-3e-4, 1e-4, 0.0, 0.0])
    comp = Compensation((table, None))
    assert np.allclose(comp.positions([0.05, 0.05]), [0.05 - 0.5e-5, 0.05])
    assert np.allclose(comp.velocities([0.05, 0.05], [2.0, 2.0]), [2.0 * (1 - 3e-4), 2.0])
    again = read_comp_file("# a comment\n" + comp_file_text(table, unit_m=1e-3), unit_m=1e-3)
    assert np.allclose(again.positions, table.positions) and np.allclose(again.corrections, table.corrections)


@pytest.mark.parametrize("rows, match", [([[0.0, 0.0]], "2 to 256"), ([[0.1, 0.0], [0.0, 0.0]], "ascending"),
                                         ([[0.0, 0.0], [0.1, 0.05]], "at most 0.01 m")])
def test_bad_tables_are_refused_naming_the_drive(rows, match):
    data = dict(load_machine("mom3").data, compensation={"q2": rows})
    with pytest.raises(ConfigError, match="compensation.q2: .*" + match):
        compensation_of(load_machine_data(data))
    with pytest.raises(ConfigError, match="'q9' is not a drive of mom3"):
        compensation_of(load_machine_data(dict(load_machine("mom3").data, compensation={"q9": [[0, 0], [1, 0]]})))


def test_a_screw_error_is_recovered_from_readings():
    """q* = q + A sin(2 pi q / P) sampled at 150 readings over 0.4 m: knots every 10 mm
    fit it within 1 um (a linear interpolant's error at that spacing: ~1 %% of A)."""
    rng = np.random.default_rng(3)
    q = rng.uniform(1.3, 1.7, size=(150, 2))
    error = np.column_stack((20e-6 * np.sin(2 * np.pi * q[:, 0] / 0.1), -15e-6 * np.sin(2 * np.pi * q[:, 1] / 0.1)))
    comp, before, after = fit_tables(q, q + error + 3e-6, 0.01)          # a constant: the geometry's zero
    grid = np.linspace(1.32, 1.68, 200)
    truth = 20e-6 * np.sin(2 * np.pi * grid / 0.1)
    fitted = comp.tables[0].correction(grid)
    assert np.abs((fitted - fitted.mean()) - (truth - truth.mean())).max() < 1.5e-6
    assert before.min() > 10e-6 and after.max() < 1e-6, (before, after)
    with pytest.raises(ValueError, match="spacing_m"):
        fit_table(q[:, 0], error[:, 0], 1e-5)


def test_the_controller_reads_true_positions_through_the_tables():
    from pkm_controller.controller import ControllerCore
    data = dict(load_machine("mom3").data, compensation={"q1": [[1.0, 2e-5], [2.0, 2e-5]]})
    core, plain = ControllerCore(load_machine_data(data)), ControllerCore(load_machine("mom3"))
    model = plain.model
    q = model.inverse_kinematics(model.home)
    plain.update(0, (q + [2e-5, 0.0, 0.0]).tolist(), [0.0] * 3)
    core.update(0, q.tolist(), [0.0] * 3)
    assert np.allclose(core.record.measured, plain.record.measured, atol=1e-12), (core.record.measured,
                                                                                 plain.record.measured)


def test_tables_are_read_in_the_files_unit_and_must_meet_the_joint_limits():
    """genhexkins is in inches: its table's positions and corrections too; a table
    off the drive's travel (metres in an inch file) is refused, as a pasted LinuxCNC
    triplet is."""
    data = dict(load_machine("genhexkins").data, compensation={"j0": [[18.0, 0.001], [42.0, 0.002]]})
    comp = compensation_of(load_machine_data(data))
    assert np.allclose(comp.positions([0.5, 0, 0, 0, 0, 0])[0], 0.5 + 0.0254 * 0.001)     # held: 0.5 m < 18 in
    assert np.isclose(comp.tables[0].correction(30 * 0.0254), 0.0254 * 0.0015)
    for rows, match in (([[0.4, 0.0], [1.0, 0.0]],
                         r"the table's positions \[0.4, 1\] miss the drive's joint limits \[18, 42\] \(inch\)"),
                        ([[18.0, 0.0, 0.0], [42.0, 0.0, 0.0]], "rows of \\[position, correction\\]")):
        with pytest.raises(ConfigError, match=r"compensation\.j0: " + match):
            compensation_of(load_machine_data(dict(load_machine("genhexkins").data, compensation={"j0": rows})))


def test_identify_takes_the_trackers_point_from_the_run_and_refuses_another(tmp_path):
    import json
    from pkm_calibration.procedure import _tool_of_run, identify_run
    (tmp_path / "run.json").write_text(json.dumps({"machine": "archi", "laser_tracker": {"tool": [0.1, 0.05, 0.0]}}))
    assert _tool_of_run(tmp_path, "laser", None) == (0.1, 0.05, 0.0)
    with pytest.raises(ValueError, match=r"tool: the run's laser tracker read the point \[0.1, 0.05, 0.0\] m of the "
                                         r"platform, not \[0.0, 0.0, -0.05\]"):
        _tool_of_run(tmp_path, "laser", (0.0, 0.0, -0.05))
    with pytest.raises(ValueError, match="table_spacing_m: archi: drive tables need an instrument that fixes"):
        identify_run(load_machine("archi"), tmp_path, None, table_spacing_m=0.02)
