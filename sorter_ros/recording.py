"""
Recording what a node publishes to MCAP, as ROS 2 CDR with the message definitions embedded.

A node that records hands every message it publishes, at the moment it publishes it,
to a ``Recorder``: the recording is exactly what subscribers saw (the same CDR bytes,
the same topic names), stamped with the node's time (simulation time for the cell
and for a controller on ``use_sim_time``). The file follows the MCAP ``ros2``
profile as rosbag2 (Jazzy) writes it: schemas named ``pkg/msg/Type`` in ``ros2msg``
with their dependencies, messages in ``cdr``,
and each channel's ``offered_qos_profiles`` (the publisher's real QoS, in rosbag2's
YAML), so that ``ros2 bag info/play``, rosbags, Foxglove and ``mcap_ros2.reader``
read it and latched topics play back latched.

Several nodes of one process that name the same path share one open file (the demo
records the cell and its controller together); the file is finished (summary and
footer written) when the last of them closes it, which the nodes do when they are
destroyed, also after Ctrl-C. The file is written by a process of its own
(``recording_writer``), fed through a pipe the node never waits on: a node killed
outright loses only what it had not yet handed over (at most ``Recorder.FLUSH_S`` of
wall time), and its writer still finishes the file. A file being recorded is locked
(``flock``): a second process that names it is refused before it truncates anything.
A write that fails (the disk full), a writer killed or stalled stops the recording,
says so once through the callbacks given to ``open_recorder``, and leaves the file
readable up to its last complete chunk (the writer closes one at least every half
second; ``sorter recover`` makes a complete file of it); the node goes on publishing.
"""

from __future__ import annotations

import errno
import fcntl
import functools
import json
import os
import select
import subprocess
import sys
import threading
import time
from pathlib import Path

from rclpy.serialization import serialize_message
from rosidl_adapter.parser import parse_message_string

from sorter_ros.recording_writer import CHANNEL, FAILED_EXIT, FINISH, HEAD, MESSAGE, METADATA

SEPARATOR = '=' * 80
PIPE_BYTES = 1024 * 1024  # the pipe to a recording's writer


def publish_recorded(publisher, msg, recorder: Recorder | None, t_ns: int) -> None:
    """
    Publish ``msg`` (a message or its CDR bytes) and hand the same bytes to ``recorder``.

    With a recorder the message is serialized once, here, and published as those bytes
    (rclpy publishes serialized messages as they are): the recording holds exactly
    what went out, and recording costs no second serialization.

    Parameters
    ----------
    publisher : rclpy.publisher.Publisher
        The publisher.
    msg : message or bytes
        The message, or its CDR bytes.
    recorder : Recorder, optional
        The recording, if any.
    t_ns : int
        The simulated time [ns] it is stamped with in the recording.

    """
    if recorder is None or recorder.closed:
        publisher.publish(msg)
        return
    if isinstance(msg, (bytes, bytearray)):
        data = msg
    else:
        data = serialize_message(msg)
    channel = recorder.channel_of(publisher)
    publisher.publish(data)
    recorder.write_channel(channel, data, t_ns)


def type_name(msg_class) -> str:
    """
    Return 'pkg/msg/Type' of a rosidl message class.

    Parameters
    ----------
    msg_class : type
        A rosidl message class.

    Returns
    -------
    str
        Its name, ``pkg/msg/Type``.

    """
    pkg = msg_class.__module__.split('.')[0]
    return f'{pkg}/msg/{msg_class.__name__}'


def _share_dirs():
    # the ament index where a ROS environment is sourced (colcon, ros2 run), then the
    # interpreter's own prefix, where the message wheels put share/<pkg>/msg
    prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    return [Path(p) / 'share' for p in prefixes + [sys.prefix]]


def _msg_file_text(pkg: str, name: str) -> str:
    for share in _share_dirs():
        path = share / pkg / 'msg' / f'{name}.msg'
        if path.is_file():
            return path.read_text()
    raise LookupError(
        f'no definition of {pkg}/msg/{name} (looked in share/{pkg}/msg under '
        f'{", ".join(str(s.parent) for s in _share_dirs())})'
    )


@functools.lru_cache(maxsize=None)
def message_type_hash(name: str) -> str:
    """
    Return the RIHS01 type hash of ``pkg/msg/Type``, or '' when its package ships none.

    The hash rosidl generates into ``share/<pkg>/msg/<Type>.json`` and DDS announces
    with each publisher; rosbag2 (Jazzy) writes it as the channel's ``topic_type_hash``
    and the topic's ``type_description_hash``.

    Parameters
    ----------
    name : str
        ``pkg/msg/Type``, whose package's description (a JSON file beside its ``.msg``)
        lists the hash of the type and of each type it uses.

    Returns
    -------
    str
        ``RIHS01_<64 hex digits>``, or '' (a package built without descriptions).

    """
    pkg, _, short = name.split('/')
    for share in _share_dirs():
        path = share / pkg / 'msg' / f'{short}.json'
        if path.is_file():
            try:
                hashes = json.loads(path.read_text())['type_hashes']
            except (OSError, ValueError, KeyError, TypeError):
                return ''  # an unreadable description: no hash rather than no recording
            for entry in hashes:
                if entry.get('type_name') == name:
                    return str(entry.get('hash_string', ''))
            return ''
    return ''


@functools.lru_cache(maxsize=None)
def message_definition(name: str) -> str:
    """
    Return the full ros2msg definition of ``pkg/msg/Type``, dependencies appended.

    The format rosbag2 writes into MCAP schemas: the type's own text, then each type
    it uses (depth first, once each) after a line of 80 '=' and ``MSG: pkg/Type``.

    Parameters
    ----------
    name : str
        ``pkg/msg/Type``.

    Returns
    -------
    str
        The definition, its dependencies appended.

    """
    pkg, _, short = name.split('/')
    order: list[tuple[str, str]] = []

    def visit(p: str, n: str) -> None:
        spec = parse_message_string(p, n, _msg_file_text(p, n))
        for field in spec.fields:
            t = field.type
            if t.is_primitive_type():
                continue
            dep = (t.pkg_name, t.type)
            if dep not in order:
                order.append(dep)
                visit(*dep)

    visit(pkg, short)
    parts = [_msg_file_text(pkg, short)]
    for p, n in order:
        parts.append(f'{SEPARATOR}\nMSG: {p}/{n}\n{_msg_file_text(p, n)}')
    return '\n'.join(parts)


def prepare_channel(msg_class) -> None:
    """
    Read a message type's definition and hash now, at a node's start, for its recording.

    A channel is written with the first message on its topic: the definition's files
    read and parsed then (some milliseconds a type) would cost the running node, when
    the first parcel reaches a sensor. Both are kept for the process (the files do not
    change while it runs).

    Parameters
    ----------
    msg_class : type
        A rosidl message class a recorded publisher publishes.

    """
    name = type_name(msg_class)
    message_definition(name)
    message_type_hash(name)


def qos_profiles_yaml(qos) -> str:
    """
    Return ``offered_qos_profiles`` of one publisher as rosbag2 (Jazzy) writes it.

    A YAML list of one profile: policies by name (keep_last, reliable, transient_local,
    automatic, ...), durations as sec/nsec, as rosbag2's ``serialize_rclcpp_qos_vector``
    gives them and rosbag2's player (and rosbags) read them back.

    Parameters
    ----------
    qos : rclpy.qos.QoSProfile
        The publisher's profile.

    Returns
    -------
    str
        The YAML.

    """
    if qos is None:
        return ''

    def duration(d) -> str:
        ns = int(d.nanoseconds)
        return f'\n    sec: {ns // 10**9}\n    nsec: {ns % 10**9}'

    return (
        f'- history: {qos.history.name.lower()}\n'
        f'  depth: {int(qos.depth)}\n'
        f'  reliability: {qos.reliability.name.lower()}\n'
        f'  durability: {qos.durability.name.lower()}\n'
        f'  deadline:{duration(qos.deadline)}\n'
        f'  lifespan:{duration(qos.lifespan)}\n'
        f'  liveliness: {qos.liveliness.name.lower()}\n'
        f'  liveliness_lease_duration:{duration(qos.liveliness_lease_duration)}\n'
        f'  avoid_ros_namespace_conventions: '
        f'{"true" if qos.avoid_ros_namespace_conventions else "false"}'
    )


class Recorder:
    """
    One MCAP file being written; use ``open_recorder`` so nodes of a process share it.

    The file is written by a process of its own (``recording_writer``): ``write`` only
    frames the message's CDR bytes into a buffer, which goes to that process through a
    pipe every ``FLUSH_BYTES`` or ``FLUSH_S`` of wall time, without ever waiting on it.
    MCAP's framing and LZ4 compression in the node's interpreter cost about as much as
    publishing (they hold the GIL the physics needs); a thread would keep them there.
    A writer that falls ``BACKLOG_BYTES`` behind (stalled) or ends (killed, or a failed
    write) stops the recording with one message; the node goes on. ``write`` takes a
    message object or its CDR bytes. Thread-safe. ``failure`` says why the recording
    stopped early (None while it runs or after a clean close).
    """

    FLUSH_BYTES = 256 * 1024
    FLUSH_S = 0.05
    BACKLOG_BYTES = 64 * 1024 * 1024
    CLOSE_WAIT_S = 20.0

    def __init__(self, path: str | Path, chunk_size: int = 1024 * 1024):
        self.path = Path(path)
        # opened without truncating, locked, then truncated: a file another process is
        # recording is refused whole, not emptied under it
        fd = os.open(self.path, os.O_WRONLY | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise ValueError(
                    f'{str(path)[:200]!r} is being recorded by another process'
                ) from None
            raise
        os.ftruncate(fd, 0)
        # the writer shares the open file and so its lock: held until both let go
        self._fd = fd
        try:
            self._proc = subprocess.Popen(
                [sys.executable, '-m', 'sorter_ros.recording_writer', str(fd), str(chunk_size)],
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                pass_fds=(fd,),
            )
        except OSError:
            os.close(fd)  # and with it the lock: the path can be tried again
            raise
        self._pipe = self._proc.stdin.fileno()
        os.set_blocking(self._pipe, False)
        try:  # a larger pipe: fewer, larger hand-overs (Linux; 1 MiB is its default limit)
            fcntl.fcntl(self._pipe, fcntl.F_SETPIPE_SZ, PIPE_BYTES)
        except (AttributeError, OSError):
            pass
        self._pending = bytearray()
        self._last_flush = time.monotonic()
        self._channels: dict[str, int] = {}
        self._by_publisher: dict = {}  # publisher -> its channel (channel_of)
        self._lock = threading.Lock()
        self._users = 0
        self.closed = False
        self.failure: str | None = None
        self.on_failure: list = []
        self.messages = 0
        # topics the nodes write as they publish (publish_recorded): a TopicRecorder
        # of the same file leaves them to the nodes
        self.published: set[str] = set()

    def _fail(self, reason: str, written: int | str | None = None) -> None:
        """Stop recording: say why, once; the writer finishes nothing more."""
        self.closed = True
        if written is None:
            written = self.messages
        self.failure = (
            f'recording to {str(self.path)[:200]} stopped: {reason} after {written} '
            'messages; the file is readable up to its last complete chunk '
            '(sorter recover writes a complete copy of it)'
        )
        self._pending = bytearray()
        if self._proc.poll() is None:
            self._proc.kill()  # a stalled writer must not finish a file with a gap
        self._release()
        if self.on_failure:  # said once, by the node that opened the file
            self.on_failure[0](self.failure)

    def _writer_ended(self) -> None:
        """Stop recording after the writer's pipe broke, saying what it said or that it ended."""
        try:
            code = self._proc.wait(1.0)
        except subprocess.TimeoutExpired:
            code = None
        said = b''
        if code is not None:
            said = self._proc.stdout.read() or b''
        words = said.decode(errors='replace').split(maxsplit=2)
        if code == FAILED_EXIT and len(words) == 3 and words[0] == 'failed':
            self._fail(words[2].strip(), words[1])
        else:
            self._fail(f'its writer process ended (exit status {code})')

    def _release(self) -> None:
        for close in (self._proc.stdin.close, self._proc.stdout.close):
            try:
                close()
            except OSError:
                pass
        try:
            os.close(self._fd)  # with the writer gone too, the file's lock goes
        except OSError:
            pass

    def _flush(self) -> None:
        """Hand the writer what it takes now, without waiting; caller holds the lock."""
        self._last_flush = time.monotonic()
        while self._pending:
            try:
                n = os.write(self._pipe, self._pending)
            except BlockingIOError:
                break
            except (BrokenPipeError, OSError):
                self._writer_ended()
                return
            del self._pending[:n]
        if len(self._pending) > self.BACKLOG_BYTES:
            self._fail(
                f'its writer process fell {self.BACKLOG_BYTES // 2**20} MiB behind '
                '(stalled, or the disk too slow)'
            )

    def _frame(self, kind: int, channel: int, t_ns: int, payload: bytes) -> None:
        self._pending += HEAD.pack(kind, channel, t_ns, len(payload))
        self._pending += payload
        if (
            len(self._pending) >= self.FLUSH_BYTES
            or time.monotonic() - self._last_flush >= self.FLUSH_S
        ):
            self._flush()

    def _channel(self, topic: str, msg_type: str, qos=None) -> int:
        channel = len(self._channels) + 1
        self._channels[topic] = channel
        definition = message_definition(msg_type)
        spec = {
            'topic': topic,
            'type': msg_type,
            'definition': definition,
            'qos': qos_profiles_yaml(qos),
            'type_hash': message_type_hash(msg_type),
        }
        self._frame(CHANNEL, channel, 0, json.dumps(spec).encode())
        return channel

    def write(self, topic: str, msg, t_ns: int, msg_type=None, qos=None) -> None:
        """
        Write ``msg`` published on ``topic`` at ``t_ns``.

        ``msg`` is a message, or its CDR bytes with ``msg_type`` (the message class or
        'pkg/msg/Type'), which is needed only the first time a topic is written; ``qos``
        is the publisher's QoS profile, recorded with the topic's channel.

        Parameters
        ----------
        topic : str
            The topic.
        msg : message or bytes
            The message, or its CDR bytes.
        t_ns : int
            The simulated time [ns].
        msg_type : type, optional
            The message class, with CDR bytes.
        qos : rclpy.qos.QoSProfile, optional
            The publisher's profile, recorded with the channel.

        """
        if isinstance(msg, (bytes, bytearray)):
            data = msg
        else:
            data = serialize_message(msg)
            msg_type = type(msg)
        with self._lock:
            if self.closed:
                return
            channel = self._channels.get(topic)
            if channel is None:
                if not isinstance(msg_type, str):
                    msg_type = type_name(msg_type)
                channel = self._channel(topic, msg_type, qos)
            self.messages += 1
            self._frame(MESSAGE, channel, t_ns, data)

    def channel_of(self, publisher) -> int:
        """
        Return the channel of a publisher of this process, made the first time it is asked.

        Its topic, type and QoS are asked of rclpy once per publisher (a topic name is a
        call into its C handle): ``write_channel`` then costs a message no more than its
        frame. The topic counts from now as the nodes' own (``published``).

        Parameters
        ----------
        publisher : rclpy.publisher.Publisher
            The publisher.

        Returns
        -------
        int
            Its channel; 0 when the recording has stopped (nothing is written to it).

        """
        channel = self._by_publisher.get(publisher)
        if channel is not None:
            return channel
        topic = publisher.topic_name
        self.published.add(topic)
        with self._lock:
            if self.closed:
                return 0
            channel = self._channels.get(topic)
            if channel is None:
                msg_type = type_name(publisher.msg_type)
                channel = self._channel(topic, msg_type, publisher.qos_profile)
            self._by_publisher[publisher] = channel
            return channel

    def write_channel(self, channel: int, data: bytes, t_ns: int) -> None:
        """
        Write CDR ``data`` on a channel from ``channel_of``, at ``t_ns``.

        Parameters
        ----------
        channel : int
            The channel (0: the recording had stopped, nothing is written).
        data : bytes
            The message's CDR bytes.
        t_ns : int
            The simulated time [ns].

        """
        with self._lock:
            if self.closed or not channel:
                return
            self.messages += 1
            self._frame(MESSAGE, channel, t_ns, data)

    def flush(self) -> None:
        """Hand the writer everything written so far that it takes now, without waiting."""
        with self._lock:
            if not self.closed:
                self._flush()

    def add_metadata(self, name: str, values: dict[str, str]) -> None:
        """
        Write a metadata record (``name`` and string key/values), e.g. a node's parameters.

        Parameters
        ----------
        name : str
            The record's name.
        values : dict
            Its string keys and values.

        """
        with self._lock:
            if not self.closed:
                payload = json.dumps({'name': name, 'values': dict(values)}).encode()
                self._frame(METADATA, 0, 0, payload)

    def close(self) -> None:
        """
        Finish the file (summary and footer): it is complete and indexed after this.

        Waits for the writer to take the rest and finish, at most ``CLOSE_WAIT_S``.
        """
        with self._lock:
            if self.closed:
                return
            self._pending += HEAD.pack(FINISH, 0, 0, 0)
            deadline = time.monotonic() + self.CLOSE_WAIT_S
            while self._pending and time.monotonic() < deadline:
                try:
                    n = os.write(self._pipe, self._pending)
                except BlockingIOError:
                    select.select([], [self._pipe], [], 0.05)
                    continue
                except (BrokenPipeError, OSError):
                    self._writer_ended()
                    return
                del self._pending[:n]
            if self._pending:
                self._fail(f'its writer process took nothing for {self.CLOSE_WAIT_S:g} s')
                return
            try:
                code = self._proc.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                self._fail(f'its writer process did not finish in {self.CLOSE_WAIT_S:g} s')
                return
            if code != 0:
                self._writer_ended()
                return
            self.closed = True
            self._release()


_open: dict[Path, Recorder] = {}
_open_lock = threading.Lock()


def recording_problem(path: str) -> str | None:
    """
    Say why ``path`` cannot take a recording (None when it can), without touching it.

    Parameters
    ----------
    path : str or Path
        Where the recording would go.

    Returns
    -------
    str or None
        Why it cannot, or None.

    """
    p = Path(path)
    if p.suffix.lower() != '.mcap':
        return f'must name a .mcap file, got {path[:200]!r}'
    if p.is_dir():
        return f'{path[:200]!r} is a directory'
    parent = p.parent if str(p.parent) else Path('.')
    if not parent.is_dir():
        return f'folder {str(parent)[:200]!r} does not exist'
    if not os.access(parent, os.W_OK) or (p.exists() and not os.access(p, os.W_OK)):
        return f'{path[:200]!r} is not writable'
    return None


def open_recorder(path: str, on_failure=None) -> Recorder:
    """
    Return the recorder of ``path``, opening the file if this process has not yet.

    ``on_failure(text)``: how the first opener is told, once, that the recording stopped
    early (a write failed); the others share the file and the news.
    Raises ValueError with one line when the path cannot take a recording (another
    process records it, no folder, not writable, ...).

    Parameters
    ----------
    path : str or Path
        The MCAP file.
    on_failure : callable
        ``on_failure(text)``: how a failure to write is reported.

    Returns
    -------
    Recorder
        The recorder, shared by every user in this process.

    """
    problem = recording_problem(path)
    key = Path(path).resolve()
    with _open_lock:
        rec = _open.get(key)
        if rec is None or (rec.closed and rec._users == 0):
            if problem:
                raise ValueError(problem)
            try:
                rec = Recorder(key)
            except OSError as exc:
                raise ValueError(f'cannot write {path[:200]!r}: {exc.strerror or exc}') from None
            _open[key] = rec
        rec._users += 1
        if on_failure is not None:
            rec.on_failure.append(on_failure)
        return rec


def release_recorder(rec: Recorder) -> None:
    """
    Give back a recorder from ``open_recorder``; the last user finishes the file.

    Parameters
    ----------
    rec : Recorder
        A recorder from ``open_recorder``.

    """
    with _open_lock:
        rec._users -= 1
        if rec._users > 0:
            return
        _open.pop(rec.path, None)
    rec.close()
