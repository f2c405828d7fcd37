"""
The cell's fieldbus I/O map: every signal a PLC exchanges with the cell, declared once.

Part of the cell description (no ROS, no protocol library): each signal has a
name, a direction (``input``: the cell to the PLC; ``output``: the PLC to the
cell), its Modbus table and address, its type, unit and scaling (engineering value
= raw register value x ``scale``), the engineering range an output accepts, and
its meaning. The Modbus and OPC UA servers (``sorter_sim.frontends.fieldbus``) are generic
over this map, the soft PLC (``sorter_control.fieldbus``) reads it to find its
I/O, and the README's table is generated from it.

The photo-eyes and chute sensors are the cell's own (``photo_eyes.names`` and the
two chute sensors): sensor i takes discrete input i and input registers
``SENSOR_EDGE_BASE + 4 i`` .. ``+ 3`` for the times of its last rising and falling
edge, as a fast input card latches them.
"""

from __future__ import annotations

from dataclasses import dataclass

INPUT, OUTPUT = 'input', 'output'
DI, COIL, IR, HR = 'discrete_input', 'coil', 'input_register', 'holding_register'
MAX_SENSORS = 16
LABEL_REGISTERS = 32  # the label in ASCII, two characters a register: 64 = LABEL_MAX
# S7: the inputs are one data block, the outputs another; bits first (discrete inputs,
# coils: bit i in byte i // 8, bit i % 8), registers after them (register a in bytes
# base + 2a, + 1, big-endian as S7 stores words), so that each S7 byte is the Modbus image's
S7_INPUT_DB, S7_OUTPUT_DB = 1, 2
S7_INPUT_BITS_BYTES = 8  # DB1.DBX0.0 .. DBX7.7: room for 64 discrete inputs
S7_OUTPUT_BITS_BYTES = 2  # DB2.DBX0.0 .. DBX1.7: 16 coils
SENSOR_EDGE_BASE = 100  # input register of sensor 0's last rising edge time
EDGE_TIME_SCALE = 1e-4  # s per count of an edge time (0.1 ms; uint32 wraps after 4.97 days)
ALPHA_LIMIT_DEG = 90.0  # the disk angle α a PLC may ask for, either way; the disk stays inside


@dataclass(frozen=True)
class Signal:
    """One signal of the I/O image."""

    name: str
    direction: str  # INPUT (cell -> PLC) or OUTPUT (PLC -> cell)
    table: str  # Modbus table: DI, COIL, IR, HR
    address: int  # first address in that table (0-based)
    type: str  # bool, int16, uint16, uint32 (two registers, high word first), string
    unit: str
    meaning: str
    scale: float = 1.0  # engineering value = raw x scale
    lo: float | None = None  # engineering range an output accepts (inclusive)
    hi: float | None = None
    # an input's range in normal operation (OPC UA Part 8's EURange), where it is
    # narrower than what its register can carry
    normal: tuple[float, float] | None = None
    words: int = 1  # registers it spans

    @property
    def s7(self) -> tuple[int, int, int, str]:
        """
        Return where the signal is in the S7 data blocks and its S7 type.

        (DB number, byte offset, bit offset, type): BOOL for a bit, INT, WORD, UDINT
        (a 32-bit value, high word first as S7 stores it) or ARRAY[0..n] OF CHAR.
        """
        bits = self.table in (DI, COIL)
        db = S7_INPUT_DB if self.direction == INPUT else S7_OUTPUT_DB
        if bits:
            return db, self.address // 8, self.address % 8, 'BOOL'
        base = S7_INPUT_BITS_BYTES if self.direction == INPUT else S7_OUTPUT_BITS_BYTES
        kind = {
            'int16': 'INT',
            'uint16': 'WORD',
            'uint32': 'UDINT',
            'string': f'ARRAY[0..{2 * self.words - 1}] OF CHAR',
        }[self.type]
        return db, base + 2 * self.address, 0, kind

    @property
    def s7_address(self) -> str:
        """Return the signal's S7 address as STEP 7 writes it (DB1.DBX2.3, DB1.DBW14 ...)."""
        db, byte, bit, kind = self.s7
        if kind == 'BOOL':
            return f'DB{db}.DBX{byte}.{bit}'
        if kind in ('INT', 'WORD'):
            return f'DB{db}.DBW{byte}'
        if kind == 'UDINT':
            return f'DB{db}.DBD{byte}'
        return f'DB{db}.DBB{byte}'

    @property
    def opcua_type(self) -> str:
        """Return the OPC UA variable type of the engineering value."""
        if self.type == 'bool':
            return 'Boolean'
        if self.type == 'string':
            return 'String'
        if self.scale != 1.0:
            return 'Double'
        return {'int16': 'Int16', 'uint16': 'UInt16', 'uint32': 'UInt32'}[self.type]

    def raw(self, value: float) -> int:
        """
        Return the raw register value of an engineering value (rounded, wrapped).

        Parameters
        ----------
        value : float
            An engineering value.

        Returns
        -------
        int
            The raw register value.

        """
        r = round(value / self.scale)
        if self.type == 'int16':
            return r & 0xFFFF
        if self.type == 'uint32':
            return r & 0xFFFFFFFF
        return r & 0xFFFF

    def value(self, raw: int) -> float:
        """
        Return the engineering value of a raw (unsigned) register value.

        Parameters
        ----------
        raw : int
            A raw register value (unsigned).

        Returns
        -------
        float
            The engineering value.

        """
        if self.type == 'int16' and raw >= 0x8000:
            raw -= 0x10000
        return raw * self.scale

    def accepts(self, value) -> bool:
        """
        Return True if an output may take the engineering ``value``.

        Parameters
        ----------
        value : float
            An engineering value.

        Returns
        -------
        bool
            True if the output may take it.

        """
        if self.type == 'bool':
            return isinstance(value, bool) or value in (0, 1)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            return False
        if value != value:  # NaN
            return False
        return self.lo <= value <= self.hi


def io_map(sensor_names) -> tuple[Signal, ...]:
    """
    Return the cell's I/O map for its sensors.

    Parameters
    ----------
    sensor_names : list of str
        The photo-eyes, then the chute sensors, in the cell's order.

    Returns
    -------
    list of Signal
        Every signal of the image: its name, direction, Modbus table and address, type,
        unit, scaling, accepted range and meaning.

    """
    names = list(sensor_names)
    if len(names) > MAX_SENSORS:
        raise ValueError(f'the I/O map takes at most {MAX_SENSORS} sensors, got {len(names)}')
    # the order is the image's: sensor bits, fixed inputs, edge times, then the outputs
    sig = [
        Signal(f'sensor.{name}', INPUT, DI, i, 'bool', '', f'{name} blocked')
        for i, name in enumerate(names)
    ]
    sig += _status_inputs()
    sig += _edge_time_inputs(names)
    sig += _outputs()
    return tuple(sig)


def _status_inputs() -> list[Signal]:
    """
    Return the inputs that do not depend on the sensors: scanner, diverter, status, counters.

    Their addresses are fixed (discrete inputs from 16, past the MAX_SENSORS sensor bits;
    input registers 0 .. 8 + LABEL_REGISTERS) so that a PLC program written for one cell
    reads them at the same place on a cell with other sensors.
    """
    return [
        Signal(
            'scanner.ready',
            INPUT,
            DI,
            16,
            'bool',
            '',
            'a label waits in scanner.label; the PLC acknowledges it with scanner.ack',
        ),
        Signal('diverter.up', INPUT, DI, 17, 'bool', '', 'disks fully up (stroke >= 0.999)'),
        Signal('diverter.down', INPUT, DI, 18, 'bool', '', 'disks fully down (stroke <= 0.001)'),
        Signal('status.estop', INPUT, DI, 19, 'bool', '', 'e-stop engaged (belt stopped)'),
        Signal('status.jam', INPUT, DI, 20, 'bool', '', 'a jam stopped a parcel'),
        Signal('status.watchdog', INPUT, DI, 21, 'bool', '', 'the watchdog tripped'),
        Signal('status.fault', INPUT, DI, 22, 'bool', '', 'e-stop, jam or watchdog'),
        Signal(
            'belt.encoder',
            INPUT,
            IR,
            0,
            'uint32',
            'm',
            'belt travel since start (0.1 mm counts; wraps after 429 km)',
            scale=1e-4,
            words=2,
        ),
        Signal(
            'cell.time',
            INPUT,
            IR,
            2,
            'uint32',
            's',
            "the cell's simulated time (0.1 ms counts), latched with the image",
            scale=EDGE_TIME_SCALE,
            words=2,
        ),
        Signal(
            'diverter.alpha',
            INPUT,
            IR,
            4,
            'int16',
            'deg',
            'physical disk angle α',
            scale=0.01,
            normal=(-ALPHA_LIMIT_DEG, ALPHA_LIMIT_DEG),
        ),
        Signal(
            'diverter.stroke',
            INPUT,
            IR,
            5,
            'uint16',
            '',
            'pop-up position, 0 down .. 1 up',
            scale=0.001,
            normal=(0.0, 1.0),
        ),
        Signal(
            'scanner.sequence',
            INPUT,
            IR,
            6,
            'uint16',
            '',
            'labels read so far (wraps at 65536)',
        ),
        Signal(
            'packml.state',
            INPUT,
            IR,
            7,
            'uint16',
            '',
            "the cell's PackML state, as PackTags StateCurrent numbers it (6 Execute; "
            'docs/simulation-node.md)',
        ),
        Signal(
            'scanner.label',
            INPUT,
            IR,
            8,
            'string',
            '',
            'the oldest label not yet acknowledged (ASCII, 2 a register, NUL-padded)',
            words=LABEL_REGISTERS,
        ),
    ]


def _edge_time_inputs(names) -> list[Signal]:
    """
    Return each sensor's rise and fall time registers, four registers a sensor.

    Sensor i's edges sit at SENSOR_EDGE_BASE + 4 i, after the fixed registers, as a fast
    input card latches them: the PLC times a parcel from them to the physics period
    rather than to its own scan.
    """
    sig = []
    for i, name in enumerate(names):
        base = SENSOR_EDGE_BASE + 4 * i
        for k, edge in enumerate(('rise', 'fall')):
            sig.append(
                Signal(
                    f'sensor.{name}.{edge}_time',
                    INPUT,
                    IR,
                    base + 2 * k,
                    'uint32',
                    's',
                    f'simulated time of the last {"rising" if k == 0 else "falling"} edge of '
                    f'{name} (0.1 ms counts, latched to the physics period)',
                    scale=EDGE_TIME_SCALE,
                    words=2,
                )
            )
    return sig


def _outputs() -> list[Signal]:
    """
    Return the PLC's outputs: the coils and holding registers the cell acts on.

    The setpoint and the PackML command carry the engineering range the cell accepts, so
    that the servers refuse a write outside it with the protocol's own error code.
    """
    return [
        Signal('diverter.popup', OUTPUT, COIL, 0, 'bool', '', 'raise the disks (0: lower)'),
        Signal('cell.reset', OUTPUT, COIL, 1, 'bool', '', 'a rising edge clears the faults'),
        Signal('belt.run', OUTPUT, COIL, 2, 'bool', '', 'run the belt (0: stop it)'),
        Signal(
            'scanner.ack', OUTPUT, COIL, 3, 'bool', '', 'a rising edge takes the waiting label'
        ),
        Signal(
            'cell.estop',
            OUTPUT,
            COIL,
            4,
            'bool',
            '',
            'a rising edge engages the e-stop (belt stops, disks drop; cell.reset releases it)',
        ),
        Signal(
            'diverter.alpha_setpoint',
            OUTPUT,
            HR,
            0,
            'int16',
            'deg',
            'disk angle α to turn to',
            scale=0.01,
            lo=-ALPHA_LIMIT_DEG,
            hi=ALPHA_LIMIT_DEG,
        ),
        Signal(
            'plc.heartbeat',
            OUTPUT,
            HR,
            1,
            'uint16',
            '',
            "the PLC's heartbeat: every change feeds the cell's watchdog",
            lo=0,
            hi=65535,
        ),
        Signal(
            'packml.command',
            OUTPUT,
            HR,
            2,
            'uint16',
            '',
            'a PackML command, numbered as PackTags CntrlCmd: 1 reset, 2 start, 3 stop, 4 hold, '
            '5 unhold, 6 suspend, 7 unsuspend, 8 abort, 9 clear; each write issues it',
            lo=1,
            hi=9,
        ),
    ]


def by_name(signals) -> dict[str, Signal]:
    """
    Return {name: signal}.

    Parameters
    ----------
    signals : list of Signal
        The I/O map.

    Returns
    -------
    dict
        {name: signal}.

    """
    return {s.name: s for s in signals}


def decode(s: Signal, regs) -> float | int | str:
    """
    Return the engineering value of a register signal from its raw registers.

    Parameters
    ----------
    s : Signal
        An input or holding register signal.
    regs : list of int
        Its ``s.words`` raw registers, in order.

    Returns
    -------
    float, int or str
        Its value (a string for the label).

    """
    if s.type == 'string':
        data = b''.join(bytes((r >> 8, r & 0xFF)) for r in regs)
        return data.rstrip(b'\0').decode('ascii', 'replace')
    if s.type == 'uint32':
        return s.value((regs[0] << 16) | regs[1])
    return s.value(regs[0])


def s7_size(signals, db: int) -> int:
    """
    Return the bytes an S7 data block of the map spans.

    Parameters
    ----------
    signals : list of Signal
        The I/O map.
    db : int
        S7_INPUT_DB or S7_OUTPUT_DB.

    Returns
    -------
    int
        Its size in bytes.

    """
    direction = INPUT if db == S7_INPUT_DB else OUTPUT
    bits = S7_INPUT_BITS_BYTES if db == S7_INPUT_DB else S7_OUTPUT_BITS_BYTES
    regs = [s for s in signals if s.direction == direction and s.table in (IR, HR)]
    return bits + 2 * max((s.address + s.words for s in regs), default=0)


def table_size(signals, table: str) -> int:
    """
    Return the number of addresses a Modbus table spans (0 .. last used address).

    Parameters
    ----------
    signals : list of Signal
        The I/O map.
    table : str
        A Modbus table.

    Returns
    -------
    int
        The number of addresses.

    """
    ends = [s.address + s.words for s in signals if s.table == table]
    return max(ends) if ends else 0


class WriteRefused(Exception):
    """A client's write that the image refuses; ``code`` names why (address/value)."""

    def __init__(self, code: str, message: str):
        super().__init__(message)
        self.code = code
