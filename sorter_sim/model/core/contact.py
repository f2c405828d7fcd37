"""
Parcels that touch: planar rigid-box contact, solved once per control period.

The cell advances each parcel over a period under the seed's floor friction
(``cell_parcel``); this module then makes the parcels that touch, and the parcels
that touch a wall, a chute opening's edge, a rail or a stopper, obey non-penetration
and Coulomb friction at the contact. Three steps, as every rigid-body contact code:

* **Broad phase** (``_broad_phase``): the parcels on the cell sorted by the lower x
  of their circumscribed circle (insertion sort of the last period's order: a stream
  keeps its order, so this is one pass), swept along x; a pair whose circles'
  bounding boxes overlap in x and y goes on. Each parcel is checked against the
  cell's obstacles (static boxes: the side walls outside the chute openings, whose
  corners are the openings' edges, and the rails and stoppers a cell declares) by
  their bounding boxes.
* **Quiet periods** (``quiet_slot``, ``quiet_movers``): most periods of a stream have no contact at
  all, and the broad phase would find none again. A parcel that moved with the belt
  (the cell's ``rigid``) kept its distance to every other such parcel, so only the
  pairs with a parcel that did not (integrated, on the disks, jammed, new on the
  cell) are looked at, by their circles; and a parcel moved along x alone stays clear
  of every obstacle over an x stretch found once (``_obstacle_room``, separating
  axes). Where all is clear, and nothing touched in the last period, the period has
  no contact step: it costs what the old rule's overlap check cost.
* **Narrow phase** (``contact_narrow.box_contacts``): two turned boxes, the
  reference face the one of greatest separation (separating axes), the incident
  edge of the other clipped to the reference face's side planes: up to two contact
  points, each with its normal and its separation (corner on edge: one point; edge
  on edge: two).
* **Solve** (``contact_solve.solve_velocities``, ``_project_positions``): velocity-level
  complementarity in the line of Stewart and Trinkle (1996) and Anitescu and Potra
  (1997). For every contact point the normal impulse p_n >= 0 is complementary to
  the normal velocity after the step, v_n+ = -e min(v_n-, 0) (e: the restitution,
  default 0), and the friction impulse lies in the Coulomb cone |p_t| <= μ p_n,
  opposing the tangential velocity where it is not zero (μ: ``mu_parcel`` between
  parcels, ``mu_wall`` at an obstacle). Projected Gauss-Seidel over the faces (a
  face's two points solved together, exactly), warm started from the last period's
  impulses of the same contact (same bodies, same features), iterated until no
  impulse changes by more than ``PGS_TOL`` of the largest: a chain of parcels
  against a stopper carries its whole load. The velocities it changes are
  the parcels' velocities at the end of the period; positions are then projected out
  of any overlap beyond ``OVERLAP_TOL`` (a mass-weighted Gauss-Seidel on the linearised
  separations, Cline and Pai 2003), which changes no velocity, so it adds no energy.

A jammed parcel (the cell's ``PH_JAMMED``) is an obstacle: it does not move.

Units: SI (m, s, rad, kg); impulses in N s, forces in N.
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from sorter_sim.model.core.contact_narrow import box_contacts, box_polygon
from sorter_sim.model.core.contact_solve import (
    CF_BIAS,
    CF_MASS_N,
    CF_MASS_T,
    CF_MU,
    CF_NEW,
    CF_NX,
    CF_NY,
    CF_PN,
    CF_PT,
    CF_PX,
    CF_PY,
    CF_SEP,
    CF_TO,
    CF_VN0,
    CF_WIDTH,
    _apply_pair,
    _effective_mass,
    _masses,
    _relative_velocity,
    solve_velocities,
)
from sorter_sim.model.core.jit import kernel_step
from sorter_sim.model.core.layout import P_HALF_A, P_HALF_B

# ---- an obstacle row: a static box (float64) --------------------------------------
OB_X = 0  # centre [m]
OB_Y = 1
OB_PHI = 2  # turn [rad]
OB_HALF_A = 3  # half extents along its own axes [m]
OB_HALF_B = 4
OB_KIND = 5  # OBK_*
OB_XLO = 6  # its bounding box [m] (``contacts_for`` fills it in)
OB_XHI = 7
OB_YLO = 8
OB_YHI = 9
OB_COS = 10  # cos and sin of its turn (``contacts_for`` fills them in: no libm call a check)
OB_SIN = 11
OB_WIDTH = 12

OBK_WALL = 0.0  # a side wall outside the chute openings (its corners: the openings' edges)
OBK_RAIL = 1.0  # a rail or a stopper the cell declares

WALL_THICKNESS = 0.05  # the side walls' boxes: how far beyond y = ±w/2 they reach [m]
WALL_REACH = 500.0  # how far up- and downstream of the opening a side wall's box reaches [m]

# contact points closer than this count as touching [m] (a face tilted by a
# microradian must keep both its points); the projection leaves at most
# OVERLAP_TOL of overlap [m]
CONTACT_REACH = 1e-6
OVERLAP_TOL = 1e-9
PROJECTION_MAX_SWEEPS = 2000

# what the contact step keeps from period to period (allocated once by the runtime):
# the obstacles (n_ob, OB_WIDTH); the sweep order of the slots; this period's and the
# last period's contacts (ints a, b, feature; floats CF_*) and their counts; per
# obstacle the force it took over the last period (Fx, Fy) [N]; the bodies' scratch:
# the sweep keys, a polygon pair, the projection's displacements; per slot its hold
# (``H_*``: where its no-progress clock started, the clock, its strongest contact);
# per slot the time since it was struck this period (0: not struck), for the cell to
# replay its floor friction over that time at its new velocity; the slots' velocities
# (ẋ, ẏ, φ̇) and positions (x, y) at the period's start, kept by the cell
# (``keep_start``); and for the quiet periods (``quiet_slot``): per slot whether it
# was found clear at the last period's end (1; 0: look at it afresh, as a slot Python
# filled), its clear row (``CL_*``), and the list of movers to look at
Contacts = namedtuple(
    'Contacts',
    [
        'obstacles',
        'order',
        'ct_i',
        'ct_f',
        'old_i',
        'old_f',
        'counts',
        'ob_force',
        'key',
        'poly',
        'disp',
        'hold',
        'impact',
        'v_start',
        'xy_start',
        'clear',
        'clear_x',
        'movers',
    ],
)

# a slot's hold row
H_X = 0  # where the parcel was when its clock started [m]
H_Y = 1
H_CLOCK = 2  # how long it has been held without progress [s]
H_LOAD = 3  # its largest normal impulse this period [N s]
H_BY = 4  # the body that takes it: a slot, or -1 - obstacle
H_WIDTH = 5
# a parcel that moves less than this from where its clock started makes no progress [m]
JAM_PROGRESS = 1e-3

# counts: this period's contacts, the last period's, PGS sweeps of the last period,
# and whether the last period was quiet (``quiet_movers``: no contact step ran)
N_CT = 0
N_OLD = 1
N_SWEEPS = 2
N_QUIET = 3

# a slot's clear row (``quiet_slot``): the x stretch over which it stays clear of
# every obstacle, for the y and turn it had when that was found
CL_X_LO = 0
CL_X_HI = 1
CL_Y = 2
CL_PHI = 3
CL_WIDTH = 4
# the clearance a quiet period asks of every pair and obstacle, beyond CONTACT_REACH:
# ten times it, so that no rounding of the bounds below lets a contact slip by [m]
QUIET_MARGIN = 10.0 * CONTACT_REACH


def contacts_for(capacity: int, obstacles: np.ndarray) -> Contacts:
    """
    Return the contact step's state for a cell of ``capacity`` slots and its obstacles.

    Parameters
    ----------
    capacity : int
        The cell's parcel slots.
    obstacles : ndarray, shape (n, 6)
        The static boxes (``side_walls``, ``rail``: OB_X .. OB_KIND); their bounding
        boxes are added here.

    Returns
    -------
    Contacts
        Zeroed state: no contacts, the slots in index order.

    """
    rows = np.asarray(obstacles, dtype=float).reshape(-1, OB_KIND + 1)
    obstacles = np.zeros((rows.shape[0], OB_WIDTH))
    obstacles[:, : OB_KIND + 1] = rows
    # the bounding box: a parcel outside it (most of them, most periods) costs 4 compares
    c = np.abs(np.cos(rows[:, OB_PHI]))
    s = np.abs(np.sin(rows[:, OB_PHI]))
    ex = c * rows[:, OB_HALF_A] + s * rows[:, OB_HALF_B]
    ey = s * rows[:, OB_HALF_A] + c * rows[:, OB_HALF_B]
    obstacles[:, OB_XLO] = rows[:, OB_X] - ex
    obstacles[:, OB_XHI] = rows[:, OB_X] + ex
    obstacles[:, OB_YLO] = rows[:, OB_Y] - ey
    obstacles[:, OB_YHI] = rows[:, OB_Y] + ey
    obstacles[:, OB_COS] = np.cos(rows[:, OB_PHI])
    obstacles[:, OB_SIN] = np.sin(rows[:, OB_PHI])
    # a box touches at most its four sides' worth of bodies with two points each
    max_ct = 8 * capacity + 2 * obstacles.shape[0] * capacity + 8
    return Contacts(
        obstacles,
        np.arange(capacity, dtype=np.int64),
        np.zeros((max_ct, 3), dtype=np.int64),
        np.zeros((max_ct, CF_WIDTH)),
        np.zeros((max_ct, 3), dtype=np.int64),
        np.zeros((max_ct, CF_WIDTH)),
        np.zeros(4, dtype=np.int64),
        np.zeros((max(obstacles.shape[0], 1), 2)),
        np.zeros(capacity),
        np.zeros((2, 4, 4)),
        np.zeros((capacity, 3)),
        np.zeros((capacity, H_WIDTH)),
        np.zeros(capacity),
        np.zeros((capacity, 3)),
        np.zeros((capacity, 2)),
        np.zeros(capacity, dtype=np.int64),
        np.zeros((capacity, CL_WIDTH)),
        np.zeros(capacity, dtype=np.int64),
    )


def fresh_slot(cont: Contacts, i: int) -> None:
    """Have the next period look at slot ``i`` afresh: Python put a parcel there."""
    cont.clear[i] = 0


def side_walls(half_w: float, open_lo: float, open_hi: float) -> np.ndarray:
    """
    Return the side walls outside the chute openings as obstacle rows (``OB_*``).

    Four boxes, WALL_THICKNESS thick, their inner faces on y = ±w/2: upstream of the
    opening (x < ``open_lo``) and downstream of it (x > ``open_hi``) on each side.
    Their corners at x = open_lo and open_hi are the openings' edges.
    """
    rows = []
    lo_len = WALL_REACH
    hi_len = WALL_REACH
    for side in (1.0, -1.0):
        yc = side * (half_w + 0.5 * WALL_THICKNESS)
        half_t = 0.5 * WALL_THICKNESS
        rows.append([open_lo - 0.5 * lo_len, yc, 0.0, 0.5 * lo_len, half_t, OBK_WALL])
        rows.append([open_hi + 0.5 * hi_len, yc, 0.0, 0.5 * hi_len, half_t, OBK_WALL])
    return np.array(rows)


def rail(x0: float, y0: float, x1: float, y1: float, thickness: float) -> np.ndarray:
    """
    Return a rail or a stopper, the segment (x0, y0)-(x1, y1), as an obstacle row.

    A box ``thickness`` thick centred on the segment [m].
    """
    length = math.hypot(x1 - x0, y1 - y0)
    if not (length > 0.0 and thickness > 0.0):
        raise ValueError(
            f'a rail needs two distinct end points and a thickness > 0 '
            f'(got length {length} m, thickness {thickness} m)'
        )
    phi = math.atan2(y1 - y0, x1 - x0)
    return np.array(
        [0.5 * (x0 + x1), 0.5 * (y0 + y1), phi, 0.5 * length, 0.5 * thickness, OBK_RAIL]
    )


# ---------------------------------------------------------------- broad phase
@kernel_step
def _broad_key(state, phase, r_out, ph_cell, ph_jammed, key):
    """Set each slot's sweep key: the lower x of its circle; +inf for a slot not on the cell."""
    for i in range(state.shape[0]):
        if phase[i] == ph_cell or phase[i] == ph_jammed:
            key[i] = state[i, 0] - r_out[i]
        else:
            key[i] = math.inf


@kernel_step
def _sort_order(key, order):
    """Sort ``order`` by ``key`` by insertion (nearly sorted from the last period: one pass)."""
    for q in range(1, order.shape[0]):
        o = order[q]
        x = key[o]
        r = q
        while r > 0 and key[order[r - 1]] > x:
            order[r] = order[r - 1]
            r -= 1
        order[r] = o


@kernel_step
def _add_contacts(a, b, mu, n_pts, cont, scratch_f, scratch_id):
    """Append the ``n_pts`` points of the pair (a, b) in the scratch rows to the contacts."""
    ct_i, ct_f, counts = cont.ct_i, cont.ct_f, cont.counts
    for q in range(n_pts):
        n = counts[N_CT]
        if n >= ct_i.shape[0]:
            return
        ct_i[n, 0] = a
        ct_i[n, 1] = b
        ct_i[n, 2] = scratch_id[q]
        for j in range(5):
            ct_f[n, j] = scratch_f[q, j]
        ct_f[n, CF_MU] = mu
        ct_f[n, CF_PN] = 0.0
        ct_f[n, CF_PT] = 0.0
        counts[N_CT] = n + 1


@kernel_step
def _broad_phase(state, phase, par, r_out, codes, mus, cont, scratch_f, scratch_id):
    """
    Find this period's contact points: parcel pairs by the x sweep, then parcel-obstacle.

    ``codes`` (PH_CELL, PH_JAMMED); ``mus`` (mu_parcel, mu_wall). A pair of jammed
    parcels is not looked at (neither moves).
    """
    ph_cell, ph_jammed = codes
    mu_parcel, mu_wall = mus
    key, order, poly, obs = cont.key, cont.order, cont.poly, cont.obstacles
    _broad_key(state, phase, r_out, ph_cell, ph_jammed, key)
    _sort_order(key, order)
    cont.counts[N_CT] = 0
    cap = state.shape[0]
    for q in range(cap):
        i = order[q]
        if key[i] == math.inf:
            break
        xi_hi = state[i, 0] + r_out[i] + CONTACT_REACH
        for r in range(q + 1, cap):
            j = order[r]
            if key[j] > xi_hi:
                break
            if phase[i] == ph_jammed and phase[j] == ph_jammed:
                continue
            if abs(state[i, 1] - state[j, 1]) > r_out[i] + r_out[j] + CONTACT_REACH:
                continue
            a = min(i, j)
            b = max(i, j)
            box_polygon(
                poly[0], state[a, 0], state[a, 1], state[a, 2], par[a, P_HALF_A], par[a, P_HALF_B]
            )
            box_polygon(
                poly[1], state[b, 0], state[b, 1], state[b, 2], par[b, P_HALF_A], par[b, P_HALF_B]
            )
            n_pts = box_contacts(poly, CONTACT_REACH, scratch_f, scratch_id)
            _add_contacts(a, b, mu_parcel, n_pts, cont, scratch_f, scratch_id)
        if phase[i] != ph_cell:
            continue
        for o in range(obs.shape[0]):
            reach = r_out[i] + CONTACT_REACH
            xi = state[i, 0]
            yi = state[i, 1]
            if xi + reach < obs[o, OB_XLO] or xi - reach > obs[o, OB_XHI]:
                continue
            if yi + reach < obs[o, OB_YLO] or yi - reach > obs[o, OB_YHI]:
                continue
            # a turned rail's box is wide: the distance across its centre line next
            c = obs[o, OB_COS]
            s = obs[o, OB_SIN]
            if abs(-s * (xi - obs[o, OB_X]) + c * (yi - obs[o, OB_Y])) > reach + obs[o, OB_HALF_B]:
                continue
            box_polygon(
                poly[0], state[i, 0], state[i, 1], state[i, 2], par[i, P_HALF_A], par[i, P_HALF_B]
            )
            box_polygon(
                poly[1],
                obs[o, OB_X],
                obs[o, OB_Y],
                obs[o, OB_PHI],
                obs[o, OB_HALF_A],
                obs[o, OB_HALF_B],
            )
            n_pts = box_contacts(poly, CONTACT_REACH, scratch_f, scratch_id)
            _add_contacts(i, -1 - o, mu_wall, n_pts, cont, scratch_f, scratch_id)


@kernel_step
def _classify(h, state, phase, ph_cell, cont):
    """
    Each contact's normal velocity before the solve, whether it is new, and if an impact when.

    A contact of the last period between the same bodies and features is not new and
    takes its impulses as a start (``CF_PN``, ``CF_PT``, not applied yet). A new one
    that overlaps while closing in, whose bodies were closing in at the period's start
    (``_approached``), is an impact: it touched t_o = sep / v_n before the end (at most
    h, ``CF_TO``), and each body it struck is noted in ``impact`` (the largest t_o).
    """
    ct_i, ct_f, old_i, old_f, counts = cont.ct_i, cont.ct_f, cont.old_i, cont.old_f, cont.counts
    for c in range(counts[N_CT]):
        a = ct_i[c, 0]
        b = ct_i[c, 1]
        cf = ct_f[c]
        vn, _ = _relative_velocity(a, b, state, cf)
        cf[CF_VN0] = vn
        cf[CF_NEW] = 1.0
        cf[CF_TO] = 0.0
        for o in range(counts[N_OLD]):
            if old_i[o, 0] == a and old_i[o, 1] == b and old_i[o, 2] == ct_i[c, 2]:
                cf[CF_PN] = old_f[o, CF_PN]
                cf[CF_PT] = old_f[o, CF_PT]
                cf[CF_NEW] = 0.0
                break
        if cf[CF_NEW] > 0.0 and cf[CF_SEP] < 0.0 and vn < 0.0:
            if _approached(a, b, h, state, cont, cf):
                cf[CF_TO] = min(h, cf[CF_SEP] / vn)
                for e in range(2):
                    i = ct_i[c, e]
                    if i >= 0 and phase[i] == ph_cell:
                        cont.impact[i] = max(cont.impact[i], cf[CF_TO])


@kernel_step
def _rewind_struck(h, state, phase, ph_cell, cont):
    """
    Take each struck parcel's velocity back to its touch: v - (v - v_start) t_o / h.

    The floor changed its velocity over the period at a mean rate (v - v_start) / h;
    the impact acts on the velocities at the touch, t_o before the end (a parcel
    decelerating into a parcel at rest hits it faster than it ends the period).
    """
    ct_i, impact, v0 = cont.ct_i, cont.impact, cont.v_start
    for c in range(cont.counts[N_CT]):
        for e in range(2):
            i = ct_i[c, e]
            # a parcel is taken back once: its mark turns negative until the solve ends
            if i < 0 or impact[i] <= 0.0 or phase[i] != ph_cell:
                continue
            w = impact[i] / h
            for j in range(3):
                state[i, j + 3] -= (state[i, j + 3] - v0[i, j]) * w
            impact[i] = -impact[i]
    for c in range(cont.counts[N_CT]):
        for e in range(2):
            i = ct_i[c, e]
            if i >= 0 and impact[i] < 0.0:
                impact[i] = -impact[i]


@kernel_step
def _prepare(h, state, phase, par, ph_cell, restitution, cont):
    """
    Each contact's effective masses and target normal velocity; warm start from the last period.

    ``_classify``, ``_rewind_struck``; then the target is -e v_n where the bodies
    approach (v_n < 0), else 0, and a contact of the last period starts from its
    impulses, applied at once.
    """
    ct_i, ct_f, counts = cont.ct_i, cont.ct_f, cont.counts
    _classify(h, state, phase, ph_cell, cont)
    _rewind_struck(h, state, phase, ph_cell, cont)
    for c in range(counts[N_CT]):
        a = ct_i[c, 0]
        b = ct_i[c, 1]
        cf = ct_f[c]
        masses = _masses(a, b, phase, par, ph_cell)
        cf[CF_MASS_N] = _effective_mass(a, b, state, cf, masses, cf[CF_NX], cf[CF_NY])
        cf[CF_MASS_T] = _effective_mass(a, b, state, cf, masses, -cf[CF_NY], cf[CF_NX])
        vn, _ = _relative_velocity(a, b, state, cf)
        cf[CF_BIAS] = -restitution * vn if vn < 0.0 else 0.0
        if cf[CF_NEW] == 0.0:
            _apply_pair(a, b, state, cf, cf[CF_PN], cf[CF_PT], masses)
        else:
            cf[CF_PN] = 0.0
            cf[CF_PT] = 0.0


@kernel_step
def _displace(i, sign, state, disp, px, py, jx, jy, im, ii):
    """Add the positional impulse sign·(jx, jy) [N s·s] at (px, py) to body i's displacement."""
    if im == 0.0:
        return
    disp[i, 0] += sign * im * jx
    disp[i, 1] += sign * im * jy
    disp[i, 2] += sign * ii * ((px - state[i, 0]) * jy - (py - state[i, 1]) * jx)


@kernel_step
def _approached(a, b, h, state, cont, cf):
    """
    Return whether a new contact's bodies closed in fast enough to be an impact.

    Fast enough: closing in at the period's start at a speed that makes its overlap
    within the period; an impact, not a press.

    A parcel at rest pressed into a stopper by the floor closes in from zero speed: its
    overlap is the floor's ½ a h², not a speed's, and it owes no floor friction.
    """
    v0 = cont.v_start
    px = cf[CF_PX]
    py = cf[CF_PY]
    dvx = 0.0
    dvy = 0.0
    if a >= 0:
        dvx -= v0[a, 0] - v0[a, 2] * (py - state[a, 1])
        dvy -= v0[a, 1] + v0[a, 2] * (px - state[a, 0])
    if b >= 0:
        dvx += v0[b, 0] - v0[b, 2] * (py - state[b, 1])
        dvy += v0[b, 1] + v0[b, 2] * (px - state[b, 0])
    return (dvx * cf[CF_NX] + dvy * cf[CF_NY]) * h < cf[CF_SEP]


@kernel_step
def keep_start(i, state, cont):
    """Keep parcel i's velocity and position at the period's start (``v_start``, ``xy_start``)."""
    for j in range(3):
        cont.v_start[i, j] = state[i, j + 3]
    cont.xy_start[i, 0] = state[i, 0]
    cont.xy_start[i, 1] = state[i, 1]


@kernel_step
def _obstacle_room(i, state, par, cont):
    """
    How far parcel i may move along x alone and stay QUIET_MARGIN clear of every obstacle [m].

    Each obstacle is kept off by a separating axis: x or y between its bounding box and
    the parcel's, or the obstacle's own normal or tangent against the parcel's extent
    along it. A gap along an axis bounds the distance from below (a contact point lies
    within CONTACT_REACH of both bodies, ``box_contacts``), and a move dx along x
    closes it by at most dx times the axis's x component; the best axis of each
    obstacle, the worst obstacle. 0 or less: an obstacle is within reach now; inf: no
    move along x reaches one (a side wall beside the parcel).
    """
    obs = cont.obstacles
    x = state[i, 0]
    y = state[i, 1]
    ha = par[i, P_HALF_A]
    hb = par[i, P_HALF_B]
    cp = math.cos(state[i, 2])
    sp = math.sin(state[i, 2])
    ex = abs(cp) * ha + abs(sp) * hb
    ey = abs(sp) * ha + abs(cp) * hb
    room = math.inf
    for o in range(obs.shape[0]):
        if max(obs[o, OB_YLO] - (y + ey), (y - ey) - obs[o, OB_YHI]) > QUIET_MARGIN:
            continue
        best = max(obs[o, OB_XLO] - (x + ex), (x - ex) - obs[o, OB_XHI]) - QUIET_MARGIN
        c = obs[o, OB_COS]
        s = obs[o, OB_SIN]
        dx = x - obs[o, OB_X]
        dy = y - obs[o, OB_Y]
        sin_rel = abs(sp * c - cp * s)
        cos_rel = abs(cp * c + sp * s)
        gap_n = abs(-s * dx + c * dy) - (ha * sin_rel + hb * cos_rel + obs[o, OB_HALF_B])
        gap_n -= QUIET_MARGIN
        if gap_n > 0.0:
            best = max(best, gap_n / abs(s) if s != 0.0 else math.inf)
        gap_t = abs(c * dx + s * dy) - (ha * cos_rel + hb * sin_rel + obs[o, OB_HALF_A])
        gap_t -= QUIET_MARGIN
        if gap_t > 0.0:
            best = max(best, gap_t / abs(c) if c != 0.0 else math.inf)
        room = min(room, best)
    return room


@kernel_step
def _clear_of_obstacles(i, state, par, cont):
    """Return whether parcel i is clear of every obstacle, and keep its clear x stretch."""
    room = _obstacle_room(i, state, par, cont)
    if not room > 0.0:
        return False
    row = cont.clear_x[i]
    row[CL_X_LO] = state[i, 0] - room
    row[CL_X_HI] = state[i, 0] + room
    row[CL_Y] = state[i, 1]
    row[CL_PHI] = state[i, 2]
    return True


@kernel_step
def quiet_slot(i, state, phase, par, rigid, codes, cont, n_mov):
    """
    Check what slot i's own period end decides of whether the period is quiet.

    Called for each slot right after the cell advanced it (its row is at hand): a
    parcel that moved with the belt (``rigid``: along x by v h, the same for all of
    them) and was clear at the last period's end keeps its distance to every other such
    parcel, and stays clear of the obstacles while its x is within its clear stretch
    (``_obstacle_room``, found again where it leaves it). Any other body (integrated,
    on the disks, jammed, new: ``clear`` 0) goes on the movers' list.

    Returns
    -------
    (bool, int)
        Whether the period may still be quiet, and the movers listed.

    """
    ph_cell, ph_jammed = codes
    ph = phase[i]
    if ph != ph_cell and ph != ph_jammed:
        cont.clear[i] = 0
        return True, n_mov
    if ph == ph_cell and rigid[i] and cont.clear[i] == 1:
        row = cont.clear_x
        x = state[i, 0]
        if (
            state[i, 1] == row[i, CL_Y]
            and state[i, 2] == row[i, CL_PHI]
            and row[i, CL_X_LO] <= x <= row[i, CL_X_HI]
        ):
            return True, n_mov
        return _clear_of_obstacles(i, state, par, cont), n_mov
    cont.movers[n_mov] = i
    return True, n_mov + 1


@kernel_step
def quiet_movers(n_mov, state, phase, par, r_out, codes, cont):
    """
    Return whether no contact can be in reach at this period's end: then none is solved.

    The cell asks only where nothing touched at the last period's end (``N_OLD`` 0)
    and every slot passed ``quiet_slot``; the claim then holds by induction from that
    period's end. The movers' circles are checked against every body's, and each
    mover against the obstacles; anything closer than QUIET_MARGIN: not quiet, and the
    contact step decides. ``codes`` (PH_CELL, PH_JAMMED).
    """
    ph_cell, ph_jammed = codes
    cap = state.shape[0]
    for q in range(n_mov):
        i = cont.movers[q]
        for j in range(cap):
            if j == i or (phase[j] != ph_cell and phase[j] != ph_jammed):
                continue
            if phase[i] == ph_jammed and phase[j] == ph_jammed:
                continue
            reach = r_out[i] + r_out[j] + QUIET_MARGIN
            if abs(state[i, 0] - state[j, 0]) > reach or abs(state[i, 1] - state[j, 1]) > reach:
                continue
            return False
        if phase[i] == ph_cell and not _clear_of_obstacles(i, state, par, cont):
            return False
    for q in range(n_mov):
        cont.clear[cont.movers[q]] = 1
    return True


@kernel_step
def _replay_impacts(h, state, phase, par, ph_cell, cont):
    """
    Move the bodies as if each contact's impulse had acted when it did, not at the end.

    The solve applies the period's contact impulses J at its end, so the positions the
    floor left lack their effect. A pressing contact (a queue at a stopper, a parcel
    along a fence) acts over the whole period: under a steady force the bodies move by
    J h / (2 m), exactly what the press took off the floor's advance. An impact (a new
    contact whose bodies were closing in at the period's start, ``_approached``)
    touched t_o = sep / v_n- before the end (at most h): the bodies move by J t_o / m,
    so a rebound starts where they touched, restitution and all. The turns likewise.
    The floor friction over t_o at the new velocities is the cell's to replay
    (``impact``, noted by ``_classify``).
    """
    ct_i, ct_f, disp = cont.ct_i, cont.ct_f, cont.disp
    for c in range(cont.counts[N_CT]):
        cf = ct_f[c]
        if cf[CF_PN] == 0.0 and cf[CF_PT] == 0.0:
            continue
        a = ct_i[c, 0]
        b = ct_i[c, 1]
        ima, iia, imb, iib = _masses(a, b, phase, par, ph_cell)
        tau = cf[CF_TO] if cf[CF_TO] > 0.0 else 0.5 * h
        jx = (cf[CF_PN] * cf[CF_NX] - cf[CF_PT] * cf[CF_NY]) * tau
        jy = (cf[CF_PN] * cf[CF_NY] + cf[CF_PT] * cf[CF_NX]) * tau
        _displace(a, -1.0, state, disp, cf[CF_PX], cf[CF_PY], jx, jy, ima, iia)
        if b >= 0:
            _displace(b, 1.0, state, disp, cf[CF_PX], cf[CF_PY], jx, jy, imb, iib)


@kernel_step
def _project_positions(h, state, phase, par, ph_cell, cont):
    """
    Replay the impacts (``_replay_impacts``), then remove any overlap beyond OVERLAP_TOL.

    Gauss-Seidel over the contacts on the separations linearised about the period's
    end: each contact still overlapping gets the mass-weighted translation that brings it
    to zero separation (no velocity changes: no energy is added; no turn, so the two
    points of a face in contact push alike and the projection leaves no spin of its own). The
    bodies' displacements accumulate (``disp``: x, y, φ) and are added to the states
    at the end.
    """
    ct_i, ct_f, n_ct, disp = cont.ct_i, cont.ct_f, cont.counts[N_CT], cont.disp
    for c in range(n_ct):
        for e in range(2):
            i = ct_i[c, e]
            if i >= 0:
                disp[i, 0] = 0.0
                disp[i, 1] = 0.0
                disp[i, 2] = 0.0
    _replay_impacts(h, state, phase, par, ph_cell, cont)
    for _ in range(PROJECTION_MAX_SWEEPS):
        worst = 0.0
        for c in range(n_ct):
            a = ct_i[c, 0]
            b = ct_i[c, 1]
            cf = ct_f[c]
            nx = cf[CF_NX]
            ny = cf[CF_NY]
            sep = cf[CF_SEP]
            # the point moves with its body: translation and the turn about the centre
            if a >= 0:
                ra = (cf[CF_PX] - state[a, 0]) * ny - (cf[CF_PY] - state[a, 1]) * nx
                sep -= disp[a, 0] * nx + disp[a, 1] * ny + disp[a, 2] * ra
            if b >= 0:
                rb = (cf[CF_PX] - state[b, 0]) * ny - (cf[CF_PY] - state[b, 1]) * nx
                sep += disp[b, 0] * nx + disp[b, 1] * ny + disp[b, 2] * rb
            if sep >= -OVERLAP_TOL:
                continue
            worst = min(worst, sep)
            ima, _, imb, _ = _masses(a, b, phase, par, ph_cell)
            # translation only: a face's two points push alike and turn nothing
            p = -sep / (ima + imb)
            _displace(a, -1.0, state, disp, cf[CF_PX], cf[CF_PY], p * nx, p * ny, ima, 0.0)
            if b >= 0:
                _displace(b, 1.0, state, disp, cf[CF_PX], cf[CF_PY], p * nx, p * ny, imb, 0.0)
        if worst >= -OVERLAP_TOL:
            break
    for c in range(n_ct):
        for e in range(2):
            i = ct_i[c, e]
            if i >= 0:
                for j in range(3):
                    state[i, j] += disp[i, j]
                    disp[i, j] = 0.0


@kernel_step
def _obstacle_forces(h, cont):
    """Sum each obstacle's contact impulses over the period into the force on it [N]."""
    ct_i, ct_f, f = cont.ct_i, cont.ct_f, cont.ob_force
    for o in range(f.shape[0]):
        f[o, 0] = 0.0
        f[o, 1] = 0.0
    for c in range(cont.counts[N_CT]):
        b = ct_i[c, 1]
        if b >= 0:
            continue
        cf = ct_f[c]
        jx = cf[CF_PN] * cf[CF_NX] - cf[CF_PT] * cf[CF_NY]
        jy = cf[CF_PN] * cf[CF_NY] + cf[CF_PT] * cf[CF_NX]
        f[-1 - b, 0] += jx / h
        f[-1 - b, 1] += jy / h


@kernel_step
def _keep_for_warm_start(cont):
    """Keep this period's contacts as the last period's (the next one's warm start)."""
    n = cont.counts[N_CT]
    for c in range(n):
        for j in range(3):
            cont.old_i[c, j] = cont.ct_i[c, j]
        for j in range(CF_WIDTH):
            cont.old_f[c, j] = cont.ct_f[c, j]
    cont.counts[N_OLD] = n


@kernel_step
def contact_step(h, state, phase, par, r_out, codes, prm, cont, scratch):
    """
    Resolve the contacts at the end of a period of length ``h`` [s]: broad, narrow, solve.

    ``state`` (cap, 6) holds the parcels at the period's end as the floor friction left
    them; their velocities and, where they overlap, positions are corrected in place.
    ``codes`` is (PH_CELL, PH_JAMMED); ``prm`` (mu_parcel, mu_wall, restitution);
    ``scratch`` (two point rows (2, 5), two feature numbers (2,)).

    Returns
    -------
    int
        The number of contact points (0: nothing touched, nothing changed).

    """
    ph_cell = codes[0]
    mu_parcel, mu_wall, restitution = prm
    scratch_f, scratch_id = scratch
    _broad_phase(
        state, phase, par, r_out, codes, (mu_parcel, mu_wall), cont, scratch_f, scratch_id
    )
    n_ct = cont.counts[N_CT]
    if n_ct > 0:
        _prepare(h, state, phase, par, ph_cell, restitution, cont)
        cont.counts[N_SWEEPS] = solve_velocities(
            state, phase, par, ph_cell, cont.ct_i, cont.ct_f, n_ct
        )
        _project_positions(h, state, phase, par, ph_cell, cont)
    if n_ct > 0 or cont.counts[N_OLD] > 0:
        _obstacle_forces(h, cont)
    _keep_for_warm_start(cont)
    # every body was looked at: what the next quiet period builds on
    ph_jammed = codes[1]
    for i in range(state.shape[0]):
        cont.clear[i] = 1 if phase[i] == ph_cell or phase[i] == ph_jammed else 0
    return n_ct


@kernel_step
def hold_clocks(h, state, phase, ph_cell, cont):
    """
    Advance each parcel's no-progress clock by the period ``h`` [s]; reset it where it moved.

    A parcel on the cell that took a normal impulse this period (held by a contact) and
    is within JAM_PROGRESS of where its clock started has been held without progress
    for one period more; any other starts its clock afresh where it is. Its strongest
    contact (``H_LOAD``, ``H_BY``) names what holds it.
    """
    hold, ct_i, ct_f = cont.hold, cont.ct_i, cont.ct_f
    if cont.counts[N_QUIET] > 0:
        # the clocks of a quiet period were not kept: nothing held anything, so each
        # started afresh where the last period left its parcel
        for i in range(hold.shape[0]):
            hold[i, H_CLOCK] = 0.0
            hold[i, H_X] = cont.xy_start[i, 0]
            hold[i, H_Y] = cont.xy_start[i, 1]
        cont.counts[N_QUIET] = 0
    for i in range(hold.shape[0]):
        hold[i, H_LOAD] = 0.0
        hold[i, H_BY] = -1.0
    for c in range(cont.counts[N_CT]):
        pn = ct_f[c, CF_PN]
        for e in range(2):
            i = ct_i[c, e]
            if i >= 0 and pn > hold[i, H_LOAD]:
                hold[i, H_LOAD] = pn
                hold[i, H_BY] = ct_i[c, 1 - e]
    for i in range(hold.shape[0]):
        if phase[i] != ph_cell:
            hold[i, H_CLOCK] = 0.0
            continue
        dx = state[i, 0] - hold[i, H_X]
        dy = state[i, 1] - hold[i, H_Y]
        if hold[i, H_LOAD] > 0.0 and dx * dx + dy * dy < JAM_PROGRESS * JAM_PROGRESS:
            hold[i, H_CLOCK] += h
        else:
            hold[i, H_X] = state[i, 0]
            hold[i, H_Y] = state[i, 1]
            hold[i, H_CLOCK] = 0.0


__all__ = [
    "CF_MU",
    "CF_NX",
    "CF_NY",
    "CF_PN",
    "CF_PT",
    "CF_PX",
    "CF_PY",
    "CF_SEP",
    "CF_WIDTH",
    "CONTACT_REACH",
    "Contacts",
    "H_BY",
    "H_CLOCK",
    "JAM_PROGRESS",
    "N_CT",
    "N_QUIET",
    "N_SWEEPS",
    "OBK_RAIL",
    "OBK_WALL",
    "OB_WIDTH",
    "OVERLAP_TOL",
    "contact_step",
    "fresh_slot",
    "hold_clocks",
    "keep_start",
    "quiet_movers",
    "quiet_slot",
    "contacts_for",
    "rail",
    "side_walls",
]
