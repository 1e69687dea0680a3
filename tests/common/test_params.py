"""pkm_common.params: typed, range-checked parameters; errors name the parameter and
the allowed range. Overrides come through ``--ros-args -p`` as on a command line."""

import math

import pytest

from pkm_common.params import (ParameterError, declare_bool, declare_float, declare_float_list,
                               declare_int, declare_str)

pytestmark = pytest.mark.ros


@pytest.fixture
def make_node(ros_context):
    from rclpy.node import Node
    nodes = []

    def make(*overrides):
        args = ['--ros-args'] + [a for o in overrides for a in ('-p', o)]
        node = Node(f'params_test_{len(nodes)}', context=ros_context, cli_args=args)
        nodes.append(node)
        return node

    yield make
    for node in nodes:
        node.destroy_node()


def test_float_default_override_and_descriptor(make_node):
    node = make_node('gain:=0.25')
    assert declare_float(node, 'gain', 0.5, 0.0, 1.0, 'a gain') == 0.25
    assert declare_float(node, 'other', 0.5, 0.0, 1.0) == 0.5
    desc = node.describe_parameter('gain')
    assert (desc.floating_point_range[0].from_value, desc.floating_point_range[0].to_value) == (0.0, 1.0)
    assert desc.description == 'a gain' and desc.read_only
    assert 'in [0, 1]' in desc.additional_constraints
    # read at start only: a later set is refused, not silently ignored
    from rclpy.parameter import Parameter
    result = node.set_parameters([Parameter('gain', Parameter.Type.DOUBLE, 0.3)])[0]
    assert not result.successful
    assert node.get_parameter('gain').value == 0.25


@pytest.mark.parametrize('override,kwargs,message', [
    ('noise_std_m:=-1.0', dict(lo=0.0, unit='m'), r"parameter 'noise_std_m': must be a number in \[0, inf\) m, got -1.0"),
    ('noise_std_m:=.nan', dict(lo=0.0), r"parameter 'noise_std_m': .* got nan"),
    ('noise_std_m:=2.0', dict(lo=0.0, hi=1e-3, unit='m'), r"in \[0, 0.001\] m, got 2.0"),
    ('noise_std_m:=0.0', dict(lo=0.0, lo_open=True), r"in \(0, inf\), got 0.0"),
    ('noise_std_m:=hello', dict(lo=0.0), r"parameter 'noise_std_m': must be a number in \[0, inf\), got 'hello'"),
])
def test_float_errors_name_the_parameter_and_range(make_node, override, kwargs, message):
    node = make_node(override)
    with pytest.raises(ParameterError, match=message) as info:
        declare_float(node, 'noise_std_m', 0.0, **kwargs)
    assert info.value.name == 'noise_std_m'
    assert isinstance(info.value, ValueError)


def test_integer_written_for_a_float_is_accepted(make_node):
    node = make_node('resolution_m:=0', 'limit:=3')
    value = declare_float(node, 'resolution_m', 1e-6, 0.0, 1e-3)
    assert value == 0.0 and isinstance(value, float)
    assert node.get_parameter('resolution_m').value == 0.0
    with pytest.raises(ParameterError, match=r"parameter 'limit': must be a number in \[0, 1\], got 3.0"):
        declare_float(node, 'limit', 0.5, 0.0, 1.0)


def test_int(make_node):
    node = make_node('seed:=42', 'bad:=-1', 'wrong:=1.5')
    assert declare_int(node, 'seed', 0, 0, 2**31 - 1) == 42
    assert declare_int(node, 'count', 7, 1, 10) == 7
    assert node.describe_parameter('seed').integer_range[0].to_value == 2**31 - 1
    with pytest.raises(ParameterError, match=r"parameter 'bad': must be an integer in \[0, 10\], got -1"):
        declare_int(node, 'bad', 0, 0, 10)
    with pytest.raises(ParameterError, match=r"parameter 'wrong': must be an integer in \[0, 10\], got 1.5"):
        declare_int(node, 'wrong', 0, 0, 10)


def test_str_with_choices(make_node):
    node = make_node('machine:=mom3', 'mode:=fast', 'empty:=""')
    assert declare_str(node, 'machine', 'archi', choices=['archi', 'mom3']) == 'mom3'
    with pytest.raises(ParameterError, match=r"parameter 'mode': must be one of \['lockstep', 'realtime'\], got 'fast'"):
        declare_str(node, 'mode', 'lockstep', choices=('lockstep', 'realtime'))
    with pytest.raises(ParameterError, match="parameter 'empty': must be a non-empty string, got ''"):
        declare_str(node, 'empty', 'x')
    assert declare_str(node, 'faults', '', allow_empty=True) == ''


def test_bool(make_node):
    node = make_node('flag:=true', 'bad:=3')
    assert declare_bool(node, 'flag', False) is True
    assert declare_bool(node, 'other', False) is False
    with pytest.raises(ParameterError, match="parameter 'bad': must be true or false, got 3"):
        declare_bool(node, 'bad', False)


def test_float_list(make_node):
    node = make_node('gains:=[1.0, 2.5, 3.0]', 'ints:=[1, 2]', 'short:=[1.0]',
                     'neg:=[0.5, -1.0]', 'pose:=[0.1, 0.2, 0.3]')
    assert declare_float_list(node, 'gains', [0.0, 0.0, 0.0], length=3) == [1.0, 2.5, 3.0]
    assert declare_float_list(node, 'ints', [0.0, 0.0], length=2) == [1.0, 2.0]
    assert declare_float_list(node, 'unset', [4.0], length=1) == [4.0]
    with pytest.raises(ParameterError, match=r"parameter 'short': must be a list of 2 numbers.*got 1 values"):
        declare_float_list(node, 'short', [0.0, 0.0], length=2)
    with pytest.raises(ParameterError, match=r"parameter 'neg': .*each in \[0, inf\), got -1.0 at index 1"):
        declare_float_list(node, 'neg', [0.0, 0.0], lo=0.0)
    # an empty default (untyped in ROS 2) still takes a list override, or stays empty
    assert declare_float_list(node, 'pose', []) == [0.1, 0.2, 0.3]
    assert declare_float_list(node, 'no_pose', []) == []


def test_nan_in_list_is_refused(make_node):
    node = make_node('gains:=[1.0, .nan]')
    with pytest.raises(ParameterError, match=r"parameter 'gains'.*got nan at index 1"):
        declare_float_list(node, 'gains', [0.0, 0.0])
    assert math.isnan(node.get_parameter('gains').value[1])   # declared, but not used
