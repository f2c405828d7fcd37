"""
The line's messages between segments, checked as protocol and as physics, without ROS.

A segment takes a parcel from another process (``frontends.segments``) and puts it on
its first station: whatever the message says becomes the state the kernels integrate.
So every field is read here once, strictly, before anything touches a station: the
fields a message of its kind has and no others, each once; integers in their range,
floats in their exact hexadecimal form (``float.hex``) and finite; and the parcel a
parcel that station could have been handed: a time at a period's end, an id in the
line's range, a label in the labels' grammar, dimensions and mass within what any
cell takes (``check_parcel``'s limits), at the straight exit of the station upstream,
on the belt, no faster than the belt and the disks (which turn at the belt's surface
speed) can move it, a contact mode the kernels have and a stick-gauge warm start of
their length. A message that fails raises ``HandoverError`` naming the field, what
it holds and what is allowed; the caller refuses it whole.
"""

from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass

from sorter_sim.model.core.cell_kernels import MODE_BELT, MODE_DISKS, MODE_SLIDE
from sorter_sim.model.core.stick import GAUGE_CARRY
from sorter_sim.model.description import label_problem, shown
from sorter_sim.runtime.cell import Handoff
from sorter_sim.runtime.params import SPECS

MAX_ID = 2**63 - 1  # the stations keep ids as int64
MAX_T_NS = 2**62  # about 146 years of simulated time: more is no line's
MAX_FIELD = 512  # characters of one field (a state is six hex floats, about 150)
MAX_IDS = 1000  # ids in one ``left`` message (a segment sends those of one slice)
MAX_STATIONS = 64
MODES = (MODE_SLIDE, MODE_BELT, MODE_DISKS)
HANDOVER_FIELDS = ('t_ns', 'id', 'label', 'state', 'mode', 'gauge', 'dims')
# a parcel's centre moves at most at the surfaces' speed (friction adds no energy);
# the margin covers the integrator's rounding and the contact model's compliance
SPEED_MARGIN = 1.5
MAX_TURN = 4.0 * math.pi  # |φ| a parcel can have turned by at a straight exit [rad]
MAX_GAUGE = 1e12  # a warm start's magnitude; only finite and bounded is checked
NODE_NAME = re.compile(r'(/[A-Za-z_][A-Za-z0-9_]*)+')  # rcl's fully qualified node names


class HandoverError(ValueError):
    """A line message that cannot be taken: the message names the field and what is allowed."""


@dataclass(frozen=True)
class HandoverLimits:
    """
    What a segment's first station can be handed (see the module).

    dt_ns: the control period [ns]; belt_speed [m/s] and belt_width [m]; exit_x: the
    straight exit of a station in its own frame [m] (a hand-over's state is in the frame
    of the station upstream).
    """

    dt_ns: int
    belt_speed: float
    belt_width: float
    exit_x: float

    @classmethod
    def from_params(cls, params) -> HandoverLimits:
        """Return the limits of stations with ``params`` (a ``CellParams``)."""
        return cls(
            dt_ns=int(params.control_period_ns),
            belt_speed=float(params.belt_speed),
            belt_width=float(params.belt_width),
            exit_x=float(params.exit_x),
        )


def message_fields(pairs, kind: str, required: tuple, optional: tuple = ()) -> dict:
    """
    Return a message's key -> value, each key once and known; HandoverError otherwise.

    Parameters
    ----------
    pairs : iterable of (str, str)
        The message's keys and values.
    kind : str
        What the message is, for the error.
    required, optional : tuple of str
        The keys it must and may have.

    """
    allowed = required + optional
    out: dict[str, str] = {}
    # a key known and once each: a message has at most its kind's fields
    for key, value in pairs:
        if key not in allowed:
            raise HandoverError(
                f'a {kind} has no field {shown(key, 40)}: its fields are {", ".join(allowed)}'
            )
        if key in out:
            raise HandoverError(f'a {kind} with field {key!r} twice')
        if len(value) > MAX_FIELD:
            raise HandoverError(
                f'a {kind}\'s {key} is at most {MAX_FIELD} characters, got {len(value)}'
            )
        out[key] = value
    missing = [k for k in required if k not in out]
    if missing:
        raise HandoverError(f'a {kind} without {", ".join(missing)}')
    return out


def integer(text: str, name: str, lo: int, hi: int) -> int:
    """Return ``text`` as a decimal integer in [lo, hi]; HandoverError naming ``name``."""
    s = text.strip()
    digits = s[1:] if s.startswith('-') else s
    # ASCII digits only: int() also reads other scripts' digits ('٣') and underscores
    if not (digits.isascii() and digits.isdigit() and len(digits) <= 20):
        raise HandoverError(f'{name} must be a decimal integer in [{lo}, {hi}], got {shown(text)}')
    v = int(s)
    if not lo <= v <= hi:
        raise HandoverError(f'{name} must be in [{lo}, {hi}], got {v}')
    return v


def floats(text: str, name: str, count: int) -> tuple:
    """Return ``count`` finite floats from their hexadecimal forms; HandoverError otherwise."""
    parts = text.split()
    if len(parts) != count:
        raise HandoverError(f'{name} must be {count} hexadecimal floats, got {len(parts)} values')
    out = []
    for p in parts:
        try:
            v = float.fromhex(p)
        except (ValueError, OverflowError):
            raise HandoverError(
                f'{name} must be {count} hexadecimal floats (float.hex), got {shown(p, 40)}'
            ) from None
        if not math.isfinite(v):
            raise HandoverError(f'{name} must be finite, got {shown(p, 40)}')
        out.append(v)
    return tuple(out)


def _check_dims(dims: tuple) -> None:
    for name, v in zip(('A', 'B', 'm'), dims):
        ps = SPECS[f'parcel_{name}']
        if not ps.lo <= v <= ps.hi:
            raise HandoverError(
                f'dims: {name} must be in [{ps.lo:g}, {ps.hi:g}] {ps.units}, got {v:.6g}'
            )


def _check_state(state: tuple, dims: tuple, lim: HandoverLimits) -> None:
    x, y, phi, vx, vy, omega = state
    A, B, _ = dims
    # it left over the straight exit (its centre crossed exit_x) in the period that
    # ended at t: at most what the surfaces carry it in a period past the line
    lo = lim.exit_x - 1e-9
    hi = lim.exit_x + SPEED_MARGIN * lim.belt_speed * lim.dt_ns * 1e-9
    if not lo <= x <= hi:
        raise HandoverError(
            f'state: x must be at the straight exit, in [{lo:.4g}, {hi:.4g}] m, got {x:.6g}'
        )
    if abs(y) > 0.5 * lim.belt_width:
        raise HandoverError(
            f'state: y must be on the belt, |y| <= {0.5 * lim.belt_width:g} m, got {y:.6g}'
        )
    if abs(phi) > MAX_TURN:
        raise HandoverError(f'state: phi must be in [-4 pi, 4 pi] rad, got {phi:.6g}')
    v_max = SPEED_MARGIN * lim.belt_speed
    if math.hypot(vx, vy) > v_max:
        raise HandoverError(
            f'state: a speed of at most {v_max:.4g} m/s (the belt\'s and the disks\'), got '
            f'{math.hypot(vx, vy):.6g}'
        )
    w_max = 2.0 * v_max / (0.5 * min(A, B))
    if abs(omega) > w_max:
        raise HandoverError(
            f'state: omega must be in [-{w_max:.4g}, {w_max:.4g}] rad/s, got {omega:.6g}'
        )


def parse_handover_fields(pairs, lim: HandoverLimits) -> tuple[Handoff, int]:
    """
    Return the parcel a ``parcel`` message carries and its send time [ns].

    Parameters
    ----------
    pairs : iterable of (str, str)
        The message's keys and values.
    lim : HandoverLimits
        What the receiving segment's first station can be handed.

    Returns
    -------
    (Handoff, int)
        The parcel and the wall-clock time it was sent [ns] (0: not given).

    Raises
    ------
    HandoverError
        The first thing wrong, named.

    """
    v = message_fields(pairs, 'hand-over', HANDOVER_FIELDS, ('wall_ns',))
    t_ns = integer(v['t_ns'], 't_ns', 0, MAX_T_NS)
    if t_ns % lim.dt_ns:
        raise HandoverError(
            f't_ns must be the end of a control period (a multiple of {lim.dt_ns} ns), got {t_ns}'
        )
    parcel_id = integer(v['id'], 'id', 0, MAX_ID)
    problem = label_problem(v['label'])
    if problem:
        raise HandoverError(problem)
    mode = integer(v['mode'], 'mode', -1, 1)
    gauge = floats(v['gauge'], 'gauge', GAUGE_CARRY)
    if max(abs(g) for g in gauge) > MAX_GAUGE:
        raise HandoverError(f'gauge values must be within +-{MAX_GAUGE:g}')
    dims = floats(v['dims'], 'dims', 3)
    _check_dims(dims)
    state = floats(v['state'], 'state', 6)
    _check_state(state, dims, lim)
    wall_ns = integer(v.get('wall_ns', '0'), 'wall_ns', 0, MAX_ID)
    return Handoff(t_ns, parcel_id, v['label'], state, mode, gauge, dims), wall_ns


def parse_horizon_fields(pairs) -> tuple[int, str]:
    """Return a ``horizon`` message's time [ns] and sender; HandoverError naming what is wrong."""
    v = message_fields(pairs, 'horizon', ('t_ns', 'identity'))
    return integer(v['t_ns'], 't_ns', 0, MAX_T_NS), parse_identity(v['identity'])


def parse_left_fields(pairs) -> tuple[list[int], str]:
    """Return the ids a ``left`` message names and its sender; HandoverError otherwise."""
    v = message_fields(pairs, 'left message', ('ids', 'identity'))
    parts = v['ids'].split()
    if len(parts) > MAX_IDS:
        raise HandoverError(f'a left message names at most {MAX_IDS} ids, got {len(parts)}')
    return [integer(p, 'an id', 0, MAX_ID) for p in parts], parse_identity(v['identity'])


def parse_identity(text: str) -> str:
    """Return a segment's identity (``<pid>-<start ns>``); HandoverError otherwise."""
    pid, _, start = text.partition('-')
    integer(pid, 'identity: the process id', 0, 2**31)
    integer(start, 'identity: the start time', 0, MAX_ID)
    return text.strip()


def host_boot_ns() -> int:
    """Return when this host booted [ns since the epoch] (Linux ``/proc/stat``); 0 unknown."""
    global _BOOT_NS
    if _BOOT_NS is None:
        _BOOT_NS = 0
        try:
            with open('/proc/stat', encoding='ascii') as f:
                for row in f:
                    if row.startswith('btime '):
                        _BOOT_NS = int(row.split()[1]) * 1_000_000_000
                        break
        except (OSError, ValueError):
            pass
    return _BOOT_NS


_BOOT_NS: int | None = None
# s a claim's start time may be ahead of this host's clock (another host's, a little fast)
MAX_CLOCK_AHEAD_S = 60.0


def check_claim_age(identity: str, now_ns: int | None = None) -> None:
    """
    Refuse a claim whose identity's start time no segment of this line can have.

    A segment's identity is its process and start time (``<pid>-<start ns>``): a start
    before this host booted is older than any line on it, and one more than
    ``MAX_CLOCK_AHEAD_S`` ahead of now is not yet; either is forged (a claim "started
    first" would make every real segment on its stations hold). HandoverError otherwise.
    """
    start = int(identity.partition('-')[2])
    now_ns = time.time_ns() if now_ns is None else now_ns
    boot = host_boot_ns()
    if boot and start < boot:
        raise HandoverError(
            f'a claim from {identity}, which started before this host did (booted at '
            f'{boot // 1_000_000_000} s): older than the line itself'
        )
    if start > now_ns + MAX_CLOCK_AHEAD_S * 1e9:
        raise HandoverError(
            f'a claim from {identity}, which starts more than {MAX_CLOCK_AHEAD_S:g} s from now'
        )


def parse_claim_fields(pairs, line_stations: int) -> tuple[str, int, int]:
    """
    Return (identity, first station 0-based, stations) of an ``owns`` message.

    Parameters
    ----------
    pairs : iterable of (str, str)
        The message's keys and values.
    line_stations : int
        The line's stations: a claim lies within them.

    """
    return parse_claim(pairs, line_stations)[:3]


def parse_claim(pairs, line_stations: int) -> tuple[str, int, int, str]:
    """
    Return (identity, first 0-based, stations, node) of an ``owns`` message.

    ``node`` is the claiming node's fully qualified name ('' when the claim has none):
    a segment restarted under its old name succeeds its own claim
    (``frontends.segment_owners.Ownership``).
    """
    v = message_fields(pairs, 'claim', ('identity', 'first', 'stations'), ('node',))
    first = integer(v['first'], 'first', 0, line_stations - 1)
    n = integer(v['stations'], 'stations', 1, line_stations - first)
    node = v.get('node', '')
    if node and not NODE_NAME.fullmatch(node):
        raise HandoverError(
            f'node must be a fully qualified node name (/ns/name), got {shown(node, 40)}'
        )
    return parse_identity(v['identity']), first, n, node


def parse_answer_fields(pairs) -> tuple[str, str]:
    """Return (sender, hello answered) of an ``answered`` message; HandoverError otherwise."""
    v = message_fields(pairs, 'answer', ('identity', 'hello'))
    return parse_identity(v['identity']), parse_identity(v['hello'])


def parse_progress_fields(pairs, line_stations: int) -> tuple[str, int, int, int]:
    """Return (identity, first, stations, k) of a ``progress`` message; HandoverError otherwise."""
    v = message_fields(pairs, 'progress message', ('identity', 'first', 'stations', 'k'))
    first = integer(v['first'], 'first', 0, line_stations - 1)
    n = integer(v['stations'], 'stations', 1, line_stations - first)
    k = integer(v['k'], 'k', 0, MAX_T_NS)
    return parse_identity(v['identity']), first, n, k


__all__ = [
    'HANDOVER_FIELDS',
    'HandoverError',
    'HandoverLimits',
    'check_claim_age',
    'host_boot_ns',
    'message_fields',
    'parse_answer_fields',
    'parse_claim',
    'parse_claim_fields',
    'parse_handover_fields',
    'parse_horizon_fields',
    'parse_identity',
    'parse_left_fields',
    'parse_progress_fields',
]
