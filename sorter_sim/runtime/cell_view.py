"""
What an overhead camera sees of a cell: its parcels' poses and how they move.

Read-only views of a ``runtime.cell.Cell``'s slots (taken as it is, not imported: the
cell imports this module), for the node's pose and marker topics, the live
view and the tests; they change nothing in the cell. Parcels riding a surface are
advanced in closed form by the kernel, which keeps no velocity for them: their
velocity is that surface's, and is filled in here.
"""

from __future__ import annotations

import math

import numpy as np

from sorter_sim.model.core import cell_kernels as ck


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
