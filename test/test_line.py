"""
A line of stations (``sorter_sim.runtime.line``): hand-over, layout rules, chutes.

The hand-over is checked against closed forms (a parcel riding the belt through
every station reaches the straight end at distance / v) and against a single cell
(a parcel handed to a station and one inducted there in the same state divert
alike); the layout rules and the chutes' fill and drain against their definitions.
"""

from __future__ import annotations

import math

import pytest

from sorter_sim.runtime.cell import Cell, Outcome, ParcelSpec, SensorEdge
from sorter_sim.runtime.line import Line, LineExit, LineLayout, StationEvent, default_layout
from sorter_sim.runtime.params import CellParams, ParamError

V = 1.5


def params(**changes) -> CellParams:
    return CellParams.defaults().with_changes({'arrival': 'none', **changes}, runtime=False)


@pytest.mark.parametrize('n', [1, 2, 5])
def test_a_parcel_rides_every_station_to_the_straight_end_at_belt_speed(n):
    p = params()
    line = Line(p, default_layout(n, p, gap=0.35))
    A = 0.5
    line.stations[0].induct(ParcelSpec(A, 0.3, 4.0, phi0=0.0, y0=0.1, label='P-1'))
    events = line.advance(round((n * 6.35 + 3) / V / line.dt))
    (out,) = [e for e in events if isinstance(e, LineExit)]
    assert (out.label, out.exit, out.station) == ('P-1', 'straight_end', n - 1)
    # from the leading edge on the first induct point to the CoG on the last exit line
    distance = line.positions[-1] - line.positions[0] + p.exit_x - (p.induct_x - A / 2)
    assert out.t_ns * 1e-9 == pytest.approx(distance / V, abs=1e-9)
    straight = [
        e.event for e in events if isinstance(e, StationEvent) and isinstance(e.event, Outcome)
    ]
    assert [o.exit for o in straight] == ['straight'] * n  # one exit per station
    assert all(o.y == pytest.approx(0.1) and o.parcel_id == 1 for o in straight)
    assert line.n_handed == n - 1 and line.n_parcels == 0


def test_a_handed_parcel_diverts_as_one_inducted_in_the_same_state():
    # A = 0.402 m: the CoG covers induct -> exit (6.201 m) in 4134 whole periods at
    # 1.5 mm per period, so station 2 receives it at a period boundary, 1.5 mm past
    # the hand-over point, exactly where a fresh induct can put it
    A, B, m = 0.402, 0.3, 4.0
    p = params(alpha_deg=60.0)
    line = Line(p, LineLayout(positions=[3.0, 9.0], chutes=[('1L', '1R'), ('2L', '2R')]))
    line.stations[1].popup(True)
    line.stations[0].induct(ParcelSpec(A, B, m, label='H'))
    line.advance(4136)
    (cell2,) = [c for c in line.stations[1:]]
    assert cell2.n_parcels == 1
    k_in = 4135  # the period boundary it arrived at
    events = [e.event for e in line.advance(4000) if isinstance(e, StationEvent)]
    handed = next(e for e in events if isinstance(e, Outcome) and e.exit == 'left')
    # the same parcel inducted fresh into a lone station 2, its CoG at x = -3 + 1.5 mm
    ref = Cell(params(alpha_deg=60.0, induct_x=-3.0 + 0.0015 + A / 2))
    ref.popup(True)
    ref.advance(k_in)  # the disks' stroke ends long before; the clocks now agree
    ref.induct(ParcelSpec(A, B, m, label='H'))
    fresh = next(e for e in ref.advance(4000) if isinstance(e, Outcome) and e.exit == 'left')
    assert handed.t_ns == fresh.t_ns
    assert handed.x == pytest.approx(fresh.x, abs=1e-9)
    assert handed.y == pytest.approx(fresh.y, abs=1e-12)
    exits = [x for x in line.exits if x.label == 'H']
    assert [x.exit for x in exits] == ['2L']


@pytest.mark.parametrize(
    'layout, message',
    [
        (LineLayout([0.0, 5.0], [('a', 'b'), ('c', 'd')]), 'stations 1 and 2 overlap'),
        (
            LineLayout([0.0, 6.0, 11.9], [('a', 'b'), ('c', 'd'), ('e', 'f')]),
            'stations 2 and 3 overlap',
        ),
        (LineLayout([2.0], [('a', 'b')]), 'station 1 lies outside the belt'),
        (
            LineLayout([3.0, 9.0], [('a', 'b'), ('c', 'd')], length=10.0),
            'station 2 lies outside the belt',
        ),
        (LineLayout([3.0, 9.0], [('a', 'b'), ('c', 'a')]), "chute 'a' named twice"),
        (LineLayout([3.0], [('a', 'straight_end')]), 'straight_end'),
        (LineLayout([3.0], [('a', '')]), 'chute name'),
        (LineLayout([3.0], [('a',)]), 'pair'),
        (LineLayout([3.0, 9.0], [('a', 'b')]), '1 pairs of names for 2 stations'),
        (LineLayout([3.0], [('a', 'b')], capacity=0), 'capacity'),
        (LineLayout([3.0], [('a', 'b')], drain_per_s=-1.0), 'drain_per_s'),
        (LineLayout([math.nan], [('a', 'b')]), 'finite'),
        (LineLayout([], []), '1 to 64 stations'),
    ],
)
def test_a_bad_layout_is_refused_naming_what_is_wrong(layout, message):
    with pytest.raises(ParamError, match=message):
        Line(params(), layout)


def test_default_layout_counts():
    p = params()
    assert len(Line(p, default_layout(64, p)).stations) == 64
    for bad in (0, 65, 2.5):
        with pytest.raises(ParamError, match='stations must be'):
            default_layout(bad, p)


def test_a_full_chute_shows_full_refuses_the_next_parcel_and_drains():
    p = params(alpha_deg=90.0, arrival='gap', arrival_gap=[1.6, 1.6])
    layout = LineLayout([3.0], [('L', 'R')], capacity=2, drain_per_s=0.0)
    line = Line(p, layout)
    line.stations[0].popup(True)
    events = line.advance(round(12.0 / line.dt))
    exits = [e for e in events if isinstance(e, LineExit)]
    assert [x.exit for x in exits[:3]] == ['L', 'L', 'jammed']
    assert exits[2].cause == 'chute full' and 'jam' in line.stations[0].faults
    full = [e for e in events if isinstance(e, SensorEdge)]
    assert [(e.sensor, e.blocked) for e in full] == [('L.full', True)]
    assert full[0].t_ns == exits[1].t_ns and line.chute_full() == {'L': True, 'R': False}
    # the take-away started at 0.5 parcels/s: the first parcel leaves 2 s later and the
    # chute is no longer full
    line.chutes[0].drain_per_s = 0.5
    line.stations[0].popup(False)
    line.stations[0].update_params(line.stations[0].params.with_changes({'arrival': 'none'}))
    t0 = line.t
    cleared = [e for e in line.advance(round(5.0 / line.dt)) if isinstance(e, SensorEdge)]
    assert [(e.sensor, e.blocked) for e in cleared] == [('L.full', False)]
    assert cleared[0].t_ns * 1e-9 - t0 == pytest.approx(2.0, abs=1e-9)
    assert line.chutes[0].level == 0  # the second one 2 s after the first
