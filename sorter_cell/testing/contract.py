"""
The station-program contract, checked: each clause a user's station program must keep.

A station program runs in its station's namespace on a line (``/S01``, ...) beside the
warehouse node; docs/testing.md states the contract. ``check_station_program`` puts
the program at station 1 of a two-station line (this project's program at station
2, the default sort plan D01 -> S01L, D02 -> S01R, D03 -> S02L, D04 -> S02R) and
sends it one parcel of each kind, far enough apart that a simple program may handle
one at a time:

=============== ===================================================================
clause          what is checked, and what breaking it does on a line
=============== ===================================================================
heartbeat       a new ``controller/heartbeat`` counter at least every
                ``watchdog_timeout`` of simulated time; else the station's watchdog
                trips (fault ``watchdog``): its disks drop and its parcels go on
routing         it subscribes to ``routing/updates``; else it never learns where a
                parcel goes
sorts           a parcel the warehouse routes to the station's left or right chute
                ends there (disposition ``sorted``); else ``lost`` or ``mis_sorted``
confirmations   one ``sort/confirmations`` per parcel, with ``label``, ``result``
                and ``destination_reached``; without them the warehouse cannot
                explain a parcel (``lost``)
passes on       a parcel bound to the next station is confirmed
                ``destination_reached: straight``, so the warehouse gives its label
                to the next station, which sorts it; else that parcel is ``lost``
no request      a parcel without a destination goes straight to the line's end
                (``no_destination``)
packml          while the station is not in ``Execute`` (``status/packml``) nothing
                is diverted and the parcel is confirmed ``not_executing``
                (disposition ``not_executing``); else a held machine moves
=============== ===================================================================

``ContractReport`` is false when a clause is broken and its text names each one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

SPACING_S = 2.5  # simulated seconds between parcels: one at a time on the station
PARCELS = (  # label, destination, the clause it checks
    ('K-LEFT', 'D01', 'sorts'),
    ('K-RIGHT', 'D02', 'sorts'),
    ('K-NEXT', 'D03', 'passes on'),
    ('K-NONE', None, 'no request'),
)
HELD_LABEL = 'K-HELD'


@dataclass
class Clause:
    """One clause of the contract and whether the program kept it."""

    name: str
    kept: bool
    detail: str


@dataclass
class ContractReport:
    """The clauses, in order; false when one is broken (its text names each)."""

    program: str
    clauses: list = field(default_factory=list)
    state: str = ''

    def __bool__(self) -> bool:
        return all(c.kept for c in self.clauses)

    @property
    def broken(self) -> list:
        """Return the broken clauses."""
        return [c for c in self.clauses if not c.kept]

    def __str__(self) -> str:
        head = (
            f'station program {self.program}: keeps the contract'
            if self
            else f'station program {self.program} breaks {len(self.broken)} clause(s) of '
            'the station-program contract (docs/testing.md)'
        )
        lines = [head] + [
            f'  [{"ok" if c.kept else "BROKEN"}] {c.name}: {c.detail}' for c in self.clauses
        ]
        if not self and self.state:
            lines += ['  ' + x for x in self.state.splitlines()]
        return '\n'.join(lines)

    __repr__ = __str__


def check_station_program(
    program, parameters: dict | None = None, *, domain_id: int | None = None, record=None
) -> ContractReport:
    """
    Run the contract's checks against a station program.

    Parameters
    ----------
    program : callable or str
        Its factory (``"module:callable"`` or the callable), called with ``context=``,
        ``namespace=`` and ``parameter_overrides=``.
    parameters : dict, optional
        Its parameter overrides.
    domain_id : int, optional
        The ROS domain.
    record : str, optional
        An MCAP file of the check.

    Returns
    -------
    ContractReport
        Each clause, kept or broken, with what was seen.

    """
    import rclpy
    from diagnostic_msgs.msg import DiagnosticStatus
    from std_srvs.srv import Trigger

    from sorter_cell.testing.line import SorterLine
    from sorter_ros.interface import EVENT_QOS
    from sorter_ros.outcomes import values

    name = program if isinstance(program, str) else getattr(program, '__name__', repr(program))
    report = ContractReport(str(name))
    with SorterLine(2, domain_id=domain_id, record=record) as line:
        st = line.station(1)
        st.replace_program(program, parameters)
        confirmations: dict[str, dict] = {}
        spy = line.add_node(rclpy.create_node('station_contract_spy', context=line.context))
        spy.create_subscription(
            DiagnosticStatus,
            f'{st.namespace}/sort/confirmations',
            lambda m: confirmations.setdefault(values(m).get('label', m.name), values(m)),
            EVENT_QOS,
        )
        line.run(1.0)  # the program subscribes; the warehouse sends it its table
        subscribed = line.wcs._pub_routing[0].get_subscription_count() > 0
        for label, dest, _ in PARCELS:
            line.induct(label, dest)
            line.run(SPACING_S)
        # the last parcels are past the disks: the station is held for the next one
        st.sim.commands.packml('hold', Trigger.Response())
        line.run(0.2)
        packml_state = st.sim.cell.packml.state
        line.induct(HELD_LABEL, 'D01')
        line.run_until(lambda: len(line.dispositions) > len(PARCELS), 30.0)
        report.clauses = _clauses(line, st, subscribed, confirmations, packml_state)
        report.state = line.explain()
    return report


def _clauses(line, st, subscribed: bool, confirmations: dict, packml_state: str) -> list:
    """Judge each clause from what the line, the warehouse and the spy saw."""
    cell = st.sim.cell
    out = []
    if cell.watchdog_trips or not cell.watchdog_armed:
        why = (
            f'the watchdog tripped {cell.watchdog_trips} time(s)'
            if cell.watchdog_trips
            else 'no heartbeat reached the station'
        )
        out.append(Clause('heartbeat', False, f'{why}: publish controller/heartbeat'))
    else:
        out.append(Clause('heartbeat', True, 'the watchdog was fed throughout'))
    out.append(
        Clause(
            'routing',
            subscribed,
            f'subscribed to {st.namespace}/routing/updates'
            if subscribed
            else f'nothing subscribed to {st.namespace}/routing/updates',
        )
    )

    def disposition(label):
        d = line.disposition(label)
        return (d.code, d.chute or d.station) if d else ('none', 'still on the line')

    left, right = st.chutes
    got = {lab: disposition(lab) for lab, _, _ in PARCELS}
    ok = got['K-LEFT'] == ('sorted', left) and got['K-RIGHT'] == ('sorted', right)
    out.append(
        Clause(
            'sorts',
            ok,
            f'K-LEFT (to {left}): {got["K-LEFT"][0]} at {got["K-LEFT"][1]}; '
            f'K-RIGHT (to {right}): {got["K-RIGHT"][0]} at {got["K-RIGHT"][1]}',
        )
    )
    missing = [
        lab
        for lab, _, _ in PARCELS
        if not {'label', 'result', 'destination_reached'} <= set(confirmations.get(lab, {}))
    ]
    out.append(
        Clause(
            'confirmations',
            not missing,
            'every parcel confirmed with label, result and destination_reached'
            if not missing
            else f'no complete confirmation on {st.namespace}/sort/confirmations for '
            + ', '.join(missing),
        )
    )
    code, where = got['K-NEXT']
    out.append(
        Clause(
            'passes on',
            code == 'sorted',
            f'K-NEXT (to the next station): {code} at {where}'
            + ('' if code == 'sorted' else " (confirm it with destination_reached 'straight')"),
        )
    )
    code, where = got['K-NONE']
    out.append(
        Clause('no request', code == 'no_destination', f'K-NONE (no request): {code} at {where}')
    )
    code, where = disposition(HELD_LABEL)
    out.append(
        Clause(
            'packml',
            code == 'not_executing',
            f'{HELD_LABEL} (to {left}, station {packml_state}): {code} at {where}'
            + ('' if code == 'not_executing' else " (confirm it with result 'not_executing')"),
        )
    )
    return out


__all__ = ['Clause', 'ContractReport', 'check_station_program']
