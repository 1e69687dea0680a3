"""pkm_common.runner.run_node: exit codes and teardown (the SIGINT path is exercised
by the multi-process node tests)."""

import gc
import subprocess
import sys
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


# A fresh interpreter (this one's lookups are warm already): the realpath calls of its
# first rclpy log call, made cold, after warm_log_caller_lookup, or in a node's first
# callback under run_node (which warms before its loop).
_FIRST_LOG = """
import os, sys
import rclpy.logging
import numpy, scipy.linalg                      # a process with many modules, as a node's
from pkm_common.runner import run_node, warm_log_caller_lookup
calls, real = [], os.path.realpath

def counted(log):
    os.path.realpath = lambda path, *a, **k: calls.append(path) or real(path, *a, **k)
    log.info("the process's first log call")
    os.path.realpath = real
    print(len(calls), len(sys.modules), flush=True)

if sys.argv[1] == "run_node":
    from rclpy.node import Node
    def factory(context):
        node = Node("first_log", context=context)
        node.create_timer(0.01, lambda: counted(node.get_logger()) or context.try_shutdown())
        return node
    sys.exit(run_node(factory, args=[]))
if sys.argv[1] == "warm":
    warm_log_caller_lookup()
counted(rclpy.logging.get_logger("first_log"))
"""


def _first_log_realpaths(mode: str) -> tuple[int, int]:
    done = subprocess.run([sys.executable, "-c", _FIRST_LOG, mode], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr[-2000:]
    calls, modules = map(int, done.stdout.split())
    return calls, modules


def test_a_nodes_first_log_call_does_not_map_every_module_inside_its_loop():
    """rclpy finds each log call's caller with inspect, whose first lookup maps every
    loaded module to its file: ~50 ms inside the real-time loop's first cycle (sim_hw's
    "loop started"), which tripped ros2_control's joint_states watchdog."""
    cold, modules = _first_log_realpaths("cold")
    assert cold > modules / 2, (cold, modules)                   # one realpath per module
    for mode in ("warm", "run_node"):
        calls, _ = _first_log_realpaths(mode)
        assert calls < 20, (mode, calls, cold)
