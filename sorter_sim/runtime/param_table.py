"""
The simulation node's parameter table: every parameter, declared once.

``SCHEMA`` lists each parameter with its type, default, allowed range, units,
whether it is structural (read-only once the node runs) and a description, in the
order of the documentation's table; the node turns each entry into a
``ParameterDescriptor``, and ``params`` checks values against it (ranges, array
lengths, and the cross-checks a range cannot express). Data only: no checks here.
"""

from __future__ import annotations


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
from sorter_sim.model.description import Q

TIME_MODES = ('realtime', 'fast', 'lockstep')
ARRIVAL_MODES = ('gap', 'rate', 'none')
INTEGRATORS = ('accurate', 'implicit')
CONTACT_MODELS = ('jam', 'rigid')
# topic names the photo-eyes may not take (other sensors/ topics of the node)
RESERVED_SENSOR_NAMES = ('edges', 'chute_left', 'chute_right')


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
    # -- parcels that touch (sorter_sim/model/core/contact.py; docs/model.md)
    _p(
        'contact',
        STRING,
        'rigid',
        'what a touch is: jam (two parcels that touch, or a parcel that reaches a side '
        'wall outside a chute opening, stop and latch a jam fault) or rigid (planar '
        'rigid-box contact: they push, slide and ride on together with Coulomb friction '
        'at the contact; a jam is parcels that make no progress for jam_time)',
        choices=CONTACT_MODELS,
    ),
    _p(
        'mu_parcel',
        DOUBLE,
        0.4,
        'Coulomb friction coefficient between two parcels that touch (contact: rigid)',
        '',
        0.0,
        3.0,
    ),
    _p(
        'mu_wall',
        DOUBLE,
        0.3,
        'Coulomb friction coefficient between a parcel and a side wall, a chute opening\'s '
        'edge, a rail or a stopper (contact: rigid)',
        '',
        0.0,
        3.0,
    ),
    _p(
        'restitution',
        DOUBLE,
        0.0,
        'normal restitution of an impact between parcels or with a wall: 0 perfectly '
        'inelastic, 1 elastic (contact: rigid)',
        '',
        0.0,
        1.0,
    ),
    _p(
        'jam_time',
        DOUBLE,
        1.0,
        'a parcel held by its contacts that makes no progress along the belt for this '
        'long is jammed (contact: rigid)',
        's',
        0.01,
        60.0,
    ),
    _p(
        'rails',
        DOUBLE_ARRAY,
        [],
        'guide rails and stoppers the parcels meet (contact: rigid), 4 numbers each: the '
        'ends x0, y0, x1, y1 of a 2 cm thick segment in the cell\'s frame, each end on the '
        'cell (x in [induct_x, exit_x], |y| at most belt_width); up to 16; a segment across '
        'the belt is a stopper',
        'm',
        -500.0,
        500.0,
        length=(0, 64),
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
        'rate of parcels/markers while someone subscribes, and of contacts (contact: '
        'rigid) while someone subscribes or the node records (simulated time)',
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


__all__ = [
    'ARRIVAL_MODES',
    'INTEGRATORS',
    'RESERVED_SENSOR_NAMES',
    'RUNTIME_NAMES',
    'SCHEMA',
    'SPECS',
    'TIME_MODES',
]
