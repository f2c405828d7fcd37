"""
Column layout of the plain float64 arrays the numba kernels share.

A cell is a set of *strips*: bands x_lo <= x <= x_hi of the conveyor plane, each
moving with a surface velocity and carrying its own friction law. The seed's
zones are strips: a = (-inf, 0) and c = (b, inf) on the belt, b = [0, b] on the
disks. Strips moving with the same velocity form one *surface* (the seed's "ac"
pair is one surface): sticking is always to a surface, never to a strip alone.

Strip row (``STRIP_WIDTH`` columns):
    x_lo, x_hi [m]; surface velocity vx, vy [m/s]; weight (share of the parcel's
    normal load carried where this strip lies under it, 1 for a plain zone; the
    disks on their way up carry ``stroke`` and the belt between them the rest);
    surface id; law id; law parameters (``friction.N_LAW_PARAMS``).

Parcel row (``PARCEL_WIDTH`` columns): half_A, half_B [m], mass [kg], inertia
[kg m²], g [m/s²], rotation flag (1 = moment of friction forces on, the seed's
full model; 0 = Fig. 7 line 2), Gauss order per direction, closed-form flag
(1 = constant-μ strips use the exact wrench instead of quadrature), stick law
(1 = exact: a stick holds while the wrench the stuck surface must supply lies in
its patch's limit set; 0 = the seed's decoupled test |F| <= F_max, |T| <= T_max).

State vector (6): x, y [m], φ [rad], ẋ, ẏ [m/s], φ̇ [rad/s] of the centre of gravity.

``Contact`` bundles what every kernel that evaluates friction takes: the strips, the
parcel's row, and the Gauss-Legendre nodes and weights on [0, 1] of the footprint's
quadrature (a numba named tuple: its fields cost nothing over separate arguments).
``Slide`` is one accurate run's problem: the scrap line y_target, the contact, its
number of surfaces, the strip borders where steps restart, and the tolerances.
``Trail`` is the trajectory a run writes into caller-owned arrays: times, states and
modes; ``Log`` its events and counters.
"""

from collections import namedtuple

from sorter_sim.model.core.friction import N_LAW_PARAMS

S_XLO = 0
S_XHI = 1
S_VX = 2
S_VY = 3
S_WEIGHT = 4
S_SURF = 5
S_LAW = 6
S_PARAMS = 7
STRIP_WIDTH = S_PARAMS + N_LAW_PARAMS

P_HALF_A = 0
P_HALF_B = 1
P_MASS = 2
P_INERTIA = 3
P_GRAV = 4
P_ROTATION = 5
P_NQUAD = 6
P_CLOSED = 7
P_STICK = 8
PARCEL_WIDTH = 9

STICK_SEED = 0
STICK_EXACT = 1

# Modes of the hybrid model: sliding, or stuck to surface k (k >= 0).
MODE_SLIDE = -1

# what a parcel slides on, and how its footprint is integrated
Contact = namedtuple('Contact', ['strips', 'parcel', 'nodes', 'weights'])
# one accurate run's problem and tolerances
Slide = namedtuple('Slide', ['y_target', 'contact', 'nsurf', 'borders', 'rtol', 'atol', 'h_max'])
# the trajectory records a run writes: times, states (6) and modes
Trail = namedtuple('Trail', ['ts', 'ys', 'ms'])
# a run's event log (rows t, kind, info) and its counters (``common.N_*``)
Log = namedtuple('Log', ['ev', 'counters'])
