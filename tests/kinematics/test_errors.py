"""One error vocabulary for refused values (pkm_kinematics.errors.FieldError): the
field's name, what is allowed and what came travel as attributes, so that whoever
reports the error under another name (a node's parameter, a scenario key) reads them
instead of splitting the message."""

import pickle
import subprocess
import sys

import pytest

from pkm_controller.config import ControllerConfig
from pkm_controller.configuration import core_from_parameters
from pkm_kinematics import load_machine
from pkm_kinematics.errors import ConfigError, FieldError, KinematicsError, ParameterError
from pkm_kinematics.yaml_files import UnreadableFileError
from pkm_trajectory.gcode import GcodeError


def test_a_field_error_carries_its_field_and_says_it():
    exc = FieldError.out_of_range("bandwidth_hz", "in (0, 250] Hz", -3.0)
    assert (exc.name, exc.allowed, exc.got) == ("bandwidth_hz", "in (0, 250] Hz", -3.0)
    assert str(exc) == "bandwidth_hz: must be in (0, 250] Hz, got -3.0" and isinstance(exc, ValueError)
    exc = ParameterError("dt_s", "must be in (0, 0.1] s, got 0.5")
    assert str(exc) == "parameter 'dt_s': must be in (0, 0.1] s, got 0.5" and isinstance(exc, FieldError)
    assert (exc.name, exc.detail) == ("dt_s", "must be in (0, 0.1] s, got 0.5")
    exc = ConfigError("legs[2].link_length", "must be > 0")
    assert isinstance(exc, KinematicsError) and isinstance(exc, FieldError) and exc.field == exc.name


@pytest.mark.parametrize("error", [FieldError.out_of_range("dt_s", "in (0, 0.1] s", 0.5),
                                   ParameterError("dt_s", "must be in (0, 0.1] s, got 0.5"),
                                   ConfigError("legs[2].link_length", "must be > 0"),
                                   GcodeError(12, "G18: arcs in the XZ plane are refused"),
                                   UnreadableFileError("archi.yaml", "not UTF-8")])
def test_an_error_crosses_a_process_boundary_whole(error):
    """A study's worker raises it on one process and the client reads it on another
    (Dask pickles it): the class, the message and the fields come across."""
    back = pickle.loads(pickle.dumps(error))
    assert type(back) is type(error) and str(back) == str(error)
    assert vars(back) == vars(error)


def test_the_controllers_refusals_name_their_field():
    with pytest.raises(FieldError) as info:
        ControllerConfig(bandwidth_hz=-1.0).validate(4, True)
    assert info.value.name == "bandwidth_hz" and info.value.got == -1.0, info.value
    # the node names the ControllerConfig field as its parameter, read from the error
    with pytest.raises(ParameterError) as info:
        core_from_parameters("archi", ControllerConfig(damping_ratio=-0.5))
    assert info.value.name == "damping_ratio" and "got -0.5" in info.value.detail, info.value
    # what the machine cannot do with a setting is named by the setting
    with pytest.raises(ParameterError) as info:
        core_from_parameters("sliding_star", ControllerConfig(strategy="sensor_space"))
    assert info.value.name == "strategy" and "metrology" in info.value.detail, info.value
    with pytest.raises(ParameterError) as info:
        core_from_parameters("no_such_machine", ControllerConfig())
    assert info.value.name == "machine", info.value


def test_the_errors_load_no_model():
    """Every package raises these: importing them loads no machine model and no
    compiled kernel (pkm_kinematics' names are imported when first used)."""
    code = ("import sys, pkm_kinematics.errors; "
            "print(sorted(m for m in sys.modules if m.startswith(('pkm_kinematics.', 'numba'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "['pkm_kinematics.errors']", out
    assert load_machine("archi").name == "archi"


def test_every_kernel_code_has_its_description():
    """Each compiled kernel family's outcomes are an IntEnum with a description per
    member (Ruckig's Result), and the ints the kernels read are those members."""
    from pkm_controller.laws import CYCLE_CODES, CycleCode
    from pkm_kinematics import bars, planar
    from pkm_kinematics.distribution import DISTRIBUTION_CODES, DistributionCode
    for enum, table in ((CycleCode, CYCLE_CODES), (DistributionCode, DISTRIBUTION_CODES), (bars.IKCode, bars.IK_CODES),
                        (bars.VelocityTermsCode, bars.VELOCITY_TERMS_CODES),
                        (bars.ThreeSpheresCode, bars.THREE_SPHERES_CODES)):
        assert set(table) == set(enum) and all(table.values()), enum
    assert set(planar.FK_REASONS) == set(planar.PlanarFKCode) - {planar.PlanarFKCode.CONVERGED,
                                                                   planar.PlanarFKCode.UNREACHABLE}
    assert (bars.IK_UNREACHABLE, bars.VT_SINGULAR, bars.TRI_OTHER_BRANCH, planar.FK_PAIR) == (
        bars.IKCode.UNREACHABLE, bars.VelocityTermsCode.SINGULAR, bars.ThreeSpheresCode.OTHER_BRANCH,
        planar.PlanarFKCode.PAIR)
