"""
Quiet periods (``contact.quiet_period``): the contact step is left out only where it finds nothing.

A period whose bodies are all clear of each other and of every obstacle, with nothing
touching in the period before, runs no contact step (``counts[N_QUIET]``). The check
here is the claim itself: after every quiet period of scenes that mix quiet periods
with contacts (a diverted stream, parcels thrown at each other on a stopped belt, a
stream along a turned fence), the full broad and narrow phase run on the cell's
state find no contact point. And the quiet periods must be most of a stream's, or
the skip does nothing.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from sorter_sim.model.core import cell_kernels as ck
from sorter_sim.model.core.contact import (
    N_CT,
    N_QUIET,
    OB_KIND,
    _broad_phase,
    contacts_for,
)
from sorter_sim.runtime.cell import Cell
from sorter_sim.runtime.cell_contacts import place_parcel
from sorter_sim.runtime.params import CellParams


def rigid_cell(**changes) -> Cell:
    values = {'contact': 'rigid', 'jam_time': 60.0, **changes}
    return Cell(CellParams.defaults().with_changes(values, runtime=False))


def contact_points_now(cell: Cell) -> int:
    """Run the full broad and narrow phase on the cell's state, on scratch of its own."""
    cont = contacts_for(cell.state.shape[0], cell.contacts.obstacles[:, : OB_KIND + 1])
    r_out = np.hypot(cell.par[:, ck.P_HALF_A], cell.par[:, ck.P_HALF_B])
    _broad_phase(
        cell.state,
        cell.phase,
        cell.par,
        r_out,
        (ck.PH_CELL, ck.PH_JAMMED),
        (0.5, 0.5),
        cont,
        np.zeros((2, 5)),
        np.zeros(2, dtype=np.int64),
    )
    return int(cont.counts[N_CT])


def run_and_check(cell: Cell, periods: int) -> tuple[int, int]:
    """Advance period by period; every quiet period must leave no contact in reach."""
    quiet = solved = 0
    for _ in range(periods):
        cell.advance(1)
        if cell.contacts.counts[N_QUIET]:
            quiet += 1
            n = contact_points_now(cell)
            assert n == 0, f'a quiet period at t = {cell.t:.3f} s left {n} contact points'
        else:
            solved += 1
    return quiet, solved


def test_a_diverted_stream_is_quiet_between_its_parcels():
    # the default stream, every parcel diverted across the disks into the chute
    # opening between the side walls' ends
    cell = rigid_cell(alpha_deg=90.0)
    cell.popup(True)
    quiet, solved = run_and_check(cell, 8000)
    assert cell.n_inducted >= 3
    assert quiet > 0.95 * (quiet + solved)


def test_parcels_thrown_at_each_other_on_a_stopped_belt():
    # impacts with rebound (restitution 0.5), sliding to rest apart or touching:
    # quiet and solved periods alternate
    cell = rigid_cell(arrival='none', restitution=0.5, mu_belt=0.3)
    cell.run_belt(False)
    rng = np.random.default_rng(7)
    for i in range(6):
        x = -3.0 + 0.8 * i
        y = rng.uniform(-0.15, 0.15)
        vel = (rng.uniform(-1.5, 1.5), rng.uniform(-0.3, 0.3), rng.uniform(-2.0, 2.0))
        place_parcel(cell, i, (x, y, rng.uniform(-0.5, 0.5)), (0.4, 0.25, 4.0), vel)
    quiet, solved = run_and_check(cell, 2500)
    assert quiet > 100 and solved > 10


@pytest.mark.parametrize('theta_deg', [20.0, 90.0])
def test_a_stream_along_a_turned_fence(theta_deg):
    # a fence across half the belt downstream of the disks, turned by θ: the parcels
    # reach it riding the belt (the quiet check's clear stretch along x ends there)
    cell = rigid_cell(mu_wall=0.2)
    hw = 0.5 * cell.params.belt_width
    t = math.radians(theta_deg)
    x0 = cell.params.disk_field_length + 0.5
    cell.add_rail(x0, hw, x0 + hw * math.cos(t) / max(math.sin(t), 1e-9), 0.0, 0.02)
    quiet, solved = run_and_check(cell, 6000)
    assert quiet > 100 and solved > 100


def test_a_parcel_put_on_a_quiet_cell_is_looked_at():
    # a parcel placed by hand over one riding the belt: the next period is not quiet
    cell = rigid_cell(arrival='none')
    place_parcel(cell, 0, (-2.0, 0.0, 0.0), (0.5, 0.3, 5.0), (cell.params.belt_speed, 0.0, 0.0))
    cell.mode[0] = ck.MODE_BELT
    cell.advance(20)
    assert cell.contacts.counts[N_QUIET]
    x = float(cell.state[0, 0])
    place_parcel(cell, 1, (x + 0.4, 0.0, 0.0), (0.5, 0.3, 5.0), (cell.params.belt_speed, 0.0, 0.0))
    cell.mode[1] = ck.MODE_BELT
    cell.advance(1)
    assert not cell.contacts.counts[N_QUIET]
    assert cell.contacts.counts[N_CT] > 0
