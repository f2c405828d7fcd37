"""
Launch-free, in-process ROS 2 test harness.

Modelled on rclpy's own tests (rclpy/test/test_executor.py): every test gets
its own ``rclpy.context.Context``, the nodes under test are created in that
context, and a ``SingleThreadedExecutor`` bound to it is spun by the test
itself, so there are no launch files, no subprocesses and no global state
shared between tests.

Use it through the ``ros_context`` and ``ros`` fixtures in conftest.py; the
context managers here are also usable directly (e.g. to check teardown).
"""

from __future__ import annotations

import contextlib
import socket
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest
import rclpy
from rclpy.client import Client
from rclpy.context import Context
from rclpy.executors import ShutdownException, SingleThreadedExecutor, TimeoutException
from rclpy.node import Node


@contextlib.contextmanager
def ros_context_scope() -> Iterator[Context]:
    """Yield a freshly initialised rclpy context; shut it down on exit."""
    ctx = Context()
    rclpy.init(context=ctx)
    try:
        yield ctx
    finally:
        rclpy.try_shutdown(context=ctx)


class RosHarness:
    """Nodes and a single-threaded executor in one context, spun by the test."""

    def __init__(self, context: Context) -> None:
        self.context = context
        self.executor = SingleThreadedExecutor(context=context)
        self.nodes: list[Node] = []

    # -- nodes -------------------------------------------------------------

    def make_node(self, name: str, **kwargs: Any) -> Node:
        """Create a node in the harness context and add it to the executor."""
        return self.add(rclpy.create_node(name, context=self.context, **kwargs))

    def add(self, node: Node) -> Node:
        """Track a node created elsewhere (it must be created with ``context=``)."""
        if node.context is not self.context:
            raise ValueError(
                f'node {node.get_name()!r} belongs to another rclpy context; '
                f'create it with context=ros.context'
            )
        if node not in self.nodes:
            self.nodes.append(node)
            self.executor.add_node(node)
        return node

    # -- spinning ----------------------------------------------------------

    def spin_until(
        self,
        predicate: Callable[[], Any],
        timeout_sec: float = 5.0,
        message: str = 'condition',
    ) -> None:
        """Spin the executor until ``predicate()`` is true, or fail the test."""
        deadline = time.monotonic() + timeout_sec
        while not predicate():
            if time.monotonic() >= deadline:
                pytest.fail(f'timed out after {timeout_sec}s waiting for: {message}')
            self.executor.spin_once(timeout_sec=0.01)

    def spin_until_matched(self, timeout_sec: float = 10.0) -> None:
        """
        Spin until every publisher of these nodes has matched every reader they have on its topic.

        DDS matches a new reader on threads of its own: a message sent before (a sensor's
        first edge, a label) is lost to that reader, and a test would depend on the
        machine's speed (``sorter_ros.run_loop.RunLoop._settle_graph`` waits alike).
        """
        from sorter_ros.run_loop import unmatched_topics

        self.spin_until(
            lambda: not unmatched_topics(self.nodes), timeout_sec, 'every reader matched'
        )

    def drain(self, limit: int = 10_000) -> int:
        """
        Run every callback that is ready now (``limit`` at the most); return how many ran.

        ``spin_once(timeout_sec=0)`` runs one callback at the most and pays for a wait
        either way: the single-threaded executor builds its wait set anew for each, about
        a millisecond with a few station nodes. A fixed count of them pays that on every
        turn that finds nothing (most of a lock-step line test's time went there); this
        stops at the first wait that finds nothing. The limit ends it should a callback
        keep itself ready (a timer whose period is shorter than its callback).
        """
        for ran in range(limit):
            try:
                handler, _, _ = self.executor.wait_for_ready_callbacks(timeout_sec=0.0)
            except (TimeoutException, ShutdownException):
                return ran
            handler()
            if handler.exception() is not None:
                raise handler.exception()
        return limit

    def spin_for(self, seconds: float) -> None:
        """Spin the executor for a fixed wall-clock time."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=min(0.01, max(0.0, deadline - time.monotonic())))

    def communicate(self, proc: subprocess.Popen, timeout_sec: float) -> tuple:
        """
        Return what the process printed (out, err) once it ends, the executor spun meanwhile.

        A test's node that stops taking what it subscribed to slows the DDS traffic of the
        processes it watches (a 5-parcel split line took twice as long), so a test that
        waits for a process keeps its own nodes spinning; a thread reads the pipes.
        """
        box: dict = {}

        def read() -> None:
            try:
                box['out'] = proc.communicate(timeout=timeout_sec)
            except BaseException as exc:  # noqa: BLE001 - raised again in the test's thread
                box['error'] = exc

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        self.spin_until(lambda: not reader.is_alive(), timeout_sec + 5.0, f'{proc.args[:4]}')
        if 'error' in box:
            raise box['error']
        return box['out']

    def call(self, client: Client, request: Any, timeout_sec: float = 5.0) -> Any:
        """Call a service and return its response; the server must be spun here too."""
        self.spin_until(
            lambda: client.wait_for_service(timeout_sec=0.0),
            timeout_sec,
            f'service {client.srv_name} to become available',
        )
        future = client.call_async(request)
        try:
            self.spin_until(
                future.done,
                timeout_sec,
                f'response from service {client.srv_name} '
                f'(is the server node added to the harness?)',
            )
        finally:
            if not future.done():
                client.remove_pending_request(future)
        return future.result()

    # -- teardown ----------------------------------------------------------

    def close(self) -> None:
        """Shut the executor down and destroy every tracked node."""
        try:
            self.executor.shutdown(timeout_sec=5.0)
        finally:
            while self.nodes:
                self.nodes.pop().destroy_node()


@contextlib.contextmanager
def ros_harness_scope(context: Context) -> Iterator[RosHarness]:
    """Yield a RosHarness bound to ``context``; close it on exit."""
    harness = RosHarness(context)
    try:
        yield harness
    finally:
        harness.close()


def free_port() -> int:
    """Return a TCP port on loopback that was free a moment ago (for a node's server)."""
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def stalled_live_view_client(port: int, clients: contextlib.ExitStack):
    """
    Open a live-view client with a 4 kB receive buffer.

    When ``clients`` ends, its socket is closed with no closing handshake, as a client
    that stopped reading goes away.
    """
    from websockets.sync.client import connect

    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    sock.connect(('127.0.0.1', port))
    ws = clients.enter_context(
        connect(f'ws://127.0.0.1:{port}', sock=sock, subprotocols=['foxglove.sdk.v1'])
    )
    clients.callback(ws.socket.close)  # runs before the context's own close
    return ws


def subscribe_to_every_channel(ws, timeout: float = 10.0) -> None:
    """Subscribe a live-view client to every channel the view advertises (within ``timeout``)."""
    import json

    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        frame = ws.recv(timeout=left)
        if isinstance(frame, str) and json.loads(frame).get('op') == 'advertise':
            channels = json.loads(frame)['channels']
            subs = [{'id': i, 'channelId': c['id']} for i, c in enumerate(channels)]
            ws.send(json.dumps({'op': 'subscribe', 'subscriptions': subs}))
            return
    pytest.fail(f"no 'advertise' message from the live view within {timeout} s")


def refused_at_run_time(ros, node, changes: dict) -> dict:
    """
    Set each of ``changes`` over the node's own ``set_parameters`` service, one at a time.

    As ``ros2 param set`` does: a real client, a request over DDS. Return {name: the
    reason it was refused, or None where it was taken}.
    """
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    probe = ros.make_node(f'param_probe_{node.get_name()}')
    client = probe.create_client(
        SetParameters, f'{node.get_fully_qualified_name()}/set_parameters'
    )
    out = {}
    for name, value in changes.items():
        request = SetParameters.Request(
            parameters=[Parameter(name, value=value).to_parameter_msg()]
        )
        result = ros.call(client, request, 10.0).results[0]
        out[name] = None if result.successful else result.reason
    return out


def recorded_topic_counts(path) -> dict:
    """Return {topic: messages} of an MCAP recording, read by mcap's default reader."""
    from collections import Counter

    from mcap.reader import make_reader

    with open(path, 'rb') as f:
        return Counter(ch.topic for _, ch, _ in make_reader(f).iter_messages())
