"""Session-wide test setup: a private ROS 2 DDS domain and rclpy fixtures.

Importing this file (pytest does it before collecting any test module) sets
``ROS_DOMAIN_ID`` and the DDS profile (pkm_common.domains.localhost_dds) in ``os.environ`` so
that every rclpy context of this session, and every process it starts, talks
only inside its own domain on localhost. Parallel pytest runs on one machine
(two developers, CI beside a developer) therefore never see each other's nodes.

Fixtures:

- ``ros_context``: a fresh ``rclpy.Context`` per test, initialised and shut
  down around the test.
- ``ros_graph``: nodes plus an executor on that context, with
  ``spin_until(predicate)`` (foreground) or ``start()`` (background thread),
  torn down in the right order: stop spinning, destroy nodes, shut down the
  executor, then the context. Parametrize it indirectly with ``'single'``
  (SingleThreadedExecutor, the default) or ``'events'`` (EventsExecutor,
  always driven by ``spin_once(timeout_sec=...)``; its ``spin()`` hangs).
"""

import contextlib
import os
import threading
import time

import pytest

# --- DDS domain isolation (must run before rclpy is imported anywhere) -------
# One domain per session (per pytest-xdist worker), locked for the process's life by
# pkm_common.domains (flock in $TMPDIR/pkm-ros-domain-locks, released by the kernel
# even after a crash); PKM_TEST_ROS_DOMAIN_ID forces an ID.
from pkm_common.domains import use_private_domain  # noqa: E402  (no rclpy inside)

ROS_DOMAIN_ID = use_private_domain()


def pytest_collection_modifyitems(config, items):
    """A test that takes ``realtime_loop_alone`` is marked ``realtime`` (make test runs
    those after the others, one at a time)."""
    for item in items:
        if "realtime_loop_alone" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.realtime)


def pytest_report_header(config):
    return (f'ROS_DOMAIN_ID={ROS_DOMAIN_ID}, DDS on localhost over UDP '
            f'(FASTRTPS_DEFAULT_PROFILES_FILE={os.environ.get("FASTRTPS_DEFAULT_PROFILES_FILE")})')


# --- rclpy fixtures ----------------------------------------------------------

@pytest.fixture
def ros_context():
    """A fresh, initialised ``rclpy.Context``; shut down after the test."""
    import rclpy

    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    try:
        yield ctx
    finally:
        rclpy.try_shutdown(context=ctx)


def _make_executor(kind, context):
    if kind == 'single':
        from rclpy.executors import SingleThreadedExecutor
        return SingleThreadedExecutor(context=context)
    if kind == 'events':
        from rclpy.experimental import EventsExecutor
        return EventsExecutor(context=context)
    raise ValueError(f"unknown executor kind {kind!r} (use 'single' or 'events')")


class RosGraph:
    """Nodes and one executor on one context, spun in a bounded way.

    Only ever calls ``executor.spin_once(timeout_sec=...)``: that is the one
    call that works for both SingleThreadedExecutor and EventsExecutor
    (EventsExecutor's ``spin()``, ``spin_once()`` without timeout and
    ``spin_until_future_complete`` hang).
    """

    def __init__(self, context, executor_kind='single', spin_period=0.01):
        self.context = context
        self.executor_kind = executor_kind
        self.executor = _make_executor(executor_kind, context)
        self.spin_period = spin_period
        self.nodes = []
        self._thread = None
        self._stop = threading.Event()
        self._thread_error = None

    def add_node(self, node):
        """Add a node (created with ``context=graph.context``); returns it."""
        self.executor.add_node(node)
        self.nodes.append(node)
        return node

    def create_node(self, name, **kwargs):
        """Create an ``rclpy.node.Node`` on this context and add it."""
        from rclpy.node import Node
        return self.add_node(Node(name, context=self.context, **kwargs))

    def spin_once(self, timeout_sec=None):
        self._check_not_background()
        self.executor.spin_once(
            timeout_sec=self.spin_period if timeout_sec is None else timeout_sec)

    def spin_until(self, predicate, timeout_sec=10.0):
        """Spin in the foreground until ``predicate()`` is true.

        Returns True if it became true, False on timeout (bounded wait).
        """
        self._check_not_background()
        deadline = time.monotonic() + timeout_sec
        while not predicate():
            if time.monotonic() >= deadline:
                return bool(predicate())
            self.executor.spin_once(timeout_sec=self.spin_period)
        return True

    def spin_for(self, seconds):
        """Spin in the foreground for a fixed wall-clock time."""
        self.spin_until(lambda: False, timeout_sec=seconds)

    def start(self):
        """Spin in a background thread until ``stop()``."""
        if self._thread is not None:
            raise RuntimeError('already spinning in the background')
        self._stop.clear()
        self._thread_error = None
        self._thread = threading.Thread(
            target=self._spin_loop, name='ros-graph-spin', daemon=True)
        self._thread.start()

    def stop(self, timeout_sec=10.0):
        """Stop the background thread (join it); re-raise its exception."""
        thread, self._thread = self._thread, None
        if thread is not None:
            self._stop.set()
            thread.join(timeout_sec)
            if thread.is_alive():
                raise RuntimeError('executor thread did not stop in time')
        error, self._thread_error = self._thread_error, None
        if error is not None:
            raise error

    def wait_until(self, predicate, timeout_sec=10.0, poll=0.005):
        """While spinning in the background, wait for ``predicate()``."""
        deadline = time.monotonic() + timeout_sec
        while not predicate():
            if self._thread_error is not None:
                self.stop()
            if time.monotonic() >= deadline:
                return bool(predicate())
            time.sleep(poll)
        return True

    def close(self):
        """Teardown: stop spinning, destroy nodes, shut down the executor."""
        try:
            self.stop()
        finally:
            for node in reversed(self.nodes):
                try:
                    self.executor.remove_node(node)
                finally:
                    node.destroy_node()
            self.nodes.clear()
            self.executor.shutdown()

    def _check_not_background(self):
        if self._thread is not None:
            raise RuntimeError('spinning in a background thread: use wait_until')

    def _spin_loop(self):
        try:
            while not self._stop.is_set() and self.context.ok():
                self.executor.spin_once(timeout_sec=self.spin_period)
        except BaseException as e:  # noqa: B902 - handed to the test thread
            self._thread_error = e


@pytest.fixture
def ros_graph(request, ros_context):
    """A ``RosGraph`` on the test's own context.

    Default executor: SingleThreadedExecutor. For another one:
    ``@pytest.mark.parametrize('ros_graph', ['single', 'events'], indirect=True)``.
    """
    graph = RosGraph(ros_context, getattr(request, 'param', 'single'))
    try:
        yield graph
    finally:
        graph.close()


# --- realtime graphs alone on the machine ---------------------------------------
# A realtime graph's deadlines are 1 ms: it must not share the two cores with the other
# worker's tests. Every other test holds _REALTIME_LOCK shared, a realtime test holds it
# exclusive. A turnstile lets the realtime test through: while it waits for the running
# tests to end, the next ones wait at the turnstile (flock would let shared holders
# overtake a waiting exclusive one for ever).
_REALTIME_LOCK = "pkm-tests-realtime-loop.lock"
_TURNSTILE = "pkm-tests-realtime-turnstile.lock"


def _lock_path(name: str) -> str:
    import os
    import tempfile
    return os.path.join(tempfile.gettempdir(), name)


@contextlib.contextmanager
def _realtime_lock(mode: int):
    """The realtime lock held in ``mode`` (fcntl.LOCK_SH or LOCK_EX), taken through
    the turnstile."""
    import fcntl
    with open(_lock_path(_TURNSTILE), "a") as turnstile, open(_lock_path(_REALTIME_LOCK), "a") as handle:
        fcntl.flock(turnstile, fcntl.LOCK_EX)
        fcntl.flock(handle, mode)
        fcntl.flock(turnstile, fcntl.LOCK_UN)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


@pytest.fixture(autouse=True)
def _no_realtime_loop_beside(request):
    """Every test but a realtime one holds the realtime lock shared (see above)."""
    if "realtime_loop_alone" in request.fixturenames:
        yield                  # takes it exclusive itself (flock: another descriptor would deadlock)
        return
    import fcntl
    with _realtime_lock(fcntl.LOCK_SH):
        yield


@pytest.fixture
def realtime_loop_alone():
    """Holds the realtime lock exclusive (flock, released by the kernel even after a
    crash) while a test runs a graph with the realtime profile: no other test of the
    suite runs meanwhile. Two SCHED_FIFO loops on the two workers starve each other (a
    run that keeps its deadlines alone tripped on following error, 485 of 2000
    deadlines missed beside the hexapod panel's loop), and beside the other worker's
    graphs a realtime run missed 338 of 2000 and tripped."""
    import fcntl
    with _realtime_lock(fcntl.LOCK_EX):
        yield
