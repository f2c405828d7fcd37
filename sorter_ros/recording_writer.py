"""
The process that writes a recording: MCAP framing, LZ4 compression and the file, off the node.

``Recorder`` (``recording.py``) starts it with the recording's file descriptor (opened,
locked and truncated by the node, so the lock covers both processes) and streams it
frames on its standard input; this process turns them into MCAP records. Nothing
here imports ROS: the node sends each schema's text with the channel that first uses it.

A frame is a fixed head (``HEAD``: kind, channel id, time [ns], payload length) and its
payload: ``CHANNEL`` (JSON: topic, schema name, schema text, QoS YAML), ``MESSAGE``
(the CDR bytes), ``METADATA`` (JSON: name, values), ``FINISH``. The file is finished
(summary and footer) on ``FINISH`` and also when the input ends without it (the node
was killed) or this process gets SIGTERM: what reached it is a complete file. SIGINT
is ignored: Ctrl-C on a terminal reaches the whole process group, and the node
finishes its recording through ``FINISH`` as it shuts down. A write that fails (the
disk full) ends this process with status 3 after one line on its standard output,
``failed <messages written> <reason>``, which the node reports.
"""

from __future__ import annotations

import json
import os
import signal
import struct
import sys

HEAD = struct.Struct('<BHqI')  # kind, channel id, time [ns], payload length
CHANNEL, MESSAGE, METADATA, FINISH = 1, 2, 3, 4
FAILED_EXIT = 3
PROFILE = 'ros2'  # MCAP's profile of ROS 2 recordings, as rosbag2 writes them


class _Terminated(Exception):
    pass


class WriteFailed(Exception):
    """A write to the file failed after ``messages`` messages."""

    def __init__(self, messages: int, reason: str):
        super().__init__(reason)
        self.messages = messages


def _on_term(signum, frame):
    raise _Terminated


def _read_exactly(stream, n: int) -> bytes | None:
    """Return ``n`` bytes, or None when the input ends first (a torn last frame is dropped)."""
    data = stream.read(n)
    return data if data is not None and len(data) == n else None


def write_recording(stream, out, chunk_size: int) -> int:
    """
    Turn the frames read from ``stream`` into an MCAP file on ``out``; return the messages.

    Parameters
    ----------
    stream : binary file
        The frames.
    out : binary file
        The recording.
    chunk_size : int
        Bytes of messages per chunk.

    Returns
    -------
    int
        The messages written.

    """
    from mcap.writer import CompressionType, Writer

    # LZ4 chunks rather than zstd: files about 1.5x larger, written faster; 1 MiB chunks,
    # so a writer killed outright loses at most one of them; the data section's CRC too,
    # so a reader finds a damaged file as such
    writer = Writer(
        out, chunk_size=chunk_size, compression=CompressionType.LZ4, enable_data_crcs=True
    )
    writer.start(profile=PROFILE, library='sorter_cell')
    schemas: dict[str, int] = {}
    channels: dict[int, int] = {}
    messages = 0
    try:
        while True:
            head = _read_exactly(stream, HEAD.size)
            if head is None:
                break
            kind, channel, t_ns, length = HEAD.unpack(head)
            payload = _read_exactly(stream, length) if length else b''
            if payload is None or kind == FINISH:
                break
            if kind == MESSAGE:
                writer.add_message(
                    channel_id=channels[channel], log_time=t_ns, publish_time=t_ns, data=payload
                )
                messages += 1
            elif kind == CHANNEL:
                c = json.loads(payload)
                schema = schemas.get(c['type'])
                if schema is None:
                    schema = schemas[c['type']] = writer.register_schema(
                        name=c['type'], encoding='ros2msg', data=c['definition'].encode()
                    )
                channels[channel] = writer.register_channel(
                    topic=c['topic'],
                    message_encoding='cdr',
                    schema_id=schema,
                    metadata={'offered_qos_profiles': c['qos']},
                )
            elif kind == METADATA:
                m = json.loads(payload)
                writer.add_metadata(name=m['name'], data=m['values'])
    except _Terminated:
        pass
    except OSError as exc:
        raise WriteFailed(messages, exc.strerror or str(exc)) from None
    try:
        writer.finish()
    except OSError as exc:
        raise WriteFailed(messages, exc.strerror or str(exc)) from None
    return messages


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
