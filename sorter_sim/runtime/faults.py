"""
Faults a test bench injects into the cell, by name, as text key/value pairs.

One vocabulary for every way in: the simulation node's ``faults/inject`` topic
(a ``diagnostic_msgs/DiagnosticStatus``: ``name`` the fault, ``values`` its
arguments), the ``sorter_cell`` pytest fixture's ``inject`` and the scenario
files' ``faults`` list. Every request is checked whole before anything changes;
a bad one raises ``ParamError`` naming what is wrong and what is allowed.

========== ======================================== =====================================
fault      arguments                                what the cell does
========== ======================================== =====================================
eye        sensor, mode (blocked | clear |          the sensor shows the fault instead of
           chatter | ok), period (chatter, s)       what it sees (the physics is as before)
chute_full chute (left | right), full (true|false)  the chute's eye held blocked, as a
                                                    full chute backs parcels into it
jam        parcel (label or id)                     that parcel stops where it is
heartbeat  lost (true | false)                      heartbeats stop reaching the watchdog
estop      (none)                                   the e-stop engages (``reset`` clears)
========== ======================================== =====================================
"""

from __future__ import annotations

import math

from sorter_sim.model.description import shown
from sorter_sim.runtime.cell import SENSOR_FAULTS, Cell
from sorter_sim.runtime.params import ParamError

ARGUMENTS = {
    'eye': ('sensor', 'mode', 'period'),
    'chute_full': ('chute', 'full'),
    'jam': ('parcel',),
    'heartbeat': ('lost',),
    'estop': (),
}
REQUIRED = {
    'eye': ('sensor', 'mode'),
    'chute_full': ('chute',),
    'jam': ('parcel',),
    'heartbeat': (),
    'estop': (),
}
FAULTS = tuple(ARGUMENTS)


def _flag(value: str, key: str) -> bool:
    text = str(value).strip().lower()
    if text in ('true', '1', 'yes'):
        return True
    if text in ('false', '0', 'no'):
        return False
    raise ParamError(f'{key} must be true or false, got {shown(value)}')


def check_fault(name: str, values: dict) -> dict:
    """
    Check a fault request whole; return its arguments as text.

    Parameters
    ----------
    name : str
        The fault (``FAULTS``).
    values : dict
        Its arguments, key -> value (text, or numbers and booleans as a YAML file
        gives them).

    Returns
    -------
    dict
        The arguments as stripped text.

    Raises
    ------
    ParamError
        An unknown fault, an unknown or missing argument.

    """
    if name not in ARGUMENTS:
        raise ParamError(f'unknown fault {shown(name)}; the cell takes {", ".join(FAULTS)}')
    args = {
        str(k): str(v).strip() if not isinstance(v, bool) else str(v).lower()
        for k, v in values.items()
    }
    extra = sorted(set(args) - set(ARGUMENTS[name]))
    if extra:
        allowed = ', '.join(ARGUMENTS[name]) or 'no arguments'
        raise ParamError(f'fault {name} does not take {", ".join(extra)} (it takes {allowed})')
    missing = [k for k in REQUIRED[name] if k not in args]
    if missing:
        raise ParamError(f'fault {name} needs {", ".join(missing)}')
    return args


def apply_fault(cell: Cell, name: str, values: dict) -> tuple[list, str]:
    """
    Inject one fault into the cell.

    Parameters
    ----------
    cell : Cell
        The cell.
    name : str
        The fault (``FAULTS``).
    values : dict
        Its arguments (see the module's table).

    Returns
    -------
    (list, str)
        The events the change shows now (sensor edges, a jam's outcome), and what was
        done, in words.

    Raises
    ------
    ParamError
        A bad request, named; nothing changes then.

    """
    args = check_fault(name, values)
    if name == 'eye':
        mode = args['mode']
        if mode not in (*SENSOR_FAULTS, 'ok'):
            raise ParamError(
                f'eye mode must be one of {", ".join((*SENSOR_FAULTS, "ok"))}, got {shown(mode)}'
            )
        period = 0.1
        if 'period' in args:
            try:
                period = float(args['period'])
            except ValueError:
                raise ParamError(f'period must be a number [s], got {shown(args["period"])}')
            if not math.isfinite(period):
                raise ParamError(f'period must be finite, got {shown(args["period"])}')
        edges = cell.inject_sensor_fault(args['sensor'], mode, period)
        done = 'cleared' if mode == 'ok' else f'held {mode}' if mode != 'chatter' else 'chattering'
        return edges, f'eye {args["sensor"]} {done}'
    if name == 'chute_full':
        chute = args['chute']
        if chute not in ('left', 'right'):
            raise ParamError(f'chute must be left or right, got {shown(chute)}')
        full = _flag(args.get('full', 'true'), 'full')
        edges = cell.inject_sensor_fault(f'chute_{chute}', 'blocked' if full else 'ok')
        return edges, f'chute {chute} {"full" if full else "no longer full"}'
    if name == 'jam':
        return cell.jam_parcel(args['parcel']), f'parcel {args["parcel"]} jammed'
    if name == 'heartbeat':
        lost = _flag(args.get('lost', 'true'), 'lost')
        cell.cut_heartbeat(lost)
        return [], 'heartbeat line cut' if lost else 'heartbeat line mended'
    cell.engage_estop()
    return [], 'e-stop engaged: belt stopped, disks dropping; reset to resume'


__all__ = ['FAULTS', 'ARGUMENTS', 'apply_fault', 'check_fault']
