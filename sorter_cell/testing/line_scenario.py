"""
Scenario files on a line: ``line: {stations: N, plan: {...}, programs: {k: ...}}``.

A scenario with ``line:`` runs a ``SorterLine`` instead of a single cell::

    name: my station program at S02
    duration: 20.0
    cell: {belt_speed: 1.5}            # every station's cell parameters
    line:
      stations: 3                      # 1-64
      plan: {D01: S01L, D02: S02L}     # destination -> chute (default D01 -> S01L, ...)
      programs: {2: "station_program:StationProgram"}   # station -> the user's program
    stream:
      parcels:
        - {label: A-1, at: 0.0, destination: D02}        # the warehouse's request
    expect:
      - {parcel: A-1, disposition: sorted, station: S02, chute: S02L}
      - {no_mis_sort: true}            # no parcel mis_sorted or lost
      - {no_jam: true}
      - {throughput_at_least: 1000}    # parcels off the line per hour

A program is ``module:callable`` (imported from the file's folder, else the directory
the command runs in), called with ``context=``, ``namespace=`` (``/S02``) and
``parameter_overrides=``; the other
stations run this project's program. A line scenario has no ``controller:``, no
generated stream and no faults; a parcel's ``destination`` is optional (none: its
disposition is ``no_destination``).
"""

from __future__ import annotations

import time

from sorter_cell.testing.lockstep import FactoryError
from sorter_cell.testing.scenario_types import (
    Check,
    ScenarioError,
    factory_problem,
    load_user_factory,
    module_problem,
    number,
    refuse_unknown,
)

LINE_KEYS = ('stations', 'plan', 'programs')
LINE_EXPECT_KEYS = ('parcel', 'disposition', 'station', 'chute')
LINE_EXPECT_KINDS = ('parcel', 'no_mis_sort', 'no_jam', 'throughput_at_least')
PROGRAM_KEYWORDS = ('context', 'namespace', 'parameter_overrides')  # a program is made with


def check_line(value, folder, imports: bool = True) -> dict:
    """
    Return a scenario's checked ``line:`` (stations, plan, programs).

    Parameters
    ----------
    value : object
        The ``line:`` mapping.
    folder : Path or None
        The scenario file's folder (programs are imported from it first, then from the
        directory the command runs in).
    imports : bool
        Import the programs' modules (False: only find them, as a campaign checks).

    """
    if not isinstance(value, dict):
        raise ScenarioError(f'line must be a mapping with {", ".join(LINE_KEYS)}, got {value!r}')
    refuse_unknown(value, LINE_KEYS, 'line')
    n = value.get('stations', 2)
    if isinstance(n, bool) or not (isinstance(n, int) and 1 <= n <= 64):
        raise ScenarioError(f'line.stations must be an integer in [1, 64], got {n!r}')
    plan = value.get('plan')
    if plan is not None and not (
        isinstance(plan, dict)
        and plan
        and all(isinstance(k, str) and isinstance(v, str) for k, v in plan.items())
    ):
        raise ScenarioError(f'line.plan must be a mapping destination -> chute, got {plan!r}')
    programs = value.get('programs') or {}
    if not isinstance(programs, dict):
        raise ScenarioError(
            f'line.programs must be a mapping station -> "module:callable", got {programs!r}'
        )
    for k, spec in programs.items():
        if isinstance(k, bool) or not (isinstance(k, int) and 1 <= k <= n):
            raise ScenarioError(f'line.programs: a station is a number in [1, {n}], got {k!r}')
        if not imports:
            problem = module_problem(spec, folder)
        else:
            try:
                problem = factory_problem(load_user_factory(spec, folder), PROGRAM_KEYWORDS)
            except FactoryError as exc:
                problem = str(exc)
            problem = problem and f'{spec!r} {problem}'
        if problem:
            raise ScenarioError(f'line.programs.{k} {problem}')
    return {'stations': n, 'plan': plan, 'programs': dict(programs)}


def check_line_expectation(k: int, entry) -> dict:
    """Return expectation ``k`` of a line scenario, checked (see the module)."""
    from sorter_control.wcs import DISPOSITIONS

    key = f'expect[{k}]'
    if not isinstance(entry, dict):
        raise ScenarioError(f'{key} must be a mapping')
    kinds = [x for x in LINE_EXPECT_KINDS if x in entry]
    if len(kinds) != 1:
        raise ScenarioError(f'{key} must have one of {", ".join(LINE_EXPECT_KINDS)} (on a line)')
    kind = kinds[0]
    allowed = set(LINE_EXPECT_KEYS) if kind == 'parcel' else {kind}
    refuse_unknown(entry, allowed, key, f' with {kind} on a line')
    if kind == 'parcel':
        if not isinstance(entry['parcel'], str) or not entry['parcel']:
            raise ScenarioError(f'{key}.parcel must be a label (a non-empty string)')
        if not set(entry) & {'disposition', 'station', 'chute'}:
            raise ScenarioError(
                f'{key} needs disposition, station or chute for {entry["parcel"]!r}'
            )
        if 'disposition' in entry and entry['disposition'] not in DISPOSITIONS:
            raise ScenarioError(
                f'{key}.disposition must be one of {", ".join(DISPOSITIONS)}, got '
                f'{entry["disposition"]!r}'
            )
        for name in ('station', 'chute'):
            if name in entry and not (isinstance(entry[name], str) and entry[name]):
                raise ScenarioError(f'{key}.{name} must be a name, got {entry[name]!r}')
    elif kind in ('no_mis_sort', 'no_jam'):
        if entry[kind] is not True:
            raise ScenarioError(f'{key}.{kind} must be true')
    else:  # the cell form's check, so .nan and .inf are refused alike
        number(entry[kind], f'{key}.{kind}', 0.0)
    return dict(entry)


def run_line_scenario(sc, result, record: str | None, domain_id: int | None):
    """
    Run a line scenario and check its expectations into ``result`` (a ``ScenarioResult``).

    Parameters
    ----------
    sc : Scenario
        With ``line``.
    result : ScenarioResult
        Filled in and returned.
    record : str, optional
        An MCAP file of the whole line.
    domain_id : int, optional
        The ROS domain.

    """
    from sorter_cell.testing.line import SorterLine
    from sorter_ros.topic_recorder import record_the_domain

    wall0 = time.perf_counter()
    folder = _folder(sc)
    line_spec = sc.line
    programs = {k: load_user_factory(v, folder) for k, v in line_spec['programs'].items()}
    with SorterLine(
        line_spec['stations'],
        plan=line_spec['plan'],
        params=sc.cell,
        programs=programs,
        domain_id=domain_id,
        record=record,
    ) as line:
        record_the_domain(line, record)  # the programs' and the warehouse's topics too
        t0 = line.t
        for p in sorted(sc.parcels, key=lambda p: p['at']):
            if p['at'] > sc.duration:
                break
            line.run(max(0.0, t0 + p['at'] - line.t))
            line.induct(
                p['label'],
                p.get('destination'),
                length=p['length'],
                width=p['width'],
                mass=p['mass'],
                skew_deg=p['skew_deg'],
                y=p['y'],
            )
        line.run(max(0.0, t0 + sc.duration - line.t))
        result.sim_s = line.t - t0
        result.dispositions = line.dispositions
        result.state = line.explain()
    for e in sc.expect:
        result.checks.append(Check(*_judge(e, result)))
    result.wall_s = time.perf_counter() - wall0
    return result


def _folder(sc):
    from pathlib import Path

    return Path(sc.path).parent if sc.path else None


def _judge(e: dict, r) -> tuple:
    """Return (text, passed, detail) of a line expectation against the dispositions."""
    disp = r.dispositions
    if 'parcel' in e:
        label = e['parcel']
        d = next((x for x in disp if x.label == label), None)
        want = {k: e[k] for k in ('disposition', 'station', 'chute') if k in e}
        have = {'disposition': d.code, 'station': d.station, 'chute': d.chute} if d else {}
        ok = d is not None and all(have[k] == v for k, v in want.items())
        text = f'parcel {label}: ' + ', '.join(f'{k} {v}' for k, v in want.items())
        got = ', '.join(f'{k} {have[k] or "-"}' for k in want) if d else 'no disposition yet'
        return text, ok, f'got {got}'
    if 'no_mis_sort' in e:
        bad = [f'{d.label} ({d.code})' for d in disp if d.code in ('mis_sorted', 'lost')]
        return 'no mis-sort', not bad, f'mis_sorted or lost: {", ".join(bad) or "none"}'
    if 'no_jam' in e:
        bad = [d.label for d in disp if d.code == 'jammed']
        return 'no jam', not bad, f'jammed: {", ".join(bad) or "none"}'
    want = float(e['throughput_at_least'])
    have = 3600.0 * len(disp) / r.sim_s if r.sim_s > 0 else 0.0
    return (
        f'throughput at least {want:g} pcs/h',
        have >= want,
        f'{have:.0f} pcs/h ({len(disp)} parcels off the line in {r.sim_s:.1f} s)',
    )
