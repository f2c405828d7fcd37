"""
What the cell reports and what it takes, as plain records.

Sensor edges, scanner reads, outcomes (where a parcel left), hand-offs to the next
station of a line, watchdog trips, the faults injected into a sensor, and the spec
of a parcel to induct with its check. ``cell.Cell`` makes and takes these; the node
turns them into messages.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


from sorter_sim.model.description import label_problem, shown
from sorter_sim.runtime.params import SPECS, ParamError, parcel_half_extents


@dataclass(frozen=True)
class SensorEdge:
    """A sensor became blocked (``blocked`` True: rising edge) or clear, at ``t_ns``."""

    t_ns: int
    sensor: str
    blocked: bool


@dataclass(frozen=True)
class LabelRead:
    """The scanner read ``label`` as the parcel's leading edge crossed the scanner line."""

    t_ns: int
    parcel_id: int
    label: str


@dataclass(frozen=True)
class Outcome:
    """
    Where a parcel left the cell: exit in left | right | straight | jammed.

    (x, y): the centre of gravity where it crossed the chute entry line or the exit,
    or where it stopped when jammed [m]; cause says what jammed it.
    """

    t_ns: int
    parcel_id: int
    label: str
    exit: str
    x: float
    y: float
    cause: str = ''

    @property
    def jammed(self) -> bool:
        return self.exit == 'jammed'


@dataclass(frozen=True)
class Handoff:
    """
    A parcel that left over the straight exit, with all it takes to go on downstream.

    t_ns: the end of the period it crossed the exit line in (its state is at that time);
    state: (x, y, φ, vx, vy, ω) in this cell's frame; mode: the kernels' MODE_* (riding
    the belt, the disks, or sliding); gauge: its stick-gauge warm start; dims: A, B, m.
    """

    t_ns: int
    parcel_id: int
    label: str
    state: tuple
    mode: int
    gauge: tuple
    dims: tuple


@dataclass(frozen=True)
class WatchdogTrip:
    """The controller's heartbeat stopped: at t_ns the cell went to its safe state."""

    t_ns: int
    silent_s: float  # simulated time since the last heartbeat [s]


# a period count no run reaches: "not before something else changes"
NEVER = 1 << 40

WATCHDOG_REFUSAL = 'refused: the controller watchdog holds the disks down (no heartbeat)'

# faults a test bench injects into a sensor's signal (the physics is untouched): held
# blocked, held clear, or toggling with a period (a loose connector, a flickering eye)
SENSOR_FAULTS = ('blocked', 'clear', 'chatter')
CHATTER_PERIOD_RANGE = (0.002, 10.0)  # s, a toggle per half period


@dataclass(frozen=True)
class SensorFault:
    """An injected sensor fault (``fault`` in SENSOR_FAULTS); chatter toggles every half_k."""

    fault: str
    half_k: int = 0
    k0: int = 0

    def blocked_at(self, k: int) -> bool:
        """Return what the sensor shows at period ``k``."""
        if self.fault == 'chatter':
            return ((k - self.k0) // self.half_k) % 2 == 0
        return self.fault == 'blocked'


@dataclass(frozen=True)
class ParcelSpec:
    """
    Describe a parcel to induct.

    A parcel to induct: A x B [m] (A along the belt at φ = 0), mass m [kg], skew φ0
    [rad], lateral offset y0 [m] of its centre of gravity, and its label ('' = generated).
    """

    A: float
    B: float
    m: float
    phi0: float = 0.0
    y0: float = 0.0
    label: str = ''


def check_parcel(spec: ParcelSpec, belt_width: float) -> ParcelSpec:
    """
    Raise ParamError unless the parcel is physical and fits on the belt at induct.

    Parameters
    ----------
    spec : ParcelSpec
        The parcel.
    belt_width : float
        The belt's width [m].

    Returns
    -------
    ParcelSpec
        The parcel, its numbers as floats.

    Raises
    ------
    ParamError
        A size, mass, skew or offset out of range, or a bad label, named.

    """
    limits = {'A': SPECS['parcel_A'], 'B': SPECS['parcel_B'], 'm': SPECS['parcel_m']}
    for key, ps in limits.items():
        v = getattr(spec, key)
        if not (isinstance(v, (int, float)) and math.isfinite(v) and ps.lo <= v <= ps.hi):
            raise ParamError(
                f'{key} must be a finite number in [{ps.lo:g}, {ps.hi:g}] {ps.units}, '
                f'got {shown(v)}'
            )
    if not (math.isfinite(spec.phi0) and abs(spec.phi0) <= math.pi / 2):
        phi = math.degrees(spec.phi0)
        raise ParamError(f'phi0_deg must be in [-90, 90] deg, got {shown(phi)}')
    if not math.isfinite(spec.y0):
        raise ParamError(f'y must be finite, got {shown(spec.y0)}')
    _, hy = parcel_half_extents(spec.A, spec.B, spec.phi0)
    if abs(spec.y0) + hy > 0.5 * belt_width + 1e-12:
        raise ParamError(
            f'the parcel must fit on the belt: |y| + half its width across the belt '
            f'= {abs(spec.y0) + hy:.4g} m exceeds belt_width/2 = {0.5 * belt_width:g} m'
        )
    if spec.label != '' and label_problem(spec.label) is not None:
        raise ParamError(label_problem(spec.label))
    return spec


__all__ = [
    "CHATTER_PERIOD_RANGE",
    "SENSOR_FAULTS",
    "WATCHDOG_REFUSAL",
    "Handoff",
    "LabelRead",
    "Outcome",
    "ParcelSpec",
    "SensorEdge",
    "SensorFault",
    "WatchdogTrip",
    "check_parcel",
]
