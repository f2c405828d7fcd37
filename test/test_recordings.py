"""
Recordings that survive a killed node, a killed or stalled writer, a full disk, a rival.

rosbags (its own Jazzy type store, no code shared with this project or with mcap_ros2)
reads what the cell records; ``sorter replay`` reads every complete message of a file cut
short and refuses, in one line, what it cannot read.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import random
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

import pytest
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message, serialize_message
from test_sim_node import SHORT_CELL

from sorter_cell import replay
from sorter_ros.recording import Recorder
from sorter_sim.frontends.node import SimNode

BIN = Path(sys.executable).parent
MCAP_MAGIC = b'\x89MCAP0\r\n'


def _sim(ros, **overrides) -> SimNode:
    values = {**SHORT_CELL, 'arrival': 'gap', 'arrival_gap': [0.3, 0.5], **overrides}
    node = SimNode(
        context=ros.context,
        parameter_overrides=[Parameter(k, value=v) for k, v in values.items()],
    )
    return ros.add(node)


def _recorded(ros, path: Path, periods: int = 6000) -> Counter:
    node = _sim(ros, record_path=str(path))
    node.advance(periods)
    published = Counter(node.published)
    node.destroy_node()
    ros.nodes.remove(node)
    return published


def _replay(*argv) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(BIN / 'sorter'), 'replay', *map(str, argv)],
        capture_output=True,
        text=True,
        timeout=60,
    )


# ---------------------------------------------------------------- an independent reader
@pytest.mark.ros
def test_rosbags_reads_the_recording_with_its_own_jazzy_type_store(ros, tmp_path):
    from rosbags.highlevel import AnyReader
    from rosbags.interfaces import QosDurability, QosReliability
    from rosbags.typesys import Stores, get_typestore

    path = tmp_path / 'cell.mcap'
    published = _recorded(ros, path)
    store = get_typestore(Stores.ROS2_JAZZY)
    decoded, refused, qos = Counter(), Counter(), {}
    with AnyReader([path], default_typestore=store) as reader:
        for conn in reader.connections:
            assert conn.msgtype.count('/msg/') == 1, conn.msgtype  # pkg/msg/Type
            qos[conn.topic] = conn.ext.offered_qos_profiles
        for conn, _, raw in reader.messages():
            try:
                reader.deserialize(raw, conn.msgtype)
                decoded[conn.topic] += 1
            except Exception:
                refused[conn.topic] += 1
    assert decoded + refused == published
    # every message, the diverter's JointState included: the node writes its CDR at its
    # exact size, where rclpy's serializer (rmw_fastrtps) sizes a JointState with an empty
    # effort 8 bytes longer than its content, which rosbags refuses. Those bytes alone:
    from sensor_msgs.msg import JointState

    alone = JointState(name=['disk_angle', 'popup_stroke'], position=[0.5, 1.0])
    data = serialize_message(alone)
    with pytest.raises(Exception, match='size'):
        store.deserialize_cdr(data, 'sensor_msgs/msg/JointState')
    assert list(deserialize_message(data, JointState).position) == [0.5, 1.0]
    assert not refused, refused
    assert sum(decoded.values()) > 1000
    # that topic decoded by another reader (mcap_ros2) and by rclpy, every message
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with open(path, 'rb') as f:
        states = [
            m
            for _, ch, _, m in make_reader(
                f, decoder_factories=[DecoderFactory()]
            ).iter_decoded_messages(topics=['/diverter/state'])
        ]
    assert len(states) == published['/diverter/state']
    assert all(list(m.name) == ['disk_angle', 'popup_stroke'] for m in states)
    # latched topics record as latched: a player offers them transient local again
    (sensor,) = qos['/sensors/pe_scan']
    assert sensor.durability == QosDurability.TRANSIENT_LOCAL
    assert sensor.reliability == QosReliability.RELIABLE and sensor.depth == 1
    (stream,) = qos['/parcels/poses']
    assert stream.durability == QosDurability.VOLATILE


# rmw's names of each policy (rmw/qos_string_conversions.c), which rosbag2 (Jazzy) decodes
# a version-9 profile's policies from; anything else decodes to "unknown"
RMW_POLICIES = {
    'history': {'system_default', 'keep_last', 'keep_all'},
    'reliability': {'system_default', 'reliable', 'best_effort', 'best_available'},
    'durability': {'system_default', 'transient_local', 'volatile', 'best_available'},
    'liveliness': {'system_default', 'automatic', 'manual_by_topic', 'best_available'},
}


def _scalar(node, kind=str):
    """Read ``node`` as yaml-cpp's ``as<T>()``: a scalar of that kind, never a map or list."""
    assert not isinstance(node, (dict, list)) and node is not None, node
    if kind is int:
        assert isinstance(node, int) and not isinstance(node, bool), node
    if kind is bool:
        assert isinstance(node, bool), node
    return node if kind is not str else str(node)


def _decode_qos(node: dict) -> dict:
    """rosbag2's ``convert<rclcpp::QoS>::decode``: policies by number (<= 8) or by name."""
    if isinstance(node['history'], int) and not isinstance(node['history'], bool):
        policies = {k: _scalar(node[k], int) for k in RMW_POLICIES}
    else:
        policies = {k: _scalar(node[k]) for k in RMW_POLICIES}
        for k, names in RMW_POLICIES.items():
            assert policies[k] in names, f'{k}: {policies[k]!r} decodes as unknown'
    for k in ('deadline', 'lifespan', 'liveliness_lease_duration'):
        assert _scalar(node[k]['sec'], int) >= 0 and _scalar(node[k]['nsec'], int) >= 0
    _scalar(node['avoid_ros_namespace_conventions'], bool)
    return {**policies, 'depth': _scalar(node['depth'], int)}


def _decode_qos_vector(node, version: int) -> list[dict]:
    """``decode_for_version<std::vector<rclcpp::QoS>>``: a sequence, else a bad conversion."""
    assert isinstance(node, list), f'version {version}: offered_qos_profiles is not a sequence'
    return [_decode_qos(p) for p in node]


def _decode_bag_metadata(text: str) -> dict:
    """
    Decode a ``serialized_metadata`` as rosbag2 Jazzy's ``yaml.hpp`` does, or fail.

    ``convert<BagMetadata>::decode`` field by field with the version the record names:
    each topic's ``offered_qos_profiles`` a sequence from version 9 (before it, a
    string holding one), ``type_description_hash`` from 7, ``ros_distro`` from 8.
    """
    import yaml

    node = yaml.safe_load(text)
    version = _scalar(node['version'], int)
    _scalar(node['storage_identifier'])
    _scalar(node['duration']['nanoseconds'], int)
    _scalar(node['starting_time']['nanoseconds_since_epoch'], int)
    _scalar(node['message_count'], int)
    topics = {}
    assert isinstance(node['topics_with_message_count'], list)
    for info in node['topics_with_message_count']:
        meta = info['topic_metadata']
        qos = meta['offered_qos_profiles']
        if version >= 9:
            profiles = _decode_qos_vector(qos, version)
        else:
            profiles = _decode_qos_vector(yaml.safe_load(_scalar(qos)) or [], version)
        topics[_scalar(meta['name'])] = {
            'type': _scalar(meta['type']),
            'serialization_format': _scalar(meta['serialization_format']),
            'qos': profiles,
            'type_hash': _scalar(meta['type_description_hash']) if version >= 7 else '',
            'messages': _scalar(info['message_count'], int),
        }
    assert all(isinstance(_scalar(p), str) for p in node['relative_file_paths'])
    _scalar(node['compression_format']), _scalar(node['compression_mode'])
    assert isinstance(node['files'], list) and isinstance(node['custom_data'], dict)
    return {'version': version, 'topics': topics, 'ros_distro': _scalar(node['ros_distro'])}


@pytest.mark.ros
def test_rosbag2_decodes_the_metadata_record_and_channels_as_its_yaml_hpp_does(ros, tmp_path):
    import yaml
    from mcap.reader import make_reader
    from rclpy.node import Node
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String

    from sorter_ros.interface import SENSOR_QOS
    from sorter_ros.recording import open_recorder, publish_recorded, release_recorder

    # published and recorded as the nodes do: the publishers' own profiles and types
    path = tmp_path / 'bag.mcap'
    node = ros.add(Node('bag_probe', context=ros.context))
    state = node.create_publisher(JointState, '/probe/state', QoSProfile(depth=10))
    label = node.create_publisher(String, '/probe/label', SENSOR_QOS)
    rec = open_recorder(str(path))
    for i in range(5):
        publish_recorded(state, JointState(name=['a'], position=[float(i)]), rec, 10**9 + i)
    publish_recorded(label, String(data='A'), rec, 2 * 10**9)
    release_recorder(rec)
    with open(path, 'rb') as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        records = [m for m in reader.iter_metadata() if m.name == 'rosbag2']
    # the record written on close, the last, is the one that counts the messages
    bag = _decode_bag_metadata(records[-1].metadata['serialized_metadata'])
    assert bag['version'] == 9 and bag['ros_distro'] == 'jazzy'
    topics = bag['topics']
    assert {t: v['messages'] for t, v in topics.items()} == {'/probe/state': 5, '/probe/label': 1}
    (latched,) = topics['/probe/label']['qos']
    assert (latched['durability'], latched['reliability'], latched['depth']) == (
        'transient_local',
        'reliable',
        1,
    )
    (stream,) = topics['/probe/state']['qos']
    assert (stream['history'], stream['durability'], stream['depth']) == (
        'keep_last',
        'volatile',
        10,
    )
    # each channel as rosbag2's MCAP storage reads it: the profiles' YAML text
    # (to_rclcpp_qos_vector) and the type hash, the same as the record's
    for ch in summary.channels.values():
        assert set(ch.metadata) == {'offered_qos_profiles', 'topic_type_hash'}, ch.topic
        profiles = _decode_qos_vector(yaml.safe_load(ch.metadata['offered_qos_profiles']), 9)
        assert profiles == topics[ch.topic]['qos']
        assert ch.metadata['topic_type_hash'] == topics[ch.topic]['type_hash']
        # the hash rmw announces for the publisher's type (its graph, not our files)
        (info,) = node.get_publishers_info_by_topic(ch.topic)
        assert str(info.topic_type_hash).startswith('RIHS01_')
        assert ch.metadata['topic_type_hash'] == str(info.topic_type_hash)


# ---------------------------------------------------------------- kill, disk full, two writers
def _node_cmd(path: Path, *extra) -> list[str]:
    return [
        str(BIN / 'sim_node'),
        '--ros-args',
        '-p',
        'time_mode:=fast',
        '-p',
        f'record_path:={path}',
        '-p',
        'arrival:=gap',
        '-p',
        'arrival_gap:=[0.3, 0.5]',
        *extra,
    ]


def _writer_of(pid: int, timeout_s: float = 20.0) -> int:
    """Return the pid of the recording writer process that ``pid`` started."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for entry in Path('/proc').iterdir():
            if not entry.name.isdigit():
                continue
            try:
                stat = (entry / 'stat').read_text()
                cmd = (entry / 'cmdline').read_bytes()
            except OSError:
                continue
            ppid = int(stat.rsplit(')', 1)[1].split()[1])
            if ppid == pid and b'sorter_ros.recording_writer' in cmd:
                return int(entry.name)
        time.sleep(0.05)
    raise AssertionError(f'process {pid} started no recording writer in {timeout_s:g} s')


def _running(pid: int) -> bool:
    """Return whether ``pid`` runs (a zombie nobody reaped yet has ended)."""
    try:
        return Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0] != 'Z'
    except OSError:
        return False


def _wait_unlocked(path: Path, timeout_s: float = 30.0) -> None:
    """Wait until nobody holds the recording's lock (its writer has finished)."""
    import fcntl

    deadline = time.monotonic() + timeout_s
    with open(path, 'rb') as f:
        while True:
            try:
                fcntl.flock(f.fileno(), fcntl.LOCK_SH | fcntl.LOCK_NB)
                return
            except OSError:
                assert time.monotonic() < deadline, f'{path} still locked after {timeout_s:g} s'
                time.sleep(0.05)


def _wait_size(proc, path: Path, size: int, timeout_s: float = 45.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and (not path.exists() or path.stat().st_size < size):
        assert proc.poll() is None, 'the node ended'
        time.sleep(0.05)
    assert path.stat().st_size >= size, f'the node did not record {size} bytes in {timeout_s:g} s'


def _tolerant_count(path: Path) -> int:
    """Count the complete messages of a file as an independent tolerant reader does."""
    from mcap.stream_reader import StreamReader

    n = 0
    with open(path, 'rb') as f:
        try:
            for record in StreamReader(f).records:
                n += type(record).__name__ == 'Message'
        except Exception:
            pass
    return n


@pytest.mark.ros
def test_a_killed_node_leaves_a_complete_recording_its_writer_finished(tmp_path):
    path = tmp_path / 'killed.mcap'
    proc = subprocess.Popen(_node_cmd(path), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        writer = _writer_of(proc.pid)
        _wait_size(proc, path, 2_300_000)
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    # the writer outlives the node: it reads to the end of what it was handed and
    # finishes the file, summary and footer, then lets go of the lock
    _wait_unlocked(path)
    deadline = time.monotonic() + 10.0
    while _running(writer) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _running(writer), 'the writer did not end with its input'
    out = _replay(path, '--no-plot', '--json')
    assert out.returncode == 0, out.stderr
    s = json.loads(out.stdout)
    assert s['damage'] is None and s['messages'] > 10_000
    assert s['messages'] == _tolerant_count(path)


@pytest.mark.ros
def test_a_killed_writer_stops_the_recording_with_one_message_and_the_node_runs_on(tmp_path):
    path = tmp_path / 'writer_killed.mcap'
    proc = subprocess.Popen(
        _node_cmd(path), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        writer = _writer_of(proc.pid)
        _wait_size(proc, path, 2_300_000)
        os.kill(writer, signal.SIGKILL)
        time.sleep(3.0)  # well past the broken pipe, still running
        assert proc.poll() is None, proc.communicate()[1][-2000:]
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err[-3000:]
    assert 'Traceback' not in err, err[-3000:]
    stopped = [line for line in err.splitlines() if 'recording to' in line and 'stopped' in line]
    assert len(stopped) == 1 and 'writer process ended' in stopped[0], err[-3000:]
    # refused in one line, naming the damage and the way to read what is there
    out = _replay(path, '--no-plot')
    assert out.returncode == 2 and '--recover' in out.stderr and 'damaged' in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1 and 'Traceback' not in out.stderr
    out = _replay(path, '--no-plot', '--json', '--recover')
    assert out.returncode == 0, out.stderr
    s = json.loads(out.stdout)
    assert s['messages'] > 10_000 and 'without its summary' in s['damage']
    # every complete message: as many as an independent tolerant reader finds
    assert s['messages'] == _tolerant_count(path)


def test_a_stalled_writer_never_holds_the_node_and_stops_the_recording_once(tmp_path):
    from std_msgs.msg import Bool

    path = tmp_path / 'stalled.mcap'
    said = []
    rec = Recorder(path)
    rec.on_failure.append(said.append)
    rec.BACKLOG_BYTES = 4 * 2**20  # reached in a second here
    data = serialize_message(Bool(data=True))
    rec.write('/x', data, 0, 'std_msgs/msg/Bool')
    rec.flush()
    os.kill(rec._proc.pid, signal.SIGSTOP)
    try:
        slowest, i = 0.0, 0
        while not rec.closed and i < 2_000_000:
            t0 = time.perf_counter()
            rec.write('/x', data, i, 'std_msgs/msg/Bool')
            slowest = max(slowest, time.perf_counter() - t0)
            i += 1
    finally:
        if rec._proc.poll() is None:
            os.kill(rec._proc.pid, signal.SIGCONT)
    assert rec.closed and len(said) == 1, said
    assert 'fell 4 MiB behind' in said[0] and 'stopped' in said[0]
    # no write waited on the stalled writer (one that fell due to flush included)
    assert slowest < 0.5, slowest
    rec.write('/x', data, i + 1, 'std_msgs/msg/Bool')  # a no-op now
    rec.close()
    assert len(said) == 1
    # the file is as far as the writer got, and nobody holds it any more
    _wait_unlocked(path, 5.0)


@pytest.mark.ros
def test_a_full_disk_stops_the_recording_with_one_message_and_the_node_runs_on(tmp_path):
    import resource

    path = tmp_path / 'full.mcap'
    limit = 1_500_000  # bytes: the file grows a chunk at least every 0.5 s until it hits this

    def small_disk():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    proc = subprocess.Popen(
        _node_cmd(path),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=small_disk,
    )
    try:
        deadline = time.monotonic() + 45.0
        while time.monotonic() < deadline and not (
            path.exists() and path.stat().st_size > limit - 200_000
        ):
            time.sleep(0.05)
        time.sleep(3.0)  # well past the failed write (the next chunk), still running
        assert proc.poll() is None, proc.communicate()[1][-2000:]
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err[-3000:]
    assert 'Traceback' not in err, err[-3000:]
    stopped = [line for line in err.splitlines() if 'recording to' in line and 'stopped' in line]
    assert len(stopped) == 1, err[-3000:]
    assert path.stat().st_size <= limit
    out = _replay(path, '--no-plot', '--json', '--recover')
    assert out.returncode == 0, out.stderr
    assert json.loads(out.stdout)['messages'] > 1000


def test_a_file_being_recorded_is_refused_to_a_second_writer_before_it_starts(tmp_path):
    path = tmp_path / 'busy.mcap'
    first = Recorder(path)
    try:
        from std_msgs.msg import Bool

        for i in range(100):
            first.write('/x', Bool(data=bool(i % 2)), i)
        first.flush()
        size = path.stat().st_size
        out = subprocess.run(_node_cmd(path), capture_output=True, text=True, timeout=60)
        assert out.returncode == 2, out.stderr[-2000:]
        # one line of refusal; a loaded machine may add the kernels' warm-up note before it
        lines = [x for x in out.stderr.strip().splitlines() if not x.startswith('[INFO]')]
        assert len(lines) == 1 and 'being recorded by another process' in lines[0], lines
        assert 'record_path' in lines[0]
        assert path.stat().st_size >= size  # not truncated under the first writer
    finally:
        first.close()
    s = replay.summarize(replay.read_recording(path))
    assert s['messages'] == 100 and s['damage'] is None


# ---------------------------------------------------------------- damaged files
def _small_recording(path: Path) -> None:
    """Write a recording of several 4 KiB chunks, shaped as the node writes one."""
    from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
    from geometry_msgs.msg import Pose, PoseArray
    from std_msgs.msg import UInt32MultiArray

    rec = Recorder(path, chunk_size=4096)
    rec.add_metadata(replay.METADATA, {'belt_width': '0.7', 'node': '"/sorter_sim"'})
    for k in range(300):
        t = k * 10_000_000
        rec.write('/parcels/ids', UInt32MultiArray(data=[1, 2]), t)
        poses = PoseArray(poses=[Pose(), Pose()])
        poses.poses[0].position.x = 0.01 * k
        rec.write('/parcels/poses', poses, t)
        if k % 50 == 49:
            values = [KeyValue(key='id', value=str(k)), KeyValue(key='exit', value='left')]
            values.append(KeyValue(key='t', value='nan' if k == 99 else str(t * 1e-9)))
            rec.write('/sort/outcomes', DiagnosticStatus(name='A', values=values), t)
    rec.close()


def _outcome(data: bytes, tmp_path: Path, name: str):
    """Read damaged bytes as sorter replay --recover --json does: its summary, or its refusal."""
    p = tmp_path / name
    p.write_bytes(data)
    args = SimpleNamespace(recording=str(p), out=None, no_plot=True, json=True, recover=True)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = replay.run(args)
    if isinstance(code, str):
        assert '\n' not in code
        return 'refused', None
    assert code == 0
    s = json.loads(out.getvalue())  # run prints it with allow_nan=False: JSON, NaN or not
    return ('damaged' if s['damage'] else 'clean'), s


def _record_starts(data: bytes) -> list[int]:
    """Return where each record outside a chunk begins (its opcode byte), magic to magic."""
    starts, at = [], len(MCAP_MAGIC)
    while at < len(data) - len(MCAP_MAGIC):
        starts.append(at)
        at += 9 + int.from_bytes(data[at + 1 : at + 9], 'little')  # opcode, length, body
    assert at == len(data) - len(MCAP_MAGIC), at
    return starts


@pytest.fixture(scope='module')
def small_recording(tmp_path_factory):
    """Return a recording of several chunks, its bytes and what replay makes of it."""
    tmp = tmp_path_factory.mktemp('small')
    _small_recording(tmp / 'clean.mcap')
    data = (tmp / 'clean.mcap').read_bytes()
    verdict, clean = _outcome(data, tmp, 'clean.mcap')
    assert verdict == 'clean' and clean['messages'] == 606
    assert clean['parcel_outcomes']['99']['t_exit_s'] is None  # t = nan: no time, no error
    return data, clean


def _damage_all(data: bytes, clean: dict, cases: list, tmp_path: Path) -> Counter:
    """Cut or flip ``data`` as each case says; check what replay reads; tally the verdicts."""
    tally = Counter()
    for kind, where in cases:
        damaged = bytearray(data)
        if kind == 'cut':
            damaged = damaged[:where]
        else:
            damaged[where // 8] ^= 1 << (where % 8)
        verdict, s = _outcome(bytes(damaged), tmp_path, 'damaged.mcap')
        tally[kind, verdict] += 1
        if verdict == 'clean':
            # a flip the reader does not see must not change what it reports
            same = ('messages', 'topics', 'parcel_outcomes', 't_first_s', 't_last_s')
            assert {k: s[k] for k in same} == {k: clean[k] for k in same}, (kind, where)
        if verdict == 'damaged':
            # what a damaged file gives is some of what is there, never an invented message
            # (a message whose channel went with a lost chunk is on "<channel N>")
            assert s['messages'] <= clean['messages'], (kind, where)
            for topic, info in clean['topics'].items():
                got = s['topics'].get(topic, {'count': 0})['count']
                assert got <= info['count'], (kind, where, topic)
            assert s['t_last_s'] is None or s['t_last_s'] <= clean['t_last_s'], (kind, where)
    assert tally['cut', 'clean'] == 0  # every truncation is seen
    assert sum(tally.values()) == len(cases)
    return tally


@pytest.mark.slow
@pytest.mark.parametrize('bit', [None, *range(8)], ids=['cut', *(f'flip{b}' for b in range(8))])
def test_every_opcode_bit_flip_and_cut_at_a_record_edge_is_refused_or_read_with_its_damage(
    small_recording, tmp_path, bit
):
    # every cut between records and every bit of every record's opcode (a MessageIndex or
    # the Header read as a Message, a Chunk as a Channel...), whatever layout the writer's
    # timing gave the file
    data, clean = small_recording
    starts = _record_starts(data)
    if bit is None:
        cases = [('cut', n) for n in starts]
    else:
        cases = [('flip', 8 * n + bit) for n in starts]
    _damage_all(data, clean, cases, tmp_path)


@pytest.mark.slow
def test_every_truncation_and_bit_flip_is_refused_read_with_its_damage_or_harmless(
    small_recording, tmp_path
):
    # a seeded sample of cuts and flips anywhere in the file
    data, clean = small_recording
    rng = random.Random(20261125)
    cases = [('cut', n) for n in sorted(rng.sample(range(len(data)), 150))]
    cases += [('flip', rng.randrange(8 * len(data))) for _ in range(400)]
    _damage_all(data, clean, cases, tmp_path)


def test_schemas_a_decoder_cannot_build_are_counted_not_fatal(tmp_path):
    from mcap.writer import Writer

    path = tmp_path / 'odd.mcap'
    with open(path, 'wb') as f:
        w = Writer(f)
        w.start(profile='ros2', library='test')
        schemas = {
            'recursive': (
                'pkg/msg/Loop',
                'pkg/Loop next\n' + '=' * 80 + '\nMSG: pkg/Loop\npkg/Loop next\n',
            ),
            'wstring': ('pkg/msg/W', 'wstring text\n'),
            'nonsense': ('pkg/msg/N', '%%% not a message %%%\n'),
        }
        for i, (topic, (name, text)) in enumerate(schemas.items()):
            sid = w.register_schema(name=name, encoding='ros2msg', data=text.encode())
            cid = w.register_channel(topic=f'/{topic}', message_encoding='cdr', schema_id=sid)
            w.add_message(channel_id=cid, log_time=i, publish_time=i, data=b'\x00\x01\x00\x00' * 3)
        w.finish()
    rec = replay.read_recording(path)
    assert rec['damage'] is None
    assert rec['undecodable'] == {'/nonsense': 1, '/recursive': 1, '/wstring': 1}
    out = _replay(path, '--no-plot')
    assert out.returncode == 0 and 'undecodable' in out.stdout, out.stderr


def test_sorter_replay_reads_a_bag_a_rosbag2_writer_made(tmp_path):
    """A bag written by rosbags' rosbag2 writer (MCAP storage), none of our code in it."""
    import numpy as np
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    DiagnosticStatus = store.types['diagnostic_msgs/msg/DiagnosticStatus']
    KeyValue = store.types['diagnostic_msgs/msg/KeyValue']
    PoseArray = store.types['geometry_msgs/msg/PoseArray']
    Pose = store.types['geometry_msgs/msg/Pose']
    Point = store.types['geometry_msgs/msg/Point']
    Quaternion = store.types['geometry_msgs/msg/Quaternion']
    Header = store.types['std_msgs/msg/Header']
    Time = store.types['builtin_interfaces/msg/Time']
    UInt32MultiArray = store.types['std_msgs/msg/UInt32MultiArray']
    Layout = store.types['std_msgs/msg/MultiArrayLayout']

    bag = tmp_path / 'bag'
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        ids = writer.add_connection('/parcels/ids', UInt32MultiArray.__msgtype__, typestore=store)
        poses = writer.add_connection('/parcels/poses', PoseArray.__msgtype__, typestore=store)
        outs = writer.add_connection(
            '/sort/outcomes', DiagnosticStatus.__msgtype__, typestore=store
        )
        for k in range(50):
            t = k * 10_000_000
            msg = UInt32MultiArray(
                layout=Layout(dim=[], data_offset=0), data=np.array([7], dtype=np.uint32)
            )
            writer.write(ids, t, store.serialize_cdr(msg, msg.__msgtype__))
            pose = Pose(
                position=Point(x=0.01 * k, y=0.0, z=0.0),
                orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
            )
            msg = PoseArray(
                header=Header(stamp=Time(sec=0, nanosec=t), frame_id='c'), poses=[pose]
            )
            writer.write(poses, t, store.serialize_cdr(msg, msg.__msgtype__))
        values = [
            KeyValue(key=k, value=v) for k, v in (('id', '7'), ('exit', 'left'), ('t', '0.49'))
        ]
        msg = DiagnosticStatus(level=0, name='A7', message='', hardware_id='', values=values)
        writer.write(outs, 490_000_000, store.serialize_cdr(msg, msg.__msgtype__))
    (mcap_file,) = bag.glob('*.mcap')
    rec = replay.read_recording(mcap_file)
    assert rec['damage'] is None and rec['undecodable'] == {}
    s = replay.summarize(rec)
    assert s['messages'] == 101
    assert s['topics']['/parcels/poses'] == {'type': 'geometry_msgs/msg/PoseArray', 'count': 50}
    assert s['exits'] == {'left': 1} and s['parcel_outcomes']['7']['t_exit_s'] == 0.49
    assert len(rec['paths'][7]) == 50 and rec['paths'][7][-1][0] == pytest.approx(0.49)


def test_a_recorded_message_asks_rclpy_nothing_its_publisher_was_asked_once(tmp_path):
    """Topic, type and QoS are taken once per publisher: a message costs its frame alone."""
    from mcap.reader import make_reader
    from rclpy.qos import QoSProfile
    from std_msgs.msg import String

    from sorter_ros.recording import open_recorder, publish_recorded, release_recorder

    class CountingPublisher:
        msg_type = String
        qos_profile = QoSProfile(depth=10)

        def __init__(self):
            self.asked = 0
            self.sent = []

        @property
        def topic_name(self):  # a call into rclpy's C handle each time
            self.asked += 1
            return '/probe/label'

        def publish(self, msg):
            self.sent.append(msg)

    path = tmp_path / 'once.mcap'
    pub = CountingPublisher()
    rec = open_recorder(str(path))
    for i in range(50):
        publish_recorded(pub, String(data=f'A{i:05d}'), rec, 10**9 + i)
    assert rec.published == {'/probe/label'}
    release_recorder(rec)
    assert pub.asked == 1
    with open(path, 'rb') as f:
        got = [(c.topic, m.log_time, m.data) for _, c, m in make_reader(f).iter_messages()]
    assert got == [('/probe/label', 10**9 + i, sent) for i, sent in enumerate(pub.sent)]
    assert [deserialize_message(d, String).data for _, _, d in got] == [
        f'A{i:05d}' for i in range(50)
    ]
