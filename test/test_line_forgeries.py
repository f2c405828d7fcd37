"""
Well-formed messages in someone else's name (D1-D5), against a keyed line and an open one.

The forgeries of the adversarial pass: a hand-over with a real parcel's id and a later
time (D1), claims from an identity older than the line (D2), parcels dated 1e15 ns
to fill the first station's room (D3), a second parcel at the same place and time
(D4), exits for real parcels and into another station's chute (D5). A keyed line
refuses each (no seal), counted, and sorts every real parcel once; an open line
refuses what cannot be true (D2, D3, D4, the chute of another station) and says a
parcel it cannot take lost, with its cause: never silently.

First each check on a segment in this process (station S02 of 3, as
``test_line_fuzz``), then a two-segment line demo with a forger beside it, keyed and
open.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from dataclasses import replace

import pytest
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rclpy.parameter import Parameter

from sorter_ros.interface import EVENT_QOS
from sorter_ros.line_key import KEY_ENV, SEAL_FIELD, Sealer, new_key_file, read_key_file
from sorter_sim.frontends.segments import HANDOVER_QOS, OWNERS_QOS, handover_message
from test_handover import REAL

pytestmark = pytest.mark.ros

KEY = os.urandom(32)


def message(name: str, pairs) -> DiagnosticStatus:
    return DiagnosticStatus(name=name, values=[KeyValue(key=k, value=v) for k, v in pairs])


def sealed(msg: DiagnosticStatus, topic: str, sealer: Sealer) -> DiagnosticStatus:
    """Seal a message as a segment holding the key would (``sorter_ros.line_seal``)."""
    pairs = [(kv.key, kv.value) for kv in msg.values]
    head = (msg.name, '0', msg.message, msg.hardware_id)
    msg.values.append(KeyValue(key=SEAL_FIELD, value=sealer.seal(topic, head, pairs)))
    return msg


def middle_segment(ros, key):
    """S02 of a three-station line, in lock-step, keyed with ``key`` (None: open)."""
    from sorter_sim.frontends.line_node import LineNode

    node = LineNode(
        node_name='sorter_line_forged',
        context=ros.context,
        line_key=key,
        parameter_overrides=[
            Parameter('time_mode', value='lockstep'),
            Parameter('stations', value=1),
            Parameter('first_station', value=2),
            Parameter('line_stations', value=3),
        ],
        station_params={'arrival': 'none'},
    )
    for n in node.nodes:
        ros.add(n)
    callbacks = {s.topic_name: s.callback for s in node.subscriptions}
    return node, callbacks


def claim(identity: str, first: int) -> DiagnosticStatus:
    return message('owns', [('identity', identity), ('first', str(first)), ('stations', '1')])


def upstream_owner(ros, callbacks, sealer=None) -> str:
    """Claim S01 for a segment started now, its horizon a second past REAL[0]; return who."""
    identity = f'{os.getpid()}-{time.time_ns()}'
    t_ns = REAL[0].t_ns + 1_000_000_000
    horizon = message('horizon', [('t_ns', str(t_ns)), ('identity', identity)])
    msg = claim(identity, 0)
    if sealer is not None:
        msg = sealed(msg, '/line/owners', sealer)
        horizon = sealed(horizon, '/line/handover/S02', sealer)
    callbacks['/line/owners'](msg)
    callbacks['/line/handover/S02'](horizon)
    return identity


def parcel(pid: int, t_ns: int | None = None, **changes):
    h = replace(REAL[0], parcel_id=pid, label=f'P{pid:05d}', **changes)
    return replace(h, t_ns=h.t_ns if t_ns is None else t_ns)


def test_an_open_segment_refuses_what_cannot_be_true_and_says_a_lost_parcel_with_its_cause(ros):
    line, callbacks = middle_segment(ros, None)
    link = line.segment
    exits = []
    watcher = ros.make_node('exit_watcher')
    watcher.create_subscription(
        DiagnosticStatus,
        '/line/exits',
        lambda m: exits.append({kv.key: kv.value for kv in m.values}),
        EVENT_QOS,
    )
    assert not line.seal.keyed
    upstream_owner(ros, callbacks)
    assert link._horizon_heard and link.horizon_k > 0
    handover = callbacks['/line/handover/S02']
    # D2: claims from an identity older than the host, on this segment's stations
    refused = link.stats['refused']
    for _ in range(8):
        callbacks['/line/owners'](claim('4242-1', 1))
    assert link.stats['refused'] == refused + 8
    assert '4242-1' not in link.owners._claims and not link.owners.refused()
    # D3: a valid parcel dated 1e15 ns, far past the horizon: refused, room kept
    for k in range(20):
        handover(handover_message(parcel(900 + k, t_ns=10**15 + k * 10**6), 1))
    assert link.inbox == [] and link.stats['refused'] == refused + 28
    # a real parcel within the horizon is taken
    real = parcel(1)
    handover(handover_message(real, 1))
    assert [h.parcel_id for h in link.inbox] == [1]
    # D4: a second parcel at the same place and time: refused
    handover(handover_message(replace(real, parcel_id=2, label='P00002'), 1))
    assert [h.parcel_id for h in link.inbox] == [1] and link.stats['refused'] == refused + 29
    # the same parcel sent again (a hello's answer): a duplicate, nothing said
    handover(handover_message(real, 1))
    assert link.stats['duplicates'] == 1 and link.stats['lost'] == 0
    # D1: a different parcel under a taken id: refused and said lost, with its cause
    later = replace(real, t_ns=real.t_ns + 100 * link.dt_ns)
    handover(handover_message(later, 1))
    assert link.stats['refused'] == refused + 30 and link.stats['lost'] == 1
    ros.spin_until(lambda: exits, 10.0, 'the lost exit on /line/exits')
    assert exits[0]['exit'] == 'lost' and exits[0]['label'] == 'P00001'
    assert exits[0]['station'] == 'S02' and exits[0]['cause'] == 'handed over twice, differently'


def test_a_keyed_segment_takes_only_sealed_messages_each_once(ros):
    line, callbacks = middle_segment(ros, KEY)
    link = line.segment
    assert line.seal.keyed
    handover = callbacks['/line/handover/S02']
    refused = link.stats['refused']
    # every kind, well formed and plausible, unsealed: refused on every topic
    identity = f'{os.getpid()}-{time.time_ns()}'
    plain = {
        '/line/owners': claim(identity, 0),
        '/line/handover/S02': handover_message(parcel(1), 1),
        '/line/handover/S03/left': message('hello', [('identity', identity)]),
    }
    for topic, msg in plain.items():
        callbacks[topic](msg)
    assert link.stats['refused'] == refused + 3
    assert link.inbox == [] and identity not in link.owners._claims
    assert link._pending_hello is None
    # sealed under another line's key: refused too
    other = Sealer(os.urandom(32))
    handover(sealed(handover_message(parcel(1), 1), '/line/handover/S02', other))
    assert link.inbox == [] and link.stats['refused'] == refused + 4
    # sealed under this line's key: taken, and the same message again is a replay
    sealer = Sealer(KEY)
    upstream_owner(ros, callbacks, sealer)
    assert link._horizon_heard
    msg = sealed(handover_message(parcel(1), 1), '/line/handover/S02', sealer)
    again = DiagnosticStatus(name=msg.name, values=list(msg.values))
    handover(msg)
    assert [h.parcel_id for h in link.inbox] == [1]
    handover(again)
    assert link.stats['refused'] == refused + 5 and link.stats['duplicates'] == 0
    assert link.seal.counts == {'unsealed': 3, 'bad_seal': 1, 'replayed': 1}


def test_a_keyed_warehouse_takes_only_sealed_exits_and_never_another_stations_chute(ros):
    from sorter_control.wcs_node import WcsNode

    wcs = ros.add(
        WcsNode(
            context=ros.context,
            line_key=KEY,
            parameter_overrides=[Parameter('stations', value=6)],
        )
    )
    exit_of = [('id', '7'), ('label', 'P00007'), ('exit', 'S01L'), ('station', 'S01')]
    exit_of.append(('t', '1.5'))
    sealer = Sealer(KEY)
    topic = wcs._sub_exits.topic_name
    wcs._on_exit(message('parcel/7', exit_of))  # D5: unsealed, in the line's name
    assert wcs.n_refused_exits == 1 and 'P00007' not in wcs.wcs.dispositions
    wrong = [(k, 'S06R' if k == 'exit' else v) for k, v in exit_of]
    wcs._on_exit(sealed(message('parcel/7', wrong), topic, sealer))  # S06R at S01
    assert wcs.n_refused_exits == 2 and 'P00007' not in wcs.wcs.dispositions
    good = sealed(message('parcel/7', exit_of), topic, sealer)
    replay = DiagnosticStatus(name=good.name, values=list(good.values))
    wcs._on_exit(good)
    assert wcs.wcs.dispositions['P00007'].chute == 'S01L'
    wcs._on_exit(replay)
    assert wcs.n_refused_exits == 3


# ---------------------------------------------------------------- the line demo, forged


class Forger:
    """
    A node beside a two-segment line demo sending D1-D5 as the real parcels come.

    It watches S02's hand-overs: for each real parcel, a copy with its id half a second
    later (D1), a second parcel at its place and time (D4) and an exit for it into
    S02L (D5), and, once, 8 claims from ``4242-1`` (D2), 250 parcels dated 1e15 ns
    (D3) and an exit into S02R at S01 (D5).
    """

    def __init__(self, ros, open_line: bool):
        self.open_line = open_line
        self.node = ros.make_node('forger')
        self.to_s02 = self.node.create_publisher(
            DiagnosticStatus, '/line/handover/S02', HANDOVER_QOS
        )
        self.owners = self.node.create_publisher(DiagnosticStatus, '/line/owners', OWNERS_QOS)
        self.exits = self.node.create_publisher(DiagnosticStatus, '/line/exits', EVENT_QOS)
        self.node.create_subscription(
            DiagnosticStatus, '/line/handover/S02', self._on_parcel, HANDOVER_QOS
        )
        self.seen: list[dict] = []
        self.ids: set[str] = set()
        self.sent = 0

    def _on_parcel(self, msg: DiagnosticStatus) -> None:
        v = {kv.key: kv.value for kv in msg.values if kv.key != SEAL_FIELD}
        if msg.name != 'parcel' or v['id'] in self.ids or v['id'].startswith('9'):
            return  # a horizon, or a parcel it has seen (its own copy), or its own
        self.ids.add(v['id'])
        self.seen.append(v)
        first = len(self.seen) == 1
        # D1: its id, half a second later; D4: another id, its place and time
        later = dict(v, t_ns=str(int(v['t_ns']) + 500_000_000))
        twin = dict(v, id=f'9{v["id"]}', label=f'Q{v["id"]}')
        for pairs in (later, twin):
            self.to_s02.publish(message('parcel', pairs.items()))
        if not self.open_line:
            # D5: its exit, forged before the real one (an open line cannot tell it)
            self._exit(v['id'], v['label'], 'S02L', 'S02')
        if first:
            for _ in range(8):  # D2
                self.owners.publish(claim('4242-1', 1))
            for k in range(250):  # D3
                far = dict(v, id=str(90_000 + k), t_ns=str(10**15 + k * 10**6))
                self.to_s02.publish(message('parcel', far.items()))
            self._exit('99', 'P00099', 'S02R', 'S01')  # D5: another station's chute
        self.sent += 1

    def _exit(self, pid, label, chute, station) -> None:
        values = [('id', pid), ('label', label), ('exit', chute), ('station', station)]
        self.exits.publish(message(f'parcel/{pid}', values + [('t', '1.000000000')]))


def _two_segment_demo(ros, env: dict, *more: str) -> subprocess.Popen:
    """Start ``sorter demo --stations 2 --segments 2 --json`` and ``more`` in the test's domain."""
    env = dict(env, ROS_DOMAIN_ID=str(ros.context.get_domain_id()))
    cmd = [sys.executable, '-m', 'sorter_cell', 'demo', '--stations', '2', '--segments', '2']
    return subprocess.Popen(
        cmd + ['--json', *more], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env
    )


def _forged_demo(ros, tmp_path, keyed: bool):
    """Run ``sorter demo --stations 2 --segments 2 --parcels 5`` with the forger; return all."""
    env = {k: v for k, v in os.environ.items() if k != KEY_ENV}
    if keyed:
        key = tmp_path / 'line.key'
        new_key_file(str(key))
        env[KEY_ENV] = str(key)
        assert len(read_key_file(str(key))) == 32
    forger = Forger(ros, open_line=not keyed)
    path = tmp_path / 'dispositions.jsonl'
    demo = _two_segment_demo(ros, env, '--parcels', '5', '--dispositions', str(path))
    try:
        out, err = ros.communicate(demo, 150.0)
    finally:
        if demo.poll() is None:
            demo.kill()
            demo.communicate()
    assert 'Traceback' not in err, err[-3000:]
    summary = json.loads(out.strip().splitlines()[-1])
    records = [json.loads(line) for line in path.read_text().splitlines()]
    return demo.returncode, summary, records, forger


def test_a_keyed_line_refuses_every_forgery_and_sorts_every_parcel_once(ros, tmp_path):
    code, summary, records, forger = _forged_demo(ros, tmp_path, keyed=True)
    assert forger.seen, 'no parcel reached segment 2: nothing was forged'
    labels = sorted(r['label'] for r in records)
    assert labels == [f'P{i:05d}' for i in range(1, 6)], records  # each once, P00099 none
    assert {r['code'] for r in records} == {'sorted'}, records
    s2 = summary['segment_stats'][1]
    # every forged parcel refused (D1, D3, D4) and the claims (D2): none taken
    assert s2['taken'] == len(forger.seen) and s2['duplicates'] == 0
    assert s2['refused'] >= 2 * len(forger.seen) + 250 + 1
    assert summary['segment_stats'][0]['refused'] >= 1  # the claims reach segment 1 too
    assert code == 1  # a segment refused messages: said in the exit code (docs/running.md)
    print(f'\nkeyed line: {forger.sent} forgeries sent, refused {s2["refused"]} at S02')


def test_an_open_line_refuses_the_implausible_and_never_loses_a_parcel_silently(ros, tmp_path):
    code, summary, records, forger = _forged_demo(ros, tmp_path, keyed=False)
    assert forger.seen, 'no parcel reached segment 2: nothing was forged'
    labels = [r['label'] for r in records]
    # every parcel once: sorted, or lost with its cause (its id handed over twice, D1)
    assert sorted(labels) == [f'P{i:05d}' for i in range(1, 6)], records
    assert {r['code'] for r in records} <= {'sorted', 'lost'}, records
    assert all(r.get('cause') for r in records if r['code'] == 'lost'), records
    s2 = summary['segment_stats'][1]
    # D3's 250, D4's twins and D1's copies refused; D2's claims too (segment 2 ran)
    assert s2['refused'] >= 250 + 1 + len(forger.seen)
    assert summary['mis_sorted'] == 0 and summary['jams'] == 0
    assert code == 1
    print(f'\nopen line: {forger.sent} forgeries sent, refused {s2["refused"]} at S02')


def _child(demo, flag: str) -> int:
    """Return the pid of the demo's segment process started with ``flag`` (at most 50 s)."""
    from test_segments import _children

    deadline = time.monotonic() + 50.0
    while True:
        assert time.monotonic() < deadline and demo.poll() is None, f'no segment {flag}'
        pid = next((p for p, cmd in _children(demo.pid) if f'{flag} ' in cmd + ' '), None)
        if pid is not None:
            return pid
        time.sleep(0.05)


def test_a_segment_that_dies_after_its_ready_while_another_starts_is_said_at_once(ros):
    """
    D14: segment 1 still starting (stopped here), segment 2 ready, then killed.

    The demo read segment 2's ``ready`` and waited for segment 1's alone: the death
    was said only once segment 1 was ready too (13.8 s in the adversarial pass; with
    segment 1 stopped, never).
    """
    import signal

    watcher = ros.make_node('watcher')
    demo = _two_segment_demo(ros, dict(os.environ), '--parcels', '3')
    first = None
    try:
        first = _child(demo, '--first 1')
        os.kill(first, signal.SIGSTOP)  # it cannot say ready
        victim = _child(demo, '--first 2')
        # its program runs once it reads its routing (the warehouse is not started yet: it
        # is the only reader); it says ready in the next pass of its loop
        ros.spin_until(
            lambda: watcher.count_subscribers('/S02/routing/updates') > 0,
            50.0,
            'station 2\'s program reading /S02/routing/updates',
        )
        ros.spin_for(1.0)
        os.kill(victim, signal.SIGKILL)
        t_kill = time.monotonic()
        out, err = ros.communicate(demo, 30.0)
        said_after = time.monotonic() - t_kill
    finally:
        if first is not None:
            try:
                os.kill(first, signal.SIGCONT)
            except ProcessLookupError:
                pass
        if demo.poll() is None:
            demo.kill()
            demo.communicate()
    assert demo.returncode == 2, out + err
    assert f'segment 2 of 2 (process {victim}) ended with signal 9' in err, err
    assert 'Traceback' not in err and len(err.strip().splitlines()) == 1, err
    print(f'\na segment killed while another started: said after {said_after:.1f} s')


@pytest.fixture
def keyed_environment(tmp_path, monkeypatch):
    """``SORTER_LINE_KEY`` naming a new key file, for the fixtures made after this one."""
    path = tmp_path / 'line.key'
    new_key_file(str(path))
    monkeypatch.setenv(KEY_ENV, str(path))
    return path


@pytest.mark.sorter_line(stations=2)
def test_the_line_fixture_takes_the_key_from_the_environment(keyed_environment, sorter_line):
    assert sorter_line.line.seal.keyed and sorter_line.wcs.seal.keyed
    sorter_line.induct('K-1', 'D03')
    assert sorter_line.run_until(lambda: sorter_line.disposition('K-1') is not None, 30.0)
    assert sorter_line.disposition('K-1').code == 'sorted'  # its exit sealed, and taken
    assert sorter_line.wcs.n_refused_exits == 0
    forged = [('id', '9'), ('label', 'K-2'), ('exit', 'S01L'), ('station', 'S01'), ('t', '1.0')]
    sorter_line.wcs._on_exit(message('parcel/9', forged))
    assert sorter_line.wcs.n_refused_exits == 1 and sorter_line.disposition('K-2') is None
