"""
The live view and the recordings, checked with the libraries' own clients.

The live view is read by a plain WebSocket client speaking the Foxglove protocol,
which decodes the advertised channels and the SceneUpdate with protobuf from the
schema the server sends (nothing of the server's code). Recordings are read back
with the MCAP ROS 2 reader, which decodes from the definitions inside the file;
its counts are compared with the nodes' own per-topic publish counters, its stamps
with the cell's clock, and its outcomes with the demo's summary.
"""

from __future__ import annotations

import base64
import contextlib
import json
import os
import signal
import socket
import struct
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.parameter import Parameter
from ros_harness import free_port, stalled_live_view_client, subscribe_to_every_channel
from test_sim_node import SHORT_CELL
from websockets.sync.client import connect

from sorter_sim.frontends.node import SimNode
from sorter_sim.runtime.params import ParamError

pytestmark = pytest.mark.ros
BIN = Path(sys.executable).parent


def _sim(ros, **overrides) -> SimNode:
    values = {**SHORT_CELL, 'arrival': 'gap', 'arrival_gap': [0.3, 0.5], **overrides}
    node = SimNode(
        context=ros.context,
        parameter_overrides=[Parameter(k, value=v) for k, v in values.items()],
    )
    return ros.add(node)


def _protobuf_class(channel: dict):
    """Build the message class of an advertised protobuf channel from its FileDescriptorSet."""
    assert channel['encoding'] == 'protobuf', channel
    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel['schema']))
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel['schemaName']))


def _recv_json(ws, op: str, timeout: float = 5.0) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        frame = ws.recv(timeout=max(0.01, deadline - time.monotonic()))
        if isinstance(frame, str):
            msg = json.loads(frame)
            if msg.get('op') == op:
                return msg
    pytest.fail(f'no {op!r} message from the live view within {timeout} s')


def test_live_view_serves_the_cell_to_a_foxglove_client(ros):
    port = free_port()
    node = _sim(ros, foxglove_port=port, foxglove_rate_hz=200.0)
    node.advance(2500)  # parcels on the belt and on their way; no client yet, no frame
    assert node.cell.n_parcels >= 2
    assert node.live_view.frames_sent == 0
    with connect(f'ws://127.0.0.1:{port}', subprotocols=['foxglove.sdk.v1']) as ws:
        assert _recv_json(ws, 'serverInfo')['name'].startswith('sorter_cell')
        channels = {c['topic']: c for c in _recv_json(ws, 'advertise')['channels']}
        assert {t: c['schemaName'] for t, c in channels.items()} == {
            '/live/scene': 'foxglove.SceneUpdate',
            '/live/tf': 'foxglove.FrameTransforms',
            '/live/values': channels['/live/values']['schemaName'],
        }
        assert channels['/live/values']['encoding'] == 'json'
        subs = {1: '/live/scene', 2: '/live/tf', 3: '/live/values'}
        ws.send(
            json.dumps(
                {
                    'op': 'subscribe',
                    'subscriptions': [
                        {'id': i, 'channelId': channels[t]['id']} for i, t in subs.items()
                    ],
                }
            )
        )
        ros.spin_until(node.live_view.listening, 5.0, 'the live view to see the client')
        scene_cls = _protobuf_class(channels['/live/scene'])
        tf_cls = _protobuf_class(channels['/live/tf'])
        got = {}
        deadline = time.monotonic() + 10.0
        while len(got) < 3 and time.monotonic() < deadline:
            # run the cell until a frame goes out, then read what arrived for it
            sent = node.live_view.frames_sent
            while node.live_view.frames_sent == sent:
                node.advance(node.params.pose_stride)
            n_cell = len(node.cell.parcels()['id'])
            t_ns = node.cell.t_ns
            while True:
                try:
                    frame = ws.recv(timeout=1.0)
                except TimeoutError:
                    break
                if isinstance(frame, str):
                    continue
                op, sub_id, log_time = struct.unpack_from('<BIQ', frame)
                assert op == 1
                if log_time == t_ns:
                    got[subs[sub_id]] = (frame[13:], n_cell, t_ns)
                if len(got) == 3:
                    break
        assert set(got) == set(subs.values()), f'frames received for {sorted(got)}'
        payload, n_cell, t_ns = got['/live/scene']
        scene = scene_cls.FromString(payload)
        parcels = [e for e in scene.entities if e.id.startswith('parcel/')]
        assert n_cell >= 2 and len(parcels) == n_cell
        ids = {e.id for e in scene.entities}
        assert {'belt', 'chutes', 'disk_field', 'sensors'} <= ids
        assert all(len(e.cubes) == 1 and e.frame_id == node.frame_id for e in parcels)
        stamp = scene.entities[0].timestamp
        assert stamp.seconds * 10**9 + stamp.nanos == t_ns
        tf = tf_cls.FromString(got['/live/tf'][0])
        assert tf.transforms[0].child_frame_id == node.frame_id
        values = json.loads(got['/live/values'][0])
        assert set(values['sensors']) == set(node.cell.sensor_names)
        assert len(values['parcels']) == got['/live/values'][1]
        belt_riders = [p for p in values['parcels'] if p['state'] == 'on_belt']
        assert belt_riders and all(
            abs(p['speed'] - 1.5) < 1e-9 and p['slip_belt'] < 1e-9 for p in belt_riders
        )


def test_bad_live_view_and_recording_values_are_refused_with_one_message(ros, tmp_path):
    busy = socket.socket()
    busy.bind(('127.0.0.1', 0))
    busy.listen()
    try:
        cases = {
            'foxglove_port': (70000, 'foxglove_port'),
            'busy': (busy.getsockname()[1], 'Address already in use'),
            'no_folder': (str(tmp_path / 'nowhere' / 'run.mcap'), 'does not exist'),
            'not_mcap': (str(tmp_path / 'run.txt'), '.mcap'),
            'a_folder': (str(tmp_path) + '/.mcap', None),
        }
        for case, (value, words) in cases.items():
            key = 'foxglove_port' if case in ('foxglove_port', 'busy') else 'record_path'
            with pytest.raises(ParamError) as err:
                _sim(ros, **{key: value})
            text = str(err.value)
            assert key in text and '\n' not in text, text
            if words:
                assert words in text, text
        assert list(tmp_path.iterdir()) == []  # nothing written, no folder made
    finally:
        busy.close()


def test_a_lockstep_recording_holds_exactly_what_the_cell_published(ros, tmp_path):
    path = tmp_path / 'cell.mcap'
    node = _sim(ros, record_path=str(path))
    node.advance(4000)
    published, t_end = Counter(node.published), node.cell.t_ns
    node.destroy_node()
    ros.nodes.remove(node)
    counts, stamps = Counter(), []
    with open(path, 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, message, msg in reader.iter_decoded_messages():
            counts[channel.topic] += 1
            stamps.append(message.log_time)
            if channel.topic == '/parcels/poses':
                assert msg.header.frame_id == node.frame_id
                assert message.log_time == msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
    assert counts == published
    assert min(stamps) == 0 and max(stamps) == t_end == 4 * 10**9
    with open(path, 'rb') as f:
        meta = {r.name: r.metadata for r in make_reader(f).iter_metadata()}
    assert json.loads(meta['sorter_sim parameters']['belt_width']) == node.params.belt_width


def test_a_recorded_demo_reads_back_as_it_ran(tmp_path):
    """The demo's recording: counts, span and outcomes agree with the nodes and the summary."""
    from sorter_cell import demo
    from sorter_cell.replay import read_recording, summarize

    path = tmp_path / 'demo.mcap'
    config = Path(__file__).resolve().parents[1] / 'config'
    plan = demo.stream_plan((0.3, 0.7), config)
    gap = [round(plan['min_gap_m'] + 0.02, 3), round(plan['min_gap_m'] + 0.4, 3)]
    plan['stream_gap_m'] = gap
    rc = demo.RunningCell(
        sim_params={
            'arrival': 'gap',
            'arrival_gap': gap,
            'labels': list(demo.LABEL_CYCLE),
            'record_path': str(path),
        },
        controller_params={'routing.rules': list(demo.ROUTING), 'record_path': str(path)},
    ).__enter__()
    try:
        wall = rc.run_for(12.0)
        t_stream = rc.finish()
        summary = demo.summarize(rc.obs, plan, t_stream, wall, rc.time_mode)
        published = Counter(rc.sim.published) + Counter(rc.ctl.published)
        t_end = rc.sim.cell.t_ns
    finally:
        rc.__exit__(None, None, None)
    rec = read_recording(path)
    assert {t: v['count'] for t, v in rec['topics'].items()} == dict(published)
    assert rec['t_first_ns'] == 0 and rec['t_last_ns'] <= t_end
    # the controller's last messages are stamped with the last clock it saw
    assert t_end - rec['t_last_ns'] < 0.05e9
    s = summarize(rec)
    assert summary['sorted_left'] >= 2 and summary['sorted_right'] >= 1
    assert s['exits'].get('left', 0) == summary['sorted_left']
    assert s['exits'].get('right', 0) == summary['sorted_right']
    assert s['exits'].get('straight', 0) == summary['straight']
    assert s['exits'].get('jammed', 0) == summary['jams'] == 0
    mis = [
        p
        for p in s['parcel_outcomes'].values()
        if p['controller'] == 'sorted' and p['exit'] != p['destination_asked']
    ]
    assert not mis and summary['mis_sorted'] == 0


def test_sorter_replay_summarises_and_draws_from_the_file_alone(ros, tmp_path):
    path = tmp_path / 'cell.mcap'
    node = _sim(ros, record_path=str(path), labels=['X'], label_pattern='{label}{id}')
    node.advance(6000)
    node.destroy_node()
    ros.nodes.remove(node)
    png = tmp_path / 'paths.png'
    out = subprocess.run(
        [str(BIN / 'sorter'), 'replay', str(path), '--out', str(png), '--json'],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr
    s = json.loads(out.stdout)
    assert s['span_s'] == pytest.approx(6.0) and s['png'] == str(png)
    assert png.stat().st_size > 10_000
    assert s['exits'].get('straight', 0) >= 1 and s['parcels'] >= 3
    for bad, words in (
        ([str(tmp_path / 'missing.mcap')], 'no such file'),
        ([str(png), '--no-plot'], 'not a readable MCAP'),
        ([str(path), '--out', str(tmp_path / 'x.jpg')], '.png'),
    ):
        out = subprocess.run(
            [str(BIN / 'sorter'), 'replay', *bad], capture_output=True, text=True, timeout=60
        )
        assert out.returncode == 2 and words in out.stderr, (bad, out.stderr)
        assert len(out.stderr.strip().splitlines()) == 1 and 'Traceback' not in out.stderr


def test_a_demo_recording_stopped_by_ctrl_c_is_a_complete_mcap_file(tmp_path):
    path = tmp_path / 'stopped.mcap'
    env = dict(os.environ, PYTHONUNBUFFERED='1')
    proc = subprocess.Popen(
        [
            str(BIN / 'sorter'),
            'demo',
            '--sim-time',
            '600',
            '--rtf',
            '1',
            '--record',
            str(path),
            '--out',
            str(tmp_path / 'paths.png'),
            '--json',
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        deadline = time.monotonic() + 45.0
        # the file is there once the cell runs; stop it in the middle of its stream
        while time.monotonic() < deadline and not path.exists():
            time.sleep(0.1)
        time.sleep(3.0)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode in (0, 1), err
    assert 'Traceback' not in err, err
    summary = json.loads(out)
    assert 0 < summary['sim_time_s'] < 600
    with open(path, 'rb') as f:
        reader = make_reader(f)
        stats = reader.get_summary().statistics  # only a finished file has a summary
        n = sum(1 for _ in reader.iter_messages())
    assert stats.message_count == n > 100


def test_sorter_demo_refuses_a_busy_live_view_port_in_one_line(tmp_path):
    with socket.socket() as busy:
        busy.bind(('127.0.0.1', 0))
        busy.listen()
        out = subprocess.run(
            [
                str(BIN / 'sorter'),
                'demo',
                '--sim-time',
                '2',
                '--foxglove',
                str(busy.getsockname()[1]),
                '--out',
                str(tmp_path / 'paths.png'),
            ],
            capture_output=True,
            text=True,
            timeout=60,
        )
    assert out.returncode == 2, out.stderr
    assert 'foxglove_port' in out.stderr and 'in use' in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1 and 'Traceback' not in out.stderr


def _rss_mb(pid: int) -> float:
    with open(f'/proc/{pid}/status') as f:
        for line in f:
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) / 1024
    return float('nan')


def test_stalled_live_view_clients_cost_frames_not_memory(ros):
    """Three clients subscribe and never read: the node drops their frames, keeps its RAM."""
    from websockets.sync.client import ClientConnection  # noqa: F401 (the client API used)

    port = free_port()
    node = _sim(ros, foxglove_port=port, foxglove_rate_hz=200.0, arrival_gap=[0.05, 0.1])
    node.advance(6000)
    assert node.cell.n_parcels >= 5
    with contextlib.ExitStack() as clients:
        for _ in range(3):
            ws = stalled_live_view_client(port, clients)
            subscribe_to_every_channel(ws, 5.0)
        # the three subscribed, and never read from again
        ros.spin_until(node.live_view.listening, 5.0, 'the live view to see the clients')
        node.advance(2000)  # the queues fill
        # the server's process warms up over its first frames (its allocator, the
        # SDK's buffers): the growth is measured over the 500 frames after 100
        t0 = time.perf_counter()
        while node.live_view.frames_sent < 100 and time.perf_counter() - t0 < 20.0:
            node.advance(node.params.pose_stride)
            time.sleep(0.001)
        rss0 = _rss_mb(node.live_view.pid)
        sent0 = node.live_view.frames_sent
        t0 = time.perf_counter()
        while node.live_view.frames_sent - sent0 < 500 and time.perf_counter() - t0 < 20.0:
            node.advance(node.params.pose_stride)
            time.sleep(0.001)
        wall = time.perf_counter() - t0
        frames = node.live_view.frames_sent - sent0
        grown = _rss_mb(node.live_view.pid) - rss0
        print(f'{frames} frames to 3 stalled clients in {wall:.2f} s, RSS +{grown:.1f} MB')
        assert frames >= 500
        # the SDK's default backlog (1024 messages a client) kept 9 MB of this small cell's
        # frames (a 200-parcel cell: hundreds of MB); a bounded one six messages a client
        assert grown < 4.0, f'RSS grew {grown:.1f} MB for {frames} frames'


def test_a_stalled_or_killed_live_view_process_never_holds_the_cell(ros):
    """The view's process stopped, then killed: the cell runs on, one line says it ended."""
    port = free_port()
    node = _sim(ros, foxglove_port=port, foxglove_rate_hz=200.0)
    view = node.live_view
    with connect(f'ws://127.0.0.1:{port}', subprotocols=['foxglove.sdk.v1']) as ws:
        subscribe_to_every_channel(ws, 5.0)
        ros.spin_until(view.listening, 5.0, 'the live view to see the client')
        sent = view.frames_sent
        while view.frames_sent < sent + 3:
            node.advance(node.params.pose_stride)
            time.sleep(0.005)
        os.kill(view.pid, signal.SIGSTOP)
        try:
            sent = view.frames_sent
            k0 = node.cell.k
            for _ in range(200):
                node.advance(node.params.pose_stride)
                time.sleep(0.001)
            # every period ran; at most the frame already asked for went out
            assert node.cell.k - k0 == 200 * node.params.pose_stride
            assert view.frames_sent - sent <= 1 and view.alive
        finally:
            os.kill(view.pid, signal.SIGCONT)
        os.kill(view.pid, signal.SIGKILL)
        view._proc.wait(5.0)
        k0 = node.cell.k
        for _ in range(100):
            node.advance(node.params.pose_stride)
        assert node.cell.k - k0 == 100 * node.params.pose_stride
        assert not view.alive and 'live view stopped' in view.failure
        sent = view.frames_sent
        node.advance(1000)
        assert view.frames_sent == sent


def test_the_live_view_draws_at_a_lower_priority_than_the_physics(ros):
    """On a machine short of cores the scheduler gives them to the node before the view."""
    from sorter_sim.frontends.live_view_process import NICE

    node = _sim(ros, foxglove_port=free_port())
    view = node.live_view
    mine = os.getpriority(os.PRIO_PROCESS, 0)
    # the view lowers its priority once it has started (just after it said so)
    deadline = time.monotonic() + 30.0
    while os.getpriority(os.PRIO_PROCESS, view.pid) == mine and time.monotonic() < deadline:
        time.sleep(0.01)
    assert os.getpriority(os.PRIO_PROCESS, view.pid) == min(19, mine + NICE)
    assert NICE > 0
    k0 = node.cell.k
    node.advance(500)  # the node itself runs at its own priority
    assert node.cell.k == k0 + 500 and os.getpriority(os.PRIO_PROCESS, 0) == mine
