"""Shared pytest set-up: a private ROS domain and in-process ROS fixtures."""

import os

# Before anything can initialise rclpy: keep DDS discovery on this host, and
# use a domain of our own so concurrent runs (and any ROS graph already on this
# machine) stay apart. Domain ids above 232 break Fast DDS, so stay in 100-199.
from sorter_ros.env import apply_ros_env_defaults  # noqa: E402 (imports no ROS)

apply_ros_env_defaults()


def _worker_domain() -> int:
    """
    Return this pytest process's ROS domain: one per xdist worker, the same run's apart.

    ``SORTER_TEST_DOMAIN_ID`` picks the first (the workers take it and the next ones);
    otherwise a run takes a pair in 150-197 from its run id, so two runs on one host
    rarely meet, and a run's two workers never do. 100-149 are left to the tests that
    start graphs of their own (test_loopback_only's 141), 200-231 to campaigns.
    """
    import hashlib

    worker = os.environ.get('PYTEST_XDIST_WORKER', 'gw0')
    index = int(worker[2:]) if worker[2:].isdigit() else 0
    given = os.environ.get('SORTER_TEST_DOMAIN_ID', '').strip()
    if given:
        return int(given) + index
    run = os.environ.get('PYTEST_XDIST_TESTRUNUID') or str(os.getppid())
    pair = int(hashlib.sha256(run.encode()).hexdigest(), 16) % 24
    return 150 + (2 * pair + index) % 48


os.environ['ROS_DOMAIN_ID'] = str(_worker_domain())

import pytest  # noqa: E402


@pytest.fixture
def ros_context():
    """Return a fresh, initialised rclpy Context, shut down after the test."""
    from ros_harness import ros_context_scope

    with ros_context_scope() as ctx:
        yield ctx


@pytest.fixture
def ros(ros_context):
    """Return a RosHarness (nodes + SingleThreadedExecutor) bound to ``ros_context``."""
    from ros_harness import ros_harness_scope

    with ros_harness_scope(ros_context) as harness:
        yield harness


def _sigint_ignored() -> bool:
    """Return whether this process ignores SIGINT, as the kernel sees it (children inherit it)."""
    import signal

    with open('/proc/self/status', encoding='ascii') as f:
        for line in f:
            if line.startswith('SigIgn:'):
                return bool(int(line.split()[1], 16) >> (signal.SIGINT - 1) & 1)
    return False


@pytest.fixture(autouse=True)
def _ctrl_c_still_stops():
    """
    Fail a test that leaves its process ignoring SIGINT.

    An ignored SIGINT is inherited over exec: every command a later test starts in this
    worker would then shrug off Ctrl-C, and a user's pytest run calling the same code
    could no longer be stopped.
    """
    before = _sigint_ignored()
    yield
    if not before and _sigint_ignored():
        import signal

        signal.signal(signal.SIGINT, signal.default_int_handler)  # for the tests after it
        pytest.fail('the test left the process ignoring SIGINT (Ctrl-C)')


def _foreground_threads() -> set:
    """Return the threads, other than the main one, that keep the interpreter from exiting."""
    import threading

    main = threading.main_thread()
    return {t for t in threading.enumerate() if t is not main and not t.daemon and t.is_alive()}


@pytest.fixture(autouse=True)
def _no_thread_left_running():
    """
    Fail a test that leaves a non-daemon thread running in the pytest process.

    Such a thread (an OPC UA client's event loop whose connect failed, a server never
    stopped) keeps the process from exiting: ``pytest -n 0`` on that file finished its
    tests and then hung at shutdown. A thread still ending gets two seconds.
    """
    import time

    before = _foreground_threads()
    yield
    deadline = time.monotonic() + 2.0
    left = _foreground_threads() - before
    while left and time.monotonic() < deadline:
        time.sleep(0.02)
        left = _foreground_threads() - before
    if left:
        names = ', '.join(
            sorted(f'{t.name} ({type(t).__module__}.{type(t).__qualname__})' for t in left)
        )
        pytest.fail(
            f'the test left non-daemon threads running, which keep pytest from exiting: {names}'
        )


def pytest_configure(config):
    """Drop the core's stale numba kernels before a test calls one (tests call them directly)."""
    from sorter_sim.model.core.cache import check_kernel_cache

    check_kernel_cache()


def pytest_collection_modifyitems(config, items):
    """Mark ``quick`` the first test of each file that is not ``slow`` (``-m quick``)."""
    seen = set()
    for item in items:
        path = item.path
        if path in seen or item.get_closest_marker('slow') is not None:
            continue
        seen.add(path)
        item.add_marker(pytest.mark.quick)
