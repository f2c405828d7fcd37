"""
Scenario files: a run of the cell, its parcels, its faults, and what must come of it.

A scenario is a YAML file (read strictly, ``sorter_ros.strict_yaml``) with these
keys; every one is checked before anything runs, and a bad file is refused in one
line naming the key::

    name: stuck divert eye          # optional (default: the file's stem)
    duration: 20.0                  # simulated seconds, after the controller runs
    seed: 7                         # the generated stream's seed (a campaign varies it)
    cell: {belt_speed: 1.5}         # cell parameters over config/cell.yaml
    controller: {}                  # the project's controller and its parameters; false: none
    stream:
      parcels:                      # explicit parcels, queued at the induction at `at`
        - {label: A-1, at: 0.0, length: 0.4, width: 0.3, mass: 5.0, skew_deg: 0, y: 0}
      generated:                    # the cell's own stream (its arrival parameters)
        arrival_gap: [1.45, 1.85]
        labels: [A, B, C]
    faults:                         # runtime.faults, at simulated times
      - {at: 5.0, fault: eye, sensor: pe_divert, mode: blocked}
    expect:
      - {parcel: A-1, exit: left}              # the cell's outcome for that label
      - {parcel: A-1, result: sorted}          # the controller's confirmation
      - {no_mis_sort: true}                    # no confirmation mis-sorted or missed
      - {no_jam: true}                         # no parcel jammed
      - {throughput_at_least: 1500}            # parcels out per hour of the run
      - {at: 6.0, faults: [jam]}               # the cell's faults at that time, exactly
      - {at: 6.0, controller_state: fault}     # the controller's state at that time

``run_scenario`` runs one in this process (``SorterCell``) and returns a
``ScenarioResult``: each expectation with whether it held and why; ``junit_xml``
writes results as a JUnit file a CI server reads.
"""

from __future__ import annotations

import math
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from sorter_ros.strict_yaml import StrictYamlError, read_yaml_file

TOP_KEYS = ('name', 'duration', 'seed', 'cell', 'controller', 'stream', 'faults', 'expect')
PARCEL_KEYS = ('label', 'at', 'length', 'width', 'mass', 'skew_deg', 'y')
EXITS = ('left', 'right', 'straight', 'jammed')
RESULTS = (
    'sorted',
    'rejected',
    'gap_too_short',
    'cannot_divert',
    'late',
    'fault',
    'mis-sorted',
    'missed',
    'aborted',
)
EXPECT_KINDS = ('parcel', 'no_mis_sort', 'no_jam', 'throughput_at_least', 'at')
MAX_DURATION = 3600.0
GENERATED_KEYS = (
    'arrival',
    'arrival_gap',
    'arrival_rate',
    'labels',
    'label_pattern',
    'parcel_A',
    'parcel_B',
    'parcel_m',
    'parcel_phi0_deg',
    'parcel_y0',
)


class ScenarioError(ValueError):
    """A scenario file that cannot run: the message names the key and what is allowed."""


@dataclass
class Scenario:
    """A checked scenario (see the module)."""

    name: str
    duration: float
    seed: int
    cell: dict
    controller: dict | None
    parcels: list
    generated: dict
    faults: list
    expect: list
    path: str = ''


@dataclass
class Check:
    """One expectation and how the run met it."""

    text: str
    passed: bool
    detail: str = ''


@dataclass
class ScenarioResult:
    """What a scenario's run gave: the checks, the outcomes, the times."""

    name: str
    checks: list = field(default_factory=list)
    outcomes: list = field(default_factory=list)
    confirmations: list = field(default_factory=list)
    sim_s: float = 0.0
    wall_s: float = 0.0
    record: str = ''
    error: str = ''

    @property
    def passed(self) -> bool:
        return not self.error and all(c.passed for c in self.checks)


# ---------------------------------------------------------------------- reading
def _number(value, key: str, lo: float = -math.inf, hi: float = math.inf) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ScenarioError(f'{key} must be a finite number, got {value!r}')
    if not lo <= value <= hi:
        raise ScenarioError(f'{key} must be in [{lo:g}, {hi:g}], got {value!r}')
    return float(value)


def _mapping(value, key: str) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise ScenarioError(f'{key} must be a mapping, got {type(value).__name__}')
    return value


def _check_cell(cell: dict, generated: dict, seed: int) -> None:
    from sorter_sim.runtime.params import CellParams, ParamError

    try:
        CellParams.defaults().with_changes({**cell, **generated, 'seed': seed}, runtime=False)
    except ParamError as exc:
        raise ScenarioError(f'cell: {exc}') from None
    except (TypeError, ValueError) as exc:
        raise ScenarioError(f'cell: {exc}') from None


def _check_controller(values: dict) -> None:
    from sorter_control.parameters import SCHEMA, config_from_values

    names = {s.name for s in SCHEMA}
    unknown = sorted(set(values) - names)
    if unknown:
        raise ScenarioError(f'controller: unknown parameter(s) {", ".join(unknown)}')
    try:
        config_from_values({**{s.name: s.default for s in SCHEMA}, **values})
    except (TypeError, ValueError) as exc:
        raise ScenarioError(f'controller: {exc}') from None


def _parcel(k: int, entry) -> dict:
    key = f'stream.parcels[{k}]'
    entry = _mapping(entry, key)
    extra = sorted(set(entry) - set(PARCEL_KEYS))
    if extra:
        raise ScenarioError(
            f'{key}: unknown key(s) {", ".join(extra)} (allowed: {", ".join(PARCEL_KEYS)})'
        )
    if not isinstance(entry.get('label'), str) or not entry['label']:
        raise ScenarioError(f'{key}.label must be a non-empty string')
    from sorter_sim.model.description import label_problem

    if label_problem(entry['label']):
        raise ScenarioError(f'{key}.label: {label_problem(entry["label"])}')
    out = {'label': entry['label'], 'at': _number(entry.get('at', 0.0), f'{key}.at', 0.0)}
    for name, default in (
        ('length', 0.4),
        ('width', 0.3),
        ('mass', 5.0),
        ('skew_deg', 0.0),
        ('y', 0.0),
    ):
        out[name] = _number(entry.get(name, default), f'{key}.{name}')
    return out


def _fault(k: int, entry) -> dict:
    from sorter_sim.runtime.faults import check_fault
    from sorter_sim.runtime.params import ParamError

    key = f'faults[{k}]'
    entry = dict(_mapping(entry, key))
    if 'fault' not in entry:
        raise ScenarioError(f'{key}.fault is missing')
    at = _number(entry.pop('at', 0.0), f'{key}.at', 0.0)
    name = entry.pop('fault')
    try:
        args = check_fault(str(name), entry)
    except ParamError as exc:
        raise ScenarioError(f'{key}: {exc}') from None
    return {'at': at, 'fault': str(name), 'args': args}


def _expectation(k: int, entry, labels: set, has_controller: bool) -> dict:
    key = f'expect[{k}]'
    entry = _mapping(entry, key)
    kinds = [x for x in EXPECT_KINDS if x in entry]
    if len(kinds) != 1:
        raise ScenarioError(f'{key} must have one of {", ".join(EXPECT_KINDS)}')
    kind = kinds[0]
    allowed = {
        'parcel': {'parcel', 'exit', 'result'},
        'no_mis_sort': {'no_mis_sort'},
        'no_jam': {'no_jam'},
        'throughput_at_least': {'throughput_at_least'},
        'at': {'at', 'faults', 'controller_state'},
    }[kind]
    extra = sorted(set(entry) - allowed)
    if extra:
        raise ScenarioError(
            f'{key}: unknown key(s) {", ".join(extra)} with {kind} (allowed: '
            f'{", ".join(sorted(allowed))})'
        )
    if kind == 'parcel':
        if not isinstance(entry['parcel'], str) or not entry['parcel']:
            raise ScenarioError(f'{key}.parcel must be a label (a non-empty string)')
        if 'exit' not in entry and 'result' not in entry:
            raise ScenarioError(f'{key} needs exit or result for parcel {entry["parcel"]!r}')
        if 'exit' in entry and entry['exit'] not in EXITS:
            raise ScenarioError(
                f'{key}.exit must be one of {", ".join(EXITS)}, got {entry["exit"]!r}'
            )
        if 'result' in entry:
            if entry['result'] not in RESULTS:
                raise ScenarioError(
                    f'{key}.result must be one of {", ".join(RESULTS)}, got {entry["result"]!r}'
                )
            if not has_controller:
                raise ScenarioError(f'{key}.result needs a controller (controller: false)')
    elif kind in ('no_mis_sort', 'no_jam'):
        if entry[kind] is not True:
            raise ScenarioError(f'{key}.{kind} must be true')
        if kind == 'no_mis_sort' and not has_controller:
            raise ScenarioError(f'{key}.no_mis_sort needs a controller (controller: false)')
    elif kind == 'throughput_at_least':
        _number(entry[kind], f'{key}.{kind}', 0.0)
    else:
        _number(entry['at'], f'{key}.at', 0.0)
        if 'faults' not in entry and 'controller_state' not in entry:
            raise ScenarioError(f'{key} needs faults or controller_state at {entry["at"]}')
        if 'faults' in entry:
            faults = entry['faults']
            if not isinstance(faults, list) or not all(
                isinstance(f, str) and f in ('estop', 'jam', 'watchdog') for f in faults
            ):
                raise ScenarioError(
                    f'{key}.faults must be a list of estop, jam, watchdog, got {faults!r}'
                )
        if 'controller_state' in entry:
            from sorter_control.logic.faults import FAULT_STATES

            states = ('running', *FAULT_STATES)
            if entry['controller_state'] not in states:
                raise ScenarioError(
                    f'{key}.controller_state must be one of '
                    f'{", ".join(states)}, got {entry["controller_state"]!r}'
                )
            if not has_controller:
                raise ScenarioError(f'{key}.controller_state needs a controller')
    return dict(entry)


def check_scenario(doc, name: str = 'scenario', path: str = '') -> Scenario:
    """
    Return a checked ``Scenario`` from a parsed document.

    Parameters
    ----------
    doc : object
        The parsed YAML.
    name : str
        Its name when the document gives none.
    path : str
        Where it came from.

    Returns
    -------
    Scenario
        The scenario.

    Raises
    ------
    ScenarioError
        The first thing wrong, named by its key.

    """
    doc = _mapping(doc, 'the scenario')
    extra = sorted(set(doc) - set(TOP_KEYS))
    if extra:
        raise ScenarioError(f'unknown key(s) {", ".join(extra)} (allowed: {", ".join(TOP_KEYS)})')
    if 'duration' not in doc:
        raise ScenarioError('duration is missing (simulated seconds to run)')
    duration = _number(doc['duration'], 'duration', 0.0, MAX_DURATION)
    seed = doc.get('seed', 1)
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**31:
        raise ScenarioError(f'seed must be an integer in [0, 2^31), got {seed!r}')
    title = doc.get('name', name)
    if not isinstance(title, str) or not title.strip() or len(title) > 200:
        raise ScenarioError('name must be a non-empty string of at most 200 characters')
    cell = dict(_mapping(doc.get('cell'), 'cell'))
    for fixed in ('time_mode', 'seed'):
        if fixed in cell:
            raise ScenarioError(
                f'cell.{fixed} is set by the scenario runner (use seed: at the top)'
            )
    ctl = doc.get('controller', {})
    controller = None if ctl is False else dict(_mapping(ctl, 'controller'))
    if controller is not None:
        _check_controller(controller)
    stream = _mapping(doc.get('stream'), 'stream')
    extra = sorted(set(stream) - {'parcels', 'generated'})
    if extra:
        raise ScenarioError(
            f'stream: unknown key(s) {", ".join(extra)} (allowed: parcels, generated)'
        )
    parcels_in = stream.get('parcels', [])
    if not isinstance(parcels_in, list):
        raise ScenarioError('stream.parcels must be a list')
    parcels = [_parcel(k, p) for k, p in enumerate(parcels_in)]
    labels = [p['label'] for p in parcels]
    if len(set(labels)) != len(labels):
        raise ScenarioError('stream.parcels: labels must be unique')
    generated = dict(_mapping(stream.get('generated'), 'stream.generated'))
    extra = sorted(set(generated) - set(GENERATED_KEYS))
    if extra:
        raise ScenarioError(
            f'stream.generated: unknown key(s) {", ".join(extra)} (allowed: '
            f'{", ".join(GENERATED_KEYS)})'
        )
    if generated:
        generated.setdefault('arrival', 'gap')
    _check_cell(cell, generated, seed)
    faults_in = doc.get('faults', [])
    if not isinstance(faults_in, list):
        raise ScenarioError('faults must be a list')
    faults = [_fault(k, f) for k, f in enumerate(faults_in)]
    expect_in = doc.get('expect', [])
    if not isinstance(expect_in, list) or not expect_in:
        raise ScenarioError('expect must be a non-empty list (what must come of the run)')
    expect = [
        _expectation(k, e, set(labels), controller is not None) for k, e in enumerate(expect_in)
    ]
    return Scenario(
        title, duration, seed, cell, controller, parcels, generated, faults, expect, path
    )


def load_scenario(path: str | Path) -> Scenario:
    """
    Read and check a scenario file.

    Parameters
    ----------
    path : str or Path
        The file.

    Returns
    -------
    Scenario
        The scenario.

    Raises
    ------
    ScenarioError
        Unreadable, not strict YAML, or a bad key: one line, the file and the key.

    """
    p = Path(path)
    try:
        doc = read_yaml_file(p, 'scenario')
        return check_scenario(doc, p.stem, str(p))
    except StrictYamlError as exc:
        raise ScenarioError(str(exc)) from None
    except ScenarioError as exc:
        raise ScenarioError(f'{p}: {exc}') from None


# ---------------------------------------------------------------------- running
def _timeline(sc: Scenario) -> list:
    """Everything that happens at a time: inducts, faults, timed checks, in order."""
    items = [(p['at'], 0, 'induct', p) for p in sc.parcels]
    items += [(f['at'], 1, 'fault', f) for f in sc.faults]
    items += [(e['at'], 2, 'check', e) for e in sc.expect if 'at' in e]
    return sorted(items, key=lambda x: (x[0], x[1]))


def run_scenario(
    sc: Scenario, record: str | None = None, seed: int | None = None, domain_id: int | None = None
) -> ScenarioResult:
    """
    Run a scenario in this process and check its expectations.

    Parameters
    ----------
    sc : Scenario
        The scenario.
    record : str, optional
        An MCAP file: everything the cell publishes, as evidence.
    seed : int, optional
        The stream's seed instead of the scenario's.
    domain_id : int, optional
        The ROS domain.

    Returns
    -------
    ScenarioResult
        The checks and what happened.

    """
    from sorter_cell.testing.harness import SorterCell

    wall0 = time.perf_counter()
    res = ScenarioResult(sc.name, record=record or '')
    params = {**sc.cell, **sc.generated, 'seed': sc.seed if seed is None else seed}
    if sc.generated:
        params['arrival'] = 'none'  # the stream starts once the controller runs
    if record:
        params['record_path'] = str(record)
    timed: dict[int, Check] = {}
    with SorterCell(params, domain_id=domain_id) as cell:
        ctl = cell.add_controller(sc.controller) if sc.controller is not None else None
        if sc.generated:
            cell.set_params(arrival=sc.generated['arrival'])
        t0 = cell.t
        for at, _, kind, item in _timeline(sc):
            if at > sc.duration:
                break
            cell.run(max(0.0, t0 + at - cell.t))
            if kind == 'induct':
                cell.induct(
                    item['label'],
                    length=item['length'],
                    width=item['width'],
                    mass=item['mass'],
                    skew_deg=item['skew_deg'],
                    y=item['y'],
                )
            elif kind == 'fault':
                cell.inject(item['fault'], **item['args'])
            else:
                timed[id(item)] = _check_at(item, cell, ctl)
        cell.run(max(0.0, t0 + sc.duration - cell.t))
        res.sim_s = cell.t - t0
        res.outcomes = cell.outcomes
        res.confirmations = cell.confirmations
    for e in sc.expect:
        res.checks.append(timed.get(id(e)) or _check_end(e, res, sc))
    res.wall_s = time.perf_counter() - wall0
    return res


def _check_at(e: dict, cell, ctl) -> Check:
    parts, ok, got = [], True, []
    if 'faults' in e:
        want = sorted(e['faults'])
        have = sorted(cell.sim.cell.faults)
        ok &= want == have
        parts.append(f'faults {want}')
        got.append(f'faults {have}')
    if 'controller_state' in e:
        have = ctl.logic.state if ctl is not None and ctl.logic is not None else 'none'
        ok &= have == e['controller_state']
        parts.append(f'controller {e["controller_state"]}')
        got.append(f'controller {have}')
    return Check(f'at {e["at"]:g} s: ' + ', '.join(parts), ok, 'got ' + ', '.join(got))


def _check_end(e: dict, res: ScenarioResult, sc: Scenario) -> Check:
    if 'parcel' in e:
        label = e['parcel']
        out = next((o for o in res.outcomes if o.label == label), None)
        conf = next((c for c in res.confirmations if c.get('label') == label), None)
        parts, ok, got = [], True, []
        if 'exit' in e:
            have = out.exit if out else 'none (still on the belt or never inducted)'
            ok &= out is not None and out.exit == e['exit']
            parts.append(f'exit {e["exit"]}')
            got.append(f'exit {have}')
        if 'result' in e:
            have = conf.get('result') if conf else 'none'
            ok &= conf is not None and conf.get('result') == e['result']
            parts.append(f'result {e["result"]}')
            got.append(f'result {have}')
        return Check(f'parcel {label}: ' + ', '.join(parts), ok, 'got ' + ', '.join(got))
    if 'no_mis_sort' in e:
        bad = [
            c['label'] for c in res.confirmations if c.get('result') in ('mis-sorted', 'missed')
        ]
        return Check('no mis-sort', not bad, f'mis-sorted or missed: {", ".join(bad) or "none"}')
    if 'no_jam' in e:
        bad = [o.label for o in res.outcomes if o.jammed]
        return Check('no jam', not bad, f'jammed: {", ".join(bad) or "none"}')
    want = float(e['throughput_at_least'])
    out = sum(1 for o in res.outcomes if not o.jammed)
    have = 3600.0 * out / res.sim_s if res.sim_s > 0 else 0.0
    return Check(
        f'throughput at least {want:g} pcs/h',
        have >= want,
        f'{have:.0f} pcs/h ({out} parcels out in {res.sim_s:.1f} s)',
    )


# ---------------------------------------------------------------------- reporting
def junit_xml(results: list, suite: str = 'sorter scenarios') -> str:
    """
    Return results as a JUnit XML document (one testcase per expectation).

    Parameters
    ----------
    results : list of ScenarioResult
        The runs.
    suite : str
        The test suite's name.

    Returns
    -------
    str
        The XML.

    """
    root = ET.Element('testsuites', name=suite)
    for r in results:
        failures = sum(not c.passed for c in r.checks) + bool(r.error)
        ts = ET.SubElement(
            root,
            'testsuite',
            name=r.name,
            tests=str(len(r.checks) + bool(r.error)),
            failures=str(failures),
            errors='0',
            time=f'{r.wall_s:.3f}',
        )
        if r.error:
            case = ET.SubElement(ts, 'testcase', classname=r.name, name='runs', time='0')
            ET.SubElement(case, 'failure', message=r.error).text = r.error
        for c in r.checks:
            case = ET.SubElement(ts, 'testcase', classname=r.name, name=c.text, time='0')
            if not c.passed:
                ET.SubElement(case, 'failure', message=c.detail).text = c.detail + (
                    f'\nevidence: {r.record}' if r.record else ''
                )
        if r.record:
            ET.SubElement(ts, 'system-out').text = f'recording: {r.record}'
    ET.indent(root)
    return ET.tostring(root, encoding='unicode', xml_declaration=True) + '\n'


def report(r: ScenarioResult) -> str:
    """
    Return a run's result as text: one line per expectation.

    Parameters
    ----------
    r : ScenarioResult
        The run.

    Returns
    -------
    str
        The lines.

    """
    lines = [
        f'scenario {r.name}: {"passed" if r.passed else "FAILED"} '
        f'({r.sim_s:.1f} s simulated in {r.wall_s:.1f} s)'
    ]
    if r.error:
        lines.append(f'  [error] {r.error}')
    for c in r.checks:
        lines.append(f'  [{"ok" if c.passed else "FAIL"}] {c.text}: {c.detail}')
    if r.record:
        lines.append(f'  recording: {r.record}')
    return '\n'.join(lines)


__all__ = [
    'Check',
    'Scenario',
    'ScenarioError',
    'ScenarioResult',
    'check_scenario',
    'junit_xml',
    'load_scenario',
    'report',
    'run_scenario',
]
