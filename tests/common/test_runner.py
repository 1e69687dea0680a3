"""pkm_common.runner.run_node: exit codes and teardown (the SIGINT path is exercised
by the multi-process node tests)."""

import gc
import weakref

import pytest

from pkm_common.params import ParameterError, declare_float
from pkm_common.runner import EXIT_BAD_PARAMETER, EXIT_ERROR, EXIT_OK, run_node, start_up_frozen

pytestmark = pytest.mark.ros


def _node(context, on_timer, **kwargs):
    from rclpy.node import Node
    node = Node('runner_test', context=context, **kwargs)
    node.create_timer(0.01, lambda: on_timer(node, context))
    return node


class _Cycle:
    def __init__(self):
        self.me = self


def test_the_start_up_heap_is_frozen_for_the_loop_and_returned_after():
    assert gc.get_freeze_count() == 0
    before = _Cycle()
    with start_up_frozen():
        assert gc.get_freeze_count() > 1000          # the interpreter's and pytest's objects at least
        made_in_the_loop = _Cycle()
        ref = weakref.ref(made_in_the_loop)
        del made_in_the_loop
        gc.collect()
        assert ref() is None                         # cycles of the loop are still collected
        before_ref = weakref.ref(before)
        del before
        gc.collect()
        assert before_ref() is not None              # a frozen cycle is not
    assert gc.get_freeze_count() == 0
    gc.collect()
    assert before_ref() is None                      # ... until it is returned


@pytest.mark.parametrize('executor', ['single', 'events'])
def test_shutdown_ends_the_loop_with_0(executor):
    seen = []
    assert gc.get_freeze_count() == 0

    def stop(node, context):
        seen.append((node.get_name(), gc.get_freeze_count() > 1000))     # the loop runs frozen
        context.try_shutdown()

    assert run_node(lambda context: _node(context, stop), args=[], executor=executor) == EXIT_OK
    assert seen == [('runner_test', True)]
    assert gc.get_freeze_count() == 0                # an embedding process is left as it was


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


def test_without_the_collection_the_garbage_of_before_is_frozen_with_the_rest_and_collected_after():
    garbage = _Cycle()
    ref = weakref.ref(garbage)
    del garbage                                       # unreachable, not yet collected
    with start_up_frozen(collect=False):
        assert gc.get_freeze_count() > 1000
        gc.collect()
        assert ref() is not None                     # frozen as it was: a study's run pays no full collection
    assert gc.get_freeze_count() == 0
    gc.collect()
    assert ref() is None
