"""
The line's warehouse side: sort plan, requests, tracking between stations, dispositions.

A line runs one PLC program per station (this project's controller node in each
station's namespace), as a real line runs one program per diverter: each decides
only its own pop-up, from its own eyes and its own routing table. What joins them
is here, in ``LineWcs`` (the logic, no ROS) and ``WcsNode`` (its ROS face):

- **Tracking between stations.** Only the line's scanner (station 1's) reads labels.
  When station k confirms a parcel went straight (passed on), its label joins
  station k + 1's queue; when station k + 1's scanner eye sees the next parcel arrive,
  the label at the head of that queue is given to station k + 1's program as if its
  own scanner had read it (first in, first out: the belt keeps the order).
- **The sort plan**: destination -> chute (a chute's name on the line), versioned;
  a new plan is checked whole (unknown chutes, a destination twice) and refused with
  one line, or applied: every station's routing table is rewritten for the parcels
  still on their way, the moving ones included.
- **Requests**: label -> destination. A station's table holds ``label = left|right``
  for the parcels bound to its chutes and sends everything else straight.
- **A full chute**: its parcels go on to the straight end while it is full
  (disposition ``chute_full``), their rules restored when it empties.
- **Dispositions**, one per parcel, from where the line says it left (``line/exits``)
  and what the stations' programs confirmed: ``sorted``, ``no_read`` (no label),
  ``no_destination`` (no request or a destination the plan does not have),
  ``gap_too_short``, ``cannot_divert``, ``chute_full``, ``late``, ``not_executing``
  (its station was not in PackML Execute), ``mis_sorted``,
  ``jammed``, ``lost`` (left the line straight with no reason its planned station
  gave, or a segment could not take it: the line's exit ``lost``), each with the
  station, the chute and, for a jam or a loss, its cause: a parcel is never lost
  without one.
"""

from __future__ import annotations

import math
import re
from collections import deque
from dataclasses import dataclass

from sorter_sim.model.description import label_problem, shown, station_name

DISPOSITIONS = (
    'sorted',
    'no_read',
    'no_destination',
    'gap_too_short',
    'cannot_divert',
    'chute_full',
    'late',
    'not_executing',
    'mis_sorted',
    'jammed',
    'lost',
)
MAX_PLAN_ENTRIES = 10_000
MAX_NAME = 64
# requests of parcels not yet disposed of: more are refused, counted, never dropped
MAX_PENDING = 100_000
MAX_DISPOSED = 100_000
MAX_T = 1e9  # s: a line exit's time (about 30 years)
_DECIMAL = re.compile(
    r'[0-9]{1,10}(\.[0-9]{1,9})?'
)  # dispositions kept, for a request that comes after its parcel left


class PlanError(ValueError):
    """A sort plan or a request that cannot be taken: the message names what is wrong."""


@dataclass(frozen=True)
class Disposition:
    """Where one parcel went and why (see the module)."""

    label: str
    code: str
    destination: str
    chute: str  # the chute it reached, '' for none
    station: str  # S01 .. where it left the line
    t: float
    cause: str = ''  # the line's cause, when it gave one (a jam's, a loss's)


def _name(value, what: str) -> str:
    # the size is named, the value shown cut short: a refusal never echoes a 1 MB name
    if isinstance(value, str) and len(value) > MAX_NAME:
        raise PlanError(
            f'{what} is {len(value)} characters, more than the {MAX_NAME} allowed: '
            f'{shown(value, 40)}'
        )
    if not isinstance(value, str) or not value.strip():
        raise PlanError(f'{what} must be 1-{MAX_NAME} characters, got {shown(value, 40)}')
    if not value.isprintable() or '=' in value:
        raise PlanError(f'{what} must be printable and without "=", got {shown(value, 40)}')
    return value.strip()


EXIT_FIELDS = ('id', 'label', 'exit', 'station', 't')
LINE_EXITS = ('straight_end', 'jammed', 'lost')  # the exits that are no chute


def parse_exit(pairs, chutes: list) -> tuple[str, str, int, float, str]:
    """
    Return (label, exit, station 0-based, t, cause) of a ``line/exits`` message.

    Parameters
    ----------
    pairs : iterable of (str, str)
        The message's keys and values.
    chutes : list of (str, str)
        The line's chutes, per station.

    Raises
    ------
    PlanError
        The first thing wrong, named with what is allowed.

    """
    v: dict[str, str] = {}
    for key, value in pairs:
        if key not in EXIT_FIELDS + ('cause',) or key in v:
            raise PlanError(
                f'a line exit has each of {", ".join(EXIT_FIELDS)} (and cause) once; got '
                f'{shown(key, 40)}'
            )
        v[key] = value
    missing = [k for k in EXIT_FIELDS if k not in v]
    if missing:
        raise PlanError(f'a line exit without {", ".join(missing)}')
    problem = label_problem(v['label'])
    if problem:
        raise PlanError(problem)
    names = [station_name(k) for k in range(len(chutes))]
    if v['station'] not in names:
        raise PlanError(
            f'station must be one of {names[0]}..{names[-1]}, got {shown(v["station"], 40)}'
        )
    exits = {name for pair in chutes for name in pair} | set(LINE_EXITS)
    if v['exit'] not in exits:
        raise PlanError(
            f'exit must be a chute of the line, straight_end, jammed or lost, got '
            f'{shown(v["exit"], 40)}'
        )
    k = names.index(v['station'])
    if v['exit'] not in LINE_EXITS and v['exit'] not in chutes[k]:
        raise PlanError(
            f'exit {v["exit"]} at station {v["station"]}, whose chutes are '
            f'{" and ".join(chutes[k])}: a parcel reaches a chute at its own station'
        )
    if not (v['id'].isascii() and v['id'].isdigit() and len(v['id']) <= 19):
        raise PlanError(f'id must be a decimal integer >= 0, got {shown(v["id"], 40)}')
    t_text = v['t']
    t = float(t_text) if _DECIMAL.fullmatch(t_text) else math.nan
    if not 0.0 <= t <= MAX_T:
        raise PlanError(
            f't must be a decimal number of seconds in [0, {MAX_T:g}], got {shown(t_text, 40)}'
        )
    cause = v.get('cause', '')
    if len(cause) > MAX_NAME or not cause.isprintable():
        raise PlanError(f'cause must be at most {MAX_NAME} printable characters')
    return v['label'], v['exit'], k, t, cause


class LineWcs:
    """
    The sort plan, the requests, the tracking between stations and the dispositions.

    Parameters
    ----------
    chutes : list of (str, str)
        Per station, its (left, right) chute names.

    """

    def __init__(self, chutes: list):
        self.chutes = [tuple(pair) for pair in chutes]
        self.where = {
            name: (k, side)
            for k, pair in enumerate(self.chutes)
            for side, name in zip(('left', 'right'), pair)
        }
        self.plan: dict[str, str] = {}
        self.version = ''
        self.requests: dict[str, str] = {}
        self.full: set[str] = set()
        self.queues = [deque() for _ in self.chutes]  # labels each station expects next
        # per station, the labels given at its scanner eye by the time of the edge, and
        # the newest such time: a station restarted runs its time again from 0
        self.given: list[dict] = [dict() for _ in self.chutes]
        self._newest_edge: list = [None] * len(self.chutes)
        self.n_replayed = 0  # edges, confirmations and exits a restarted station said again
        self.results: dict[str, dict] = {}  # label -> {station: result}
        self.dispositions: dict[str, Disposition] = {}
        self.rules = [dict() for _ in self.chutes]  # the rules each station holds: label -> side
        self._rule_of: dict[str, tuple[int, str]] = {}  # label -> (station, side) of its rule
        self.n_taken = 0  # requests taken, ever
        self.passed_full: set[str] = set()  # passed its station while its chute was full

    # ------------------------------------------------------------------ plan and requests
    def set_plan(self, version: str, entries: list) -> list:
        """
        Check and take a sort plan; return the routing updates it makes.

        Parameters
        ----------
        version : str
            The plan's version (any name; the latest one taken is the plan).
        entries : list of (str, str)
            (destination, chute) pairs.

        Returns
        -------
        list of (int, str, str)
            (station, label, side or '') routing updates to send.

        Raises
        ------
        PlanError
            The first thing wrong; the current plan stays.

        """
        version = _name(version, 'the plan version')
        if len(entries) > MAX_PLAN_ENTRIES:
            raise PlanError(
                f'a sort plan has at most {MAX_PLAN_ENTRIES} entries, got {len(entries)}'
            )
        plan: dict[str, str] = {}
        for dest, chute in entries:
            dest = _name(dest, 'a destination')
            chute = _name(chute, f'the chute for {dest!r}')
            if chute not in self.where and chute != 'straight_end':
                raise PlanError(
                    f'destination {dest!r}: no chute {chute!r} on this line '
                    f'(chutes: {", ".join(self.where)}, or straight_end)'
                )
            if dest in plan:
                raise PlanError(
                    f'destination {dest!r} is in two chutes ({plan[dest]!r} and {chute!r})'
                )
            plan[dest] = chute
        self.plan, self.version = plan, version
        return self.rebuild()

    def request(self, label: str, destination: str) -> list:
        """
        Take a parcel's destination; return the routing updates it makes.

        Parameters
        ----------
        label : str
            The parcel's label.
        destination : str
            Its destination ('' withdraws the request).

        Returns
        -------
        list of (int, str, str)
            Routing updates.

        """
        # the stations' routing takes a label only in the labels' grammar: one outside it
        # would be refused there, one station at a time, and its parcel run on untracked
        problem = label_problem(label)
        if problem:
            raise PlanError(problem)
        if destination == '':
            self.requests.pop(label, None)
        else:
            destination = _name(destination, f'the destination of {label!r}')
            if label not in self.requests and len(self.requests) >= MAX_PENDING:
                raise PlanError(
                    f'{MAX_PENDING} requests wait for their parcels already: {label!r} refused'
                )
            self.requests[label] = destination
        self.n_taken += 1
        # one parcel's rule: the cost of a request does not grow with the requests held
        return self._retarget(label)

    def _retarget(self, label: str) -> list:
        """Move one parcel's rule to where it is bound now; return the routing updates."""
        new = None
        if label in self.requests and label not in self.dispositions:
            new = self._target(label)
        old = self._rule_of.pop(label, None)
        if new is not None:
            self._rule_of[label] = new
        if old == new:
            return []
        updates = []
        if old is not None:
            del self.rules[old[0]][label]
            updates.append((old[0], label, ''))
        if new is not None:
            self.rules[new[0]][label] = new[1]
            updates.append((new[0], label, new[1]))
        return updates

    def forget(self, label: str) -> list:
        """
        Let a parcel that left the line go: its request, its rule, its results.

        Parameters
        ----------
        label : str
            The parcel's label.

        Returns
        -------
        list of (int, str, str)
            The routing update withdrawing its rule, if it had one.

        """
        self.requests.pop(label, None)
        self.results.pop(label, None)
        self.passed_full.discard(label)
        return self._retarget(label)

    def chute_full(self, chute: str, full: bool) -> list:
        """
        Note a chute's full sensor; return the routing updates it makes.

        Parameters
        ----------
        chute : str
            The chute.
        full : bool
            Whether it is full.

        Returns
        -------
        list of (int, str, str)
            Routing updates.

        """
        (self.full.add if full else self.full.discard)(chute)
        return self.rebuild()

    def _target(self, label: str) -> tuple[int, str] | None:
        """Return the (station, side) a pending parcel is bound to now, or None (straight)."""
        chute = self.plan.get(self.requests.get(label, ''))
        if chute is None or chute == 'straight_end' or chute in self.full:
            return None
        return self.where[chute]

    def rebuild(self) -> list:
        """Rewrite every station's rules for the parcels not yet disposed of."""
        want = [dict() for _ in self.chutes]
        for label in self.requests:
            if label in self.dispositions:
                continue
            t = self._target(label)
            if t is not None:
                want[t[0]][label] = t[1]
        updates = []
        for k, (have, new) in enumerate(zip(self.rules, want)):
            for label in sorted(set(have) - set(new)):
                updates.append((k, label, ''))
            for label, side in sorted(new.items()):
                if have.get(label) != side:
                    updates.append((k, label, side))
        self.rules = want
        self._rule_of = {
            label: (k, side) for k, rules in enumerate(want) for label, side in rules.items()
        }
        return updates

    # ------------------------------------------------------------------ tracking
    def confirmed(self, station: int, label: str, reached: str, result: str) -> None:
        """
        Take a station program's confirmation; a parcel passed on joins the next queue.

        Parameters
        ----------
        station : int
            The station (0-based).
        label : str
            The parcel's label.
        reached : str
            Where it went at that station (left, right, straight).
        result : str
            The program's result code.

        """
        if label and station in self.results.get(label, {}):
            # said again by a station that restarted and ran its time again: the parcel
            # joined the next queue the first time
            self.n_replayed += 1
            return
        self.results.setdefault(label, {})[station] = result
        chute = self.plan.get(self.requests.get(label, ''))
        if reached == 'straight' and chute in self.full and self.where[chute][0] == station:
            self.passed_full.add(label)
        if reached == 'straight' and station + 1 < len(self.chutes):
            # a parcel passed on without a label (a no-read) keeps its place in the queue:
            # the next station must not give its neighbour's label to it
            self.queues[station + 1].append(label or None)

    def arriving(self, station: int, t_ns: int | None = None) -> str | None:
        """
        Return the label of the parcel a station's scanner eye sees arrive (or None).

        Parameters
        ----------
        station : int
            The station (1-based stations after the first; 0 has the real scanner).
        t_ns : int, optional
            The edge's time on the station's clock [ns]. An edge no later than one seen
            before is that station's time run again (its segment restarted, from t = 0,
            with the parcels it held sent back): it gets the label given at that time
            then, and the queue is left as it is.

        Returns
        -------
        str or None
            The label to give its program.

        """
        if t_ns is not None:
            newest = self._newest_edge[station]
            if newest is not None and t_ns <= newest:
                self.n_replayed += 1
                return self.given[station].get(t_ns)
            self._newest_edge[station] = t_ns
        q = self.queues[station]
        label = q.popleft() if q else None  # None also for a parcel that had no label
        if t_ns is not None:
            given = self.given[station]
            given[t_ns] = label
            if len(given) > MAX_DISPOSED:
                del given[next(iter(given))]  # the oldest
        return label

    # ------------------------------------------------------------------ dispositions
    def exited(
        self, label: str, exit: str, station: int, t: float, cause: str = ''
    ) -> Disposition:
        """
        Decide a parcel's disposition from where the line says it left.

        Parameters
        ----------
        label : str
            The parcel's label.
        exit : str
            A chute's name, straight_end or jammed.
        station : int
            Where it left (0-based).
        t : float
            When [s].
        cause : str
            The line's cause (a jam's).

        Returns
        -------
        Disposition
            The disposition.

        """
        dest = self.requests.get(label, '')
        planned = self.plan.get(dest)
        results = self.results.get(label, {})
        chute = exit if exit in self.where else ''
        if exit == 'jammed':
            code = 'chute_full' if cause == 'chute full' else 'jammed'
        elif exit == 'lost':
            code = 'lost'  # the line said so, with its cause
        elif not label:
            code = 'no_read'
        elif planned is None:
            code = 'no_destination' if exit == 'straight_end' else 'mis_sorted'
        elif exit == planned:
            code = 'sorted'
        elif exit == 'straight_end':
            k = self.where.get(planned, (None,))[0]
            r = results.get(k)
            if label in self.passed_full:
                code = 'chute_full'
            elif r in ('gap_too_short', 'cannot_divert', 'late', 'not_executing'):
                code = r
            elif r == 'rejected':
                code = 'no_read'
            else:
                code = 'lost'
                cause = cause or 'passed its station, which never answered for it'
        else:
            code = 'mis_sorted'
        d = Disposition(label, code, dest, chute, station_name(station), t, cause)
        if label:
            self.dispositions.pop(label, None)
            self.dispositions[label] = d
            if len(self.dispositions) > MAX_DISPOSED:
                del self.dispositions[next(iter(self.dispositions))]  # the oldest
        return d


__all__ = ['DISPOSITIONS', 'Disposition', 'LineWcs', 'PlanError', 'parse_exit']
