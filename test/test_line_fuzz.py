"""
Every way into a segment of the line, fuzzed: its ``line/*`` callbacks and a segment process.

A segment in the middle of a line (station S02 of three, in ``barrier`` sync so that it
reads ``line/progress`` too) is a real rclpy node; hypothesis draws messages of every
kind and shape (the issue's forged payloads first) and hands them to each of its
subscriptions' callbacks, as the executor would. The properties: no exception leaves
a callback; a refused message is counted and changes nothing (the inbox, the horizon,
the ids taken, the custody, the claims, the barrier's times, the stations); the node
keeps running. Then the same payloads go over DDS to a segment process, which must
live on and report them refused. The counts are printed (``-s``) for the record.
"""

from __future__ import annotations

import copy
import json
import os
import signal
import subprocess
import sys
import threading

import pytest
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from rclpy.parameter import Parameter

from sorter_sim.frontends.line_node import LineNode
from sorter_sim.frontends.segments import HANDOVER_QOS
from test_handover import FIELD_DRAWS, REAL, fields

pytestmark = pytest.mark.ros


def message(name: str, pairs) -> DiagnosticStatus:
    return DiagnosticStatus(name=name, values=[KeyValue(key=k, value=v) for k, v in pairs])


H = REAL[0]


def _hexes(*values) -> str:
    return ' '.join(float(v).hex() for v in values)


# the issue's payloads: each killed a segment, jammed the line or let it run ahead
ISSUE_PAYLOADS = [
    message('parcel', fields(H, dims=f'inf {_hexes(0.3, 1.0)}')),
    message('parcel', fields(H, dims=_hexes(1e6, 0.3, 1.0))),
    message('parcel', fields(H, dims=_hexes(1e-300, 0.3, 1.0))),
    message('parcel', fields(H, id=str(2**64))),
    message('parcel', fields(H, mode=str(10**30))),
    message('parcel', fields(H, gauge='')),
    message('parcel', fields(H, gauge=' '.join(['0x0p+0'] * 50))),
    message('parcel', fields(H, state='0x1p+99999 0 0 0 0 0')),
    message('parcel', fields(H, state=_hexes(float('nan'), *H.state[1:]))),
    message('parcel', fields(H, state=_hexes(*H.state[:3], float('inf'), *H.state[4:]))),
    message('parcel', fields(H, state=_hexes(H.state[0], 1e300, *H.state[2:]))),
    message('parcel', fields(H, id='-7', label='x' * 10_000)),
    message('parcel', fields(H, label='P\x07\x1b[31m')),
    message('horizon', [('t_ns', str(10**18 * 10**9))]),
    message('horizon', [('t_ns', '1000000000000000000')]),
    message('progress', [('first', '40'), ('stations', '1'), ('k', '0')]),
    message('owns', [('identity', '1-1'), ('first', '40'), ('stations', '2')]),
    message('left', [('ids', '1 2 x')]),
    message('hello', []),
    message('teleport', []),
    message('parcel', []),
]


@pytest.fixture
def segment(ros):
    node = LineNode(
        node_name='sorter_line_fuzz',
        context=ros.context,
        parameter_overrides=[
            Parameter('time_mode', value='lockstep'),
            Parameter('stations', value=1),
            Parameter('first_station', value=2),
            Parameter('line_stations', value=3),
            Parameter('segment_sync', value='barrier'),
        ],
        station_params={'arrival': 'none'},
    )
    for n in node.nodes:
        ros.add(n)
    yield node


def snapshot(line) -> dict:
    link = line.segment
    return copy.deepcopy(
        {
            'inbox': list(link.inbox),
            'horizon': (link.horizon_k, link._horizon_heard),
            'taken': set(link._taken),
            'outbox': dict(link.outbox),
            'progress': dict(link._progress),
            'claims': {i: c[:2] for i, c in link.owners._claims.items()},
            'hello': (link._pending_hello, link._downstream_identity),
            'line': (line.line.k, line.line.n_parcels),
        }
    )


COUNTS = {'inputs': 0, 'refusals': 0, 'escapes': 0, 'state_changes_on_refusal': 0}
NAMES = ['parcel', 'horizon', 'left', 'hello', 'owns', 'progress']
any_pairs = st.lists(
    st.tuples(
        st.sampled_from(['t_ns', 'id', 'ids', 'identity', 'first', 'stations', 'k', 'label']),
        st.one_of(FIELD_DRAWS['t_ns'], st.text(max_size=40)),
    ),
    max_size=6,
)


@st.composite
def parcel_pairs(draw):
    base = dict(fields(REAL[draw(st.integers(0, len(REAL) - 1))]))
    base['id'] = str(draw(st.integers(10_000, 20_000)))
    out = []
    for key, value in base.items():
        how = draw(st.sampled_from(['keep', 'keep', 'keep', 'draw', 'drop']))
        if how == 'keep':
            out.append((key, value))
        elif how == 'draw':
            out.append((key, draw(FIELD_DRAWS[key])))
    return out


def feed(line, callbacks, topic, msg) -> None:
    link = line.segment
    before = snapshot(line)
    refused = link.stats['refused']
    COUNTS['inputs'] += 1
    try:
        callbacks[topic](msg)
    except Exception as exc:  # noqa: BLE001 - counted: the property is that none escapes
        COUNTS['escapes'] += 1
        raise AssertionError(f'{topic}: {type(exc).__name__}: {exc}') from exc
    if link.stats['refused'] > refused:
        COUNTS['refusals'] += 1
        if snapshot(line) != before:
            COUNTS['state_changes_on_refusal'] += 1
            raise AssertionError(f'{topic}: a refused {msg.name!r} changed the segment')


def test_fuzz_every_line_callback_of_a_segment(ros, segment):
    callbacks = {
        s.topic_name: s.callback
        for s in segment.subscriptions
        if s.topic_name.startswith('/line/')
    }
    assert sorted(callbacks) == [
        '/line/handover/S02',
        '/line/handover/S03/left',
        '/line/owners',
        '/line/progress',
    ]
    for msg in ISSUE_PAYLOADS:
        for topic in callbacks:
            feed(segment, callbacks, topic, msg)
    assert segment.segment.inbox == [] and segment.segment.horizon_k == 0

    @settings(
        max_examples=800,
        deadline=None,
        derandomize=True,
        phases=[Phase.explicit, Phase.generate],
        suppress_health_check=list(HealthCheck),
    )
    @given(
        topic=st.sampled_from(sorted(callbacks)),
        name=st.one_of(st.sampled_from(NAMES), st.text(max_size=20)),
        pairs=st.one_of(parcel_pairs(), any_pairs),
    )
    def one(topic, name, pairs):
        feed(segment, callbacks, topic, message(name, pairs))

    one()
    # the segment still runs: a step with nothing from upstream waits, no exception
    segment.advance(5)
    for _ in range(20):
        ros.executor.spin_once(timeout_sec=0.0)
    print(f'\nline callbacks fuzzed: {COUNTS}')
    assert COUNTS['escapes'] == 0 and COUNTS['state_changes_on_refusal'] == 0
    assert COUNTS['refusals'] > 0.5 * COUNTS['inputs']


def test_a_segment_process_lives_through_every_forged_payload(ros):
    """
    The issue's payloads over DDS to ``line_segment`` (S02 of 2): it refuses them all.

    It reports every 20 ms: its first line is still ``ready`` (a report printed before it,
    when the controllers took longer than a period to run, was read as a failed start).
    """
    proc = subprocess.Popen(
        [sys.executable, '-m', 'sorter_cell.line_segment', '--first', '2', '--stations', '1']
        + ['--line-stations', '2', '--report', '0.02'],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, 'ROS_DOMAIN_ID': str(ros.context.get_domain_id())},
    )
    lines = []
    try:
        first = proc.stdout.readline().strip()
        assert first == 'ready', first
        # its reports drained as they come: a full pipe would stop the segment
        reader = threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True)
        reader.start()
        probe = ros.make_node('forger')
        pub = probe.create_publisher(DiagnosticStatus, '/line/handover/S02', HANDOVER_QOS)
        ros.spin_until(lambda: pub.get_subscription_count() > 0, 20.0)
        payloads = [m for m in ISSUE_PAYLOADS if m.name in ('parcel', 'horizon', 'teleport')]
        for msg in payloads:
            pub.publish(msg)
        ros.spin_for(3.0)
        assert proc.poll() is None, proc.stderr.read()
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=30)
        finally:
            if proc.poll() is None:
                proc.kill()
        err = proc.stderr.read()
    reader.join(timeout=10)
    assert len(lines) > 10, lines  # its reports, then its last words
    report = json.loads(lines[-1])
    assert proc.returncode == 0, err
    # every one refused: the parcels as physics, the horizons as not the upstream owner's
    assert report['refused'] == len(payloads), report
    assert report['taken'] == 0 and report['parcels'] == 0
    assert 'Traceback' not in err
    print(
        f'\nsegment process: {len(payloads)} forged messages, {report["refused"]} refused, alive'
    )
