"""
Every shell command of README.md and docs/*.md runs as written.

Each command (``docs_commands.collect``: the fenced ``bash`` blocks, what cannot run
here marked where it stands) is started as a reader would start it, from a folder
that looks like the repository's root (``config/``, ``examples/``, ``benchmarks/``
and ``.venv`` linked, ``docs/`` copied, so what a command writes stays out of the
checkout). A command still running is stopped as a reader stops it, with Ctrl-C
(SIGINT to its process group), once it has shown that it works: a command that runs
the cell or the line (``sorter demo``, ``scripts/run.sh``, ``sim_node``,
``line_node``) once a clock it publishes on the test's ROS domain has passed
``CELL_RUNS_S`` of simulated time (within ``CELL_START_S``, or it fails: a cell that
starts but never runs is caught), a node of the controller side (``controller_node``,
``wcs_node``) once its node is on the graph of the test's ROS domain (within
``CELL_START_S``, or it fails), any other after ``BRIEF_S``. It must then end
within ``STOP_S``. Either way its exit status must be 0 (130 is Ctrl-C's own, taken
from a command that was stopped, as is an end by the signal itself, which a shell
reports as 130) and nothing it prints may be a traceback.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest
from docs_commands import REPO, collect
from ros_harness import ros_context_scope, ros_harness_scope

from sorter_control.node import NODE_NAME as CONTROLLER_NODE
from sorter_control.wcs_node import NODE_NAME as WCS_NODE

# a page's commands in one worker, in the page's order: a command may read what the one
# before it wrote (``FEEDS_LATER``); the pages share out over the workers
pytestmark = [pytest.mark.ros]

BRIEF_S = 8.0  # the most a command that does not run the cell runs before it is stopped
CELL_RUNS_S = 1.0  # simulated seconds a cell's clock passes before its command is stopped
CELL_START_S = 45.0  # the most a command takes to get its cell's clock there
STOP_S = 30.0  # the most it may take to end after Ctrl-C
BIN = Path(sys.executable).parent

COMMANDS = collect()
RUNNABLE = []
_seen = set()
for _c in COMMANDS:
    if not _c.skip and _c.text not in _seen:
        _seen.add(_c.text)
        RUNNABLE.append(_c)


def _files(cmd) -> set[str]:
    return {w for w in cmd.argv[1:] if not w.startswith('-') and '.' in w and '/' not in w}


# a command whose file a later command of the same page reads (``--record run.mcap``,
# then ``sorter replay run.mcap``) runs to its end, not briefly
FEEDS_LATER = {
    (c.doc, c.line)
    for i, c in enumerate(RUNNABLE)
    if any(later.doc == c.doc and _files(c) & _files(later) for later in RUNNABLE[i + 1 :])
}
WHOLE_S = 50.0  # the most such a command may take


def test_the_collector_finds_the_commands_and_every_skip_says_why():
    """The documentation's commands are found, and each one the suite skips says why."""
    texts = [c.text for c in COMMANDS]
    assert any(t.startswith('.venv/bin/line_node') for t in texts), texts
    assert any(t.startswith('.venv/bin/sorter demo') for t in texts)
    for c in COMMANDS:
        assert c.skip == '' or len(c.skip) > 10, f'{c.doc}:{c.line}: a skip without a reason'
    # what the suite skips is the exception: ros2cli, a workspace build, the suite itself
    assert len(RUNNABLE) >= 25, [c.text for c in RUNNABLE]
    # most commands that run on start the cell: their clock shows they work
    assert sum(_starts_a_cell(c) for c in RUNNABLE) >= 12
    # the recording the replay reads is made whole first
    assert any('--record' in c.text for c in RUNNABLE if (c.doc, c.line) in FEEDS_LATER)


# the pages whose commands open the fieldbus ports (5020, 4840, 1102) take turns
_PORTS = {'README.md', 'docs/fieldbus.md'}


def _group(cmd) -> str:
    return 'docs:fieldbus ports' if cmd.doc in _PORTS else f'docs:{cmd.doc}'


@pytest.fixture(scope='module')
def reader_root(tmp_path_factory) -> Path:
    """Return a folder laid out as the repository's root, for the commands to run in."""
    root = tmp_path_factory.mktemp('reader')
    for name in ('config', 'examples', 'benchmarks', 'scripts', '.venv'):
        (root / name).symlink_to(REPO / name)
    shutil.copytree(REPO / 'docs', root / 'docs')
    return root


def _argv(cmd) -> list[str]:
    argv = cmd.argv
    if argv[0].startswith('.venv/bin/'):
        argv[0] = str(BIN / argv[0].removeprefix('.venv/bin/'))
    elif argv[0].startswith('scripts/'):
        # the scripts work from the checkout (they keep its .venv up to date)
        argv[0] = str(REPO / argv[0])
    return argv


def _feeders(cmd) -> list:
    """Return the commands before ``cmd`` on its page that write a file it reads."""
    i = RUNNABLE.index(cmd)
    return [
        c
        for c in RUNNABLE[:i]
        if c.doc == cmd.doc and (c.doc, c.line) in FEEDS_LATER and _files(c) & _files(cmd)
    ]


_done = set()  # the commands that ran whole in this worker's reader_root


@contextlib.contextmanager
def _ports_lock(cmd):
    """Let one worker at a time run a command that opens the fieldbus or live-view ports."""
    if not any(w.startswith('--io') or w.endswith('_port') or '_port:=' in w for w in cmd.argv):
        yield
        return
    with open(Path(tempfile.gettempdir()) / f'sorter_docs_ports_{os.getuid()}.lock', 'w') as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def _as_from_a_shell() -> None:
    """
    Give the command the signal state a reader's shell gives it: Ctrl-C default, none blocked.

    Run in the child between fork and exec. A pytest worker is a long-lived process
    that other tests' libraries may have left with SIGINT ignored or blocked, and both
    are inherited over exec: the command would then shrug off the Ctrl-C that stops it.
    """
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_SETMASK, set())


def _signal_state() -> str:
    """Return this process's ignored and blocked signal masks, for a failure's message."""
    with open('/proc/self/status', encoding='ascii') as f:
        return ', '.join(
            line.strip() for line in f if line.startswith(('SigIgn:', 'SigBlk:', 'SigCgt:'))
        )


def _starts_a_cell(cmd) -> bool:
    """Return whether ``cmd`` runs the cell or the line: its simulated clock shows it works."""
    name = Path(cmd.argv[0]).name
    return name in ('sim_node', 'line_node', 'run.sh') or (
        name == 'sorter' and cmd.argv[1:2] == ['demo']
    )


# the node each controller-side executable starts
NODE_OF = {'controller_node': CONTROLLER_NODE, 'wcs_node': WCS_NODE}


def _until_its_node_is_up(reader: threading.Thread, name: str) -> bool:
    """Wait while the command runs and its node ``name`` is not on the graph; return if it came."""
    with ros_context_scope() as ctx, ros_harness_scope(ctx) as ros:
        watcher = ros.make_node('docs_node_watch')
        deadline = time.monotonic() + CELL_START_S
        while reader.is_alive() and time.monotonic() < deadline:
            if name in watcher.get_node_names():
                ros.spin_for(0.5)  # and it stays up a moment: a start that fails is seen
                return reader.is_alive()
            ros.spin_for(0.1)
        return False


class _ClockWatch:
    """The latest time any clock topic on the test's ROS domain said (``/clock``, remapped)."""

    def __init__(self, ros) -> None:
        self.node = ros.make_node('docs_clock_watch')
        self.t = 0.0
        self._subs = {}

    def look(self) -> None:
        """Subscribe to the clock topics that appeared since the last look."""
        from rclpy.qos import qos_profile_sensor_data
        from rosgraph_msgs.msg import Clock

        for name, types in self.node.get_topic_names_and_types():
            if name.endswith('clock') and 'rosgraph_msgs/msg/Clock' in types:
                if name not in self._subs:
                    # best effort, volatile: matches any publisher's QoS
                    self._subs[name] = self.node.create_subscription(
                        Clock, name, self._on_clock, qos_profile_sensor_data
                    )

    def _on_clock(self, msg) -> None:
        self.t = max(self.t, msg.clock.sec + 1e-9 * msg.clock.nanosec)


def _until_its_clock_runs(reader: threading.Thread) -> float:
    """Wait while the command runs and no clock passed ``CELL_RUNS_S``; return the latest time."""
    with ros_context_scope() as ctx, ros_harness_scope(ctx) as ros:
        watch = _ClockWatch(ros)
        deadline = time.monotonic() + CELL_START_S
        while reader.is_alive() and watch.t < CELL_RUNS_S and time.monotonic() < deadline:
            watch.look()
            ros.spin_for(0.1)
        return watch.t


def _run_as_written(cmd, reader_root) -> None:
    env = dict(os.environ)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['PATH'] = f'{BIN}{os.pathsep}{env.get("PATH", "")}'
    whole = (cmd.doc, cmd.line) in FEEDS_LATER
    cell = _starts_a_cell(cmd) and not whole
    node = None if whole else NODE_OF.get(Path(cmd.argv[0]).name)
    with _ports_lock(cmd):
        proc = subprocess.Popen(
            _argv(cmd),
            cwd=reader_root,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
            preexec_fn=_as_from_a_shell,
        )
        box = {}

        def read() -> None:
            try:
                box['out'] = proc.communicate()[0]
            except BaseException as exc:  # noqa: BLE001 (re-raised in the test)
                box['error'] = exc

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        hung = False
        try:
            if cell:
                clock = _until_its_clock_runs(reader)
            elif node:
                up = _until_its_node_is_up(reader, node)
            else:
                reader.join(WHOLE_S if whole else BRIEF_S)
            stopped = reader.is_alive()
            if stopped:
                with contextlib.suppress(ProcessLookupError):  # it may just have ended
                    os.killpg(proc.pid, signal.SIGINT)
                reader.join(STOP_S)
                hung = reader.is_alive()
        finally:
            # whatever failed above: nothing it started runs on into the next command's test
            if proc.poll() is None or reader.is_alive():
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                reader.join()
        if 'error' in box:
            raise box['error']
        out = box['out']
        if hung:
            pytest.fail(
                f'{cmd.doc}:{cmd.line}: `{cmd.text}` did not end within {STOP_S:g} s of '
                f'Ctrl-C (the test process: {_signal_state()}); it printed:\n{out[-3000:]}'
            )
        assert not (stopped and whole), (
            f'{cmd.doc}:{cmd.line}: `{cmd.text}` did not end within {WHOLE_S:g} s; the '
            f'commands after it read what it writes. It printed:\n{out[-3000:]}'
        )
        assert not (stopped and node and not up), (
            f'{cmd.doc}:{cmd.line}: `{cmd.text}` ran {CELL_START_S:g} s and its node {node} '
            f'did not come on the graph; it printed:\n{out[-3000:]}'
        )
        assert not (stopped and cell and clock < CELL_RUNS_S), (
            f'{cmd.doc}:{cmd.line}: `{cmd.text}` ran {CELL_START_S:g} s and no clock of its '
            f'cell passed {CELL_RUNS_S:g} s (the latest said {clock:g} s); it printed:\n'
            f'{out[-3000:]}'
        )
    where = f'{cmd.doc}:{cmd.line}: `{cmd.text}`'
    # a process ended by the SIGINT itself is what a shell reports as 130
    allowed = (0, 130, -signal.SIGINT) if stopped else (0,)
    assert proc.returncode in allowed, (
        f'{where} exited {proc.returncode}{" after Ctrl-C" if stopped else ""}; it printed:\n'
        f'{out[-3000:]}'
    )
    assert 'Traceback (most recent call last)' not in out, f'{where} printed a traceback:\n{out}'
    _done.add((cmd.doc, cmd.line))


@pytest.mark.parametrize(
    'cmd',
    [
        pytest.param(c, id=f'{c.doc}:{c.line}', marks=pytest.mark.xdist_group(_group(c)))
        for c in RUNNABLE
    ],
)
def test_a_documented_command_runs_as_written(cmd, reader_root):
    # what it reads is made first, as the reader made it, should this worker not have run the
    # command before it (the workers share the pages out)
    for feeder in _feeders(cmd):
        if (feeder.doc, feeder.line) not in _done:
            _run_as_written(feeder, reader_root)
    _run_as_written(cmd, reader_root)
