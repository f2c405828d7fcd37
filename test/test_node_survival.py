"""
Both executables survive bad requests inside rclpy's own callbacks, and end cleanly.

The nodes run as their console scripts (``sim_node``, ``controller_node``) in
processes of their own, so that what is tested is the executables' spin loop, not
the test's executor. A ParameterValue of an unknown type (raised in rclpy's
parameter service) and a /clock message with negative seconds (raised in rclpy's
time source) must be logged and counted while the nodes go on serving; SIGINT then
ends each with exit code 0 and no traceback.
"""

import contextlib
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from builtin_interfaces.msg import Time
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, SetParameters, SetParametersAtomically
from ros_harness import stalled_live_view_client, subscribe_to_every_channel
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_srvs.srv import SetBool, Trigger

from sorter_ros.interface import STREAM_QOS

pytestmark = pytest.mark.ros

BIN = Path(sys.executable).parent
NS = '/survival'


def _start(exe: str, *ros_args: str, ns: str = NS) -> subprocess.Popen:
    return subprocess.Popen(
        [str(BIN / exe), '--ros-args', '-r', f'__ns:={ns}', *ros_args],
        env=dict(os.environ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def _stop(proc: subprocess.Popen) -> tuple[int, str]:
    proc.send_signal(signal.SIGINT)
    try:
        out, err = proc.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
        pytest.fail(f'{proc.args[0]} did not end within 20 s of SIGINT:\n{err[-2000:]}')
    return proc.returncode, out + err


def test_bad_requests_inside_rclpy_callbacks_do_not_end_the_nodes(ros):
    procs = {
        'sorter_sim': _start('sim_node', '-p', 'time_mode:=lockstep', '-p', 'arrival:=none'),
        'sorter_controller': _start(
            'controller_node', '-p', 'use_sim_time:=true', '-p', "cell_node:=''"
        ),
    }
    try:
        node = ros.make_node('fuzzer')
        get = {n: node.create_client(GetParameters, f'{NS}/{n}/get_parameters') for n in procs}
        setp = {n: node.create_client(SetParameters, f'{NS}/{n}/set_parameters') for n in procs}
        step = node.create_client(Trigger, f'{NS}/step')
        clock = node.create_publisher(Clock, '/clock', STREAM_QOS)
        ros.spin_until(
            lambda: all(c.service_is_ready() for c in (*get.values(), *setp.values(), step)),
            30.0,
            'both nodes to start and offer their services',
        )
        # a parameter value of a type that does not exist, to each node, alone and
        # atomically: rclpy's service raised on it and never answered; now it is refused
        bad = Parameter(name='alpha_deg', value=ParameterValue(type=42))
        for name, client in setp.items():
            (result,) = ros.call(client, SetParameters.Request(parameters=[bad]), 10.0).results
            assert not result.successful, name
            assert result.reason.startswith("parameter 'alpha_deg': type 42 is not a parameter"), (
                result.reason
            )
            atomic = node.create_client(
                SetParametersAtomically, f'{NS}/{name}/set_parameters_atomically'
            )
            reply = ros.call(atomic, SetParametersAtomically.Request(parameters=[bad]), 10.0)
            assert not reply.result.successful and 'type 42' in reply.result.reason, name
            # a name the node does not have is named (rclpy's reason named none)
            unknown = Parameter(
                name='no_such', value=ParameterValue(type=ParameterType.PARAMETER_BOOL)
            )
            (result,) = ros.call(client, SetParameters.Request(parameters=[unknown]), 10.0).results
            assert (
                result.reason == "no parameter 'no_such' on this node (ros2 param list names them)"
            )
        # a /clock with negative seconds, to the controller (it runs on simulation time)
        ros.spin_until(lambda: clock.get_subscription_count() >= 1, 10.0, 'a /clock subscriber')
        clock.publish(Clock(clock=Time(sec=-5, nanosec=0)))
        ros.spin_for(1.0)
        # both still serve
        for name, client in get.items():
            reply = ros.call(client, GetParameters.Request(names=['use_sim_time']))
            assert len(reply.values) == 1, name
        assert ros.call(step, Trigger.Request()).success
        for name, proc in procs.items():
            assert proc.poll() is None, f'{name} ended: {proc.communicate()[1][-2000:]}'
    finally:
        results = {name: _stop(proc) for name, proc in procs.items()}
    for name, (code, text) in results.items():
        assert code == 0, f'{name} exit {code}:\n{text[-3000:]}'
        assert 'Traceback' not in text, f'{name}:\n{text[-3000:]}'
    # the /clock of negative seconds raises inside rclpy's time source: survived, logged
    code, text = results['sorter_controller']
    assert 'a callback raised' in text, f'logged no ignored error:\n{text[-3000:]}'


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
def test_a_controller_that_stops_lowers_the_disks_itself(ros, sig):
    # the cell's watchdog is off here, so only the controller's last words can lower the disks
    procs = {
        'sorter_sim': _start('sim_node', '-p', 'arrival:=none', '-p', 'watchdog_timeout:=0.0'),
        'sorter_controller': _start('controller_node', '-p', f'cell_node:={NS}/sorter_sim'),
    }
    ctl = procs['sorter_controller']
    try:
        node = ros.make_node('plc_watcher')
        stroke = []
        node.create_subscription(
            JointState, f'{NS}/diverter/state', lambda m: stroke.append(m.position[1]), STREAM_QOS
        )
        popup = node.create_client(SetBool, f'{NS}/diverter/popup')
        get = node.create_client(GetParameters, f'{NS}/sorter_controller/get_parameters')
        ros.spin_until(
            lambda: popup.service_is_ready() and get.service_is_ready(),
            30.0,
            'both nodes to start and offer their services',
        )
        # the controller's first scan commands the disks down; then raise them from outside,
        # as a PLC program would have for a divert under way. On a loaded machine that
        # first scan may come after the raise and lower them again: raise them until they
        # stay up (the controller commands only on a change, so it lowers them once)
        ros.spin_for(1.0)
        for _ in range(3):
            assert ros.call(popup, SetBool.Request(data=True)).success
            ros.spin_for(0.5)
            if stroke and stroke[-1] == 1.0:
                break
        ros.spin_until(lambda: stroke and stroke[-1] == 1.0, 5.0, 'the disks to be up')
        ctl.send_signal(sig)
        try:
            ros.spin_until(lambda: stroke[-1] == 0.0, 5.0, 'the disks to be lowered')
        except pytest.fail.Exception as failed:
            out, err = ctl.communicate(timeout=20)
            pytest.fail(f'{failed}; the controller said:\n{(out + err)[-3000:]}')
        out, err = ctl.communicate(timeout=20)
    finally:
        results = {name: _stop(proc) for name, proc in procs.items() if proc.poll() is None}
    text = out + err
    assert ctl.returncode == 0, text[-3000:]
    assert 'stopping: disks lowered' in text and 'Traceback' not in text, text[-3000:]
    for name, (code, text) in results.items():
        assert code == 0, f'{name} exit {code}:\n{text[-3000:]}'
    # the cell ran in real time from its first period: no simulated time dropped at start-up
    # (later, a machine loaded by other jobs may hold the process back past the catch-up
    # limit; the node then says so and drops time, as an emulator must)
    assert not _drops_at_start_up(results['sorter_sim'][1]), results['sorter_sim'][1][-3000:]


def _drops_at_start_up(log: str, within_s: float = 1.0) -> bool:
    """Return whether the sim node dropped simulated time within ``within_s`` of being ready."""
    stamps = {}
    for line in log.splitlines():
        m = re.match(r'\[\w+\] \[(\d+\.\d+)\]', line)
        if m is None:
            continue
        if 'sorter cell ready' in line:
            stamps.setdefault('ready', float(m.group(1)))
        elif 'dropping' in line and 'ready' in stamps:
            if float(m.group(1)) - stamps['ready'] < within_s:
                return True
    return 'ready' not in stamps


# executable -> (node name, arguments that start it on its own)
ALONE = {
    'sim_node': ('sorter_sim', ['-p', 'arrival:=none', '-p', 'time_mode:=fast']),
    'controller_node': ('sorter_controller', ['-p', "cell_node:=''"]),
}


@pytest.mark.parametrize('exe', list(ALONE))
def test_a_double_sigint_is_a_clean_exit_whenever_the_second_lands(ros, exe):
    """The second signal only hurries the stop: no exception thrown into a running callback."""
    name, extra = ALONE[exe]
    node = ros.make_node('signal_watcher')
    for i, gap in enumerate((0.0, 0.02, 0.05, 0.1)):
        # each run in a namespace of its own: the graph may list the last run's node until
        # its participant's lease runs out (a stop the second signal hurried may not say
        # goodbye), and that name must not be taken for this run's node being up
        ns = f'{NS}_{exe}_{i}'
        proc = _start(exe, *extra, ns=ns)
        try:
            ros.spin_until(
                lambda: (
                    (name, ns) in node.get_node_names_and_namespaces()
                    and _catches_sigterm(proc.pid)
                ),
                30.0,
                f'{exe} to start',
            )
            proc.send_signal(signal.SIGINT)
            time.sleep(gap)
            proc.send_signal(signal.SIGINT)
            out, err = proc.communicate(timeout=20)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
        text = out + err
        assert proc.returncode == 0, f'{exe}, second signal after {gap} s:\n{text[-3000:]}'
        assert 'Traceback' not in text and 'Exception ignored' not in text, text[-3000:]


def _catches_sigterm(pid: int) -> bool:
    with open(f'/proc/{pid}/status') as fh:
        for line in fh:
            if line.startswith('SigCgt:'):
                return bool(int(line.split()[1], 16) & (1 << (signal.SIGTERM - 1)))
    return False


@pytest.mark.parametrize('sig', [signal.SIGINT, signal.SIGTERM], ids=['SIGINT', 'SIGTERM'])
@pytest.mark.parametrize('exe', list(ALONE))
def test_a_stop_while_the_node_still_loads_is_a_clean_exit(exe, sig):
    """The executables catch SIGINT and SIGTERM before their modules load (a few tenths of a s)."""
    _, extra = ALONE[exe]
    for delay in (0.0, 0.1, 0.3):
        proc = _start(exe, *extra)
        try:
            deadline = time.monotonic() + 10.0
            while not _catches_sigterm(proc.pid):
                assert proc.poll() is None and time.monotonic() < deadline, (
                    f'{exe} never caught SIGTERM'
                )
                time.sleep(0.001)
            time.sleep(delay)
            proc.send_signal(sig)
            out, err = proc.communicate(timeout=20)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
        text = out + err
        assert proc.returncode == 0, f'{exe}, {sig.name} {delay} s into the start:\n{text[-3000:]}'
        assert 'Traceback' not in text and 'Exception ignored' not in text, text[-3000:]


def test_the_executables_load_nothing_heavy_before_their_handlers():
    """A console script imports no ROS, no numerics before ``start_node`` installs the handlers."""
    heavy = ('numpy', 'numba', 'scipy', 'rclpy', 'yaml')
    probe = (
        'import sys, sorter_sim.executable, sorter_control.executable; '
        f'print(sorted(m for m in {heavy!r} if m in sys.modules))'
    )
    out = subprocess.run(
        [sys.executable, '-c', probe], capture_output=True, text=True, check=True
    ).stdout
    assert out.strip() == '[]'


def _wait_listening(ports: dict, timeout: float) -> None:
    """Wait until every server accepts connections on its port, or the time is up."""
    import socket

    deadline = time.monotonic() + timeout
    for key in ('foxglove_port', 'modbus_port', 'opcua_port'):
        while time.monotonic() < deadline:
            with socket.socket() as s:
                if s.connect_ex(('127.0.0.1', ports[key])) == 0:
                    break
            time.sleep(0.2)


def _subscribe_opcua(endpoint: str, stop_clients) -> None:
    """Start three OPC UA clients subscribed to the cell's time; they hold on until told."""
    import asyncio
    import threading

    from asyncua import Client

    async def subscribers():
        class Quiet:
            def datachange_notification(self, node, val, data):
                pass

        clients = []
        for _ in range(3):
            c = Client(endpoint, timeout=10)
            await c.connect()
            idx = await c.get_namespace_index('urn:sorter_cell')
            # the cell's folder is named by its namespace
            folder = NS.strip('/').replace('/', '_')
            t = await c.nodes.objects.get_child(
                [f'{idx}:{folder}', f'{idx}:Inputs', f'{idx}:cell.time']
            )
            sub = await c.create_subscription(50, Quiet())
            await sub.subscribe_data_change(t)
            clients.append(c)
        subscribed.set()
        while not stop_clients.is_set():
            await asyncio.sleep(0.1)

    subscribed = threading.Event()
    threading.Thread(target=lambda: asyncio.run(subscribers()), daemon=True).start()
    assert subscribed.wait(30.0), 'the OPC UA subscribers did not connect'


def _connect_modbus(port: int, clients: contextlib.ExitStack) -> None:
    """Connect three Modbus clients that read once and then stay idle."""
    from pymodbus.client import ModbusTcpClient

    for _ in range(3):
        m = ModbusTcpClient('127.0.0.1', port=port, timeout=5, retries=0)
        clients.callback(m.close)
        assert m.connect() and not m.read_input_registers(0, count=10).isError()


def _stall_foxglove(port: int, clients: contextlib.ExitStack) -> None:
    """Subscribe three WebSocket clients to every channel, with small buffers they never read."""
    for _ in range(3):
        subscribe_to_every_channel(stalled_live_view_client(port, clients))  # never read again


def test_sigterm_with_every_server_busy_and_clients_connected_ends_the_node_promptly():
    """OPC UA subscriptions, idle Modbus sockets, WebSocket clients that stopped reading."""
    import threading

    from ros_harness import free_port

    ports = {'modbus_port': free_port(), 'opcua_port': free_port(), 'foxglove_port': free_port()}
    args = [a for k, v in ports.items() for a in ('-p', f'{k}:={v}')]
    proc = _start('sim_node', '-p', 'time_mode:=realtime', *args)
    endpoint = f'opc.tcp://127.0.0.1:{ports["opcua_port"]}/sorter_cell/'
    stop_clients = threading.Event()
    clients = contextlib.ExitStack()
    try:
        _wait_listening(ports, 60.0)
        _subscribe_opcua(endpoint, stop_clients)
        _connect_modbus(ports['modbus_port'], clients)
        _stall_foxglove(ports['foxglove_port'], clients)
        time.sleep(5.0)  # frames pile up for the stalled clients
        assert proc.poll() is None
        # the fieldbus servers' process: it must not outlive the node
        children = subprocess.run(
            ['ps', '-o', 'pid=', '--ppid', str(proc.pid)], capture_output=True, text=True
        ).stdout.split()
        assert children, 'the fieldbus servers run in a child process'
        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        try:
            out, err = proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, err = proc.communicate()
        took = time.monotonic() - t0
        print(f'SIGTERM to exit: {took:.2f} s')
        assert proc.returncode == 0 and 'Traceback' not in err, err[-2000:]
        # 26-31 s before the servers' stops were bounded; ros2 launch kills after 10 s
        assert took < 5.0, f'{took:.1f} s from SIGTERM to exit'
        for pid in children:
            deadline = time.monotonic() + 5.0
            while Path(f'/proc/{pid}').exists() and time.monotonic() < deadline:
                time.sleep(0.1)
            assert not Path(f'/proc/{pid}').exists(), f'child {pid} outlived the node'
    finally:
        stop_clients.set()
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        clients.close()


def test_a_command_line_rcl_cannot_parse_is_refused_in_one_line():
    out = subprocess.run(
        [str(BIN / 'sim_node'), '--ros-args', '-p', 'modbus_host:='],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2 and 'Traceback' not in out.stderr, out.stderr
    ours = [line for line in out.stderr.splitlines() if line.startswith('sim_node:')]
    assert len(ours) == 1 and 'modbus_host' in ours[0] and 'name:=value' in ours[0]


def test_a_params_file_that_is_not_there_is_named_with_where_the_shipped_ones_are(tmp_path):
    """The docs' ``--params-file config/cell.yaml`` run where there is no ``config/``."""
    out = subprocess.run(
        [str(BIN / 'controller_node'), '--ros-args', '--params-file', 'config/controller.yaml'],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=tmp_path,
    )
    assert out.returncode == 2 and 'Traceback' not in out.stderr, out.stderr
    ours = [line for line in out.stderr.splitlines() if line.startswith('controller_node:')]
    assert len(ours) == 1, out.stderr
    said = re.fullmatch(
        r"controller_node: the params file 'config/controller.yaml' cannot be opened "
        r"\(from (.+)\); this package's own are in (.+) \(cell.yaml, controller.yaml\)",
        ours[0],
    )
    assert said and Path(said[1]) == tmp_path, ours[0]
    assert (Path(said[2]) / 'controller.yaml').is_file()


@pytest.mark.parametrize(
    'exe, given, said',
    [
        # rclpy's own parameter, declared before the node's: refused by rclpy's type check
        ('controller_node', 'use_sim_time:=x', "'use_sim_time' must be true or false, got 'x'"),
        # the node's own: named with what it allows
        ('line_node', 'fast_slice:=x', "'fast_slice' must be a number in (0, 1] s, got 'x'"),
    ],
)
def test_a_parameter_of_another_type_is_refused_in_one_line_naming_what_it_allows(
    exe, given, said
):
    out = subprocess.run(
        [str(BIN / exe), '--ros-args', '-p', given],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 2 and 'Traceback' not in out.stderr, out.stderr
    assert out.stderr.strip().splitlines() == [f'{exe}: parameter {said} (string)']
