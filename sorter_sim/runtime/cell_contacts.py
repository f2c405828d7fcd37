"""
The cell's contacts as the runtime sets them up: parameters, obstacles, jam causes.

The contact model itself is ``sorter_sim.model.core.contact``; here the cell's
parameters (``contact``, ``mu_parcel``, ``mu_wall``, ``restitution``, ``jam_time``)
go into the kernels' configuration row, the side walls outside the chute openings
and the rails a cell declares become the contact step's obstacles, and a jam's code
becomes the cause an outcome names.
"""

from __future__ import annotations

import numpy as np

from sorter_sim.model.core import cell_kernels as ck
from sorter_sim.model.core.contact import Contacts, contacts_for, fresh_slot, rail, side_walls
from sorter_sim.model.core.simulate import Parcel, parcel_array

# the footprint quadrature's points per direction in the cell
N_QUAD = 8

# a rail's thickness when none is given [m]
RAIL_THICKNESS = 0.02


def configure_contacts(cfg: np.ndarray, params) -> None:
    """Write the contact parameters of ``params`` (a ``CellParams``) into the row ``cfg``."""
    cfg[ck.C_CONTACT] = 1.0 if params.contact == 'rigid' else 0.0
    cfg[ck.C_MU_PARCEL] = params.mu_parcel
    cfg[ck.C_MU_WALL] = params.mu_wall
    cfg[ck.C_RESTITUTION] = params.restitution
    cfg[ck.C_JAM_TIME] = params.jam_time


def cell_contacts(params, rails: list | tuple = ()) -> Contacts:
    """
    Return the contact step's state for a cell: its side walls and the ``rails`` given.

    Parameters
    ----------
    params : CellParams
        The cell's parameters (belt width, chute range, capacity).
    rails : sequence of ndarray
        Obstacle rows (``contact.rail``).

    """
    lo, hi = params.chute_x_range
    rows = [side_walls(0.5 * params.belt_width, lo, hi), *(np.reshape(r, (1, -1)) for r in rails)]
    return contacts_for(params.max_parcels, np.vstack(rows))


def rail_row(x0: float, y0: float, x1: float, y1: float, thickness: float = RAIL_THICKNESS):
    """Return a rail or a stopper from (x0, y0) to (x1, y1) [m] (``contact.rail``)."""
    return rail(x0, y0, x1, y1, thickness)


def jam_cause(b: int, ids: np.ndarray) -> str:
    """Return the cause an EV_JAM's code ``b`` names: a parcel's id, the side wall, a rail."""
    if b >= 0:
        return f'parcel {int(ids[b])}'
    return {-1: 'side wall', -2: 'integration failed', -3: 'rail'}[b]


def place_parcel(cell, i: int, pose: tuple, size: tuple, vel: tuple = (0.0, 0.0, 0.0)) -> None:
    """
    Put a parcel straight into slot ``i`` of ``cell``, sliding (a set-up for tests and benchmarks).

    ``pose`` is (x, y, φ) [m, m, rad], ``size`` (A, B, m) [m, m, kg], ``vel`` (ẋ, ẏ, φ̇);
    its id is 100 + i. Nothing checks that the slot is free or the place clear.
    """
    a, b, m = size
    cell.par[i] = parcel_array(Parcel(a, b, m), n_quad=N_QUAD)
    cell.state[i] = [*pose, *vel]
    cell.phase[i] = ck.PH_CELL
    cell.mode[i] = ck.MODE_SLIDE
    cell.ids[i] = 100 + i
    fresh_slot(cell.contacts, i)
    cell.dims[i] = size
