"""
The process that writes a recording: MCAP framing, LZ4 compression and the file, off the node.

``Recorder`` (``recording.py``) starts it with the recording's file descriptor (opened,
locked and truncated by the node, so the lock covers both processes) and streams it
frames on its standard input; this process turns them into MCAP records. Nothing
here imports ROS: the node sends each schema's text with the channel that first uses it.

A frame is a fixed head (``HEAD``: kind, channel id, time [ns], payload length) and its
payload: ``CHANNEL`` (JSON: topic, schema name, schema text, QoS YAML, type hash), ``MESSAGE``
(the CDR bytes), ``METADATA`` (JSON: name, values), ``FINISH``. The file is finished
(summary and footer) on ``FINISH`` and also when the input ends without it (the node
was killed) or this process gets SIGTERM: what reached it is a complete file.

A chunk is closed and written out at least every ``CHUNK_S`` of wall time, and the
file synced then (``fdatasync``): this process killed with the node (a whole process
group, a container stopped, the power gone) leaves every message handed over more
than about a second before in complete chunks, which ``sorter recover`` turns into a
complete file. Every file opens with rosbag2's ``rosbag2`` metadata record (the bag's
``serialized_metadata`` with ``ros_distro``, and ``ROS_DISTRO``) and a finished one
repeats it with the counts, as rosbag2's MCAP storage writes it on close. SIGINT
is ignored: Ctrl-C on a terminal reaches the whole process group, and the node
finishes its recording through ``FINISH`` as it shuts down. A write that fails (the
disk full) ends this process with status 3 after one line on its standard output,
``failed <messages written> <reason>``, which the node reports.
"""

from __future__ import annotations

import json
import os
import select
import signal
import struct
import sys
import time

import yaml

HEAD = struct.Struct('<BHqI')  # kind, channel id, time [ns], payload length
CHANNEL, MESSAGE, METADATA, FINISH = 1, 2, 3, 4
FAILED_EXIT = 3
PROFILE = 'ros2'  # MCAP's profile of ROS 2 recordings, as rosbag2 writes them
CHUNK_S = 0.5  # s of wall time a chunk stays open at most: what a kill of both loses
# the distribution the package is built for (its rclpy and message wheels are Jazzy's);
# a sourced ROS environment says its own
ROS_DISTRO = os.environ.get('ROS_DISTRO') or 'jazzy'
BAG_VERSION = 9  # rosbag2's metadata version of Jazzy


class _Terminated(Exception):
    pass


class WriteFailed(Exception):
    """A write to the file failed after ``messages`` messages."""

    def __init__(self, messages: int, reason: str):
        super().__init__(reason)
        self.messages = messages


def _on_term(signum, frame):
    raise _Terminated


class _Input:
    """The frames' pipe, read so that the writer gets a turn (``idle``) while it waits."""

    def __init__(self, stream, idle):
        self._fd = stream.fileno()
        self._idle = idle

    def read_exactly(self, n: int) -> bytes | None:
        """Return ``n`` bytes, or None when the input ends first (a torn last frame is dropped)."""
        parts, got = [], 0
        while got < n:
            ready, _, _ = select.select([self._fd], [], [], CHUNK_S / 2)
            if not ready:
                self._idle()
                continue
            data = os.read(self._fd, n - got)
            if not data:
                return None
            parts.append(data)
            got += len(data)
        return b''.join(parts)


def bag_metadata(
    topics: dict | None = None, counts: dict | None = None, span=None, distro: str = ROS_DISTRO
) -> dict:
    """
    Return the ``rosbag2`` metadata record's values, as rosbag2's MCAP storage writes them.

    ``serialized_metadata`` is the bag's metadata (version 9, with ``ros_distro``) in
    YAML; ``ROS_DISTRO`` is where older readers look. Each topic is in the schema
    rosbag2 decodes for version 9 (``rosbag2_storage/yaml.hpp``): ``offered_qos_profiles``
    a YAML sequence of profiles (a string only up to version 8) and
    ``type_description_hash`` the type's RIHS01 hash (a string from version 7).

    Parameters
    ----------
    topics : dict, optional
        {topic: (type, QoS YAML, type hash)} of the channels so far.
    counts : dict, optional
        {topic: messages}.
    span : (int, int), optional
        The first and last message time [ns].
    distro : str
        The ROS distribution the messages are of.

    """
    topics, counts = topics or {}, counts or {}
    first, last = span or (0, 0)
    meta = {
        'version': BAG_VERSION,
        'storage_identifier': 'mcap',
        'duration': {'nanoseconds': last - first},
        'starting_time': {'nanoseconds_since_epoch': first},
        'message_count': sum(counts.values()),
        'topics_with_message_count': [
            {
                'topic_metadata': {
                    'name': topic,
                    'type': msg_type,
                    'serialization_format': 'cdr',
                    # the channel's YAML text, as a sequence: version 9 decodes a
                    # string here as no profiles at all and refuses the record
                    'offered_qos_profiles': (yaml.safe_load(qos) or []) if qos else [],
                    'type_description_hash': type_hash,
                },
                'message_count': counts.get(topic, 0),
            }
            for topic, (msg_type, qos, type_hash) in topics.items()
        ],
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [],
        'files': [],
        'custom_data': {},
        'ros_distro': distro,
    }
    # JSON is YAML: rosbag2's yaml-cpp reads it as it reads its own dump
    return {'serialized_metadata': json.dumps(meta, indent=1), 'ROS_DISTRO': distro}


class BagCounts:
    """
    What a bag holds so far, by channel: its topics, messages per topic, time span.

    What the ``rosbag2`` metadata record counts (``record``), kept as the file is
    written or, by ``sorter recover``, as it is read back.
    """

    def __init__(self):
        self.topics: dict[str, tuple[str, str, str]] = {}  # topic -> (type, QoS YAML, hash)
        self.counts: dict[str, int] = {}
        self.span: tuple[int, int] | None = None  # first and last message time [ns]
        self.messages = 0
        self._topic_of: dict[int, str] = {}

    def channel(
        self, channel: int, topic: str, msg_type: str, qos: str, type_hash: str = ''
    ) -> None:
        self.topics[topic] = (msg_type, qos, type_hash)
        self._topic_of[channel] = topic

    def message(self, channel: int, t_ns: int) -> None:
        topic = self._topic_of[channel]
        self.counts[topic] = self.counts.get(topic, 0) + 1
        first, last = self.span or (t_ns, t_ns)
        self.span = (min(first, t_ns), max(last, t_ns))
        self.messages += 1

    def record(self, distro: str = ROS_DISTRO) -> dict:
        """Return the ``rosbag2`` metadata record's values for what was counted."""
        return bag_metadata(self.topics, self.counts, self.span, distro)


class _Bag:
    """One MCAP file in the making: its writer, channels and counts, chunks closed in time."""

    def __init__(self, out, chunk_size: int):
        from mcap.writer import CompressionType, Writer

        self._out = out
        # LZ4 chunks rather than zstd: files about 1.5x larger, written faster; the data
        # section's CRC too, so a reader finds a damaged file as such
        self.writer = Writer(
            out, chunk_size=chunk_size, compression=CompressionType.LZ4, enable_data_crcs=True
        )
        self.writer.start(profile=PROFILE, library='sorter_cell')
        self.writer.add_metadata(name='rosbag2', data=bag_metadata())
        self.schemas: dict[str, int] = {}
        self.channels: dict[int, int] = {}
        self.counts = BagCounts()
        self._open_since: float | None = None  # when the open chunk took its first message
        self.sync()

    def frame(self, kind: int, channel: int, t_ns: int, payload: bytes) -> None:
        w = self.writer
        if kind == MESSAGE:
            w.add_message(
                channel_id=self.channels[channel], log_time=t_ns, publish_time=t_ns, data=payload
            )
            self.counts.message(channel, t_ns)
            if self._open_since is None:
                self._open_since = time.monotonic()
            elif time.monotonic() - self._open_since >= CHUNK_S:
                self.sync()
        elif kind == CHANNEL:
            c = json.loads(payload)
            schema = self.schemas.get(c['type'])
            if schema is None:
                schema = self.schemas[c['type']] = w.register_schema(
                    name=c['type'], encoding='ros2msg', data=c['definition'].encode()
                )
            self.channels[channel] = w.register_channel(
                topic=c['topic'],
                message_encoding='cdr',
                schema_id=schema,
                # both keys on every channel, as rosbag2's MCAP storage writes them
                metadata={
                    'offered_qos_profiles': c['qos'],
                    'topic_type_hash': c.get('type_hash', ''),
                },
            )
            self.counts.channel(channel, c['topic'], c['type'], c['qos'], c.get('type_hash', ''))
        elif kind == METADATA:
            m = json.loads(payload)
            w.add_metadata(name=m['name'], data=m['values'])

    def idle(self) -> None:
        """Close a chunk that has waited ``CHUNK_S`` while no frame came."""
        if self._open_since is not None and time.monotonic() - self._open_since >= CHUNK_S:
            self.sync()

    def sync(self) -> None:
        """Write the open chunk out and sync the file: what it holds survives any kill."""
        self.writer.flush()
        self._open_since = None
        try:
            os.fdatasync(self._out.fileno())
        except (AttributeError, OSError, ValueError):
            pass  # a pipe or a file system without it: written is what can be

    def finish(self) -> None:
        self.writer.add_metadata(name='rosbag2', data=self.counts.record())
        self.writer.finish()


def write_recording(stream, out, chunk_size: int) -> int:
    """
    Turn the frames read from ``stream`` into an MCAP file on ``out``; return the messages.

    Parameters
    ----------
    stream : binary file
        The frames (a pipe or a file: read through its descriptor).
    out : binary file
        The recording.
    chunk_size : int
        Bytes of messages per chunk at most (a chunk also closes every ``CHUNK_S``).

    Returns
    -------
    int
        The messages written.

    """
    try:
        bag = _Bag(out, chunk_size)
    except OSError as exc:
        raise WriteFailed(0, exc.strerror or str(exc)) from None
    frames = _Input(stream, bag.idle)
    try:
        while True:
            head = frames.read_exactly(HEAD.size)
            if head is None:
                break
            kind, channel, t_ns, length = HEAD.unpack(head)
            payload = frames.read_exactly(length) if length else b''
            if payload is None or kind == FINISH:
                break
            bag.frame(kind, channel, t_ns, payload)
    except _Terminated:
        pass
    except OSError as exc:
        raise WriteFailed(bag.counts.messages, exc.strerror or str(exc)) from None
    try:
        bag.finish()
    except OSError as exc:
        raise WriteFailed(bag.counts.messages, exc.strerror or str(exc)) from None
    return bag.counts.messages


def main(argv: list[str]) -> int:
    """Write the recording on descriptor ``argv[0]`` in chunks of ``argv[1]`` bytes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _on_term)
    fd, chunk_size = int(argv[0]), int(argv[1])
    out = os.fdopen(fd, 'wb')
    try:
        messages = write_recording(sys.stdin.buffer, out, chunk_size)
        try:
            out.close()  # the footer's last bytes go out here
        except OSError as exc:
            raise WriteFailed(messages, exc.strerror or str(exc)) from None
    except WriteFailed as exc:
        print(f'failed {exc.messages} {exc}', flush=True)
        return FAILED_EXIT
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
