"""
Recording what a node publishes to MCAP, as ROS 2 CDR with the message definitions embedded.

A node that records hands every message it publishes, at the moment it publishes it,
to a ``Recorder``: the recording is exactly what subscribers saw (the same CDR bytes,
the same topic names), stamped with the node's time (simulation time for the cell
and for a controller on ``use_sim_time``). The file follows the MCAP ``ros2`` profile
(schema encoding ``ros2msg``, message encoding ``cdr``), which ``ros2 bag info``,
``ros2 bag play``, Foxglove and ``mcap_ros2.reader`` read.

Several nodes of one process that name the same path share one open file (the demo
records the cell and its controller together); the file is finished (summary and
footer written) when the last of them closes it, which the nodes do when they are
destroyed, also after Ctrl-C.
"""

from __future__ import annotations

import os
import sys
import threading
from pathlib import Path

from mcap.writer import CompressionType, Writer
from rclpy.serialization import serialize_message
from rosidl_adapter.parser import parse_message_string

PROFILE = 'ros2'
SEPARATOR = '=' * 80


def publish_recorded(publisher, msg, recorder: Recorder | None, t_ns: int) -> None:
    """
    Publish ``msg`` (a message or its CDR bytes) and hand the same bytes to ``recorder``.

    With a recorder the message is serialized once, here, and published as those bytes
    (rclpy publishes serialized messages as they are): the recording holds exactly
    what went out, and recording costs no second serialization.
    """
    if recorder is None:
        publisher.publish(msg)
        return
    if isinstance(msg, (bytes, bytearray)):
        data = msg
    else:
        data = serialize_message(msg)
    publisher.publish(data)
    recorder.write(publisher.topic_name, data, t_ns, publisher.msg_type)


def type_name(msg_class) -> str:
    """Return 'pkg/msg/Type' of a rosidl message class."""
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


def message_definition(name: str) -> str:
    """
    Return the full ros2msg definition of ``pkg/msg/Type``, dependencies appended.

    The format rosbag2 writes into MCAP schemas: the type's own text, then each type
    it uses (depth first, once each) after a line of 80 '=' and ``MSG: pkg/Type``.
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


class Recorder:
    """
    One MCAP file being written; use ``open_recorder`` so nodes of a process share it.

    ``write`` takes a message object or its CDR bytes. Thread-safe.
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self._stream = open(self.path, 'wb')
        # LZ4 chunks rather than zstd: cheaper on the node's thread, files about 1.5x larger;
        # 1 MiB chunks, so a process killed outright (no Ctrl-C) loses at most one of them
        self._writer = Writer(
            self._stream, chunk_size=1024 * 1024, compression=CompressionType.LZ4
        )
        self._writer.start(profile=PROFILE, library='sorter_cell')
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self._lock = threading.Lock()
        self._users = 0
        self.closed = False
        self.messages = 0

    def _channel(self, topic: str, msg_type: str) -> int:
        schema = self._schemas.get(msg_type)
        if schema is None:
            schema = self._writer.register_schema(
                name=msg_type.replace('/msg/', '/'),
                encoding='ros2msg',
                data=message_definition(msg_type).encode(),
            )
            self._schemas[msg_type] = schema
        channel = self._writer.register_channel(
            topic=topic, message_encoding='cdr', schema_id=schema
        )
        self._channels[topic] = channel
        return channel

    def write(self, topic: str, msg, t_ns: int, msg_type=None) -> None:
        """
        Write ``msg`` published on ``topic`` at ``t_ns``.

        ``msg`` is a message, or its CDR bytes with ``msg_type`` (the message class or
        'pkg/msg/Type'), which is needed only the first time a topic is written.
        """
        if isinstance(msg, (bytes, bytearray)):
            data = bytes(msg)
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
                channel = self._channel(topic, msg_type)
            self._writer.add_message(
                channel_id=channel, log_time=t_ns, publish_time=t_ns, data=data
            )
            self.messages += 1

    def add_metadata(self, name: str, values: dict[str, str]) -> None:
        """Write a metadata record (``name`` and string key/values), e.g. a node's parameters."""
        with self._lock:
            if not self.closed:
                self._writer.add_metadata(name=name, data=dict(values))

    def close(self) -> None:
        """Finish the file (summary and footer): it is complete and indexed after this."""
        with self._lock:
            if self.closed:
                return
            self.closed = True
            try:
                self._writer.finish()
            finally:
                self._stream.close()


_open: dict[Path, Recorder] = {}
_open_lock = threading.Lock()


def recording_problem(path: str) -> str | None:
    """Say why ``path`` cannot take a recording (None when it can), without touching it."""
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


def open_recorder(path: str) -> Recorder:
    """
    Return the recorder of ``path``, opening the file if this process has not yet.

    Raises ValueError with one line when the path cannot take a recording.
    """
    problem = recording_problem(path)
    key = Path(path).resolve()
    with _open_lock:
        rec = _open.get(key)
        if rec is None or rec.closed:
            if problem:
                raise ValueError(problem)
            try:
                rec = Recorder(key)
            except OSError as exc:
                raise ValueError(f'cannot write {path[:200]!r}: {exc.strerror or exc}') from None
            _open[key] = rec
        rec._users += 1
        return rec


def release_recorder(rec: Recorder) -> None:
    """Give back a recorder from ``open_recorder``; the last user finishes the file."""
    with _open_lock:
        rec._users -= 1
        if rec._users > 0:
            return
        _open.pop(rec.path, None)
    rec.close()
