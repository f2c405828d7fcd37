"""
What an overhead camera sees of a cell: its parcels' poses and how they move.

Read-only views of a ``runtime.cell.Cell``'s slots (taken as it is, not imported: the
cell imports this module), for the node's pose, marker and contact topics, the live
view and the tests; they change nothing in the cell. Parcels riding a surface are
advanced in closed form by the kernel, which keeps no velocity for them: their
velocity is that surface's, and is filled in here.
"""

from __future__ import annotations

import math

import numpy as np

from sorter_sim.model.core import cell_kernels as ck
from sorter_sim.model.core.contact import (
    CF_NX,
    CF_NY,
    CF_PN,
    CF_PT,
    CF_PX,
    CF_PY,
    N_CT,
    OB_KIND,
    OBK_WALL,
)

# what a contact's second body is (``contacts``'s ``with`` column)
WITH_PARCEL, WITH_WALL, WITH_RAIL = 0, 1, 2
WITH_NAMES = ('parcel', 'side wall', 'rail')


def parcels(cell) -> dict[str, np.ndarray]:
    """
    Return the parcels in the cell.

    Parcels in the cell (on it, jammed, or sliding onto a chute), in id order:
    id, x, y, phi, A, B, state (index into ``runtime.cell.STATE_NAMES``).
    """
    n = ck.cell_snapshot(
        cell.phase,
        cell.mode,
        cell.ids,
        cell.state,
        cell.par,
        cell.params.disk_field_length,
        cell.snapshot_rows,
    )
    rows = cell.snapshot_rows[:n]
    return {
        'id': rows[:, 0].astype(np.int64),
        'x': rows[:, 1].copy(),
        'y': rows[:, 2].copy(),
        'phi': rows[:, 3].copy(),
        'A': rows[:, 4].copy(),
        'B': rows[:, 5].copy(),
        'state': rows[:, 6].astype(np.int64),
    }


def parcel_motion(cell) -> dict:
    """
    Return label, speed and slip of each parcel in the cell, in id order (as ``parcels``).

    speed: of the centre of gravity [m/s]; slip_belt, slip_disks: its speed relative to
    the belt's and to the disks' surface [m/s], the relative speeds the friction zones
    see at the CoG.
    """
    idx = np.flatnonzero(cell.phase != ck.PH_FREE)
    idx = idx[np.argsort(cell.ids[idx], kind='mergesort')]
    v = cell.state[idx, 3:5].copy()
    mode, phase = cell.mode[idx], cell.phase[idx]
    speed = cell.belt_velocity
    belt = np.array([speed, 0.0])
    disks = speed * np.array([math.cos(cell.alpha), math.sin(cell.alpha)])
    riding = phase == ck.PH_CELL
    v[riding & (mode == ck.MODE_BELT)] = belt
    v[riding & (mode == ck.MODE_DISKS)] = disks
    return {
        'label': [cell.labels[i] for i in idx],
        'speed': np.hypot(v[:, 0], v[:, 1]),
        'slip_belt': np.hypot(v[:, 0] - belt[0], v[:, 1] - belt[1]),
        'slip_disks': np.hypot(v[:, 0] - disks[0], v[:, 1] - disks[1]),
    }


def n_contact_points(cell) -> int:
    """Return how many contact points the cell's last period has (0 under ``contact: jam``)."""
    return int(cell.contacts.counts[N_CT]) if cell.params.contact == 'rigid' else 0


def contacts(cell) -> dict[str, np.ndarray]:
    """
    Return the contact points of the cell's last period (``contact: rigid``), as arrays.

    One row per contact point, as the contact step left them at the period's end:
    ``x``, ``y`` the point [m]; ``nx``, ``ny`` the unit normal from the first body to
    the second; ``force`` the normal force over the period, impulse / h [N] (>= 0: the
    second body is pushed along the normal, the first against it); ``friction`` the
    tangential force, impulse / h [N], along (-ny, nx); ``a`` the first body's parcel
    id; ``with`` what the second is (``WITH_PARCEL``, ``WITH_WALL``, ``WITH_RAIL``);
    ``b`` its parcel id, or its obstacle's index (the side walls first, then the rails
    in the order declared); ``second`` the second body as a jam's cause names it
    (``parcel <id>``, ``side wall``, ``rail``). Empty under ``contact: jam`` and while
    nothing touches. Nothing is kept: each call reads the contact step's own rows.
    """
    cont = cell.contacts
    n = n_contact_points(cell)
    ct_i, ct_f = cont.ct_i[:n], cont.ct_f[:n]
    a, b = ct_i[:, 0], ct_i[:, 1]
    obstacle = b < 0
    ob = np.where(obstacle, -1 - b, 0)
    kind = (
        np.where(cont.obstacles[ob, OB_KIND] == OBK_WALL, WITH_WALL, WITH_RAIL)
        if n
        else np.zeros(0, dtype=np.int64)
    )
    inv_h = 1.0 / cell.dt
    b_id = np.where(obstacle, ob, cell.ids[np.maximum(b, 0)]).astype(np.int64)
    with_ = np.where(obstacle, kind, WITH_PARCEL).astype(np.int64)
    return {
        'x': ct_f[:, CF_PX].copy(),
        'y': ct_f[:, CF_PY].copy(),
        'nx': ct_f[:, CF_NX].copy(),
        'ny': ct_f[:, CF_NY].copy(),
        'force': ct_f[:, CF_PN] * inv_h,
        'friction': ct_f[:, CF_PT] * inv_h,
        'a': cell.ids[a].astype(np.int64),
        'with': with_,
        'b': b_id,
        'second': [
            f'parcel {j}' if w == WITH_PARCEL else WITH_NAMES[w]
            for w, j in zip(with_.tolist(), b_id.tolist())
        ],
    }
