"""``run_node``: the ``main()`` of every PKM node.

rclpy.init with the process arguments (``--ros-args ...``), the node built by a
factory, a bounded spin loop (``spin_once(timeout_sec=...)`` while the context is ok:
the one call that works for SingleThreadedExecutor and EventsExecutor alike, see
ROS2_NOTES.md), then teardown in order: destroy the node, shut down the executor, then
the context.

Exit codes: 0 after SIGINT / SIGTERM (a flag ends the loop between callbacks, then
the ordered teardown; a KeyboardInterrupt is caught too); 2 when
the node refuses its parameters or configuration (ParameterError, or any ValueError
raised while it is built; logged as one line naming the parameter), or when the memory
lock asked for by ``PKM_MLOCKALL=1`` fails (pkm-run's realtime profile,
pkm_bringup.rt_profile); 1 for any other exception.
"""

from __future__ import annotations

import contextlib
import ctypes
import gc
import inspect
import os
import signal
import sys
import threading
from typing import Callable

import rclpy
import rclpy.signals
from rclpy.executors import ExternalShutdownException

from pkm_common.domains import use_localhost_dds
from pkm_kinematics.errors import FieldError

EXIT_OK, EXIT_ERROR, EXIT_BAD_PARAMETER = 0, 1, 2
EXECUTORS = ('single', 'events')
# "1": run_node locks the process's memory once the node is built (lock_memory)
MEMORY_LOCK_ENV = 'PKM_MLOCKALL'
# a directory: run_node profiles its spin loop (cProfile) into <dir>/<name>.prof
PROFILE_DIR_ENV = 'PKM_PROFILE_DIR'
_MCL_CURRENT, _MCL_FUTURE = 1, 2            # sys/mman.h


def _libc():
    return ctypes.CDLL(None, use_errno=True)


def lock_memory() -> None:
    """``mlockall(MCL_CURRENT | MCL_FUTURE)``: every page mapped now is faulted in and
    locked, and so is every later mapping when it is made, so that the loop never waits
    for a page (no swap-in, no reload of an evicted page of code, no first-touch fault
    of a page mapped before). Raises OSError (ENOMEM: over the memlock limit without
    CAP_IPC_LOCK, or out of memory; EPERM)."""
    if _libc().mlockall(_MCL_CURRENT | _MCL_FUTURE) != 0:
        err = ctypes.get_errno()
        raise OSError(err, f'mlockall(MCL_CURRENT | MCL_FUTURE): {os.strerror(err)}')


def unlock_memory() -> None:
    """``munlockall``: undoes lock_memory (an embedding process left as it was)."""
    _libc().munlockall()


def make_executor(kind: str, context):
    if kind == 'single':
        from rclpy.executors import SingleThreadedExecutor
        return SingleThreadedExecutor(context=context)
    if kind == 'events':
        from rclpy.experimental import EventsExecutor
        return EventsExecutor(context=context)
    raise FieldError('executor', f'must be one of {list(EXECUTORS)}, got {kind!r}')


def warm_log_caller_lookup() -> None:
    """rclpy's logger looks up the caller of every log call (rcutils_logger._find_caller:
    ``inspect.getframeinfo``), and a process's first lookup maps every loaded module to
    its file (``inspect.getmodule``: a realpath per module; 46 ms for the ~1400 modules of
    a graph's process on an idle host, over 100 ms on a loaded one). Done before the spin
    loop instead of inside the first callback that logs: sim_hw's and ros2_control's
    "loop started" at the first command held the real-time loop's first cycle that long,
    and the ros2_control interface's joint_states watchdog tripped on the silence
    (tests/common/test_runner.py). Later lookups map only modules imported since."""
    inspect.getframeinfo(inspect.currentframe())


@contextlib.contextmanager
def start_up_frozen(collect: bool = True):
    """The objects of start-up (modules, compiled kernels, the nodes) frozen out of the
    cyclic garbage collector for the block (``gc.freeze``), then returned to it. The loop
    allocates little, but each collection of the oldest generation scanned all of
    them on the loop's thread: in one process of archi_demo (~150,000 objects) the
    full collections took 86-182 ms each, the middle ones up to 9 ms.
    ``collect=False``: frozen as they are, without the collection first (one run of many
    in a long-lived process: a study's worker, ~230,000 objects, ~0.1 s a collection);
    what was garbage is collected after the block, as it would have been."""
    if collect:
        gc.collect()
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


@contextlib.contextmanager
def _profiled(name: str):
    """The block under cProfile when ``PKM_PROFILE_DIR`` names a directory (for
    experiments: where a node's loop spends its time, each node of a graph of processes
    in its own file, read with ``python -m pstats``); otherwise nothing."""
    directory = os.environ.get(PROFILE_DIR_ENV)
    if not directory:
        yield
        return
    import cProfile
    profiler = cProfile.Profile()
    profiler.enable()
    try:
        yield
    finally:
        profiler.disable()
        os.makedirs(directory, exist_ok=True)
        profiler.dump_stats(os.path.join(directory, f'{name}.prof'))


def run_node(factory: Callable, args=None, executor: str = 'single', name: str = 'node',
             spin_period_s: float = 0.1) -> int:
    """Build ``factory(context=ctx)`` and spin it until shutdown; returns the exit code.

    ``args`` are the command-line arguments (``sys.argv`` if None); ``name`` labels
    errors raised before the node (and its logger) exists.
    """
    return run_nodes([factory], args, executor, name, spin_period_s)


def run_nodes(factories: list, args=None, executor: str = 'single', name: str = 'node',
              spin_period_s: float = 0.1, done: Callable | None = None) -> int:
    """``run_node`` for several nodes in one process: each built in order on one
    context, all spun by one executor (a composition: still separate nodes exchanging
    messages), torn down in reverse order while the context is up (their last batches
    published); the loop ends on a signal, when the context is shut down, or when
    ``done(nodes)`` says so."""
    executor = os.environ.get('PKM_EXECUTOR', executor)     # for experiments: single | events
    use_localhost_dds()             # a node started by hand talks as a graph's nodes do
    context = rclpy.Context()
    # SIGINT/SIGTERM only set a flag, checked between two spin_once calls: the loop
    # ends at a callback boundary and the teardown runs in order. rclpy's own handlers
    # (options.ALL) shut the context down inside the signal handler instead, so a
    # callback running at that moment publishes on a dead context and the executor logs
    # it as FATAL; without any handler SIGTERM kills the process (status -15).
    stop = []
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda *_: stop.append(True))
    rclpy.init(args=args, context=context, signal_handler_options=rclpy.signals.SignalHandlerOptions.NO)
    nodes = []
    exec_ = None
    code = EXIT_OK
    locked = False
    try:
        try:
            for factory in factories:
                nodes.append(factory(context=context))
        except ValueError as exc:      # ParameterError, ConfigError: a refused configuration
            rclpy.logging.get_logger(name).error(str(exc))
            return EXIT_BAD_PARAMETER
        exec_ = make_executor(executor, context)
        for node in nodes:
            exec_.add_node(node)
        if os.environ.get(MEMORY_LOCK_ENV) == '1':
            try:
                lock_memory()
                locked = True
            except OSError as exc:
                nodes[0].get_logger().error(f'realtime profile: memory not locked: {exc}')
                return EXIT_BAD_PARAMETER
        warm_log_caller_lookup()
        with start_up_frozen(), _profiled(name):
            while context.ok() and not stop and not (done is not None and done(nodes)):
                exec_.spin_once(timeout_sec=spin_period_s)
    except (KeyboardInterrupt, ExternalShutdownException):
        code = EXIT_OK
    except Exception as exc:          # noqa: BLE001 - reported, then a non-zero exit
        logger = nodes[-1].get_logger() if nodes else rclpy.logging.get_logger(name)
        logger.fatal(f'{type(exc).__name__}: {exc}')
        code = EXIT_ERROR
    finally:
        try:
            for node in reversed(nodes):         # each torn down whatever another's teardown raised
                try:
                    try:
                        if exec_ is not None:
                            exec_.remove_node(node)
                    finally:
                        node.destroy_node()
                except Exception as exc:          # noqa: BLE001 - reported; the next node still goes
                    node.get_logger().error(f'teardown: {type(exc).__name__}: {exc}')
                    code = code or EXIT_ERROR
        finally:
            if exec_ is not None:
                exec_.shutdown()
            rclpy.try_shutdown(context=context)
            if locked:
                unlock_memory()
            for sig, handler in previous.items():     # leave an embedding process as it was
                signal.signal(sig, handler)
    return code


def main_exit(code: int) -> None:
    """``sys.exit`` with a flush first (logs of a dying process are not lost)."""
    sys.stdout.flush()
    sys.stderr.flush()
    sys.exit(code)
