"""
The cell's physical quantities, each declared once: name, unit, default, range, meaning.

A sorter cell is a belt, a field of torsional disks (zone b of the seed's Fig. 6)
with its chute openings, the friction between parcel and surfaces, a pop-up
diverter, photo-eyes along the belt and the parcels themselves. Every place that
takes one of these quantities from a user reads its range and meaning here: the
scene schema (``runtime/scene.py``, hence ``sorter run --set`` and the design sweeps), the
simulation node's parameters (``params.py``), the controller's configuration
(``sorter_control.node``), and the README's table (``markdown_table``; a test
keeps the two equal). So the node, the controller and the model accept the same
values, and a value the model cannot handle is refused with one message naming
the key, the value and what is allowed.

The ranges are physical, not the seed's: belts from a crawl (0.05 m/s) to 10 m/s,
parcels from 1 cm to 5 m and from 10 g to a tonne. A lower bound keeps the model
away from degenerate cases (a 1e-300 m parcel, a belt at rest that never
delivers), an upper bound from values no conveyor has. Defaults are the seed's
cell (belt width s = 0.7 m, v = 1.5 m/s, μ = 0.6, disks at α = 90°) and the
default cell of ``config/cell.yaml``.

This module is plain Python: no ROS, no YAML, no numba.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

# A parcel's label, as the scanner reads it and the routing table names it: 1 to
# LABEL_MAX letters, digits and - _ . : / # (no spaces, '=', ';' or '*', which the
# routing grammar and the diagnostics use as separators).
LABEL_MAX = 64
LABEL_CHARS = 'letters, digits and - _ . : / #'
LABEL_RE = re.compile(r'[A-Za-z0-9_.:/#-]{1,%d}' % LABEL_MAX)
PENDING_INDUCTS_MAX = 1000  # parcels parcels/induct may queue while the belt is full


def label_problem(label) -> str | None:
    """
    Say why ``label`` is not a parcel label, or None.

    Parameters
    ----------
    label : str
        A label.

    Returns
    -------
    str or None
        Why it is not a label, or None.

    """
    if not isinstance(label, str):
        return f'a label must be a string, got {shown(label)}'
    if not LABEL_RE.fullmatch(label):
        return f'a label is 1 to {LABEL_MAX} {LABEL_CHARS}; got {shown(label)}'
    return None


def station_name(k: int) -> str:
    """
    Return the name of a line's station ``k`` (0-based): S01, S02, ... (its namespace too).

    Parameters
    ----------
    k : int
        The station, 0-based.

    Returns
    -------
    str
        Its name.

    """
    return f'S{k + 1:02d}'


def chute_pairs(n: int, names=()) -> list[tuple[str, str]]:
    """
    Return each station's (left, right) chute names: ``names`` in pairs, or S01L, S01R, ...

    Parameters
    ----------
    n : int
        The line's stations.
    names : sequence of str
        Two names per station, left then right; empty (or only empty strings): the
        default names.

    Returns
    -------
    list of (str, str)
        One pair per station.

    Raises
    ------
    ValueError
        Names given, but not two per station.

    """
    names = [x for x in names if x]
    if not names:
        return [(station_name(k) + 'L', station_name(k) + 'R') for k in range(n)]
    if len(names) != 2 * n:
        raise ValueError(
            f"parameter 'chute_names' must name 2 chutes per station ({2 * n} for {n}), "
            f'got {len(names)}'
        )
    return [(names[2 * k], names[2 * k + 1]) for k in range(n)]


def shown(value, limit: int = 60) -> str:
    """
    Quote a value for an error message, cut short: no message echoes a large input whole.

    Parameters
    ----------
    value : object
        The value, as given.
    limit : int
        The most characters shown.

    Returns
    -------
    str
        The value quoted, cut short.

    """
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + '...'


class DescriptionError(ValueError):
    """A value lies outside the physical range of its quantity, or is not a number."""


@dataclass(frozen=True)
class Quantity:
    """One physical quantity of the cell."""

    key: str  # canonical name, section.quantity
    unit: str  # SI, or deg; '' for dimensionless
    default: float
    lo: float
    hi: float
    meaning: str
    lo_open: bool = False  # lo itself excluded

    @property
    def allowed(self) -> str:
        """Return what is allowed, in words (the range with its unit)."""
        unit = f' {self.unit}' if self.unit else ''
        bracket = '(' if self.lo_open else '['
        return f'a finite number in {bracket}{self.lo:g}, {self.hi:g}]{unit}'

    def contains(self, value: float) -> bool:
        """
        Return True if ``value`` is a finite number in the range.

        Parameters
        ----------
        value : object
            The value, as given.

        Returns
        -------
        bool
            True if it is a finite number in the range.

        """
        if not math.isfinite(value):
            return False
        above = value > self.lo if self.lo_open else value >= self.lo
        return above and value <= self.hi

    def check(self, value: Any, name: str | None = None) -> float:
        """
        Return ``value`` as a float, or raise DescriptionError naming ``name`` (or the key).

        Parameters
        ----------
        value : object
            The value, as given.
        name : str, optional
            The name the message uses (default: the quantity's key).

        Returns
        -------
        float
            The value.

        """
        what = f'{name or self.key}: must be {self.allowed}, got {shown(value)}'
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise DescriptionError(what)
        if not self.contains(float(value)):
            raise DescriptionError(what)
        return float(value)


def _q(key, unit, default, lo, hi, meaning, lo_open=False) -> Quantity:
    return Quantity(key, unit, default, lo, hi, meaning, lo_open)


# The order here is the order of the README table.
QUANTITIES: tuple[Quantity, ...] = (
    # -- belt
    _q(
        'belt.speed',
        'm/s',
        1.5,
        0.05,
        10.0,
        'belt speed v (the disks turn at the same surface speed)',
    ),
    _q(
        'belt.width',
        'm',
        0.7,
        0.1,
        5.0,
        'belt width s; the belt spans y in [-s/2, s/2] and the scrap line lies s away across it',
    ),
    # -- disk field (zone b) and chutes
    _q(
        'disk_field.length',
        'm',
        1.2,
        0.0,
        10.0,
        'length b of the disk field, zone b '
        '(0 <= x <= b); a scene may also give .inf, the seed\'s b -> ∞',
        lo_open=True,
    ),
    _q(
        'disk_field.chute_margin',
        'm',
        0.1,
        0.0,
        2.0,
        'the chute openings in both side walls '
        'reach this far beyond the disk field, upstream and downstream',
    ),
    # -- friction
    _q(
        'friction.mu',
        '',
        0.6,
        0.0,
        3.0,
        'a zone\'s friction coefficient parcel/belt or '
        'parcel/disks, at the reference speed (the law of Fig. 3 is scaled to it)',
    ),
    # -- diverter
    _q(
        'diverter.alpha_deg',
        'deg',
        90.0,
        -90.0,
        90.0,
        'disk angle α; > 0 diverts to the left chute (+y)',
    ),
    _q(
        'diverter.alpha_slew_rate',
        'deg/s',
        360.0,
        1.0,
        36000.0,
        'slew rate of the physical disk angle',
    ),
    _q(
        'diverter.stroke',
        '',
        1.0,
        0.0,
        1.0,
        'pop-up position, 0 down .. 1 up: the share of the load the disks carry',
    ),
    _q(
        'diverter.stroke_time',
        's',
        0.1,
        0.0,
        5.0,
        'time for a full pop-up stroke (0 = instantaneous)',
    ),
    _q(
        'diverter.watchdog_timeout',
        's',
        0.3,
        0.0,
        60.0,
        'the controller\'s heartbeat may be '
        'this late (simulated time) before the diverter fails safe; 0: no watchdog',
    ),
    _q(
        'diverter.safe_alpha_deg',
        'deg',
        0.0,
        -90.0,
        90.0,
        'disk angle the watchdog commands when it trips',
    ),
    # -- sensors
    _q(
        'sensors.x',
        'm',
        0.0,
        -500.0,
        50.0,
        'position of a photo-eye beam or the scanner line '
        'along the belt (x = 0: upstream edge of the disk field)',
    ),
    # -- parcels
    _q('parcel.length', 'm', 0.7, 0.01, 5.0, 'parcel length A (along the belt at φ = 0)'),
    _q('parcel.width', 'm', 0.2, 0.01, 5.0, 'parcel width B'),
    _q(
        'parcel.mass', 'kg', 5.0, 0.01, 1000.0, 'parcel mass m (uniform pressure on the footprint)'
    ),
    _q('parcel.skew_deg', 'deg', 0.0, -180.0, 180.0, 'parcel skew φ on the belt'),
    # -- parcel stream
    _q(
        'stream.gap',
        'm',
        1.45,
        0.0,
        100.0,
        'belt gap between consecutive parcels, trailing edge to leading edge (below '
        '5 cm, down to 0: end to end, only under contact: rigid; under contact: jam '
        'parcels that close up or touch jam)',
    ),
    _q('stream.rate', '1/s', 1.0, 0.001, 50.0, 'mean arrival rate of a Poisson stream'),
)

Q: dict[str, Quantity] = {q.key: q for q in QUANTITIES}


def markdown_table() -> str:
    """Return the README's table of the cell's quantities."""
    lines = ['| quantity | unit | range | default | meaning |', '|---|---|---|---|---|']
    for q in QUANTITIES:
        bracket = '(' if q.lo_open else '['
        lines.append(
            f'| `{q.key}` | {q.unit or "–"} | {bracket}{q.lo:g}, {q.hi:g}] | {q.default:g} | '
            f'{q.meaning} |'
        )
    return '\n'.join(lines)


__all__ = [
    'DescriptionError',
    'Quantity',
    'QUANTITIES',
    'Q',
    'chute_pairs',
    'markdown_table',
    'station_name',
]
