"""
``sorter recover IN.mcap OUT.mcap``: a complete MCAP file from one cut short.

A recording whose writer was killed (alone, or with its node: a process group, a
container stopped, the power gone) ends without its summary and footer; seeking
readers (mcap's default reader, rosbags, ``ros2 bag``) refuse it. Its complete chunks
are intact, each closed within a second of its first message
(``sorter_ros.recording_writer``). This reads the file as a stream from its first
byte, checking every CRC, up to the first record that is torn or damaged, and writes
what came before into a new file with its summary, indexes and footer, as ``mcap
recover`` does: the same header, schemas, channels, messages (times and sequence
numbers unchanged), metadata and attachments, and a ``rosbag2`` metadata record with
the counts of what was recovered.
"""

from __future__ import annotations

import os
from pathlib import Path

RECORD_SIZE_LIMIT = 256 * 1024 * 1024  # no record of ours comes near; a flipped length may
# bytes a chunk may inflate to: ours hold 1 MiB of messages (sorter_ros.recording); a chunk
# of zeros 33 kB long states or inflates to 1 GiB, and is refused rather than held
CHUNK_INFLATE_LIMIT = 64 * 1024 * 1024


class ChunkTooLarge(ValueError):
    """A chunk that states or inflates to more than the limit: refused, never held whole."""


def chunk_records(chunk, limit: int = CHUNK_INFLATE_LIMIT) -> list:
    """
    Return the schemas, channels and messages of ``chunk``, inflating at most ``limit`` bytes.

    mcap's own ``breakup_chunk`` inflates a chunk whole, to whatever size its bytes
    make (a 33 kB zstd chunk of zeros: 1 GiB); here the chunk is inflated as a stream
    that stops one byte past its stated size or the limit, whichever is smaller, so
    memory stays bounded whatever the file says. Its CRC is checked as mcap does.

    Parameters
    ----------
    chunk : mcap.records.Chunk
        The chunk, as the stream reader returned it.
    limit : int
        Bytes the chunk may inflate to.

    Returns
    -------
    list
        Its records, in order.

    Raises
    ------
    ChunkTooLarge
        When the chunk states, or inflates to, more than ``limit`` bytes.
    ValueError
        When it inflates to another size than it states, or its CRC does not match.

    """
    import io
    import zlib

    from mcap.stream_reader import CRCValidationError, breakup_chunk

    stated = chunk.uncompressed_size
    if stated > limit:
        raise ChunkTooLarge(
            f'a chunk states {stated} bytes inflated, over the limit of {limit}: refused'
        )
    if chunk.compression == 'zstd':
        import zstandard

        with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(chunk.data)) as z:
            data = z.read(stated + 1)
    elif chunk.compression == 'lz4':
        import lz4.frame

        data = lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=stated + 1)
    elif chunk.compression == '':
        data = chunk.data
    else:
        raise ValueError(f'a chunk compressed with {chunk.compression[:40]!r}, unknown')
    if len(data) != stated:
        raise ValueError(
            f'a chunk inflates to {"more than " * (len(data) > stated)}{len(data)} bytes, '
            f'not the {stated} it states'
        )
    if chunk.uncompressed_crc != 0 and zlib.crc32(data) != chunk.uncompressed_crc:
        raise CRCValidationError(chunk.uncompressed_crc, zlib.crc32(data), chunk)
    plain = type(chunk)(
        compression='',
        data=data,
        message_end_time=chunk.message_end_time,
        message_start_time=chunk.message_start_time,
        uncompressed_crc=0,  # checked above
        uncompressed_size=stated,
    )
    return breakup_chunk(plain, validate_crc=False)


def add_arguments(parser) -> None:
    """
    Add ``sorter recover``'s arguments to its parser.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The verb's parser.

    """
    parser.add_argument('recording', help='the MCAP file cut short (it is only read)')
    parser.add_argument('out', help='the complete MCAP file to write (not the same file)')


def _problem(src: Path, dst: Path) -> str | None:
    from sorter_cell.scenario_cli import output_problem

    if not src.is_file():
        return f'{str(src)[:200]!r} is not a file'
    if dst.suffix.lower() != '.mcap':
        return f'the output must name a .mcap file, got {str(dst)[:200]!r}'
    if dst.exists() and dst.resolve() == src.resolve():
        return 'the output must be another file than the recording'
    parent = dst.parent if str(dst.parent) else Path('.')
    if not parent.is_dir():
        return f'folder {str(parent)[:200]!r} does not exist'
    # a link is never followed, a file that is no recording never replaced (as sorter
    # scenario --record); the .part written first is held to the same
    part = dst.with_name(dst.name + '.part')
    for path, what in ((dst, 'the output'), (part, 'the output\'s temporary file')):
        problem = output_problem(str(path), what, 'recording')
        if problem:
            return problem[:400]
    with open(src, 'rb') as f:
        if f.read(8) != b'\x89MCAP0\r\n':
            return f'{str(src)[:200]!r} is not an MCAP file (its first bytes are not the magic)'
    return None


class _Copy:
    """The records taken so far, written through a new writer with ids of its own."""

    def __init__(self, out):
        from mcap.writer import CompressionType, Writer

        self.writer = Writer(out, compression=CompressionType.LZ4, enable_data_crcs=True)
        self.started = False
        from sorter_ros.recording_writer import BagCounts

        self.schemas: dict[int, int] = {}
        self.channels: dict[int, int] = {}
        self.schema_names: dict[int, str] = {}
        self.counts = BagCounts()
        self.distro: str | None = None
        self.finished = False

    def take(self, record) -> None:
        from mcap.records import (
            Attachment,
            Channel,
            DataEnd,
            Footer,
            Header,
            Message,
            Metadata,
            Schema,
        )

        w = self.writer
        if isinstance(record, Header):
            w.start(profile=record.profile, library=record.library)
            self.started = True
        elif isinstance(record, Schema) and record.id not in self.schemas:
            self.schemas[record.id] = w.register_schema(
                name=record.name, encoding=record.encoding, data=record.data
            )
            self.schema_names[record.id] = record.name
        elif isinstance(record, Channel) and record.id not in self.channels:
            self.channels[record.id] = w.register_channel(
                topic=record.topic,
                message_encoding=record.message_encoding,
                schema_id=self.schemas.get(record.schema_id, 0),
                metadata=dict(record.metadata),
            )
            self.counts.channel(
                record.id,
                record.topic,
                self.schema_names.get(record.schema_id, ''),
                record.metadata.get('offered_qos_profiles', ''),
                record.metadata.get('topic_type_hash', ''),
            )
        elif isinstance(record, Message):
            w.add_message(
                channel_id=self.channels[record.channel_id],
                log_time=record.log_time,
                publish_time=record.publish_time,
                sequence=record.sequence,
                data=record.data,
            )
            self.counts.message(record.channel_id, record.log_time)
        elif isinstance(record, Metadata):
            if record.name == 'rosbag2':  # rewritten at the end with what was recovered
                self.distro = record.metadata.get('ROS_DISTRO') or self.distro
            else:
                w.add_metadata(name=record.name, data=dict(record.metadata))
        elif isinstance(record, Attachment):
            w.add_attachment(
                create_time=record.create_time,
                log_time=record.log_time,
                name=record.name,
                media_type=record.media_type,
                data=record.data,
            )
        elif isinstance(record, (DataEnd, Footer)):
            self.finished = True

    def finish(self) -> None:
        from sorter_ros.recording_writer import ROS_DISTRO

        self.writer.add_metadata(
            name='rosbag2', data=self.counts.record(self.distro or ROS_DISTRO)
        )
        self.writer.finish()


def recover(src: str | Path, dst: str | Path) -> dict:
    """
    Write into ``dst`` every record of ``src`` before its first torn or damaged one.

    Parameters
    ----------
    src : str or Path
        The recording, cut short or not (only read).
    dst : str or Path
        The complete file to write (replaced whole once it is written).

    Returns
    -------
    dict
        ``messages``, ``topics`` ({topic: count}), ``span_ns`` (first, last) or None,
        ``complete`` (the recording had its footer), ``damage`` (what ended the read, or
        None), ``bytes_read`` (where the last whole record taken ends) and ``bytes``
        (of ``src``).

    Raises
    ------
    ValueError
        With one line, when ``src`` is no MCAP file or ``dst`` cannot be written.

    """
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    src, dst = Path(src), Path(dst)
    problem = _problem(src, dst)
    if problem:
        raise ValueError(problem)
    part = dst.with_name(dst.name + '.part')
    damage = None
    fd = None
    try:
        part.unlink(missing_ok=True)  # a plain file an earlier run left (checked above)
        # created anew, never through a link put there since the check
        fd = os.open(part, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o644)
        with open(src, 'rb') as f, open(fd, 'wb') as out:
            copy = _Copy(out)
            reader = StreamReader(
                f, emit_chunks=True, validate_crcs=True, record_size_limit=RECORD_SIZE_LIMIT
            )
            read = 0  # the end of the last whole record taken
            try:
                for record in reader.records:
                    inner = chunk_records(record) if isinstance(record, Chunk) else [record]
                    for one in inner:
                        copy.take(one)
                    read = f.tell()
            except ChunkTooLarge as exc:
                damage = str(exc)
            except Exception as exc:  # whatever a torn or damaged byte makes the parser do
                damage = f'{type(exc).__name__} ({str(exc)[:120] or "no detail"})'
            else:
                read = f.tell()
            if not copy.started:
                raise ValueError(f'{str(src)[:200]!r} has no MCAP header to recover from')
            copy.finish()
        os.replace(part, dst)
    except OSError as exc:
        raise ValueError(f'cannot write {str(dst)[:200]!r}: {exc.strerror or exc}') from None
    finally:
        if fd is not None and part.is_file() and not part.is_symlink():
            part.unlink()  # ours, left when the read or the write failed
    return {
        'messages': copy.counts.messages,
        'topics': dict(copy.counts.counts),
        'span_ns': copy.counts.span,
        'complete': copy.finished and damage is None,
        'damage': damage,
        'bytes_read': read,
        'bytes': src.stat().st_size,
    }


def run(args) -> int | str:
    """Run ``sorter recover``; return 0, or one line saying what is wrong."""
    try:
        got = recover(args.recording, args.out)
    except ValueError as exc:
        return str(exc)
    span = ''
    if got['span_ns']:
        first, last = got['span_ns']
        span = f', {first / 1e9:.3f} s to {last / 1e9:.3f} s'
    cut = got['bytes'] - got['bytes_read']
    if got['complete']:
        lost = 'the recording was complete: nothing lost'
    elif cut == 0:
        lost = (
            f'nothing of the file is lost: it ends at byte {got["bytes_read"]}, at a '
            "record's end, only without its summary and footer"
        )
    else:
        why = got['damage'] or 'it ends without its summary and footer'
        lost = f'the last {cut} bytes (from byte {got["bytes_read"]}) are lost: {why}'
    topics = len(got['topics'])
    print(
        f'{args.out}: {got["messages"]} messages on {topics} topic{"s" * (topics != 1)}'
        f'{span}; {lost}'
    )
    return 0
