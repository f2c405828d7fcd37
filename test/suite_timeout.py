"""
A per-test time limit that holds inside compiled code, without losing the tests after it.

numba-compiled code keeps the GIL, so neither a signal handler (pytest-timeout's
``signal`` method: it runs only when control is back in Python, and then may break
pytest's own reporting) nor a Python watchdog thread (its ``thread`` method: it never
gets the GIL) can stop a test spinning in a kernel. ``faulthandler``'s watchdog is a
C thread that needs no GIL: when a test (set-up, call and teardown) runs past
``test_timeout`` seconds it dumps every thread's stack to the worker's stderr and ends
the worker process. pytest.ini runs the tests in one pytest-xdist worker, so xdist
reports that test as an ordinary failure and goes on with the next test in a fresh
worker; ``pytest_handlecrashitem`` below makes the failure say what happened.

With ``--dist loadgroup`` xdist (3.8) puts the whole unfinished group of a crashed worker
back in the queue, the test that crashed included: that test then ran again in the
next worker, crashed it again, and so on up to ``--max-worker-restart`` times, one
time limit each. ``_NoRerunLoadGroup`` marks the crashed test done before the rest of
its group goes back, so it fails once and the tests after it run.
"""

import faulthandler
import os

import pytest


def pytest_addoption(parser):
    """Declare the ``test_timeout`` ini key (seconds; 0 turns the limit off)."""
    parser.addini(
        'test_timeout', 'per-test time limit [s] (set-up + call + teardown); 0: none', default='0'
    )


def _timeout(config) -> float:
    try:
        value = float(config.getini('test_timeout'))
    except ValueError:
        raise pytest.UsageError(
            f"test_timeout must be a number of seconds, got {config.getini('test_timeout')!r}"
        )
    return value


_stderr = None


def pytest_configure(config):
    """Keep a file on the process's own stderr: pytest captures sys.stderr during tests."""
    global _stderr
    if _timeout(config) > 0 and _stderr is None:
        _stderr = os.fdopen(os.dup(2), 'w')


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """Arm the watchdog for the whole protocol of one test, disarm it after."""
    timeout = _timeout(item.config)
    if timeout > 0:
        faulthandler.dump_traceback_later(timeout, exit=True, file=_stderr)
    try:
        yield
    finally:
        if timeout > 0:
            faulthandler.cancel_dump_traceback_later()


@pytest.hookimpl(optionalhook=True)
def pytest_handlecrashitem(crashitem, report, sched):
    """Name the time limit in the failure of a test whose worker ended under it."""
    report.longrepr = (
        f'{report.longrepr}\n'
        f'{crashitem} ended its test worker: it ran past the per-test time limit of '
        f'{_timeout(sched.config):g} s (the stacks dumped on stderr show where), or its process '
        f'died. The suite went on in a new worker.'
    )


def _no_rerun_scheduler(config, log):
    from xdist.scheduler import LoadGroupScheduling

    class _NoRerunLoadGroup(LoadGroupScheduling):
        def remove_node(self, node):
            crashitem = None
            for unit in self.assigned_work.get(node, {}).values():
                crashitem = next((nid for nid, done in unit.items() if not done), None)
                if crashitem is not None:
                    unit[crashitem] = True  # reported once, by pytest_handlecrashitem
                    break
            super().remove_node(node)  # the rest of the group goes back in the queue
            return crashitem

    return _NoRerunLoadGroup(config, log)


@pytest.hookimpl(optionalhook=True, tryfirst=True)
def pytest_xdist_make_scheduler(config, log):
    """``--dist loadgroup``, but a test that crashed its worker is not run again."""
    if config.getvalue('dist') != 'loadgroup':
        return None
    return _no_rerun_scheduler(config, log)
