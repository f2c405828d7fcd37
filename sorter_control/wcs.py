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
  gave, or never seen again), each with the station and the chute.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from sorter_sim.model.description import label_problem, station_name

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


def _name(value, what: str) -> str:
    if not isinstance(value, str) or not value.strip() or len(value) > MAX_NAME:
        raise PlanError(f'{what} must be 1-{MAX_NAME} characters, got {value!r}')
    if not value.isprintable() or '=' in value:
        raise PlanError(f'{what} must be printable and without "=", got {value!r}')
    return value.strip()


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
        self.results: dict[str, dict] = {}  # label -> {station: result}
        self.dispositions: dict[str, Disposition] = {}
        self.rules = [dict() for _ in self.chutes]  # the rules each station holds: label -> side
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
            self.requests[label] = _name(destination, f'the destination of {label!r}')
        return self.rebuild()

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
        self.results.setdefault(label, {})[station] = result
        chute = self.plan.get(self.requests.get(label, ''))
        if reached == 'straight' and chute in self.full and self.where[chute][0] == station:
            self.passed_full.add(label)
        if reached == 'straight' and station + 1 < len(self.chutes):
            # a parcel passed on without a label (a no-read) keeps its place in the queue:
            # the next station must not give its neighbour's label to it
            self.queues[station + 1].append(label or None)

    def arriving(self, station: int) -> str | None:
        """
        Return the label of the parcel a station's scanner eye sees arrive (or None).

        Parameters
        ----------
        station : int
            The station (1-based stations after the first; 0 has the real scanner).

        Returns
        -------
        str or None
            The label to give its program.

        """
        q = self.queues[station]
        return q.popleft() if q else None  # None also for a parcel that had no label

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
        else:
            code = 'mis_sorted'
        d = Disposition(label, code, dest, chute, station_name(station), t)
        if label:
            self.dispositions[label] = d
        return d


__all__ = ['DISPOSITIONS', 'Disposition', 'LineWcs', 'PlanError']
