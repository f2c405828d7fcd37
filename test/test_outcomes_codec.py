"""
The outcome messages: what the cell, the line and the warehouse write, their readers read back.

``sorter_ros.outcomes`` is the one place that builds and reads ``sort/outcomes``,
``line/exits`` and ``wcs/dispositions``. Each record written here and read back must
come back field for field, to the nanosecond where the message carries nanoseconds;
a message from a writer that left fields out reads with the name and the message in
their place; and every node and reader of the project goes through it (no hand-made
decoding left that a renamed field would miss).
"""

from __future__ import annotations

import math
import re
from pathlib import Path

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

from sorter_control.wcs import Disposition
from sorter_ros import outcomes
from sorter_sim.runtime.cell_records import Outcome
from sorter_sim.runtime.line import LineExit

ROOT = Path(__file__).resolve().parents[1]


def test_a_cell_outcome_reads_back_as_it_was_written_to_the_nanosecond():
    e = Outcome(
        t_ns=12_345_678_901,
        parcel_id=42,
        label='P00042',
        exit='jammed',
        x=0.25,
        y=-0.125,
        cause='side wall',
    )
    msg = outcomes.outcome_msg(e, '/sorter_sim')
    assert msg.level == DiagnosticStatus.WARN and msg.name == 'parcel/42'
    assert msg.hardware_id == '/sorter_sim'
    r = outcomes.read_outcome(msg)
    assert (r.label, r.id, r.exit, r.cause, r.jammed) == (
        'P00042',
        42,
        'jammed',
        'side wall',
        True,
    )
    assert round(r.t * 1e9) == e.t_ns
    v = outcomes.values(msg)
    assert (float(v['x_exit']), float(v['y_exit'])) == (0.25, -0.125)
    ok = outcomes.read_outcome(outcomes.outcome_msg(Outcome(1, 7, 'P7', 'left', 0, 0), ''))
    assert ok.cause == '' and not ok.jammed
    assert 'cause' not in outcomes.values(
        outcomes.outcome_msg(Outcome(1, 7, 'P7', 'left', 0, 0), '')
    )


def test_a_line_exit_reads_back_with_its_station():
    e = LineExit(t_ns=3_000_000_001, parcel_id=9, label='P9', exit='lost', station=2, cause='x')
    msg = outcomes.exit_msg(e, 'S03', '/sorter_line')
    assert msg.level == DiagnosticStatus.WARN and msg.message == 'lost'
    r = outcomes.read_exit(msg)
    assert (r.label, r.id, r.exit, r.station, r.cause) == ('P9', 9, 'lost', 'S03', 'x')
    assert round(r.t * 1e9) == e.t_ns
    sorted_ = outcomes.exit_msg(LineExit(1, 1, 'P1', 'S01L', 0), 'S01', '')
    assert sorted_.level == DiagnosticStatus.OK


def test_a_disposition_reads_back_field_for_field():
    d = Disposition('P5', 'mis_sorted', 'D03', 'S02R', 'S02', 4.5, 'wrong side')
    msg = outcomes.disposition_msg(d)
    assert msg.level == DiagnosticStatus.WARN and msg.name == 'P5'
    r = outcomes.read_disposition(msg)
    assert r == outcomes.LineDisposition('P5', 'mis_sorted', 'D03', 'S02R', 'S02', 4.5)
    assert outcomes.values(msg)['cause'] == 'wrong side'
    ok = outcomes.disposition_msg(Disposition('P6', 'sorted', 'D01', 'S01L', 'S01', 1.0))
    assert ok.level == DiagnosticStatus.OK and 'cause' not in outcomes.values(ok)


def test_a_message_without_its_fields_reads_from_its_name_and_message():
    bare = DiagnosticStatus(name='parcel/17', message='straight')
    r = outcomes.read_outcome(bare)
    assert (r.label, r.id, r.exit, r.cause) == ('', 17, 'straight', '') and math.isnan(r.t)
    e = outcomes.read_exit(DiagnosticStatus(name='parcel/x', message='S01L'))
    assert (e.id, e.exit) == (0, 'S01L')  # a name that is not an id: no id, not a crash
    d = outcomes.read_disposition(
        DiagnosticStatus(name='P1', message='sorted', values=[KeyValue(key='t', value='oops')])
    )
    assert (d.label, d.code) == ('P1', 'sorted') and math.isnan(d.t)


def test_no_reader_or_writer_of_the_project_builds_or_reads_the_records_by_hand():
    """A key-value dict comprehension over a message is the codec's alone."""
    by_hand = re.compile(r'\{\s*kv\.key\s*:\s*kv\.value\s+for\s+kv\s+in')
    found = []
    for folder in ('sorter_cell', 'sorter_control', 'sorter_sim', 'sorter_ros', 'benchmarks'):
        for path in sorted((ROOT / folder).rglob('*.py')):
            if path.name == 'outcomes.py' and path.parent.name == 'sorter_ros':
                continue
            text = path.read_text(encoding='utf-8')
            if by_hand.search(text) or "('exit', e.exit)" in text:
                found.append(str(path.relative_to(ROOT)))
    # the simulation node's fault injection reads a fault's parameters, not a record
    assert found == ['sorter_sim/frontends/node_diagnostics.py'], found
