"""
The simulation node's parameters: a declared schema, read once into a frozen dataclass.

This module owns the cell's configuration and knows nothing of ROS: ``SCHEMA``
lists every parameter with its type, default, allowed range, units, whether it
is structural (read-only once the node runs) and a description; the node turns
each entry into a ``ParameterDescriptor``. ``CellParams.from_values`` checks a
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
    DOUBLE_ARRAY,
    INTEGER,
    STRING,
    STRING_ARRAY,
    ParamSpec,
    quantity_spec,
)
from sorter_sim.model.core.friction import LAW_NAMES
from sorter_sim.model.description import LABEL_MAX, Q, label_problem, shown
from sorter_sim.model.io_map import MAX_SENSORS

TIME_MODES = ('realtime', 'fast', 'lockstep')
ARRIVAL_MODES = ('gap', 'rate', 'none')
INTEGRATORS = ('accurate', 'implicit')
# topic names the photo-eyes may not take (other sensors/ topics of the node)
RESERVED_SENSOR_NAMES = ('edges', 'chute_left', 'chute_right')
_SENSOR_NAME = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')
_FORMAT_FIELD = re.compile(r'\{([^{}:!]*)')
LABEL_FIELDS = ('id', 'n', 'label')


class ParamError(ValueError):
    """A parameter value is of the wrong type, out of range, or inconsistent with another."""


def _p(
    name,
    type_,
    default,
    description,
    units='',
    lo=None,
    hi=None,
    choices=(),
    read_only=True,
    length=None,
):
    return ParamSpec(
        name, type_, default, description, units, lo, hi, tuple(choices), read_only, length
    )


# The order here is the order of the documentation's table.
SCHEMA: tuple[ParamSpec, ...] = (
    # -- time
    _p(
        'control_period',
        DOUBLE,
        0.001,
        'physics and actuator update period; events are located inside it',
        's',
        1e-4,
        0.02,
    ),
    _p(
        'time_mode',
        STRING,
        'realtime',
        'realtime: follow the wall clock times real_time_factor; '
        'fast: as fast as possible; lockstep: one control period per call of the step service',
        choices=TIME_MODES,
    ),
    _p(
        'real_time_factor',
        DOUBLE,
        1.0,
        'simulated seconds per wall second in realtime mode',
        '',
        0.01,
        100.0,
        read_only=False,
    ),
    _p(
        'fast_slice',
        DOUBLE,
        0.05,
        'fast mode: simulated time run per executor callback before '
        'services, parameters and in-process subscribers get their turn (smaller: they react '
        'sooner in simulated time; larger: less overhead)',
        's',
        1e-4,
        10.0,
        read_only=False,
    ),
    _p(
        'wall_tick',
        DOUBLE,
        0.002,
        'wall-clock period of the realtime-mode timer (outputs are published at most this late)',
        's',
        0.0005,
        0.1,
    ),
    # -- cell geometry (conveyor frame)
    quantity_spec('belt_speed', Q['belt.speed']),
    quantity_spec('belt_width', Q['belt.width']),
    quantity_spec('disk_field_length', Q['disk_field.length'], extra='finite here'),
    quantity_spec('chute_margin', Q['disk_field.chute_margin']),
    _p(
        'induct_x',
        DOUBLE,
        -3.0,
        'x of a new parcel\'s leading edge when it appears',
        'm',
        -500.0,
        -0.01,
    ),
    _p(
        'exit_x',
        DOUBLE,
        3.0,
        'a parcel whose centre of gravity passes this x has left straight',
        'm',
        0.2,
        50.0,
    ),
    _p(
        'scanner_x',
        DOUBLE,
        -2.0,
        'x of the barcode scanner line (a label is read when the leading edge crosses it)',
        'm',
        -500.0,
        0.0,
    ),
    _p(
        'photo_eyes.names',
        STRING_ARRAY,
        ['pe_scan', 'pe_divert', 'pe_exit'],
        'photo-eye names '
        '(topics sensors/<name>); must include pe_scan (at scanner_x) and pe_divert (upstream of '
        'the disk field)',
        length=(2, 32),
    ),
    quantity_spec(
        'photo_eyes.x',
        Q['sensors.x'],
        DOUBLE_ARRAY,
        [-2.0, -0.3, 2.0],
        extra='one per name; each beam spans the belt',
        length=(2, 32),
    ),
    # -- diverter
    quantity_spec(
        'alpha_deg',
        Q['diverter.alpha_deg'],
        extra='commanded; the physical angle follows at alpha_slew_rate_deg_s',
        read_only=False,
    ),
    quantity_spec('alpha_slew_rate_deg_s', Q['diverter.alpha_slew_rate']),
    quantity_spec('popup_stroke_time', Q['diverter.stroke_time']),
    quantity_spec(
        'watchdog_timeout',
        Q['diverter.watchdog_timeout'],
        extra='armed by the first heartbeat on controller/heartbeat; tripped, the disks drop '
        'and turn to safe_alpha_deg until heartbeats return',
    ),
    quantity_spec('safe_alpha_deg', Q['diverter.safe_alpha_deg']),
    # -- friction (seed Fig. 3 laws, scaled to these coefficients at 1 m/s)
    _p(
        'friction_model',
        STRING,
        'const1',
        'friction characteristic of Fig. 3 (shape parameters '
        'as in config/scenes; const1 is the seed\'s sorting runs)',
        choices=tuple(LAW_NAMES),
    ),
    quantity_spec('mu_belt', Q['friction.mu'], extra='parcel/belt, zones a and c, at 1 m/s'),
    quantity_spec('mu_disks', Q['friction.mu'], extra='parcel/disks, zone b, at 1 m/s'),
    _p(
        'integrator',
        STRING,
        'accurate',
        'method for parcels off the belt\'s closed form: '
        'accurate (event-located Dormand-Prince per control period) or implicit (one '
        'backward-Euler step per control period)',
        choices=INTEGRATORS,
    ),
    _p(
        'integrator_rtol',
        DOUBLE,
        1e-6,
        'relative tolerance of the accurate method',
        '',
        1e-12,
        1e-2,
    ),
    _p(
        'integrator_atol',
        DOUBLE,
        1e-8,
        'absolute tolerance of the accurate method',
        '',
        1e-14,
        1e-2,
    ),
    # -- parcel stream
    _p(
        'arrival',
        STRING,
        'gap',
        'parcel stream: gap (belt gap drawn from arrival_gap), rate '
        '(Poisson arrivals at arrival_rate, never closer than arrival_gap[0]) or none (only '
        'parcels/induct)',
        choices=ARRIVAL_MODES,
        read_only=False,
    ),
    quantity_spec(
        'arrival_gap',
        Q['stream.gap'],
        DOUBLE_ARRAY,
        # the least gap the default controller (config/controller.yaml) needs for the
        # default stream, 1.40 m, and some: test_defaults_agree keeps it so
        [1.45, 1.85],
        extra='[min, max], drawn uniformly',
        read_only=False,
        length=(2, 2),
    ),
    quantity_spec('arrival_rate', Q['stream.rate'], extra='in rate mode', read_only=False),
    _p(
        'arrival_count',
        INTEGER,
        0,
        'the stream stops after this many parcels (0: it never stops): a batch of a known '
        'size, the same parcels however long the run takes',
        '',
        0,
        2**31 - 1,
        read_only=False,
    ),
    _p(
        'arrival_duration_s',
        DOUBLE,
        0.0,
        'the stream stops this long (simulated) after it opens (0: it never stops): a '
        'stream of a known span, the same parcels however fast the run goes',
        's',
        0.0,
        1e6,
        read_only=False,
    ),
    quantity_spec(
        'parcel_A',
        Q['parcel.length'],
        DOUBLE_ARRAY,
        [0.3, 0.7],
        extra='[min, max] of the stream',
        read_only=False,
        length=(2, 2),
    ),
    quantity_spec(
        'parcel_B',
        Q['parcel.width'],
        DOUBLE_ARRAY,
        [0.2, 0.4],
        extra='[min, max] of the stream',
        read_only=False,
        length=(2, 2),
    ),
    quantity_spec(
        'parcel_m',
        Q['parcel.mass'],
        DOUBLE_ARRAY,
        [1.0, 10.0],
        extra='[min, max] of the stream',
        read_only=False,
        length=(2, 2),
    ),
    quantity_spec(
        'parcel_phi0_deg',
        Q['parcel.skew_deg'],
        DOUBLE_ARRAY,
        [-3.0, 3.0],
        extra='initial skew φ0, [min, max] of the stream',
        read_only=False,
        length=(2, 2),
    ),
    _p(
        'parcel_y0',
        DOUBLE_ARRAY,
        [-0.03, 0.03],
        'lateral offset of the centre of gravity at induct [min, max]',
        'm',
        -1.0,
        1.0,
        read_only=False,
        length=(2, 2),
    ),
    _p(
        'labels',
        STRING_ARRAY,
        ['A', 'B', 'C'],
        'labels cycled over the stream (field {label} of label_pattern), each 1 to 64 '
        'letters, digits and - _ . : / #',
        read_only=False,
        length=(1, 10000),
    ),
    _p(
        'label_pattern',
        STRING,
        '{label}{id:05d}',
        'a parcel\'s label: a Python format string '
        'with fields {id} (parcel id), {n} (stream index) and {label}, at most 200 characters; '
        'every label it makes must be 1 to 64 letters, digits and - _ . : / #',
        read_only=False,
    ),
    _p('seed', INTEGER, 1, 'seed of the parcel stream (same seed, same stream)', '', 0, 2**31 - 1),
    _p(
        'max_parcels',
        INTEGER,
        200,
        'capacity of the cell; inducts wait while it is full',
        '',
        1,
        5000,
    ),
    # -- machine state (PackML; sorter_sim.model.packml)
    _p(
        'packml_auto',
        BOOL,
        True,
        'automatic mode: the cell resets and starts itself at power-up and after a clear, '
        'unholds when a jam or watchdog trip it held for clears and unsuspends when parcels '
        'come again; false: it powers up Stopped and only commands (packml/*) move it',
    ),
    _p(
        'packml_starved_s',
        DOUBLE,
        5.0,
        'Execute suspends (starved) after this long with no parcel on the cell and none '
        'inducted; 0: never',
        's',
        0.0,
        3600.0,
    ),
    _p(
        'packml_blocked_s',
        DOUBLE,
        1.0,
        'Execute suspends (blocked) when a chute\'s eye stays blocked this long (the chute is '
        'full); 0: never',
        's',
        0.0,
        3600.0,
    ),
    # -- outputs
    _p(
        'frame_id',
        STRING,
        '',
        'frame of every stamped message (parcels/poses, parcels/markers, diverter/state; a '
        'sensor edge is stamped <frame_id>/<sensor>); empty: conveyor in the root namespace, '
        '<namespace>/conveyor in a namespace, so that two cells never share a frame',
    ),
    _p(
        'pose_rate_hz',
        DOUBLE,
        100.0,
        'rate of parcels/poses, parcels/ids and diverter/state (simulated time)',
        'Hz',
        1.0,
        1000.0,
    ),
    _p(
        'marker_rate_hz',
        DOUBLE,
        10.0,
        'rate of parcels/markers while someone subscribes (simulated time)',
        'Hz',
        0.1,
        1000.0,
    ),
    _p(
        'sensor_heartbeat_s',
        DOUBLE,
        0.5,
        'every sensor republishes its state this often (simulated time)',
        's',
        0.01,
        3600.0,
    ),
    # -- live view and recording
    _p(
        'foxglove_port',
        INTEGER,
        0,
        'TCP port of the live view, a Foxglove WebSocket server (<ns>/live/scene, '
        '<ns>/live/tf, <ns>/live/values); 0: off',
        '',
        0,
        65535,
    ),
    _p(
        'foxglove_host',
        STRING,
        '127.0.0.1',
        'address the live view binds to (loopback unless told otherwise)',
    ),
    _p(
        'foxglove_rate_hz',
        DOUBLE,
        30.0,
        'most live-view frames per wall-clock second (sent only while a client subscribes)',
        'Hz',
        1.0,
        200.0,
    ),
    _p(
        'modbus_port',
        INTEGER,
        0,
        'TCP port of the Modbus TCP server of the I/O image (README, Fieldbus); 0: off',
        '',
        0,
        65535,
    ),
    _p('modbus_host', STRING, '127.0.0.1', 'address the Modbus TCP server binds to'),
    _p(
        'opcua_port',
        INTEGER,
        0,
        'TCP port of the OPC UA server of the I/O image (opc.tcp://<host>:<port>/sorter_cell/); '
        '0: off',
        '',
        0,
        65535,
    ),
    _p('opcua_host', STRING, '127.0.0.1', 'address the OPC UA server binds to'),
    _p(
        's7_port',
        INTEGER,
        0,
        'TCP port of the S7 (ISO-on-TCP) server of the I/O image: DB1 inputs, DB2 outputs '
        '(docs/fieldbus.md); 0: off (102 is S7\'s own port)',
        '',
        0,
        65535,
    ),
    _p('s7_host', STRING, '127.0.0.1', 'IPv4 address the S7 server binds to'),
    _p(
        'io_cycle',
        DOUBLE,
        0.001,
        'I/O cycle of the fieldbus image (simulated time, rounded to whole control periods): '
        'outputs applied at its start, inputs latched at its end; edge times stay exact to '
        'the period (docs/fieldbus.md, Timing)',
        's',
        1e-4,
        1.0,
    ),
    _p(
        'record_path',
        STRING,
        '',
        'MCAP file (.mcap) that records every message the node publishes, as ROS 2 CDR '
        'stamped with simulated time; empty: no recording',
    ),
)

SPECS: dict[str, ParamSpec] = {s.name: s for s in SCHEMA}
RUNTIME_NAMES = frozenset(s.name for s in SCHEMA if not s.read_only)


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
    'format_label',
    'parcel_half_extents',
]
