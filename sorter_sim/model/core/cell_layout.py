"""
The cell's data layout: the rows the cell kernels exchange with the runtime, by name.

The configuration row (``C_*``), the actuators' state (``A_*``), a parcel's phase
(``PH_*``) and mode, the state codes shown on markers (``S_*``), the event buffer's
kinds (``EV_*``), the geometric features a sensor looks at (``F_*``), and the bundles
``advance_cell`` takes. Plain constants and named tuples: the kernels
(``cell_kernels``), what they observe (``cell_sensing``) and the runtime share them.
"""

from __future__ import annotations

from collections import namedtuple

# a period's motion of a parcel: its state at the start and the end, and the period
Motion = namedtuple('Motion', ['s0', 's1', 'h'])
# the conditions a sensor's blocked set is made of (scratch): feature kinds, levels, signs
Conditions = namedtuple('Conditions', ['kinds', 'levels', 'signs'])

# ---- configuration row (float64) ---------------------------------------------------
C_V = 0  # belt speed v [m/s] while the belt runs
C_HALF_W = 1  # w/2 [m]
C_B = 2  # disk field length b [m]
C_OPEN_LO = 3  # chute openings: x range [m]
C_OPEN_HI = 4
C_EXIT_X = 5  # straight exit: CoG beyond this x [m]
C_SCAN_X = 6  # scanner line x [m]
C_DT = 7  # control period [s]
C_ALPHA_RATE = 8  # disk-angle slew rate [rad/s]
C_STROKE_RATE = 9  # pop-up stroke rate [1/s] (inf: instantaneous)
C_RTOL = 10
C_ATOL = 11
C_METHOD = 12  # 0 accurate, 1 implicit
C_LAW_A = 13  # law ids of the belt and the disks
C_LAW_B = 14
C_CONTACT = 15  # what a touch is: 0 jam (the parcels stop, a fault), 1 rigid (``contact``)
C_MU_PARCEL = 16  # Coulomb friction at a parcel-parcel contact
C_MU_WALL = 17  # at a parcel-wall, -rail or -stopper contact
C_RESTITUTION = 18  # normal restitution of an impact, 0 .. 1
C_JAM_TIME = 19  # no progress for this long while held by contacts: a jam [s]
CFG_WIDTH = 20

# ---- actuator state (float64) ------------------------------------------------------
A_ALPHA = 0  # physical disk angle [rad]
A_ALPHA_CMD = 1  # commanded disk angle [rad]
A_STROKE = 2  # pop-up position 0 (down) .. 1 (up)
A_STROKE_TARGET = 3
A_BELT_ON = 4  # 1 running, 0 stopped (e-stop)
A_ALPHA_DOT = 5  # rates over the last period [rad/s], [1/s]
A_STROKE_DOT = 6
ACT_WIDTH = 7

# ---- parcel phases -----------------------------------------------------------------
PH_FREE = 0  # empty slot
PH_CELL = 1  # on the belt / disks
PH_CHUTE_LEFT = 2  # centre of gravity past y = +w/2: sliding off onto the left chute
PH_CHUTE_RIGHT = 3
PH_JAMMED = 4  # stopped by a jam until reset

# parcel modes (surface ids of the cell's strips: the belt is always surface 0)
MODE_SLIDE = -1
MODE_BELT = 0
MODE_DISKS = 1

# what a parcel is doing, for markers: codes into cell.STATE_NAMES
S_ON_BELT = 0
S_ON_DISKS = 1
S_SLIDING = 2
S_DIVERTED = 3
S_STRAIGHT = 4
S_JAMMED = 5

# ---- events: ev_i rows [period index, kind, a, b], ev_f rows [tau, x, y] ------------
EV_EDGE = 1  # a sensor changed: a = sensor index, b = 1 rising (blocked) / 0 falling
EV_SCAN = 2  # leading edge crossed the scanner line: a = slot
EV_LEFT = 3  # CoG crossed y = +w/2 in the opening: a = slot, (x, y) there
EV_RIGHT = 4  # CoG crossed y = -w/2 in the opening
EV_STRAIGHT = 5  # CoG passed exit_x: a = slot (now free), (x, y) there
EV_JAM = 6  # a = slot jammed; b = other slot, -1 side wall, -2 integration failed, -3 rail
EV_GONE = 7  # a parcel on a chute cleared the entry line: a = slot (now free)

# geometric features a sensor condition looks at
F_XMAX = 0
F_XMIN = 1
F_YMAX = 2
F_YMIN = 3
F_XCOG = 4
F_YCOG = 5

# overlaps and wall crossings below this are contact, not a jam [m]
CONTACT_TOL = 1e-9
MAX_STRIPS = 4  # strips of a period at most (``cell_strips``)


# what ``advance_cell`` takes, by name
CellSetup = namedtuple('CellSetup', ['cfg', 'laws', 'nodes', 'weights'])
Parcels = namedtuple('Parcels', ['state', 'mode', 'phase', 'par', 'scanned', 'gauge_xi'])
Sensors = namedtuple('Sensors', ['eye_x', 'blocked', 'counts'])
EventLog = namedtuple('EventLog', ['ev_i', 'ev_f', 'reserve'])
Memo = namedtuple('Memo', ['stats', 'last_strips', 'last_info'])


__all__ = [
    "Motion",
    "Conditions",
    "C_V",
    "C_HALF_W",
    "C_B",
    "C_OPEN_LO",
    "C_OPEN_HI",
    "C_EXIT_X",
    "C_SCAN_X",
    "C_DT",
    "C_ALPHA_RATE",
    "C_STROKE_RATE",
    "C_RTOL",
    "C_ATOL",
    "C_METHOD",
    "C_LAW_A",
    "C_LAW_B",
    "C_CONTACT",
    "C_MU_PARCEL",
    "C_MU_WALL",
    "C_RESTITUTION",
    "C_JAM_TIME",
    "CFG_WIDTH",
    "A_ALPHA",
    "A_ALPHA_CMD",
    "A_STROKE",
    "A_STROKE_TARGET",
    "A_BELT_ON",
    "A_ALPHA_DOT",
    "A_STROKE_DOT",
    "ACT_WIDTH",
    "PH_FREE",
    "PH_CELL",
    "PH_CHUTE_LEFT",
    "PH_CHUTE_RIGHT",
    "PH_JAMMED",
    "MODE_SLIDE",
    "MODE_BELT",
    "MODE_DISKS",
    "S_ON_BELT",
    "S_ON_DISKS",
    "S_SLIDING",
    "S_DIVERTED",
    "S_STRAIGHT",
    "S_JAMMED",
    "EV_EDGE",
    "EV_SCAN",
    "EV_LEFT",
    "EV_RIGHT",
    "EV_STRAIGHT",
    "EV_JAM",
    "EV_GONE",
    "F_XMAX",
    "F_XMIN",
    "F_YMAX",
    "F_YMIN",
    "F_XCOG",
    "F_YCOG",
    "CONTACT_TOL",
    "MAX_STRIPS",
    "CellSetup",
    "Parcels",
    "Sensors",
    "EventLog",
    "Memo",
]
