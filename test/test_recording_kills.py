"""
A recording killed any way loses at most the last second and is read by independent readers.

A process records as the nodes do (``recording_driver.py``: the nodes' recorder and its
writer process, a message every 2 ms stamped with the wall clock) and is killed mid-chunk:
the recording process alone, its writer alone, or both at once with SIGKILL to their
process group (a container stopped, an OOM kill of the group, the power gone). The file
is then read as it was left, or through ``sorter recover``, by mcap's default reader
(``make_reader``, which seeks to the summary) and by rosbags (its own Jazzy type store):
every message handed over more than a second before the kill is there, numbered without
a gap, and the file carries rosbag2's metadata record with ``ros_distro``.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

BIN = Path(sys.executable).parent
DRIVER = Path(__file__).with_name('recording_driver.py')
RUN_S = 2.7  # s of recording before the kill: a chunk closes every 0.5 s, so it is mid-chunk


def _read_both(path: Path) -> list[tuple[int, int]]:
    """Return (number, time [ns]) of every message, by mcap's default reader and by rosbags."""
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    with open(path, 'rb') as f:
        reader = make_reader(f)
        assert reader.get_summary() is not None, 'no summary: the file is not complete'
        by_mcap = [(m.log_time, m.data) for _, _, m in reader.iter_messages()]
    store = get_typestore(Stores.ROS2_JAZZY)
    got = []
    with AnyReader([path], default_typestore=store) as reader:
        for conn, t, raw in reader.messages():
            got.append((int(reader.deserialize(raw, conn.msgtype).data), t))
    assert [t for t, _ in by_mcap] == [t for _, t in got]  # the two readers agree
    return got


def _bag_metadata(path: Path) -> list[dict]:
    """Return the rosbag2 metadata records of a file, read as a stream (torn ends tolerated)."""
    from mcap.records import Metadata
    from mcap.stream_reader import StreamReader

    found = []
    with open(path, 'rb') as f:
        try:
            for record in StreamReader(f).records:
                if isinstance(record, Metadata) and record.name == 'rosbag2':
                    found.append(dict(record.metadata))
        except Exception:
            pass
    return found


def _readable_as_left(path: Path) -> bool:
    try:
        _read_both(path)
    except Exception:
        return False
    return True


def _group_gone(pgid: int, timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.05)
    raise AssertionError(f'process group {pgid} still runs {timeout_s:g} s after the kill')


@pytest.mark.parametrize('kill', ['node', 'writer', 'group'])
def test_a_recording_killed_any_way_loses_at_most_the_last_second(kill, tmp_path):
    path = tmp_path / f'{kill}.mcap'
    proc = subprocess.Popen(
        [sys.executable, str(DRIVER), str(path)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group, as a container's processes are
    )
    try:
        writer = int(proc.stdout.readline())
        time.sleep(RUN_S)
        killed_at = time.time_ns()
        if kill == 'node':
            proc.send_signal(signal.SIGKILL)
        elif kill == 'writer':
            os.kill(writer, signal.SIGKILL)
            time.sleep(0.5)  # the recorder finds its writer gone, says so, and runs on
            assert proc.poll() is None, proc.stderr.read()[-2000:]
            os.killpg(proc.pid, signal.SIGKILL)
        else:
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(10)
        _group_gone(proc.pid)  # the writer, too, has ended (finished the file or been killed)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    err = proc.stderr.read()
    assert 'Traceback' not in err, err[-2000:]
    # rosbag2's metadata record with the distribution, from the first bytes on
    first = _bag_metadata(path)
    assert first and first[0]['ROS_DISTRO'] == 'jazzy'
    assert json.loads(first[0]['serialized_metadata'])['ros_distro'] == 'jazzy'
    as_left = _readable_as_left(path)
    # the writer finishes the file when only the recording process dies; else recover
    assert as_left == (kill == 'node'), kill
    readable = path
    if not as_left:
        readable = tmp_path / f'{kill}_recovered.mcap'
        out = subprocess.run(
            [str(BIN / 'sorter'), 'recover', str(path), str(readable)],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert out.returncode == 0 and not out.stderr, out.stderr[-2000:]
        assert len(out.stdout.strip().splitlines()) == 1 and 'lost' in out.stdout, out.stdout
    got = _read_both(readable)
    numbers = [n for n, _ in got]
    assert numbers == list(range(len(numbers)))  # every message up to the loss, in order
    lost_s = (killed_at - got[-1][1]) / 1e9
    assert lost_s <= 1.0, f'{kill}: the last message kept was handed over {lost_s:.2f} s before'
    assert len(numbers) > 200  # well over a second of messages at one every 2 ms (loaded)
    # the finished file's last rosbag2 record counts what it holds
    (meta,) = [m for m in _bag_metadata(readable)[-1:]]
    bag = json.loads(meta['serialized_metadata'])
    assert bag['message_count'] == len(numbers) and bag['ros_distro'] == 'jazzy'
    (topic,) = bag['topics_with_message_count']
    assert topic['topic_metadata']['name'] == '/counter'
    assert topic['topic_metadata']['type'] == 'std_msgs/msg/String'


def test_sorter_recover_refuses_what_it_cannot_recover_in_one_line(tmp_path):
    text = tmp_path / 'notes.mcap'
    text.write_text('not a recording\n')
    cases = {
        (tmp_path / 'missing.mcap', tmp_path / 'out.mcap'): 'is not a file',
        (text, tmp_path / 'out.mcap'): 'is not an MCAP file',
        (text, text): 'another file than the recording',
        (text, tmp_path / 'out.txt'): 'must name a .mcap file',
        (text, tmp_path / 'nowhere' / 'out.mcap'): 'does not exist',
    }
    for (src, dst), why in cases.items():
        out = subprocess.run(
            [str(BIN / 'sorter'), 'recover', str(src), str(dst)],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert out.returncode == 2, (src, dst, out.stderr)
        assert len(out.stderr.strip().splitlines()) == 1 and why in out.stderr, out.stderr
        assert 'Traceback' not in out.stderr
    assert not (tmp_path / 'out.mcap').exists()


def _torn_with(tmp_path: Path, last_chunk: bytes) -> Path:
    """Write a recording of three messages in one chunk, then ``last_chunk``, and no footer."""
    import zlib

    from mcap.data_stream import RecordBuilder
    from mcap.records import Channel, Chunk, Header, Message, Schema

    inner = RecordBuilder()
    Schema(id=1, name='std_msgs/msg/String', encoding='ros2msg', data=b'string data').write(inner)
    Channel(id=1, schema_id=1, topic='/counter', message_encoding='cdr', metadata={}).write(inner)
    for k in range(3):
        Message(channel_id=1, sequence=k, log_time=k, publish_time=k, data=b'x').write(inner)
    data = inner.end()
    out = RecordBuilder()
    Header(profile='ros2', library='test').write(out)
    Chunk(
        compression='',
        data=data,
        message_start_time=0,
        message_end_time=2,
        uncompressed_crc=zlib.crc32(data),
        uncompressed_size=len(data),
    ).write(out)
    path = tmp_path / 'bomb.mcap'
    path.write_bytes(b'\x89MCAP0\r\n' + out.end() + last_chunk)
    return path


def _bomb_chunk(compression: str, stated: int) -> bytes:
    """Return a chunk of 1 GiB of zeros, compressed to tens of kB, stating ``stated`` bytes."""
    from mcap.data_stream import RecordBuilder
    from mcap.records import Chunk

    zeros = bytes(1 << 20)
    if compression == 'zstd':
        import zstandard

        z = zstandard.ZstdCompressor().compressobj()
    else:
        import lz4.frame

        z = lz4.frame.LZ4FrameCompressor()
        head = z.begin()
    parts = [head] if compression == 'lz4' else []
    parts += [z.compress(zeros) for _ in range(1024)]
    parts.append(z.flush())
    b = RecordBuilder()
    Chunk(
        compression=compression,
        data=b''.join(parts),
        message_start_time=3,
        message_end_time=3,
        uncompressed_crc=0,
        uncompressed_size=stated,
    ).write(b)
    return b.end()


@pytest.mark.parametrize(
    'compression,stated,why',
    [
        ('zstd', 1 << 30, 'over the limit of'),  # states what it inflates to
        ('zstd', 1000, 'inflates to more than 1001 bytes, not the 1000 it states'),
        ('lz4', 1000, 'inflates to more than 1001 bytes, not the 1000 it states'),
    ],
)
def test_sorter_recover_keeps_a_chunk_that_inflates_to_1_gib_out_of_memory(
    tmp_path, compression, stated, why
):
    src = _torn_with(tmp_path, _bomb_chunk(compression, stated))
    assert src.stat().st_size < 5_000_000
    dst = tmp_path / 'out.mcap'
    # the command run in a process that says its own peak afterwards (VmHWM: the resident
    # high-water mark of this program's memory only; a child's ru_maxrss also counts the
    # image of the test's process it was forked from)
    peak = (
        'import sys\n'
        'from sorter_cell.cli import main\n'
        'rc = main(sys.argv[1:])\n'
        'with open("/proc/self/status") as f:\n'
        '    kb = next(line.split()[1] for line in f if line.startswith("VmHWM:"))\n'
        'print("peak kB", kb, file=sys.stderr)\n'
        'sys.exit(rc)\n'
    )
    done = subprocess.run(
        [sys.executable, '-c', peak, 'recover', str(src), str(dst)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    out, err = done.stdout, done.stderr
    assert done.returncode == 0, err
    kb = int(err.strip().splitlines()[-1].split()[-1])
    # the chunk is never inflated whole: the program stays far below its 1 GiB
    assert kb < 400 * 1024, f'{kb} kB at most'
    err = '\n'.join(err.strip().splitlines()[:-1])
    assert len(out.strip().splitlines()) == 1 and why in out, out
    assert '3 messages on 1 topic' in out and 'Traceback' not in err
    from mcap.reader import make_reader

    with open(dst, 'rb') as f:
        assert len(list(make_reader(f).iter_messages())) == 3


def _plain_recording(path: Path) -> None:
    from mcap.writer import Writer

    with open(path, 'wb') as f:
        w = Writer(f)
        w.start(profile='ros2', library='test')
        w.finish()


def test_sorter_recover_follows_no_link_and_replaces_only_a_recording(tmp_path):
    src = _torn_with(tmp_path, b'')
    victim = tmp_path / 'victim.txt'
    victim.write_text('kept\n')
    notes = tmp_path / 'notes.mcap'
    notes.write_text('my notes\n')
    (tmp_path / 'linked.mcap').symlink_to(victim)
    (tmp_path / 'parted.mcap.part').symlink_to(victim)
    cases = {
        'linked.mcap': 'is not a plain file: not written',
        'parted.mcap': 'is not a plain file: not written',
        'notes.mcap': 'is not a recording this command wrote: not overwritten',
    }
    for name, why in cases.items():
        out = subprocess.run(
            [str(BIN / 'sorter'), 'recover', str(src), str(tmp_path / name)],
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert out.returncode == 2, (name, out.stdout, out.stderr)
        assert len(out.stderr.strip().splitlines()) == 1 and why in out.stderr, out.stderr
    assert victim.read_text() == 'kept\n' and notes.read_text() == 'my notes\n'
    assert (tmp_path / 'parted.mcap.part').is_symlink()
    assert not (tmp_path / 'parted.mcap').exists()
    # a recording from an earlier run is replaced, as sorter scenario --record does
    earlier = tmp_path / 'earlier.mcap'
    _plain_recording(earlier)
    out = subprocess.run(
        [str(BIN / 'sorter'), 'recover', str(src), str(earlier)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0 and '3 messages on 1 topic' in out.stdout, out.stderr
