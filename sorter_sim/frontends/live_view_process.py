"""
The live view in a process of its own, so that drawing the cell never holds its physics.

A live view frame of 200 parcels is some 1,400 Foxglove objects (a box, a label and
a path of up to ``PATH_POINTS`` points each) built in Python: about 10 ms, which in
the node's interpreter the physics waits for. Here the node only pickles the state it
already has (the parcels' columns, their motion, α, the stroke, the sensors: some
tens of µs) and hands it through a socket to a plain interpreter that runs
``LiveView`` (the Foxglove server, the paths, the frames), at a lower priority
(``NICE``): on a machine short of cores the physics goes first and the view draws
fewer frames.

The child asks for each frame: it sends ``WANT`` when a client listens and the rate
allows one (``LiveView.due``), ``IDLE`` when the last client left; the node hands
over a frame only when asked, so at most one frame is ever on its way and a slow
or stalled child costs the node nothing but frames. A child that ends (killed)
ends the live view, said once; the node goes on.
"""

from __future__ import annotations

import os
import pickle
import select
import socket
import struct
import subprocess
import sys

LENGTH = struct.Struct('<I')
WANT, IDLE = b'F', b'N'
START_TIMEOUT_S = 20.0
STOP_WAIT_S = 2.0
# the drawing process runs this much nicer than the node: where the cores are short
# (the node, its clients, other work) the scheduler gives them to the physics first,
# and the view draws fewer frames rather than the cell running slower
NICE = 5


def _send_blocking(sock: socket.socket, obj) -> None:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    sock.sendall(LENGTH.pack(len(data)) + data)


def _recv_blocking(sock: socket.socket):
    def exactly(n: int) -> bytes:
        buf = b''
        while len(buf) < n:
            part = sock.recv(n - len(buf))
            if not part:
                raise EOFError
            buf += part
        return buf

    (n,) = LENGTH.unpack(exactly(LENGTH.size))
    return pickle.loads(exactly(n))


class LiveViewProcess:
    """
    ``LiveView``'s interface (``due``, ``update``, ``update_stations``, ``close``) for the node.

    The server runs in a child process; the arguments are ``LiveView``'s.
    ``on_failure(text)`` is how the node is told, once, that the child ended.
    Raises ValueError with one line when the server cannot start (the port in use).
    """

    def __init__(
        self,
        layout,
        *,
        host: str,
        port: int,
        prefix: str = '',
        max_rate_hz: float = 30.0,
        stations: list | None = None,
        on_failure=None,
    ):
        mine, theirs = socket.socketpair()
        self._sock = mine
        try:
            self._proc = subprocess.Popen(
                [
                    sys.executable,
                    '-m',
                    'sorter_sim.frontends.live_view_process',
                    str(theirs.fileno()),
                ],
                pass_fds=(theirs.fileno(),),
                stdin=subprocess.DEVNULL,
            )
        except OSError as exc:
            mine.close()
            raise ValueError(f'cannot start the live view process: {exc}') from None
        finally:
            theirs.close()
        self.frames_sent = 0
        self.failure: str | None = None
        self._on_failure = on_failure
        self._wanted = False
        self._listening = False
        self._pending = b''
        try:
            _send_blocking(mine, (layout, host, port, prefix, max_rate_hz, stations))
            mine.settimeout(START_TIMEOUT_S)
            answer = _recv_blocking(mine)
        except (EOFError, OSError):
            self._stop()
            raise ValueError(
                f'the live view process did not start within {START_TIMEOUT_S:g} s'
            ) from None
        if answer[0] == 'error':
            self._stop()
            raise ValueError(answer[1])
        self._port = answer[1]
        mine.setblocking(False)

    @property
    def port(self) -> int:
        return self._port

    @property
    def pid(self) -> int:
        return self._proc.pid

    @property
    def alive(self) -> bool:
        return self.failure is None and self._proc.poll() is None

    def _ended(self) -> None:
        if self.failure is not None:
            return
        self.failure = (
            f'the live view stopped: its process ended (exit status {self._proc.poll()}); '
            'the node goes on without it'
        )
        self._wanted = self._listening = False
        if self._on_failure is not None:
            self._on_failure(self.failure)

    def _poll(self) -> None:
        """Read what the child said (want a frame, nobody listens), without waiting."""
        if self.failure is not None:
            return
        try:
            said = self._sock.recv(4096)
        except BlockingIOError:
            return
        except OSError:
            said = b''
        if not said:
            self._ended()
            return
        last = said[-1:]
        self._wanted = last == WANT
        self._listening = last == WANT or (self._listening and IDLE not in said)

    def _send_pending(self) -> None:
        try:
            n = self._sock.send(self._pending)
        except BlockingIOError:
            return
        except OSError:
            self._pending = b''
            self._ended()
            return
        self._pending = self._pending[n:]

    def listening(self) -> bool:
        """Return True when a client listens (as the child last said)."""
        self._poll()
        return self._listening

    def due(self) -> bool:
        """Return True when the child asked for a frame and the last one is on its way."""
        self._poll()
        if self._pending:
            self._send_pending()
            return False
        return self._wanted

    def update(self, t_ns: int, *, state_names, **state) -> None:
        """Hand over one frame of one cell (``LiveView.update``'s arguments)."""
        self.update_stations(t_ns, [state], state_names)

    def update_stations(self, t_ns: int, states: list, state_names) -> None:
        """Hand over one frame of every station (``LiveView.update_stations``'s arguments)."""
        if self.failure is not None:
            return
        data = pickle.dumps((t_ns, states, tuple(state_names)), protocol=pickle.HIGHEST_PROTOCOL)
        self._pending = LENGTH.pack(len(data)) + data
        self._wanted = False
        self.frames_sent += 1
        self._send_pending()

    def _stop(self) -> None:
        try:
            self._sock.close()  # the child reads the end of its input and stops its server
        except OSError:
            pass
        try:
            self._proc.wait(STOP_WAIT_S)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait(1.0)

    def close(self) -> None:
        """Stop the server and its process, in at most about ``STOP_WAIT_S``."""
        self.failure = self.failure or 'closed'
        self._stop()


def _serve(sock: socket.socket) -> None:
    """Run the live view for the node at the other end of ``sock``, until it closes."""
    import signal

    from sorter_sim.frontends.live_view import LiveView

    # Ctrl-C reaches the whole process group: the node ends this process by closing
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    layout, host, port, prefix, max_rate_hz, stations = _recv_blocking(sock)
    try:
        view = LiveView(
            layout, host=host, port=port, prefix=prefix, max_rate_hz=max_rate_hz, stations=stations
        )
    except ValueError as exc:
        _send_blocking(sock, ('error', str(exc)))
        return
    _send_blocking(sock, ('ready', view.port))
    try:  # started (at the node's priority: its start is the node's too), it yields
        os.nice(NICE)
    except OSError:  # a system that refuses it: the view draws at the node's priority
        pass
    tick = min(0.01, 0.25 * view.min_wall_interval)
    buf = bytearray()
    asked = said_listening = False
    try:
        while True:
            readable, _, _ = select.select([sock], [], [], tick)
            if readable:
                data = sock.recv(1 << 20)
                if not data:
                    break
                buf += data
                frame = None
                while len(buf) >= LENGTH.size:
                    (n,) = LENGTH.unpack_from(buf)
                    if len(buf) < LENGTH.size + n:
                        break
                    frame = bytes(buf[LENGTH.size : LENGTH.size + n])
                    del buf[: LENGTH.size + n]
                if frame is not None:
                    t_ns, states, state_names = pickle.loads(frame)
                    view.update_stations(t_ns, states, state_names)
                    asked = False
            if not asked and view.due():
                sock.sendall(WANT)
                asked = said_listening = True
            elif said_listening and not view.listening():
                sock.sendall(IDLE)
                asked = said_listening = False
    except OSError:
        pass  # the node went away
    finally:
        view.close()


if __name__ == '__main__':
    _serve(socket.socket(fileno=int(sys.argv[1])))
    os._exit(0)  # the server's threads are not waited for: close() gave them their time
