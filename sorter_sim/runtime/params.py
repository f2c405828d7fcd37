"""
The simulation node's parameters: a declared schema, read once into a frozen dataclass.

This module owns the cell's configuration and knows nothing of ROS: ``SCHEMA``
(``param_table``, re-exported here) lists every parameter with its type, default,
allowed range, units, whether it is structural (read-only once the node runs) and
a description; the node turns each entry into a ``ParameterDescriptor``. Here are
its checks: ``CellParams.from_values`` checks a
complete set of values (ranges, array lengths, and the cross-checks a range
cannot express: the scanner's photo-eye on the scanner line, parcels that fit
on the belt, ...) and raises ``ParamError`` naming the parameter and what is
allowed. The same check guards run-time changes (``with_changes``), so a bad
value is refused and nothing changes.

Geometry follows the seed's Fig. 6 frame ``conveyor``: x along belt travel from
the upstream edge of the disk field (zone a/b border), y across the belt toward
the chute that α > 0 diverts to. SI units, except names ending in ``_deg``.
The defaults are the seed's cell (belt width s = 0.7 m, v = 1.5 m/s within the
seed's 0.5-1.5 m/s, μ = 0.6) and equal config/cell.yaml.
"""

from __future__ import annotations

import math
import re
import string
from dataclasses import dataclass
from functools import cached_property
from typing import Any

from sorter_ros.param_spec import (
    BOOL,
    DOUBLE,
    INTEGER,
    STRING,
    STRING_ARRAY,
    ParamSpec,
)
from sorter_sim.model.description import LABEL_MAX, label_problem, shown
from sorter_sim.model.io_map import MAX_SENSORS
from sorter_sim.runtime.param_table import (
    ARRIVAL_MODES,
    INTEGRATORS,
    RESERVED_SENSOR_NAMES,
    RUNTIME_NAMES,
    SCHEMA,
    SPECS,
    TIME_MODES,
)

_SENSOR_NAME = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')
_FORMAT_FIELD = re.compile(r'\{([^{}:!]*)')
LABEL_FIELDS = ('id', 'n', 'label')
# the least stream gap under contact: jam [m]: closer, the photo-eyes cannot tell two
# parcels apart within a scan, and parcels that close up touch, which jams them
JAM_CONTACT_MIN_GAP = 0.05


class ParamError(ValueError):
    """A parameter value is of the wrong type, out of range, or inconsistent with another."""


def _field(name: str) -> str:
    return name.replace('.', '_')


def _check_value(spec: ParamSpec, value: Any) -> Any:
    """Type and range of one value; returns it normalised (tuples for arrays)."""
    bad = ParamError(f'parameter {shown(spec.name)} must be {spec.allowed}, got {shown(value)}')
    if spec.type == BOOL:
        if not isinstance(value, bool):
            raise bad
        return value
    if spec.type == STRING:
        if not isinstance(value, str) or (spec.choices and value not in spec.choices):
            raise bad
        return value
    if spec.type == INTEGER:
        if (
            isinstance(value, bool)
            or not isinstance(value, int)
            or not spec.lo <= value <= spec.hi
        ):
            raise bad
        return int(value)
    if spec.type == DOUBLE:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise bad
        v = float(value)
        if not (math.isfinite(v) and spec.in_range(v)):
            raise bad
        return v
    if not isinstance(value, (list, tuple)) or not spec.length[0] <= len(value) <= spec.length[1]:
        raise bad
    if spec.type == STRING_ARRAY:
        if not all(isinstance(v, str) for v in value):
            raise bad
        return tuple(value)
    out = []
    for v in value:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise bad
        v = float(v)
        if not (math.isfinite(v) and spec.in_range(v)):
            raise bad
        out.append(v)
    return tuple(out)


def _range_pair(name: str, pair: tuple) -> None:
    if pair[0] > pair[1]:
        raise ParamError(
            f'parameter {shown(name)} is a range [min, max]: min must not exceed max, '
            f'got {list(pair)}'
        )


def format_label(pattern: str, *, id: int, n: int, label: str) -> str:
    """
    Return a parcel's label from ``label_pattern``.

    Parameters
    ----------
    pattern : str
        The pattern, with the fields ``{id}``, ``{n}`` and ``{label}``.
    id : int
        The parcel's id.
    n : int
        Its number in the stream.
    label : str
        The label drawn from ``labels``.

    Returns
    -------
    str
        The label.

    """
    return pattern.format(id=id, n=n, label=label)


PATTERN_MAX = 200  # characters of label_pattern
_FRAME_ID = re.compile(r'[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*){0,15}')


def check_label_pattern(pattern: str, labels=('A',)) -> None:
    """
    Refuse a label pattern that could make a label outside the label grammar.

    Every label of ``labels`` must itself be a label, and the pattern, formatted
    with each of them and with ids up to a billion, must give one (so a pattern
    cannot index past a label's end, pad a label to megabytes, or insert a
    separator the routing grammar uses).

    Parameters
    ----------
    pattern : str
        The label pattern.
    labels : sequence of str
        The labels it may be given.

    Raises
    ------
    ParamError
        A label, or a label the pattern could make, outside the label grammar.

    """
    if len(pattern) > PATTERN_MAX:
        raise ParamError(
            f'parameter \'label_pattern\' may have at most {PATTERN_MAX} characters, '
            f'got {len(pattern)}'
        )
    fields = {f.split('.')[0].split('[')[0] for f in _FORMAT_FIELD.findall(pattern)}
    unknown = sorted(fields - set(LABEL_FIELDS))
    if unknown:
        raise ParamError(
            f'parameter \'label_pattern\' may use only the fields {{id}}, {{n}} and '
            f'{{label}}, got {shown(pattern)} (unknown: {", ".join(unknown)})'
        )
    try:
        specs = [spec or '' for _, _, spec, _ in string.Formatter().parse(pattern)]
    except ValueError as exc:
        raise ParamError(
            f'parameter \'label_pattern\' is not a valid format string: {shown(pattern)} ({exc})'
        ) from None
    for spec in specs:
        # checked before formatting: a width of a billion would allocate gigabytes
        if '{' in spec or any(int(w) > LABEL_MAX for w in re.findall(r'\d+', spec)):
            raise ParamError(
                f'parameter \'label_pattern\': format spec {shown(spec)} could make a label '
                f'longer than {LABEL_MAX} characters'
            )
    for label in dict.fromkeys(labels):
        problem = label_problem(label)
        if problem is not None:
            raise ParamError(f'parameter \'labels\': {problem}')
        for pid in (1, 10**9):
            try:
                text = format_label(pattern, id=pid, n=pid - 1, label=label)
            except (ValueError, IndexError, KeyError, AttributeError, TypeError) as exc:
                raise ParamError(
                    f'parameter \'label_pattern\' {shown(pattern)} cannot label a parcel '
                    f'with label {shown(label)} and id {pid}: {shown(str(exc))}'
                ) from None
            problem = label_problem(text)
            if problem is not None:
                raise ParamError(
                    f'parameter \'label_pattern\' {shown(pattern)} with label {shown(label)} '
                    f'and id {pid}: {problem}'
                )


def parcel_half_extents(A: float, B: float, phi: float) -> tuple[float, float]:
    """
    Return the half extents of the A x B footprint turned by φ.

    Parameters
    ----------
    A, B : float
        Length and width [m].
    phi : float
        The turn [rad].

    Returns
    -------
    (float, float)
        The half extents along x and along y [m].

    """
    c = abs(math.cos(phi))
    s = abs(math.sin(phi))
    return 0.5 * (A * c + B * s), 0.5 * (A * s + B * c)


def max_half_width(A_max: float, B_max: float, phi_lo_deg: float, phi_hi_deg: float) -> float:
    """
    Return the largest half extent across the belt over the skew range.

    Largest half extent across the belt over the skew range (it is maximal at an end or
    where tan φ = A/B).

    Parameters
    ----------
    A_max, B_max : float
        The largest length and width of the stream [m].
    phi_lo_deg, phi_hi_deg : float
        The skew range [deg].

    Returns
    -------
    float
        The largest half extent across the belt [m].

    """
    lo, hi = math.radians(phi_lo_deg), math.radians(phi_hi_deg)
    cands = [lo, hi, 0.0]
    crit = math.atan2(A_max, B_max)
    cands += [p for p in (crit, -crit) if lo <= p <= hi]
    return max(parcel_half_extents(A_max, B_max, p)[1] for p in cands if lo <= p <= hi)


@dataclass(frozen=True)
class CellParams:
    """
    Every parameter of the simulation node, checked (see ``SCHEMA`` for meaning and units).

    Field names are the parameter names with '.' replaced by '_'.
    """

    control_period: float
    time_mode: str
    real_time_factor: float
    fast_slice: float
    wall_tick: float
    belt_speed: float
    belt_width: float
    disk_field_length: float
    chute_margin: float
    induct_x: float
    exit_x: float
    scanner_x: float
    photo_eyes_names: tuple
    photo_eyes_x: tuple
    alpha_deg: float
    alpha_slew_rate_deg_s: float
    popup_stroke_time: float
    watchdog_timeout: float
    safe_alpha_deg: float
    friction_model: str
    mu_belt: float
    mu_disks: float
    integrator: str
    integrator_rtol: float
    integrator_atol: float
    contact: str
    mu_parcel: float
    mu_wall: float
    restitution: float
    jam_time: float
    rails: tuple
    arrival: str
    arrival_gap: tuple
    arrival_rate: float
    arrival_count: int
    arrival_duration_s: float
    parcel_A: tuple
    parcel_B: tuple
    parcel_m: tuple
    parcel_phi0_deg: tuple
    parcel_y0: tuple
    labels: tuple
    label_pattern: str
    seed: int
    max_parcels: int
    packml_auto: bool
    packml_starved_s: float
    packml_blocked_s: float
    frame_id: str
    pose_rate_hz: float
    marker_rate_hz: float
    sensor_heartbeat_s: float
    foxglove_port: int
    foxglove_host: str
    foxglove_rate_hz: float
    modbus_port: int
    modbus_host: str
    opcua_port: int
    opcua_host: str
    s7_port: int
    s7_host: str
    io_cycle: float
    record_path: str

    # -- construction ------------------------------------------------------
    @classmethod
    def defaults(cls) -> 'CellParams':
        return cls.from_values({})

    @classmethod
    def from_values(cls, values: dict[str, Any]) -> 'CellParams':
        """
        Check a mapping {parameter name: value}; missing names take their defaults.

        Parameters
        ----------
        values : dict
            Parameter values by name (``SCHEMA``).

        Returns
        -------
        CellParams
            The checked set.

        Raises
        ------
        ParamError
            An unknown name, a value of the wrong type or out of range, or values that
            contradict each other; the message names the parameter and what is allowed.

        """
        unknown = sorted(set(values) - set(SPECS))
        if unknown:
            raise ParamError(
                f'unknown parameter(s) {", ".join(map(repr, unknown))}; see the '
                f'README table for the allowed names'
            )
        kw = {}
        for spec in SCHEMA:
            kw[_field(spec.name)] = _check_value(spec, values.get(spec.name, spec.default))
        params = cls(**kw)
        params._cross_check()
        return params

    def value(self, name: str) -> Any:
        """
        Return the value of one parameter.

        Parameters
        ----------
        name : str
            The parameter.

        Returns
        -------
        object
            Its value (lists for arrays, as ROS holds them).

        """
        v = getattr(self, _field(name))
        return list(v) if isinstance(v, tuple) else v

    def as_values(self) -> dict[str, Any]:
        return {spec.name: self.value(spec.name) for spec in SCHEMA}

    def with_changes(self, changes: dict[str, Any], *, runtime: bool = True) -> 'CellParams':
        """
        Return a new, checked parameter set with ``changes`` applied; raises ParamError otherwise.

        runtime: refuse changes to structural (read-only) parameters.

        Parameters
        ----------
        changes : dict
            Parameter values by name.
        runtime : bool
            Refuse changes to structural (read-only) parameters.

        Returns
        -------
        CellParams
            The new set; this one is not changed.

        """
        if runtime:
            fixed = sorted(n for n in changes if n in SPECS and n not in RUNTIME_NAMES)
            if fixed:
                raise ParamError(
                    f'parameter(s) {", ".join(map(repr, fixed))} are structural '
                    f'(read-only) and cannot change while the cell runs'
                )
        values = self.as_values()
        values.update(changes)
        return CellParams.from_values(values)

    # -- derived (computed once: a CellParams never changes) -----------------
    @cached_property
    def alpha_rad(self) -> float:
        return math.radians(self.alpha_deg)

    @cached_property
    def chute_x_range(self) -> tuple[float, float]:
        """X range of the chute openings (and of the chute-entry sensors) [m]."""
        return -self.chute_margin, self.disk_field_length + self.chute_margin

    @cached_property
    def pose_stride(self) -> int:
        """Control periods between pose publications."""
        return max(1, round(1.0 / (self.pose_rate_hz * self.control_period)))

    @cached_property
    def io_stride(self) -> int:
        """Control periods per I/O cycle of the fieldbus image."""
        return max(1, round(self.io_cycle / self.control_period))

    @cached_property
    def fast_slice_periods(self) -> int:
        return max(1, round(self.fast_slice / self.control_period))

    @cached_property
    def marker_stride(self) -> int:
        return max(1, round(1.0 / (self.marker_rate_hz * self.control_period)))

    @cached_property
    def heartbeat_stride(self) -> int:
        return max(1, round(self.sensor_heartbeat_s / self.control_period))

    @cached_property
    def control_period_ns(self) -> int:
        return round(self.control_period * 1e9)

    def photo_eye(self, name: str) -> float:
        """
        Return the x of a photo-eye.

        Parameters
        ----------
        name : str
            The photo-eye's name (``photo_eyes.names``).

        Returns
        -------
        float
            Its x [m].

        """
        return self.photo_eyes_x[self.photo_eyes_names.index(name)]

    # -- cross-checks --------------------------------------------------------
    def _cross_check(self) -> None:
        # in this order: the first inconsistency found is the one reported
        self._check_photo_eyes()
        self._check_layout()
        self._check_outputs()

    def _check_photo_eyes(self) -> None:
        """Check the photo-eyes: names, the two the program needs, where they sit."""
        names, xs = self.photo_eyes_names, self.photo_eyes_x
        if len(names) != len(xs):
            raise ParamError(
                f'parameters \'photo_eyes.names\' and \'photo_eyes.x\' must have the '
                f'same length, got {len(names)} names and {len(xs)} positions'
            )
        for n in names:
            if not _SENSOR_NAME.match(n) or n in RESERVED_SENSOR_NAMES:
                raise ParamError(
                    f'parameter \'photo_eyes.names\': {shown(n)} is not allowed; a name '
                    f'starts with a letter, has only letters, digits and _, and is '
                    f'none of {", ".join(RESERVED_SENSOR_NAMES)}'
                )
        if len(set(names)) != len(names):
            raise ParamError(f'parameter \'photo_eyes.names\' has duplicates: {list(names)}')
        for need in ('pe_scan', 'pe_divert'):
            if need not in names:
                raise ParamError(
                    f'parameter \'photo_eyes.names\' must include {shown(need)}, got {list(names)}'
                )
        if self.photo_eye('pe_scan') != self.scanner_x:
            raise ParamError(
                f'photo-eye pe_scan sits on the scanner line: \'photo_eyes.x\' of '
                f'pe_scan must equal scanner_x = {self.scanner_x:g} m, got '
                f'{self.photo_eye("pe_scan"):g} m'
            )
        if not self.photo_eye('pe_divert') < 0.0:
            raise ParamError(
                f'photo-eye pe_divert must lie upstream of the disk field (x < 0), '
                f'got {self.photo_eye("pe_divert"):g} m'
            )

    def _check_layout(self) -> None:
        """Check the cell's lines along the belt, parcels that fit, rates and periods."""
        names, xs = self.photo_eyes_names, self.photo_eyes_x
        if not self.induct_x < self.scanner_x:
            raise ParamError(
                f'parameter \'induct_x\' ({self.induct_x:g} m) must lie upstream of '
                f'scanner_x ({self.scanner_x:g} m), or parcels are never scanned'
            )
        lo_open, hi_open = self.chute_x_range
        if not self.exit_x > hi_open:
            raise ParamError(
                f'parameter \'exit_x\' must lie beyond the chute openings (> '
                f'disk_field_length + chute_margin = {hi_open:g} m), got '
                f'{self.exit_x:g} m'
            )
        for n, x in zip(names, xs):
            if not self.induct_x <= x < self.exit_x:
                raise ParamError(
                    f'photo-eye {n} at x = {x:g} m must lie on the cell, in '
                    f'[induct_x, exit_x) = [{self.induct_x:g}, {self.exit_x:g}) m'
                )
        for name in (
            'arrival_gap',
            'parcel_A',
            'parcel_B',
            'parcel_m',
            'parcel_phi0_deg',
            'parcel_y0',
        ):
            _range_pair(name, getattr(self, name))
        if self.arrival_gap[0] < JAM_CONTACT_MIN_GAP and self.contact != 'rigid':
            raise ParamError(
                f'parameter \'arrival_gap\' below {JAM_CONTACT_MIN_GAP:g} m (got '
                f'{list(self.arrival_gap)}) needs contact: rigid: under contact: '
                f'{self.contact} parcels that close up or touch jam'
            )
        self._check_rails()
        half_w = 0.5 * self.belt_width
        hy = max_half_width(self.parcel_A[1], self.parcel_B[1], *self.parcel_phi0_deg)
        worst = max(abs(self.parcel_y0[0]), abs(self.parcel_y0[1])) + hy
        if worst > half_w:
            raise ParamError(
                f'parcels from parcel_A, parcel_B, parcel_phi0_deg and parcel_y0 can '
                f'reach {worst:g} m from the belt axis, beyond belt_width/2 = '
                f'{half_w:g} m; narrow the ranges'
            )
        if self.pose_rate_hz * self.control_period > 1.0 + 1e-9:
            raise ParamError(
                f'parameter \'pose_rate_hz\' ({self.pose_rate_hz:g} Hz) cannot exceed '
                f'the control rate 1/control_period = {1 / self.control_period:g} Hz'
            )
        if abs(self.control_period * 1e9 - self.control_period_ns) > 1e-6:
            raise ParamError(
                f'parameter \'control_period\' must be a whole number of nanoseconds, '
                f'got {shown(self.control_period)}'
            )

    @property
    def rail_segments(self) -> tuple[tuple[float, float, float, float], ...]:
        """Return the rails and stoppers (``rails``) as (x0, y0, x1, y1) segments [m]."""
        r = self.rails
        return tuple(tuple(r[k : k + 4]) for k in range(0, len(r), 4))

    def _check_rails(self) -> None:
        """Check the rails: whole segments, two distinct ends on the cell, rigid contact."""
        if len(self.rails) % 4:
            raise ParamError(
                f'parameter \'rails\' takes 4 numbers a rail (x0, y0, x1, y1 [m]), got '
                f'{len(self.rails)} numbers'
            )
        if self.rails and self.contact != 'rigid':
            raise ParamError(
                f'parameter \'rails\' needs contact: rigid (under contact: {self.contact} '
                f'nothing meets a rail); got {len(self.rails) // 4} rail(s)'
            )
        w = self.belt_width
        for k, (x0, y0, x1, y1) in enumerate(self.rail_segments):
            for x, y in ((x0, y0), (x1, y1)):
                if not (self.induct_x <= x <= self.exit_x and abs(y) <= w):
                    raise ParamError(
                        f'parameter \'rails\': rail {k + 1} has an end at ({x:g}, {y:g}) m, '
                        f'off the cell: x must be in [induct_x, exit_x] = '
                        f'[{self.induct_x:g}, {self.exit_x:g}] m and |y| at most '
                        f'belt_width = {w:g} m'
                    )
            if math.hypot(x1 - x0, y1 - y0) < 0.01:
                raise ParamError(
                    f'parameter \'rails\': rail {k + 1} must be at least 1 cm long, got ends '
                    f'({x0:g}, {y0:g}) and ({x1:g}, {y1:g}) m'
                )

    def _check_outputs(self) -> None:
        """Labels, the servers' hosts, the fieldbus I/O map, the recording and the frame."""
        check_label_pattern(self.label_pattern, self.labels)
        for name in ('foxglove', 'modbus', 'opcua', 's7'):
            host = getattr(self, f'{name}_host')
            if getattr(self, f'{name}_port') and not 0 < len(host) <= 253:
                raise ParamError(
                    f'parameter \'{name}_host\' must be a host name or address (1 to 253 '
                    f'characters), got {shown(host)}'
                )
        if len(self.photo_eyes_names) + 2 > MAX_SENSORS and (
            self.modbus_port or self.opcua_port or self.s7_port
        ):
            raise ParamError(
                f'the fieldbus I/O map takes at most {MAX_SENSORS} sensors (photo-eyes and the '
                f'two chute sensors); photo_eyes.names has {len(self.photo_eyes_names)}'
            )
        if len(self.record_path) > 4096:
            raise ParamError(
                f'parameter \'record_path\' must be a path of at most 4096 characters, got '
                f'{shown(self.record_path)}'
            )
        if self.frame_id and not _FRAME_ID.fullmatch(self.frame_id):
            raise ParamError(
                f'parameter \'frame_id\' must be empty or a frame name (letters, digits, _ '
                f'and / between names, no leading /), got {shown(self.frame_id)}'
            )


__all__ = [
    'CellParams',
    'ParamError',
    'ParamSpec',
    'SCHEMA',
    'SPECS',
    'RUNTIME_NAMES',
    'TIME_MODES',
    'ARRIVAL_MODES',
    'INTEGRATORS',
    'format_label',
    'parcel_half_extents',
]
