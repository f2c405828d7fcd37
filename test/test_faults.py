"""
Injected faults (``sorter_sim.runtime.faults``): what each shows, and bad requests.

A fault changes only the signal it names (a sensor, the heartbeat line) or stops
one parcel; the tests check the signal against the true one of the same run
without the fault, and the timing against the control period.
"""

from __future__ import annotations

import pytest

from sorter_sim.runtime.cell import Cell, Outcome, ParcelSpec, SensorEdge, WatchdogTrip
from sorter_sim.runtime.faults import FAULTS, apply_fault
from sorter_sim.runtime.params import CellParams, ParamError


def make_cell(**changes) -> Cell:
    return Cell(CellParams.defaults().with_changes({'arrival': 'none', **changes}, runtime=False))


def edges(events, sensor):
    return [e for e in events if isinstance(e, SensorEdge) and e.sensor == sensor]


def run_two(fault=None, periods=3000):
    """Run two parcels, with a fault injected at period 100 when one is given."""
    cell = make_cell()
    for label in ('P1', 'P2'):
        cell.induct(ParcelSpec(0.4, 0.3, 4.0, label=label))
    events = cell.advance(100)
    if fault:
        events += apply_fault(cell, *fault)[0]
    return cell, events + cell.advance(periods)


def test_an_eye_held_blocked_shows_blocked_and_the_others_are_untouched():
    clean, clean_ev = run_two()
    eye = clean.sensor_names[0]
    cell, ev = run_two(('eye', {'sensor': eye, 'mode': 'blocked'}))
    assert clean_ev and edges(clean_ev, eye)  # the parcels do pass it
    (edge,) = edges(ev, eye)  # one edge: the fault's own, at its time
    assert edge.blocked and edge.t_ns == 100 * cell.params.control_period_ns
    assert cell.sensor_states()[eye] is True
    for other in cell.sensor_names[1:]:
        assert edges(ev, other) == edges(clean_ev, other)
    assert [e for e in ev if isinstance(e, Outcome)] == [
        e for e in clean_ev if isinstance(e, Outcome)
    ]
    # cleared: the eye shows what it sees again (clear, the parcels are gone), one edge
    back, text = apply_fault(cell, 'eye', {'sensor': eye, 'mode': 'ok'})
    assert [e.blocked for e in back] == [False] and 'cleared' in text
    assert cell.sensor_states() == clean.sensor_states()


def test_an_eye_held_clear_never_shows_the_parcels():
    clean, clean_ev = run_two()
    eye = clean.sensor_names[1]
    cell2, ev2 = run_two(('eye', {'sensor': eye, 'mode': 'clear'}))
    assert edges(clean_ev, eye) and not edges(ev2, eye)
    assert cell2.sensor_states()[eye] is False


def test_a_chattering_eye_toggles_every_half_period_on_the_control_grid():
    cell = make_cell()
    eye = cell.sensor_names[0]
    cell.advance(7)
    first = apply_fault(cell, 'eye', {'sensor': eye, 'mode': 'chatter', 'period': '0.02'})[0]
    assert [e.blocked for e in first] == [True]  # the belt is empty: clear -> blocked
    ev = edges(cell.advance(100), eye)
    dt_ns = cell.params.control_period_ns
    assert [e.t_ns for e in ev] == [(7 + 10 * j) * dt_ns for j in range(1, 11)]
    assert [e.blocked for e in ev] == [j % 2 == 0 for j in range(1, 11)]
    # advanced in one piece or in many, the same edges
    again = make_cell()
    again.advance(7)
    apply_fault(again, 'eye', {'sensor': eye, 'mode': 'chatter', 'period': 0.02})
    pieces = []
    for n in (3, 1, 40, 56):
        pieces += edges(again.advance(n), eye)
    assert pieces == ev


def test_a_full_chute_holds_its_eye_blocked():
    cell = make_cell()
    ev, text = apply_fault(cell, 'chute_full', {'chute': 'left'})
    assert [(e.sensor, e.blocked) for e in ev] == [('chute_left', True)] and 'full' in text
    cell.advance(500)
    assert cell.sensor_states()['chute_left'] is True
    ev, _ = apply_fault(cell, 'chute_full', {'chute': 'left', 'full': 'false'})
    assert [(e.sensor, e.blocked) for e in ev] == [('chute_left', False)]


def test_a_jammed_parcel_stops_where_it_is_until_reset():
    cell = make_cell()
    cell.induct(ParcelSpec(0.4, 0.3, 4.0, label='SNAG'))
    cell.advance(200)
    x_before = float(cell.parcels()['x'][0])
    ev, _ = apply_fault(cell, 'jam', {'parcel': 'SNAG'})
    (out,) = ev
    assert out.exit == 'jammed' and out.cause == 'injected' and out.x == pytest.approx(x_before)
    assert cell.faults == ['jam']
    cell.advance(500)
    assert float(cell.parcels()['x'][0]) == x_before
    cell.reset()
    assert cell.n_parcels == 0 and cell.faults == []
    # by id as well; a parcel that is not there is refused
    cell.induct(ParcelSpec(0.4, 0.3, 4.0))
    cell.advance(10)
    assert apply_fault(cell, 'jam', {'parcel': '2'})[0][0].parcel_id == 2
    with pytest.raises(ParamError, match='no parcel'):
        apply_fault(cell, 'jam', {'parcel': 'NOBODY'})


def test_a_lost_heartbeat_trips_the_watchdog_though_the_controller_still_beats():
    cell = make_cell(watchdog_timeout=0.3)
    cell.heartbeat(1)
    cell.advance(100)
    apply_fault(cell, 'heartbeat', {'lost': 'true'})
    trips = []
    for beat in range(2, 40):
        cell.heartbeat(beat)  # a live controller: a new counter every 10 ms
        trips += [e for e in cell.advance(10) if isinstance(e, WatchdogTrip)]
    (trip,) = trips
    assert trip.t_ns == 300 * cell.params.control_period_ns and cell.heartbeats_lost == 38
    apply_fault(cell, 'heartbeat', {'lost': False})
    cell.heartbeat(99)
    assert not cell.watchdog_tripped


def test_estop_as_a_fault():
    cell = make_cell()
    apply_fault(cell, 'estop', {})
    assert cell.faults == ['estop'] and cell.belt_velocity == 0.0


@pytest.mark.parametrize(
    'name, values, message',
    [
        ('smoke', {}, 'unknown fault'),
        ('eye', {'sensor': 'pe_nowhere', 'mode': 'blocked'}, 'unknown sensor'),
        ('eye', {'sensor': 'chute_left', 'mode': 'sticky'}, 'mode must be one of'),
        ('eye', {'sensor': 'chute_left'}, 'needs mode'),
        ('eye', {'sensor': 'chute_left', 'mode': 'chatter', 'period': '0'}, 'period must be in'),
        ('eye', {'sensor': 'chute_left', 'mode': 'chatter', 'period': 'nan'}, 'finite'),
        ('eye', {'sensor': 'chute_left', 'mode': 'chatter', 'period': 'soon'}, 'number'),
        ('eye', {'sensor': 'chute_left', 'mode': 'ok', 'colour': 'red'}, 'does not take colour'),
        ('chute_full', {'chute': 'middle'}, 'left or right'),
        ('chute_full', {'chute': 'left', 'full': 'maybe'}, 'true or false'),
        ('heartbeat', {'lost': '2'}, 'true or false'),
        ('estop', {'now': 'yes'}, 'no arguments'),
    ],
)
def test_bad_fault_requests_are_refused_whole(name, values, message):
    cell = make_cell()
    before = (cell.sensor_states(), cell.faults, cell.heartbeat_cut)
    with pytest.raises(ParamError, match=message):
        apply_fault(cell, name, values)
    assert (cell.sensor_states(), cell.faults, cell.heartbeat_cut) == before


def test_every_fault_is_in_the_vocabulary():
    assert set(FAULTS) == {'eye', 'chute_full', 'jam', 'heartbeat', 'estop'}
