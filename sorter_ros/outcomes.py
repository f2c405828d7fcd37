"""
Where a parcel went, as the cell, the line and the warehouse say it: encoded and decoded here.

Three topics carry it, each a ``diagnostic_msgs/DiagnosticStatus`` (a standard type: no
custom interface to build) whose key-value pairs are the record:

* the cell's ``sort/outcomes``: name ``parcel/<id>``, message the exit, values ``id``,
  ``label``, ``exit`` (left, right, straight, jammed), ``t`` (simulated, s, 9 decimals:
  the nanosecond), ``jammed``, ``x_exit``, ``y_exit`` and, for a jam, ``cause``;
* the line's ``line/exits``: the same, with ``station`` and without the exit point
  (``exit`` may also be ``lost``);
* a controller's ``sort/confirmations`` (read here; the controller node writes it):
  ``label``, ``result``, ``destination_asked``, ``destination_reached``, ``seq``, ``t``;
* the warehouse's ``wcs/dispositions``: name the label, message the code, values
  ``label``, ``code``, ``destination``, ``chute``, ``station``, ``t`` and ``cause``.

The cell's ``contacts`` markers (``contact: rigid``) carry each contact point's bodies
and normal force in their ``text``, written and read here too (``contact_text``).

Every node that publishes one builds it here, and every reader (the demos, the test
fixtures, the replay, the warehouse) reads it here, so that a field added or renamed
is added or renamed once. A reader takes what a well-formed message holds and falls
back to the name and the message for a record from an older writer.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType


@dataclass(frozen=True)
class OutcomeRecord:
    """
    Where the cell says a parcel went (``sort/outcomes``).

    label, id, exit (left | right | straight | jammed), t (simulated, s), cause (what
    jammed it, or '').
    """

    label: str
    id: int
    exit: str
    t: float
    cause: str = ''

    @property
    def jammed(self) -> bool:
        return self.exit == 'jammed'


@dataclass(frozen=True)
class ExitRecord:
    """
    Where the line says a parcel left it (``line/exits``).

    label, id, exit (a chute's name, straight_end, jammed or lost), station (S01 ...),
    t (simulated, s), cause (what jammed it, or '').
    """

    label: str
    id: int
    exit: str
    station: str
    t: float
    cause: str = ''


@dataclass(frozen=True)
class LineDisposition:
    """
    Where one parcel left the line and why (``wcs/dispositions``).

    label, code (``sorted``, ``no_read``, ``no_destination``, ``gap_too_short``,
    ``cannot_divert``, ``chute_full``, ``late``, ``not_executing``, ``mis_sorted``,
    ``jammed``, ``lost``), destination, chute ('' for none), station (S01 ...), t [s].
    """

    label: str
    code: str
    destination: str
    chute: str
    station: str
    t: float


@dataclass(frozen=True)
class ConfirmationRecord:
    """
    What a controller confirmed of a parcel (``sort/confirmations``).

    label, result (sorted, gap_too_short, cannot_divert, late, ...), destination_asked,
    destination_reached (left | right | straight), seq (the program's count, None when
    the message has none), t (simulated, s; nan without one). ``c['label']`` and
    ``c.get('seq')`` read the message's key/values as it sent them, all strings, as
    the fixture gave them before a confirmation was an object.
    """

    label: str
    result: str
    destination_asked: str
    destination_reached: str
    seq: int | None
    t: float
    values: Mapping[str, str] = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def from_message(cls, msg) -> ConfirmationRecord:
        """Return the confirmation a ``DiagnosticStatus`` carries; what it lacks is '' or None."""
        v = MappingProxyType(values(msg))
        seq = v.get('seq', '')
        return cls(
            v.get('label', msg.name),
            v.get('result', msg.message),
            v.get('destination_asked', ''),
            v.get('destination_reached', ''),
            int(seq) if seq.isascii() and seq.isdigit() else None,
            _float(v.get('t', 'nan')),
            v,
        )

    def __getitem__(self, key: str) -> str:
        return self.values[key]

    def get(self, key: str, default=None):
        """Return the message's value of ``key`` (a string), or ``default``."""
        return self.values.get(key, default)

    def keys(self):
        """Return the message's keys."""
        return self.values.keys()


# ---------------------------------------------------------------------- reading
def values(msg) -> dict:
    """Return a status message's key-value pairs as a dict (the last of a repeated key)."""
    return {kv.key: kv.value for kv in msg.values}


def _float(text: str) -> float:
    try:
        return float(text)
    except (TypeError, ValueError):
        return math.nan


def _int(text: str) -> int:
    try:
        return int(text)
    except (TypeError, ValueError):
        return 0


def read_outcome(msg) -> OutcomeRecord:
    """Return the cell's outcome in ``msg`` (``sort/outcomes``)."""
    v = values(msg)
    return OutcomeRecord(
        v.get('label', ''),
        _int(v.get('id', msg.name.rpartition('/')[2])),
        v.get('exit', msg.message),
        _float(v.get('t', 'nan')),
        v.get('cause', ''),
    )


def read_exit(msg) -> ExitRecord:
    """Return the line's exit in ``msg`` (``line/exits``)."""
    v = values(msg)
    return ExitRecord(
        v.get('label', ''),
        _int(v.get('id', msg.name.rpartition('/')[2])),
        v.get('exit', msg.message),
        v.get('station', ''),
        _float(v.get('t', 'nan')),
        v.get('cause', ''),
    )


def read_confirmation(msg) -> ConfirmationRecord:
    """Return a controller's confirmation in ``msg`` (``sort/confirmations``)."""
    return ConfirmationRecord.from_message(msg)


def read_disposition(msg) -> LineDisposition:
    """Return the warehouse's disposition in ``msg`` (``wcs/dispositions``)."""
    v = values(msg)
    return LineDisposition(
        v.get('label', msg.name),
        v.get('code', msg.message),
        v.get('destination', ''),
        v.get('chute', ''),
        v.get('station', ''),
        _float(v.get('t', 'nan')),
    )


# ---------------------------------------------------------------------- writing
def contact_text(a: int, second: str, force: float) -> str:
    """
    Return a contact marker's text: ``parcel <a> | <second body> | <force> N``.

    ``second`` is named as a jam's cause names it (``parcel <id>``, ``side wall``,
    ``rail``); the force [N] is written to its last digit.
    """
    return f'parcel {a} | {second} | {force!r} N'


def parse_contact_text(text: str) -> tuple[str, str, float]:
    """
    Return (first body, second body, normal force [N]) of a contact marker's ``text``.

    Raises ValueError when the text is not one ``contact_text`` writes.
    """
    parts = text.split(' | ')
    if len(parts) != 3 or not parts[2].endswith(' N'):
        raise ValueError(f'not a contact marker text: {text[:80]!r}')
    return parts[0], parts[1], float(parts[2][:-2])


def _status(level_warn: bool, name: str, message: str, pairs: list, hardware_id: str = ''):
    from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

    return DiagnosticStatus(
        level=DiagnosticStatus.WARN if level_warn else DiagnosticStatus.OK,
        name=name,
        message=message,
        hardware_id=hardware_id,
        values=[KeyValue(key=k, value=v) for k, v in pairs],
    )


def outcome_msg(e, hardware_id: str):
    """
    Return the ``sort/outcomes`` message of the cell's outcome ``e``.

    ``e`` has ``parcel_id``, ``label``, ``exit``, ``t_ns``, ``jammed``, ``x``, ``y``
    and ``cause`` (``sorter_sim.runtime.cell.Outcome``).
    """
    pairs = [
        ('id', str(e.parcel_id)),
        ('label', e.label),
        ('exit', e.exit),
        ('t', f'{e.t_ns * 1e-9:.9f}'),
        ('jammed', 'true' if e.jammed else 'false'),
        ('x_exit', f'{e.x:.6f}'),
        ('y_exit', f'{e.y:.6f}'),
    ]
    if e.cause:
        pairs.append(('cause', e.cause))
    return _status(e.jammed, f'parcel/{e.parcel_id}', e.exit, pairs, hardware_id)


def exit_msg(e, station: str, hardware_id: str):
    """
    Return the ``line/exits`` message of the line's exit ``e`` at ``station`` (S01 ...).

    ``e`` has ``parcel_id``, ``label``, ``exit``, ``t_ns`` and ``cause``
    (``sorter_sim.runtime.line.LineExit``).
    """
    pairs = [
        ('id', str(e.parcel_id)),
        ('label', e.label),
        ('exit', e.exit),
        ('station', station),
        ('t', f'{e.t_ns * 1e-9:.9f}'),
    ]
    if e.cause:
        pairs.append(('cause', e.cause))
    return _status(
        e.exit in ('jammed', 'lost'), f'parcel/{e.parcel_id}', e.exit, pairs, hardware_id
    )


def disposition_msg(d):
    """
    Return the ``wcs/dispositions`` message of the warehouse's disposition ``d``.

    ``d`` has ``label``, ``code``, ``destination``, ``chute``, ``station``, ``t`` and
    ``cause`` (``sorter_control.wcs.Disposition``).
    """
    pairs = [
        ('label', d.label),
        ('code', d.code),
        ('destination', d.destination),
        ('chute', d.chute),
        ('station', d.station),
        ('t', f'{d.t:.6f}'),
    ] + ([('cause', d.cause)] if d.cause else [])
    return _status(d.code != 'sorted', d.label, d.code, pairs)
