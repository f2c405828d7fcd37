"""
The sorter cell without ROS: parameters, the per-period kernels, sensors, exits, jams.

Expected values come from closed forms (a parcel stuck to the belt moves at v; a
parcel sliding on a stopped belt stops after v²/(2μg)), from the model core run
on its own for one parcel (the reference for a diversion), and from invariants
(mirror symmetry, no overlap beyond one period's travel, same seed same stream).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from sorter_sim.model.core import cell_kernels as ck
from sorter_sim.model.core.cell_kernels import Motion
from sorter_sim.model.core.simulate import (
    FrictionLaw,
    Parcel,
    simulate,
    strip_array,
    three_zone_strips,
)
from sorter_sim.runtime.cell import (
    STATE_NAMES,
    Cell,
    LabelRead,
    Outcome,
    ParcelSpec,
    SensorEdge,
    WatchdogTrip,
    check_parcel,
)
from sorter_sim.runtime.params import SCHEMA, SPECS, CellParams, ParamError

REPO = Path(__file__).resolve().parents[1]
G = 9.81
MU = 0.6


def make_cell(**changes) -> Cell:
    """Return a default cell with no parcel stream unless asked, and the changes applied."""
    values = {'arrival': 'none', **changes}
    return Cell(CellParams.defaults().with_changes(values, runtime=False))


def edges_of(events, sensor=None):
    return [
        e for e in events if isinstance(e, SensorEdge) and (sensor is None or e.sensor == sensor)
    ]


def outcomes_of(events):
    return [e for e in events if isinstance(e, Outcome)]


# ---------------------------------------------------------------- parameters
def test_schema_and_dataclass_agree():
    fields = [f for f in CellParams.__dataclass_fields__]
    assert fields == [s.name.replace('.', '_') for s in SCHEMA]
    for spec in SCHEMA:
        assert spec.description and spec.allowed


def test_cell_yaml_is_the_declared_default():
    data = yaml.safe_load((REPO / 'config' / 'cell.yaml').read_text())
    ((key, body),) = data.items()
    assert key.endswith('sorter_sim')
    flat = {}
    for name, value in body['ros__parameters'].items():
        if isinstance(value, dict):
            flat.update({f'{name}.{k}': v for k, v in value.items()})
        else:
            flat[name] = value
    assert set(flat) == set(SPECS)
    params = CellParams.from_values(flat)
    assert params == CellParams.defaults()


@pytest.mark.parametrize(
    'name, value',
    [
        ('belt_speed', math.nan),
        ('belt_speed', math.inf),
        ('belt_speed', 20.0),
        ('belt_speed', 'fast'),
        ('belt_speed', True),
        ('alpha_deg', 91.0),
        ('alpha_deg', -math.inf),
        ('control_period', 0.0),
        ('time_mode', 'slow'),
        ('seed', 1.5),
        ('seed', -1),
        ('parcel_A', [0.3]),
        ('parcel_A', [0.3, math.nan]),
        ('parcel_A', [0.7, 0.3]),
        ('labels', []),
        ('labels', [1, 2]),
        ('photo_eyes.x', [-2.0, -0.3]),
    ],
)
def test_bad_values_are_refused_naming_the_parameter(name, value):
    with pytest.raises(ParamError, match=name.split('.')[0]):
        CellParams.defaults().with_changes({name: value}, runtime=False)


@pytest.mark.parametrize(
    'changes, match',
    [
        ({'scanner_x': -2.5}, 'pe_scan'),
        ({'photo_eyes.names': ['pe_scan', 'pe_x', 'pe_exit']}, 'pe_divert'),
        ({'photo_eyes.names': ['pe_scan', 'pe_divert', 'edges']}, 'edges'),
        ({'photo_eyes.x': [-2.0, 0.5, 2.0]}, 'upstream'),
        ({'exit_x': 1.0}, 'exit_x'),
        ({'induct_x': -1.0}, 'induct_x'),
        ({'parcel_B': [0.2, 0.7]}, 'belt_width'),
        ({'label_pattern': '{label}{serial}'}, 'label_pattern'),
        ({'label_pattern': '{id:q}'}, 'label_pattern'),
        # a pattern or labels that could make a label outside the label grammar
        ({'label_pattern': '{label[0]}', 'labels': ['']}, 'labels'),
        ({'label_pattern': '{label[3]}', 'labels': ['AB']}, 'cannot label'),
        ({'label_pattern': '{id:>20000000}'}, 'longer than 64'),
        ({'label_pattern': '{id:>{n}}'}, 'longer than 64'),
        ({'label_pattern': '{id:>60}{label}'}, '1 to 64'),
        ({'label_pattern': '{label} {id}'}, '1 to 64'),
        ({'label_pattern': '{label}=' + 'x' * 300}, 'at most 200'),
        ({'labels': ['A;B']}, 'labels'),
        ({'labels': ['L' * 65]}, 'labels'),
        ({'pose_rate_hz': 1000.0, 'control_period': 0.002}, 'pose_rate_hz'),
    ],
)
def test_inconsistent_values_are_refused(changes, match):
    with pytest.raises(ParamError, match=match):
        CellParams.defaults().with_changes(changes, runtime=False)


def test_structural_parameters_cannot_change_at_run_time():
    p = CellParams.defaults()
    with pytest.raises(ParamError, match='read-only'):
        p.with_changes({'belt_speed': 1.0})
    assert p.with_changes({'alpha_deg': 45.0}).alpha_deg == 45.0
    assert p.alpha_deg == 90.0


@pytest.mark.parametrize(
    'spec, match',
    [
        (ParcelSpec(math.nan, 0.2, 5.0), 'A'),
        (ParcelSpec(0.4, 0.0, 5.0), 'B'),
        (ParcelSpec(0.4, 0.2, -1.0), 'm'),
        (ParcelSpec(0.4, 0.2, 5.0, 2.0), 'phi0'),
        (ParcelSpec(0.4, 0.2, 5.0, 0.0, 0.3), 'fit'),
        (ParcelSpec(0.4, 0.2, 5.0, 0.0, math.inf), 'y'),
        (ParcelSpec(0.4, 0.2, 5.0, label='A B'), '1 to 64'),
        (ParcelSpec(0.4, 0.2, 5.0, label='x' * 100_000), '1 to 64'),
    ],
)
def test_bad_parcels_are_refused(spec, match):
    with pytest.raises(ParamError, match=match):
        check_parcel(spec, 0.7)


# ---------------------------------------------------------------- kernels
@pytest.mark.parametrize('v', [1.5, 0.0])
@pytest.mark.parametrize('alpha', [math.pi / 2, -math.pi / 4, 0.0, 1e-12])
@pytest.mark.parametrize('stroke', [0.0, 0.3, 1.0])
def test_cell_strips_match_the_core_builder(v, alpha, stroke):
    law_a = FrictionLaw('const1', (0.6,))
    law_b = FrictionLaw('linear', (0.65, -0.1))
    ref = strip_array(three_zone_strips(v, alpha, 1.2, law_a, law_b, stroke=stroke))
    out = np.zeros((4, ref.shape[1]))
    n, disk_sid = ck.cell_strips(
        v, alpha, 1.2, stroke, law_a.law_id, law_a.row(), law_b.law_id, law_b.row(), out
    )
    assert n == ref.shape[0]
    np.testing.assert_array_equal(out[:n], ref)
    assert disk_sid == (-1 if stroke == 0.0 else int(ref[1, 5]))


def test_separating_axis_overlap():
    s = np.array([0.0, 0.0, 0.0])
    ov = ck.rectangles_overlap
    assert ov(s, 0.2, 0.1, np.array([0.39, 0.0, 0.0]), 0.2, 0.1, 1e-9)
    assert not ov(s, 0.2, 0.1, np.array([0.40, 0.0, 0.0]), 0.2, 0.1, 1e-9)  # touching
    # a diamond beside the box corner: their bounding boxes overlap, the shapes do not
    # (its lower-left edge lies on x + y = cx + cy - 0.1 sqrt(2); the box corner has x + y = 0.3)
    assert not ov(s, 0.2, 0.1, np.array([0.3, 0.2, math.pi / 4]), 0.1, 0.1, 1e-9)
    assert ov(s, 0.2, 0.1, np.array([0.25, 0.15, math.pi / 4]), 0.1, 0.1, 1e-9)


def test_crossing_time_is_exact_for_linear_motion_and_located_for_curved():
    s0 = np.array([-0.5, 0.0, 0.0, 1.5, 0.0, 0.0])
    s1 = s0 + np.array([1.5e-3, 0, 0, 0, 0, 0])
    tau = ck.crossing_time(ck.F_XMAX, -0.2, Motion(s0, s1, 1e-3), 0.3, 0.1)
    assert tau == pytest.approx((-0.2 - (-0.5 + 0.3)) / 1.5, abs=1e-15)
    # uniformly decelerated motion: x(t) = x0 + v t - a t²/2 is reproduced by the Hermite cubic
    a, h = 5.0, 1e-3
    s1 = np.array([-0.5 + 1.5 * h - 0.5 * a * h * h, 0.0, 0.0, 1.5 - a * h, 0.0, 0.0])
    level = -0.5 + 0.3 + 1.5 * 4e-4 - 0.5 * a * 4e-4**2
    s0[5] = s1[5] = 0.0
    s0b = s0.copy()
    s0b[5] = 1e-30  # force the interpolating branch
    tau = ck.crossing_time(ck.F_XMAX, level, Motion(s0b, s1, h), 0.3, 0.1)
    assert tau == pytest.approx(4e-4, abs=1e-12)


# ---------------------------------------------------------------- a parcel on the belt
def test_sensors_switch_when_the_geometry_says():
    """Belt-stuck parcel: edge at x_e when x_lead(t) = x_lead0 + v t (closed form)."""
    cell = make_cell(parcel_phi0_deg=[0.0, 0.0])
    p = cell.params
    A, B = 0.5, 0.3
    cell.induct(ParcelSpec(A, B, 4.0, 0.0, 0.1, 'P1'))
    events = cell.advance(4500)
    v = p.belt_speed
    for name, x_e in zip(p.photo_eyes_names, p.photo_eyes_x):
        rise, fall = edges_of(events, name)
        assert rise.blocked and not fall.blocked
        assert rise.t_ns * 1e-9 == pytest.approx((x_e - p.induct_x) / v, abs=2e-9)
        assert fall.t_ns * 1e-9 == pytest.approx((x_e - p.induct_x + A) / v, abs=2e-9)
    (read,) = [e for e in events if isinstance(e, LabelRead)]
    assert read.label == 'P1' and read.parcel_id == 1
    assert read.t_ns * 1e-9 == pytest.approx((p.scanner_x - p.induct_x) / v, abs=2e-9)
    # with the disks down it goes straight on, unturned
    (out,) = outcomes_of(events)
    assert out.exit == 'straight' and out.label == 'P1'
    assert out.t_ns * 1e-9 == pytest.approx((p.exit_x - (p.induct_x - A / 2)) / v, abs=2e-9)
    assert out.y == pytest.approx(0.1, abs=1e-15)
    assert not edges_of(events, 'chute_left') and not edges_of(events, 'chute_right')
    assert cell.n_parcels == 0 and cell.sensor_states() == dict.fromkeys(cell.sensor_names, False)


def _diversion_reference(A, B, m, alpha, b):
    """
    Return the model core on one parcel: leading edge on the a/b border, disks up, to y = w/2.

    Returns the time the centre of gravity reaches y = w/2, the state there, and the time
    the footprint first reaches past y = w/2 (from the trajectory at 0.1 ms steps, linearly
    interpolated: the reference for the chute-entry sensor's rising edge).
    """
    law = FrictionLaw('const1', (MU,))
    res = simulate(
        Parcel(A, B, m),
        three_zone_strips(1.5, alpha, b, law, law),
        [-A / 2, 0.0, 0.0, 1.5, 0.0, 0.0],
        (0.0, 5.0),
        'accurate',
        rtol=1e-10,
        atol=1e-12,
        y_target=0.35,
        h_max=1e-4,
    )
    phi = res.y[:, 2]
    reach = res.y[:, 1] + 0.5 * (A * np.abs(np.sin(phi)) + B * np.abs(np.cos(phi))) - 0.35
    j = int(np.argmax(reach > 0.0))
    t_corner = res.t[j - 1] + (res.t[j] - res.t[j - 1]) * -reach[j - 1] / (reach[j] - reach[j - 1])
    return res.t_target, res.y[-1], t_corner


@pytest.mark.parametrize('alpha_deg, chute', [(90.0, 'left'), (-90.0, 'right'), (45.0, 'left')])
def test_raised_disks_divert_as_the_model_core_predicts(alpha_deg, chute):
    A, B, m = 0.6, 0.3, 5.0
    cell = make_cell(alpha_deg=alpha_deg, popup_stroke_time=0.0)
    p = cell.params
    assert cell.popup(True)[0]
    cell.induct(ParcelSpec(A, B, m, 0.0, 0.0, 'D'))
    events = cell.advance(4000)
    (out,) = outcomes_of(events)
    assert out.exit == chute
    t_ref, y_ref, t_corner = _diversion_reference(
        A, B, m, math.radians(abs(alpha_deg)), p.disk_field_length
    )
    t_at_field = -p.induct_x / p.belt_speed  # leading edge from induct_x to the disk field
    # the cell integrates at its own tolerances (rtol 1e-6, atol 1e-8) and restarts every
    # period: a single core run at those tolerances is 1e-7 s off the reference; the cell,
    # re-entering the break-away layer (``layer._layer``) at each period's end, 5e-7 s
    assert out.t_ns * 1e-9 == pytest.approx(t_at_field + t_ref, abs=1e-6)
    assert out.x == pytest.approx(y_ref[0], abs=1e-6)
    # the chute-entry sensor of that side: blocked when the footprint first reaches past the
    # entry line (located inside a period of sliding), clear after the crossing; the other never
    side = f'chute_{chute}'
    rise, fall = edges_of(events, side)
    assert rise.blocked and rise.t_ns < out.t_ns < fall.t_ns and not fall.blocked
    assert rise.t_ns * 1e-9 == pytest.approx(t_at_field + t_corner, abs=5e-7)
    other = 'chute_right' if chute == 'left' else 'chute_left'
    assert not edges_of(events, other)
    assert cell.n_parcels == 0 and not cell.faults


def test_a_parcel_stuck_to_the_disks_astride_the_border_rides_as_the_core_predicts():
    """
    Check a parcel the disks hold while it lies across the a/b border against the core.

    Disks gripping harder than the belt (μ 0.9 against 0.3) at α = 90° take the parcel over
    while it still lies across the border: stuck to them it rides straight across the
    belt. The cell carries such a stick in closed form from one period to the next (its part
    over each zone only slides along y, so no force changes); the model core integrates it.
    """
    A, B, m = 0.6, 0.3, 5.0
    cell = make_cell(alpha_deg=90.0, popup_stroke_time=0.0, mu_belt=0.3, mu_disks=0.9)
    p = cell.params
    assert cell.popup(True)[0]
    cell.induct(ParcelSpec(A, B, m, 0.0, 0.0, 'S'))
    t_at_field = -p.induct_x / p.belt_speed
    n_field = math.ceil(t_at_field / cell.dt)
    cell.advance(n_field)
    t_cell = n_field * cell.dt - t_at_field  # since the leading edge met the disk field
    integrated = []
    for _ in range(620):
        before = cell.stats.copy()
        cell.advance(1)
        integrated.append(cell.stats[1] - before[1])
        t_cell += cell.dt
    assert cell.mode[0] == ck.MODE_DISKS and cell.state[0, 0] - A / 2 < 0.0 < cell.state[0, 0]
    # once stuck astride, no period needs the integrator
    assert integrated[-50:] == [0] * 50
    res = simulate(
        Parcel(A, B, m),
        three_zone_strips(
            1.5,
            math.radians(90.0),
            p.disk_field_length,
            FrictionLaw('const1', (0.3,)),
            FrictionLaw('const1', (0.9,)),
        ),
        [-A / 2, 0.0, 0.0, 1.5, 0.0, 0.0],
        (0.0, t_cell),
        'accurate',
        rtol=1e-10,
        atol=1e-12,
    )
    assert res.mode[-1] == ck.MODE_DISKS
    assert np.allclose(cell.state[0], res.y[-1], atol=2e-6)


def test_actuators_move_at_their_rates():
    cell = make_cell(alpha_deg=0.0, alpha_slew_rate_deg_s=180.0, popup_stroke_time=0.2)
    dt = cell.dt
    cell.set_alpha(math.radians(90.0))
    cell.popup(True)
    cell.advance(100)
    assert cell.stroke == pytest.approx(0.5, abs=1e-12)
    assert cell.stroke_rate == pytest.approx(5.0)
    assert cell.alpha == pytest.approx(math.radians(18.0 * 100 * dt / 0.1), abs=1e-12)
    assert cell.alpha_rate == pytest.approx(math.radians(180.0))
    cell.advance(500)
    assert cell.stroke == 1.0 and cell.alpha == pytest.approx(math.pi / 2)
    assert cell.stroke_rate == 0.0 and cell.alpha_rate == 0.0


# ---------------------------------------------------------------- e-stop and reset
def test_estop_stops_the_belt_and_parcels_slide_to_rest():
    """On a belt stopped at once a parcel slides v²/(2μg) and stops after v/(μg)."""
    cell = make_cell()
    cell.induct(ParcelSpec(0.5, 0.3, 5.0, 0.0, 0.0, 'E'))
    cell.advance(400)
    x0 = cell.parcels()['x'][0]
    cell.engage_estop()
    assert not cell.popup(True)[0] and not cell.set_alpha(0.0)[0]
    v = cell.params.belt_speed
    t_stop = v / (MU * G)
    n_stop = math.floor(t_stop / cell.dt)
    cell.advance(n_stop)
    assert cell.state[0, 3] == pytest.approx(v - MU * G * n_stop * cell.dt, abs=1e-9)
    cell.advance(1000)
    assert cell.parcels()['x'][0] - x0 == pytest.approx(v * v / (2 * MU * G), abs=1e-9)
    assert cell.state[0, 3] == 0.0 and cell.faults == ['estop']
    # the stream waits while the belt stands
    cell.induct(ParcelSpec(0.3, 0.3, 5.0))
    cell.advance(100)
    assert cell.n_parcels == 1 and cell.pending_inducts == 1
    # reset: the belt restarts and drags the parcel up to speed over v/(μg)
    cell.reset()
    assert cell.faults == [] and cell.popup(True)[0]
    x1 = cell.parcels()['x'][0]
    cell.advance(1000)
    assert cell.parcels()['x'][0] == pytest.approx(x1 + v * 1.0 - v * v / (2 * MU * G), abs=1e-9)


# ---------------------------------------------------------------- jams
def test_wall_and_parcel_jams_stop_the_parcels_until_reset():
    # the old rule (contact: jam), a touch is a fault: a short disk field with no
    # margin, the disks push a parcel riding near the left edge into the wall
    # downstream of the opening
    cell = make_cell(disk_field_length=0.3, chute_margin=0.0, popup_stroke_time=0.0, contact='jam')
    cell.popup(True)
    cell.induct(ParcelSpec(0.4, 0.2, 5.0, 0.0, 0.2, 'W'))
    events = cell.advance(3000)
    (jam,) = outcomes_of(events)
    assert jam.exit == 'jammed' and jam.jammed and jam.cause == 'side wall'
    assert cell.faults == ['jam']
    parked = cell.parcels()
    assert STATE_NAMES[parked['state'][0]] == 'jammed'
    # it stays put, and the next parcel in its lane runs into it on the belt
    cell.popup(False)
    cell.induct(ParcelSpec(0.4, 0.2, 5.0, 0.0, 0.2, 'N'))
    events = cell.advance(3000)
    (hit,) = outcomes_of(events)
    assert hit.exit == 'jammed' and hit.cause == 'parcel 1' and hit.label == 'N'
    now = cell.parcels()
    np.testing.assert_array_equal(now['x'][:1], parked['x'])
    # never overlapped by more than one period's travel
    i, j = np.flatnonzero(cell.phase == ck.PH_JAMMED)
    s_i, s_j = cell.state[i].copy(), cell.state[j].copy()
    s_j[0] -= cell.params.belt_speed * cell.dt
    assert not ck.rectangles_overlap(s_i, *cell.par[i, :2], s_j, *cell.par[j, :2], 1e-9)
    # reset takes them off and clears the fault; the sensors they blocked clear
    edges = cell.reset()
    assert cell.n_parcels == 0 and cell.faults == []
    assert all(not e.blocked for e in edges)
    assert not any(cell.sensor_states().values())


# ---------------------------------------------------------------- the parcel stream
def test_gap_stream_keeps_its_gaps_and_is_reproducible():
    def run(seed):
        cell = make_cell(
            arrival='gap',
            seed=seed,
            parcel_phi0_deg=[0.0, 0.0],
            arrival_gap=[0.4, 0.8],
            induct_x=-10.0,
        )
        cell.popup(True)
        events = cell.advance(12000)
        return cell, events

    cell, events = run(7)
    p = cell.params
    parcels = cell.parcels()
    upstream = parcels['x'] < -0.5  # still on the belt, before the disk field
    x, A = parcels['x'][upstream], parcels['A'][upstream]
    gaps = (x[:-1] - A[:-1] / 2) - (x[1:] + A[1:] / 2)
    assert len(gaps) >= 5
    assert np.all(gaps >= 0.4 - 1e-12) and np.all(gaps <= 0.8 + p.belt_speed * cell.dt + 1e-12)
    assert all(0.3 <= a <= 0.7 for a in parcels['A'])
    labels = [e.label for e in events if isinstance(e, LabelRead)]
    assert labels[:4] == ['A00001', 'B00002', 'C00003', 'A00004']
    again_cell, again = run(7)
    assert again == events
    np.testing.assert_array_equal(again_cell.state, cell.state)
    _, other = run(8)
    assert other != events


def test_rate_stream_never_inducts_closer_than_the_minimum_gap():
    cell = make_cell(
        arrival='rate', arrival_rate=3.0, arrival_gap=[0.2, 0.2], parcel_phi0_deg=[0.0, 0.0]
    )
    cell.advance(8000)
    parcels = cell.parcels()
    on_belt = parcels['x'] < -0.5
    x, A = parcels['x'][on_belt], parcels['A'][on_belt]
    gaps = (x[:-1] - A[:-1] / 2) - (x[1:] + A[1:] / 2)
    assert len(gaps) >= 3 and np.all(gaps >= 0.2 - 1e-12)
    assert cell.n_inducted >= 8


@pytest.mark.parametrize(
    'module',
    ['runtime/cell.py', 'runtime/params.py', 'frontends/cdr.py', 'model/core/cell_kernels.py'],
)
def test_the_cell_imports_no_ros(module):
    from test_core_has_no_ros import ros_imports

    path = REPO / 'sorter_sim' / module
    assert ros_imports(path.read_text(), str(path)) == []


def test_the_docs_document_every_parameter():
    text = (REPO / 'docs' / 'simulation-node.md').read_text()
    section = text.split('\n## Parameters', 1)[1].split('\n## ', 1)[0]
    for spec in SCHEMA:
        assert f'| `{spec.name}` |' in section, spec.name


# ---------------------------------------------------------------- the controller watchdog
def test_watchdog_fails_safe_when_the_heartbeat_stops_and_clears_when_it_returns():
    cell = make_cell(
        alpha_deg=45.0,
        popup_stroke_time=0.1,
        alpha_slew_rate_deg_s=360.0,
        watchdog_timeout=0.3,
        safe_alpha_deg=0.0,
    )
    dt_ns = cell.params.control_period_ns
    assert cell.popup(True)[0]
    # not armed before the first heartbeat: a cell driven without a controller never trips
    cell.advance(2000)
    assert not cell.watchdog_armed and not cell.watchdog_tripped and cell.stroke == 1.0
    # heartbeats in time keep it quiet
    for beat in range(10):
        cell.heartbeat(beat)
        cell.advance(290)
    assert not cell.watchdog_tripped and cell.stroke == 1.0
    cell.heartbeat(10)
    k0 = cell.k
    assert not any(isinstance(e, WatchdogTrip) for e in cell.advance(299))
    assert not cell.watchdog_tripped
    # the 300th period after the heartbeat (0.3 s) trips it, at exactly that time
    (trip,) = [e for e in cell.advance(1) if isinstance(e, WatchdogTrip)]
    assert trip.t_ns == (k0 + 300) * dt_ns and trip.silent_s == pytest.approx(0.3, abs=1e-12)
    assert cell.watchdog_tripped and cell.faults == ['watchdog'] and cell.watchdog_trips == 1
    ok, why = cell.popup(True)
    assert not ok and 'watchdog' in why
    assert not cell.set_alpha(math.radians(30.0))[0]
    assert cell.popup(False)[0]
    # safe state: the disks drop in their stroke time, α slews 45° -> 0° at 360°/s (0.125 s)
    cell.advance(100)
    assert cell.stroke == 0.0
    cell.advance(30)
    assert cell.alpha == 0.0
    # a controller that comes back takes over: cleared, commands accepted again
    assert cell.heartbeat(11) is True
    assert not cell.watchdog_tripped and cell.faults == []
    assert cell.popup(True)[0] and cell.set_alpha(math.radians(30.0))[0]


def test_a_frozen_heartbeat_does_not_feed_the_watchdog_nor_clear_it():
    cell = make_cell(alpha_deg=45.0, watchdog_timeout=0.3, safe_alpha_deg=0.0)
    assert cell.popup(True)[0]
    cell.heartbeat(7)  # the first heartbeat arms it, whatever its value
    k0 = cell.k
    # a frozen controller rewrites its last counter every 0.1 s: that is silence
    trips = []
    for _ in range(30):
        trips += [e for e in cell.advance(100) if isinstance(e, WatchdogTrip)]
        assert cell.heartbeat(7) is False
    assert cell.watchdog_tripped and cell.watchdog_trips == 1 and len(trips) == 1
    assert trips[0].t_ns == (k0 + 300) * cell.params.control_period_ns
    assert cell.heartbeats_frozen == 30
    # tripped 0.3 s after the last changed counter, not fed by the 30 repeats
    assert cell.watchdog.fed_k == k0
    # the same value does not clear it either; a changed one does
    assert cell.heartbeat(7) is False and cell.watchdog_tripped
    assert cell.heartbeat(8) is True and not cell.watchdog_tripped
    # a counter that wraps (0xFFFF -> 0) is a change like any other
    cell.heartbeat(0xFFFF)
    cell.advance(200)
    cell.heartbeat(0)
    cell.advance(200)
    assert not cell.watchdog_tripped


def test_watchdog_off_and_ranges():
    cell = make_cell(watchdog_timeout=0.0)
    cell.heartbeat(1)
    cell.advance(5000)
    assert not cell.watchdog_armed and not cell.watchdog_tripped
    for name, bad in (
        ('watchdog_timeout', -0.1),
        ('watchdog_timeout', 61.0),
        ('safe_alpha_deg', 91.0),
        ('watchdog_timeout', math.nan),
    ):
        with pytest.raises(ParamError, match=name):
            CellParams.defaults().with_changes({name: bad}, runtime=False)


def test_pending_inducts_are_capped_and_the_excess_counted():
    from sorter_sim.model.description import PENDING_INDUCTS_MAX

    cell = Cell(CellParams.defaults().with_changes({'arrival': 'none'}, runtime=False))
    for _ in range(PENDING_INDUCTS_MAX):
        cell.induct(ParcelSpec(0.4, 0.2, 5.0))
    with pytest.raises(ParamError, match='refused'):
        cell.induct(ParcelSpec(0.4, 0.2, 5.0))
    assert cell.pending_inducts == PENDING_INDUCTS_MAX and cell.n_induct_refused == 1


def test_a_stream_of_a_known_span_stops_that_long_after_it_opens_however_it_is_sliced():
    """arrival_duration_s counts from the period the stream opens, in simulated time."""

    def run(span, slices):
        cell = make_cell(arrival='none', arrival_gap=[0.3, 0.4], arrival_duration_s=span)
        cell.advance(1234)  # the line runs empty before the stream opens
        cell.update_params(cell.params.with_changes({'arrival': 'gap'}))
        events = []
        for n in slices:
            events += cell.advance(n)
        outcomes = [(e.t_ns, e.parcel_id, e.exit) for e in events if isinstance(e, Outcome)]
        return cell, outcomes

    one, out = run(2.0, [20_000])
    # a parcel every 0.3-0.4 m of gap plus 0.3-0.7 m of length at 1.5 m/s: 3 to 4 in
    # 2 s, none after, and the cell completes once the last is out
    assert 3 <= one.n_streamed <= 4 and len(out) == one.n_streamed
    assert one.n_parcels == 0 and one.packml.state == 'Complete'
    # the same parcels at the same times, however the time is sliced
    sliced, out_sliced = run(2.0, [7] * 2000 + [6000])
    assert out_sliced == out
    # the span counts from the opening, not from t = 0: a longer one gives more
    longer, _ = run(4.0, [20_000])
    assert longer.n_streamed >= one.n_streamed + 2


def test_a_batch_stream_stops_after_arrival_count_parcels_and_the_cell_completes():
    cell = make_cell(arrival='gap', arrival_gap=[0.3, 0.4], arrival_count=3)
    cell.advance(20_000)
    assert cell.n_inducted == cell.n_streamed == 3
    assert cell.n_parcels == 0 and cell.packml.state == 'Complete'
    # Complete takes nothing in, from outside either: the parcel waits at the infeed
    cell.induct(ParcelSpec(0.4, 0.3, 4.0, label='X1'))
    cell.advance(2_000)
    assert cell.n_inducted == 3 and cell.pending_inducts == 1
    # a bigger batch at run time, then reset and start: the parcel waiting and the stream
    # (parcels/induct goes first, it is not the stream) come in
    cell.update_params(cell.params.with_changes({'arrival_count': 5}))
    assert cell.packml_command('start') == (
        False,
        'Complete does not take start: PackML takes it in Idle only',
    )
    assert cell.packml_command('reset')[0] and cell.packml.state == 'Idle'
    assert cell.packml_command('start')[0] and cell.packml.state == 'Execute'
    cell.advance(20_000)
    assert cell.n_inducted == 6 and cell.n_streamed == 5 and cell.labels.count('X1') == 1
