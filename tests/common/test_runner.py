"""pkm_common.runner.run_node: exit codes and teardown (the SIGINT path is exercised
by the multi-process node tests)."""

import pytest

from pkm_common.params import ParameterError, declare_float
from pkm_common.runner import EXIT_BAD_PARAMETER, EXIT_ERROR, EXIT_OK, run_node

pytestmark = pytest.mark.ros


def _node(context, on_timer, **kwargs):
    from rclpy.node import Node
    node = Node('runner_test', context=context, **kwargs)
    node.create_timer(0.01, lambda: on_timer(node, context))
    return node


@pytest.mark.parametrize('executor', ['single', 'events'])
def test_shutdown_ends_the_loop_with_0(executor):
    seen = []

    def stop(node, context):
        seen.append(node.get_name())
        context.try_shutdown()

    assert run_node(lambda context: _node(context, stop), args=[], executor=executor) == EXIT_OK
    assert seen == ['runner_test']


def test_refused_parameter_exits_2(capfd):
    def factory(context):
        from rclpy.node import Node
        node = Node('runner_bad', context=context, cli_args=['--ros-args', '-p', 'gain:=-1.0'])
        try:
            declare_float(node, 'gain', 1.0, 0.0, 10.0)
        except ParameterError:
            node.destroy_node()
            raise
        return node

    assert run_node(factory, args=[], name='runner_bad') == EXIT_BAD_PARAMETER
    assert "parameter 'gain': must be a number in [0, 10], got -1.0" in capfd.readouterr().err


def test_exception_in_a_callback_exits_1(capfd):
    def boom(node, context):
        raise RuntimeError('boom in a timer')

    assert run_node(lambda context: _node(context, boom), args=[]) == EXIT_ERROR
    assert 'RuntimeError: boom in a timer' in capfd.readouterr().err
