"""
Contact: rigid at its extremes, and the jams that emerge from it.

The stiff cases of the contact solve (a mass ratio of 1:100 in a chain, floor and
contact friction from 0.05 to 1.5, ten skewed parcels pressed together by the belt,
a parcel wedged between two converging rails) stay finite, keep their overlap
within the projection's tolerance and carry the closed-form load; a parcel held by
its contacts without progress for ``jam_time`` jams with the cause of its strongest
contact, as the old rule's jam does (fault, outcome ``jammed``, ``reset``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_contact import G, RAIL_T, V, place, rigid_cell, stopper_across

from sorter_sim.model.core import cell_kernels as ck
from sorter_sim.runtime.cell import Outcome
from sorter_sim.runtime.params import CellParams, ParamError


def _overlapping_pairs(cell, tol):
    """Return the pairs of parcels on the cell that interpenetrate by more than ``tol`` [m]."""
    on = np.flatnonzero(cell.phase == ck.PH_CELL)
    s, par = cell.state, cell.par
    return [
        (i, j)
        for k, i in enumerate(on)
        for j in on[k + 1 :]
        if ck.rectangles_overlap(s[i], par[i, 0], par[i, 1], s[j], par[j, 0], par[j, 1], tol)
    ]


@pytest.mark.parametrize(
    'masses, mu_belt, mu_parcel',
    [
        ([50.0, 0.5, 50.0, 0.5, 50.0], 0.6, 0.4),  # mass ratio 1:100 in the chain
        ([2.0, 3.0, 4.0], 0.05, 0.05),  # slippery belt and parcels
        ([2.0, 3.0, 4.0], 1.5, 1.5),  # grippy
    ],
)
def test_stiff_queues_carry_their_load(masses, mu_belt, mu_parcel):
    """
    Stiff queues at a stopper carry their load, at rest, with no NaN.

    The queue of ``test_queue_against_a_stopper_carries_the_belt_friction_of_all`` at
    the matrix's extremes: the stopper carries Σ μ m_i g within 0.1 %, at rest (below
    1e-9 m/s), no NaN, overlap within the 1e-9 m tolerance (plus one period's push).
    """
    cell = rigid_cell(mu_belt=mu_belt, mu_parcel=mu_parcel)
    ob = stopper_across(cell, -0.6)
    a, b = 0.3, 0.2
    for i, m in enumerate(masses):
        place(cell, i, -0.6 - 0.5 * a - i * a, 0.0, (a, b, m))
    cell.advance(400)
    n = len(masses)
    expected = mu_belt * G * sum(masses)
    for _ in range(20):
        cell.advance(1)
        assert not np.isnan(cell.state).any()
        assert cell.contacts.ob_force[ob, 0] == pytest.approx(expected, rel=1e-3)
        assert np.max(np.abs(cell.state[:n, 3:6])) < 1e-9
        gaps = -np.diff(cell.state[:n, 0]) - a
        assert gaps.min() >= -2e-9


def test_ten_skewed_parcels_pressed_by_the_belt():
    """
    Ten parcels, skewed ±10° and off-centre, carried by the belt into a stopper.

    They collide, turn against each other and the side walls and pile up against the
    stopper, jostled by the belt sliding under them: no NaN, every parcel on the belt
    between the walls and none jammed (jam_time is 60 s), the stopper pushing back
    (+x on it) throughout the last second, and no two overlapping at a period's end
    by more than one period's sweep of a footprint point, 2 max(|v| + |ω| r) h (the
    contacts are found at the period's end: a corner of a parcel spinning at 4 rad/s
    can sweep 0.7 mm into a neighbour it did not touch yet; it is found and pushed
    out the next period, as the old rule's overlap at detection was bounded).
    """
    cell = rigid_cell(mu_parcel=0.4, mu_wall=0.3)
    ob = stopper_across(cell, -0.5)
    rng = np.random.default_rng(3)
    a, b, m = 0.25, 0.18, 3.0
    hw = 0.5 * cell.params.belt_width
    for i in range(10):
        place(
            cell,
            i,
            -0.9 - 0.4 * i,
            rng.uniform(-0.08, 0.08),
            (a, b, m),
            (V, 0.0, 0.0),
            phi=math.radians(rng.uniform(-10, 10)),
        )
    for k in range(2500):
        cell.advance(1)
        assert not np.isnan(cell.state).any()
        on = cell.phase == ck.PH_CELL
        speed = np.abs(cell.state[on, 3:5]).sum(axis=1) + np.abs(cell.state[on, 5]) * 0.16
        assert not _overlapping_pairs(cell, 2 * speed.max() * cell.dt + 1e-6), k
        if k >= 1500:
            assert cell.contacts.ob_force[ob, 0] > 0.0
    assert np.all(np.abs(cell.state[:10, 1]) < hw)
    assert np.all(cell.phase[:10] == ck.PH_CELL)
    assert not cell.faults


def _funnel(cell, x_tip, half_gap):
    """Two rails converging along the belt to a throat of width 2 half_gap at x_tip."""
    hw = 0.5 * cell.params.belt_width
    for side in (1.0, -1.0):
        cell.add_rail(x_tip - 1.0, side * (hw - 0.01), x_tip, side * (half_gap + 0.5 * RAIL_T))


def test_a_parcel_wedged_between_two_rails_jams_with_cause_rail():
    """
    A funnel narrower than the parcel: the belt carries it in until it wedges.

    Wedged, it stops (no NaN, overlap within tolerance, no hang) and after jam_time
    without progress it jams: fault `jam`, outcome `jammed`, cause `rail`; `reset`
    takes it off and clears the fault.
    """
    cell = rigid_cell(jam_time=0.3, mu_wall=0.3)
    _funnel(cell, -1.0, 0.08)
    place(cell, 0, -2.4, 0.0, (0.3, 0.25, 5.0), (V, 0.0, 0.0))
    events = []
    for _ in range(3000):
        events += cell.advance(1)
        assert not np.isnan(cell.state).any()
        if cell.faults:
            break
    outs = [e for e in events if isinstance(e, Outcome)]
    assert [o.exit for o in outs] == ['jammed']
    assert outs[0].cause == 'rail'
    assert 'jam' in cell.faults
    assert cell.state[0, 0] < -1.0
    cell.reset()
    assert not cell.faults and cell.phase[0] == ck.PH_FREE


@pytest.mark.parametrize('declared_by', ['add_rail', 'the rails parameter'])
def test_a_queue_at_a_stopper_jams_after_jam_time_with_its_causes(declared_by):
    """
    A queue held at a stopper jams after ``jam_time``, each with its cause.

    Held by the stopper and by each other, making no progress: after jam_time (0.2 s)
    each parcel of the queue jams, the front one by the rail, each other by the
    parcel ahead of it (its strongest contact). The stopper is the same whether the
    code declares it (``Cell.add_rail``) or the cell's ``rails`` parameter does.
    """
    if declared_by == 'add_rail':
        cell = rigid_cell(jam_time=0.2)
        stopper_across(cell, -0.6)
    else:
        hw = 0.5 * CellParams.defaults().belt_width
        x = -0.6 + 0.5 * RAIL_T
        cell = rigid_cell(jam_time=0.2, rails=[x, -hw, x, hw])
        assert np.array_equal(cell.contacts.obstacles[-1], rigid_stopper_row(hw, x))
    a, b = 0.3, 0.2
    for i in range(3):
        place(cell, i, -0.6 - 0.5 * a - i * a, 0.0, (a, b, 2.0))
    events = cell.advance(150)
    assert not [e for e in events if isinstance(e, Outcome)]
    events = cell.advance(100)
    causes = {o.parcel_id: o.cause for o in events if isinstance(o, Outcome)}
    assert causes == {100: 'rail', 101: 'parcel 100', 102: 'parcel 101'}


def rigid_stopper_row(hw, x):
    """Return the obstacle row of a stopper across the belt at x, as add_rail makes it."""
    cell = rigid_cell()
    cell.add_rail(x, -hw, x, hw, RAIL_T)
    return cell.contacts.obstacles[-1]


@pytest.mark.parametrize(
    'rails, words',
    [
        ([0.0, 0.0, 1.0], 'takes 4 numbers a rail'),
        ([0.0, -0.3, 0.0, 0.3, 1.0], 'takes 4 numbers a rail'),
        ([0.0, -0.3, 0.005, -0.3], 'at least 1 cm long'),
        ([0.0, -0.3, 3.5, 0.3], 'off the cell'),
        ([-3.5, -0.3, 0.0, 0.3], 'off the cell'),
        ([0.0, -0.71, 0.0, 0.3], 'off the cell'),
        ([0.0, math.nan, 0.0, 0.3], 'finite numbers'),
        ([0.0, -0.3, math.inf, 0.3], 'finite numbers'),
        ([0.0] * 68, '0 to 64'),
        (['a', 'b', 'c', 'd'], 'finite numbers'),
    ],
)
def test_the_rails_are_checked(rails, words):
    """A rail that is not a segment on the cell is refused, naming it; nothing changes."""
    base = CellParams.defaults()
    with pytest.raises(ParamError, match='rails') as err:
        base.with_changes({'rails': rails}, runtime=False)
    assert words in str(err.value) and '\n' not in str(err.value)
    with pytest.raises(ParamError, match='needs contact: rigid'):
        base.with_changes({'rails': [0.0, -0.3, 0.0, 0.3], 'contact': 'jam'}, runtime=False)


def test_the_contact_parameters_are_checked():
    """A contact model or coefficient out of range is refused with what is allowed."""
    base = CellParams.defaults()
    with pytest.raises(ParamError, match='contact.*jam, rigid'):
        base.with_changes({'contact': 'soft'}, runtime=False)
    with pytest.raises(ParamError, match='restitution'):
        base.with_changes({'restitution': 1.5}, runtime=False)
    with pytest.raises(ParamError, match='mu_wall'):
        base.with_changes({'mu_wall': -0.1}, runtime=False)
