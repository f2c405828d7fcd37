"""
Scenario files: a run of the cell, its parcels, its faults, and what must come of it.

A scenario is a YAML file (read strictly, ``sorter_ros.strict_yaml``) with these
keys; every one is checked before anything runs, and a bad file is refused in one
line naming the key::

    name: stuck divert eye          # optional (default: the file's stem)
    duration: 20.0                  # simulated seconds, after the controller runs
    seed: 7                         # the generated stream's seed (a campaign varies it)
    cell: {belt_speed: 1.5}         # cell parameters over config/cell.yaml
    controller: {}                  # the project's controller and its parameters; false: none;
                                    # {node: "module:callable", parameters: {...}}: yours, in
                                    # this process, in lock-step; {command: [...]}: a process
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
      - {parcel: A-3, exit: jammed, cause: rail}  # what jammed it: rail, side wall,
                                               # parcel <id>, chute full
      - {no_mis_sort: true}                    # no confirmation mis-sorted or missed
      - {no_jam: true}                         # no parcel jammed
      - {throughput_at_least: 1500}            # parcels out per hour of the run
      - {at: 6.0, faults: [jam]}               # the cell's faults at that time, exactly
      - {at: 6.0, controller_state: fault}     # the controller's state at that time

``run_scenario`` runs one in this process (``SorterCell``) and returns a
``ScenarioResult``: each expectation with whether it held and why, and when one
did not, the state of the cell (``LockStep.explain``); ``junit_xml`` writes results
as a JUnit file a CI server reads.

The controller under test (``controller:``) is one of

- this project's controller: a mapping of its parameters (``{}``: as shipped);
- ``false``: none (a test of the cell alone, or of nodes started elsewhere);
- ``{node: "module:callable", parameters: {...}}``: the user's node(s), made in this
  process by ``callable(context=..., parameter_overrides=[...])`` (``use_sim_time``
  and the given parameters) and spun in lock-step with the cell: the module is
  imported from the scenario file's folder, else the directory the command runs in,
  else ``sys.path`` (``load_user_factory``). Runs of the
  same file give the same exits at the same simulated times;
- ``{command: [...], start_timeout: 30}``: a process the scenario starts in its own
  ROS domain (``ROS_DOMAIN_ID``), in the file's folder (``{python}`` in the command
  stands for the Python interpreter running the scenario); time starts once it has
  subscribed to ``/clock`` (within ``start_timeout`` wall seconds). It follows
  simulated time as any node on ``use_sim_time`` does: the cell advances a slice,
  publishes the clock and what it sensed, and waits until the graph has been quiet
  for ``COMMAND_GRACE_S`` of wall time; an answer that takes longer is taken in the
  next slice. On an idle machine runs repeat; a loaded one can move a command by a
  slice (5 ms). A slice that would trip the watchdog first waits up to
  ``COMMAND_HEARTBEAT_WAIT_S`` of wall time for the next heartbeat: a process starved
  of the core is late in wall time only, and a frozen one still trips at the same
  simulated moment. A process that ends early fails the run with its exit code.
"""

from __future__ import annotations

import re
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from sorter_cell.testing.lockstep import FactoryError, make_user_nodes
from sorter_cell.testing.scenario_types import (
    Check,
    ScenarioError,
    ScenarioResult,
    factory_problem,
    load_user_factory,
    module_problem,
    refuse_unknown,
)
from sorter_cell.testing.scenario_types import number as _number
from sorter_cell.testing.scenario_report import junit_xml, report, xml_safe  # noqa: F401
from sorter_ros.strict_yaml import StrictYamlError, read_yaml_file

TOP_KEYS = ('name', 'duration', 'seed', 'cell', 'controller', 'line', 'stream', 'faults', 'expect')
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
# what an outcome names as a jam's cause (runtime.cell_contacts.jam_cause, the line's
# full chute, a jam injected by a fault), or the parcel it jammed against
JAM_CAUSES = ('rail', 'side wall', 'chute full', 'injected', 'integration failed')
PARCEL_CAUSE = re.compile(r'parcel [0-9]{1,10}')
MAX_DURATION = 3600.0
COMMAND_GRACE_S = 0.002  # quiet that ends a slice with a controller in another process
COMMAND_HEARTBEAT_WAIT_S = 2.0  # wall s a slice waits for its late heartbeat (SorterCell)
COMMAND_STOP_S = 5.0  # wall s a command's process group has from SIGTERM to SIGKILL
BLOCKED_S = 1.0  # wall s a callback of the user's node may take before the result says so
NODE_KEYWORDS = ('context', 'parameter_overrides')  # what a node factory is called with
CONTROLLER_FORMS = (
    'false, a mapping of this project\'s controller\'s parameters, '
    '{node: "module:callable", parameters: {...}} or {command: [...]}'
)
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


@dataclass(frozen=True)
class ControllerSpec:
    """
    The controller under test (see the module).

    kind: ``project``, ``node`` or ``command``; params: the project's controller's or
    the node's parameters; factory: ``module:callable``; command: the process's
    arguments; start_timeout: wall seconds the process has to subscribe to /clock.
    """

    kind: str
    params: dict = field(default_factory=dict)
    factory: str = ''
    command: tuple = ()
    start_timeout: float = 30.0


@dataclass
class Scenario:
    """A checked scenario (see the module)."""

    name: str
    duration: float
    seed: int
    cell: dict
    controller: ControllerSpec | None
    parcels: list
    generated: dict
    faults: list
    expect: list
    path: str = ''
    line: dict | None = None  # a line scenario's stations, plan and programs (line_scenario)


# ---------------------------------------------------------------------- reading
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


def _parameter_values(values, key: str) -> dict:
    values = dict(_mapping(values, key))
    scalar = (bool, int, float, str)
    for name, v in values.items():
        ok = isinstance(v, scalar) or (
            isinstance(v, list) and v and all(isinstance(x, type(v[0])) for x in v)
        )
        if not isinstance(name, str) or not ok:
            raise ScenarioError(
                f'{key}.{name}: a parameter is a number, string, bool or a list of one '
                f'type, got {v!r}'
            )
    return values


def _check_controller_spec(ctl, folder, imports: bool = True) -> ControllerSpec | None:
    """Return the controller a scenario's ``controller:`` names (see the module)."""
    if ctl is False:
        return None
    if ctl is None:
        ctl = {}
    if not isinstance(ctl, dict):
        raise ScenarioError(f'controller must be {CONTROLLER_FORMS}, got {ctl!r}')
    if 'node' in ctl:
        refuse_unknown(ctl, ('node', 'parameters'), 'controller', ' with node')
        if not imports:
            problem = module_problem(ctl['node'], folder)
        else:
            try:
                problem = factory_problem(load_user_factory(ctl['node'], folder), NODE_KEYWORDS)
            except FactoryError as exc:
                problem = str(exc)
            problem = problem and f'{ctl["node"]!r} {problem}'
        if problem:
            raise ScenarioError(f'controller.node {problem}')
        params = _parameter_values(ctl.get('parameters'), 'controller.parameters')
        return ControllerSpec('node', params, factory=ctl['node'])
    if 'command' in ctl:
        refuse_unknown(ctl, ('command', 'start_timeout'), 'controller', ' with command')
        cmd = ctl['command']
        if not (isinstance(cmd, list) and cmd and all(isinstance(x, str) and x for x in cmd)):
            raise ScenarioError(
                f'controller.command must be a non-empty list of strings, got {cmd!r}'
            )
        for k, arg in enumerate(cmd):
            if '\0' in arg:  # no command line carries one; Popen would raise
                raise ScenarioError(
                    f'controller.command[{k}] {arg[:80]!r} holds a NUL byte (\\0), which '
                    'no command line can carry'
                )
        start = _number(ctl.get('start_timeout', 30.0), 'controller.start_timeout', 0.1, 600.0)
        return ControllerSpec('command', command=tuple(cmd), start_timeout=start)
    _check_controller(ctl)
    return ControllerSpec('project', dict(ctl))


def _check_controller(values: dict) -> None:
    from sorter_control.parameters import SCHEMA, config_from_values

    names = {s.name for s in SCHEMA}
    unknown = sorted(set(values) - names)
    if unknown:
        raise ScenarioError(
            f'controller: unknown parameter(s) {", ".join(unknown)} of this project\'s '
            f'controller (the forms: {CONTROLLER_FORMS})'
        )
    try:
        config_from_values({**{s.name: s.default for s in SCHEMA}, **values})
    except (TypeError, ValueError) as exc:
        raise ScenarioError(f'controller: {exc}') from None


def _parcel(k: int, entry, on_line: bool = False) -> dict:
    key = f'stream.parcels[{k}]'
    entry = _mapping(entry, key)
    keys = PARCEL_KEYS + (('destination',) if on_line else ())
    extra = sorted(set(entry) - set(keys))
    if extra:
        raise ScenarioError(
            f'{key}: unknown key(s) {", ".join(extra)} (allowed: {", ".join(keys)})'
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
    if 'destination' in entry:
        if not isinstance(entry['destination'], str) or not entry['destination']:
            raise ScenarioError(f'{key}.destination must be a destination of the sort plan')
        out['destination'] = entry['destination']
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


def _parcel_expectation(key: str, entry: dict, has_controller: bool) -> None:
    """Check a parcel's expectation: its label, and its exit, cause or result."""
    if not isinstance(entry['parcel'], str) or not entry['parcel']:
        raise ScenarioError(f'{key}.parcel must be a label (a non-empty string)')
    if 'exit' not in entry and 'result' not in entry:
        raise ScenarioError(f'{key} needs exit or result for parcel {entry["parcel"]!r}')
    if 'exit' in entry and entry['exit'] not in EXITS:
        raise ScenarioError(f'{key}.exit must be one of {", ".join(EXITS)}, got {entry["exit"]!r}')
    if 'cause' in entry:
        cause = entry['cause']
        if entry.get('exit') != 'jammed':
            raise ScenarioError(f'{key}.cause is a jam\'s: it needs exit: jammed')
        if not (isinstance(cause, str) and (cause in JAM_CAUSES or PARCEL_CAUSE.fullmatch(cause))):
            raise ScenarioError(
                f'{key}.cause must be what jams a parcel: one of {", ".join(JAM_CAUSES)} '
                f'or parcel <id>; got {cause!r}'
            )
    if 'result' in entry:
        if entry['result'] not in RESULTS:
            raise ScenarioError(
                f'{key}.result must be one of {", ".join(RESULTS)}, got {entry["result"]!r}'
            )
        if not has_controller:
            raise ScenarioError(f'{key}.result needs a controller (controller: false)')


def _expectation(k: int, entry, labels: set, controller: ControllerSpec | None) -> dict:
    has_controller = controller is not None
    key = f'expect[{k}]'
    entry = _mapping(entry, key)
    kinds = [x for x in EXPECT_KINDS if x in entry]
    if len(kinds) != 1:
        raise ScenarioError(f'{key} must have one of {", ".join(EXPECT_KINDS)}')
    kind = kinds[0]
    allowed = {
        'parcel': {'parcel', 'exit', 'result', 'cause'},
        'no_mis_sort': {'no_mis_sort'},
        'no_jam': {'no_jam'},
        'throughput_at_least': {'throughput_at_least'},
        'at': {'at', 'faults', 'controller_state'},
    }[kind]
    refuse_unknown(entry, allowed, key, f' with {kind}')
    if kind == 'parcel':
        _parcel_expectation(key, entry, has_controller)
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
            if controller is None or controller.kind != 'project':
                raise ScenarioError(
                    f"{key}.controller_state needs this project's controller (it reads its state)"
                )
    return dict(entry)


def check_scenario(doc, name: str = 'scenario', path: str = '', imports: bool = True) -> Scenario:
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
    imports : bool
        Import the user's modules and check their callables (False: only that each
        module can be found; a campaign checks its files so, and imports nothing).

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
    folder = Path(path).parent if path else None
    line = None
    if 'line' in doc:
        from sorter_cell.testing.line_scenario import check_line

        line = check_line(doc['line'], folder, imports)
        for key in ('controller', 'faults'):
            if key in doc:
                raise ScenarioError(
                    f'{key}: a line scenario gives each station\'s program in line.programs '
                    'and has no faults (allowed with line: name, duration, seed, cell, stream, '
                    'expect)'
                )
    controller = (
        None if line else _check_controller_spec(doc.get('controller', {}), folder, imports)
    )
    stream = _mapping(doc.get('stream'), 'stream')
    extra = sorted(set(stream) - {'parcels', 'generated'})
    if extra:
        raise ScenarioError(
            f'stream: unknown key(s) {", ".join(extra)} (allowed: parcels, generated)'
        )
    parcels_in = stream.get('parcels', [])
    if not isinstance(parcels_in, list):
        raise ScenarioError('stream.parcels must be a list')
    parcels = [_parcel(k, p, line is not None) for k, p in enumerate(parcels_in)]
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
    if generated and line:
        raise ScenarioError('stream.generated: a line scenario lists its parcels (stream.parcels)')
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
    if line:
        from sorter_cell.testing.line_scenario import check_line_expectation

        expect = [check_line_expectation(k, e) for k, e in enumerate(expect_in)]
    else:
        expect = [_expectation(k, e, set(labels), controller) for k, e in enumerate(expect_in)]
    return Scenario(
        title, duration, seed, cell, controller, parcels, generated, faults, expect, path, line
    )


def load_scenario(path: str | Path, imports: bool = True) -> Scenario:
    """
    Read and check a scenario file.

    Parameters
    ----------
    path : str or Path
        The file.
    imports : bool
        Import the user's modules (see ``check_scenario``).

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
        return check_scenario(doc, p.stem, str(p), imports)
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
    from sorter_ros.topic_recorder import record_the_domain

    wall0 = time.perf_counter()
    res = ScenarioResult(sc.name, record=record or '')
    if sc.line is not None:
        from sorter_cell.testing.line_scenario import run_line_scenario

        return run_line_scenario(sc, res, record, domain_id)
    params = {**sc.cell, **sc.generated, 'seed': sc.seed if seed is None else seed}
    if sc.generated:
        params['arrival'] = 'none'  # the stream starts once the controller runs
    spec = sc.controller
    command = spec is not None and spec.kind == 'command'
    timed: dict[int, Check] = {}
    with SorterCell(
        params,
        domain_id=domain_id,
        record=record,
        grace_s=COMMAND_GRACE_S if command else None,
        heartbeat_wait_s=COMMAND_HEARTBEAT_WAIT_S if command else 0.0,
    ) as cell:
        record_the_domain(cell, record)  # the controller's topics too, a process's included
        t0 = cell.t
        try:
            with _controller_running(cell, spec, sc, res.notes) as ctl:
                t0 = _play(sc, cell, ctl, timed)
                res.error = ctl.error if isinstance(ctl, _Process) else ''
        except (ScenarioError, FactoryError) as exc:
            res.error = f'controller: {exc}' if isinstance(exc, FactoryError) else str(exc)
            res.refused = isinstance(exc, FactoryError)
        res.sim_s = cell.t - t0
        res.outcomes = cell.outcomes
        res.confirmations = cell.confirmations
        res.state = cell.explain()
    for e in sc.expect:
        res.checks.append(timed.get(id(e)) or _check_end(e, res, sc))
    res.wall_s = time.perf_counter() - wall0
    return res


def _play(sc: Scenario, cell, ctl, timed: dict) -> float:
    """Run the scenario's timeline on ``cell``; return the time it started at."""
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
    return t0


@dataclass
class _Process:
    """A controller the scenario started as a process (``controller: {command: ...}``)."""

    proc: object
    error: str = ''


@contextmanager
def _controller_running(cell, spec: ControllerSpec | None, sc: Scenario, notes: list):
    """
    Start the scenario's controller in ``cell``; yield it (a node, a _Process or None).

    A callback of the user's node that blocks is said in ``notes``.
    """
    if spec is None:
        yield None
    elif spec.kind == 'project':
        yield cell.add_controller(spec.params)
    elif spec.kind == 'node':
        folder = Path(sc.path).parent if sc.path else None
        factory = load_user_factory(spec.factory, folder)
        try:
            made = make_user_nodes(factory, cell.context, spec.params)
        except FactoryError:
            raise
        except Exception as exc:  # noqa: BLE001 - the user's factory: what it raised is said
            what = str(exc).splitlines()[0][:200] if str(exc) else 'no message'
            raise FactoryError(
                f'node {spec.factory!r} raised {type(exc).__name__} making its node: {what}'
            ) from None
        for node in made:
            _time_callbacks(node, cell, notes)
        nodes = cell.add_node(made)
        yield nodes[0]
    else:
        with _command_running(cell, spec, sc) as proc:
            yield proc


def _time_callbacks(node, cell, notes: list) -> None:
    """
    Time each callback of the user's ``node``; one that blocks ``BLOCKED_S`` or more is noted.

    The cell waits for the node's callbacks in lock-step, so a callback that blocks
    stretches the run's wall time by as much (a 1 s scenario took 31.6 s for a 25 s
    sleep): the result says which callback, for how long and at what simulated time.
    """
    entities = [
        *((f'subscription to {e.topic_name}', e) for e in node.subscriptions),
        *((f'timer of {e.timer_period_ns / 1e9:g} s', e) for e in node.timers),
        *((f'service {e.srv_name}', e) for e in node.services),
    ]
    for what, entity in entities:
        entity.callback = _timed(entity.callback, f'{node.get_name()!r} {what}', cell, notes)


def _timed(callback, what: str, cell, notes: list):
    def timed(*args):
        t0 = time.perf_counter()
        try:
            return callback(*args)
        finally:
            took = time.perf_counter() - t0
            if took >= BLOCKED_S and len(notes) < 20:
                notes.append(
                    f'controller.node: the callback of {what[:160]} blocked for {took:.1f} s '
                    f'of wall time at t = {cell.t:.3f} s (the cell waits for it)'
                )

    return timed


@contextmanager
def _command_running(cell, spec: ControllerSpec, sc: Scenario):
    """Start the command in the cell's domain; time starts once it subscribes to /clock."""
    import os
    import subprocess
    import sys
    import tempfile

    env = dict(os.environ, ROS_DOMAIN_ID=str(cell.domain_id))
    before = cell.sim.count_subscribers('/clock')
    err = tempfile.TemporaryFile(mode='w+')
    try:
        proc = subprocess.Popen(
            [x.replace('{python}', sys.executable) for x in spec.command],
            cwd=str(Path(sc.path).parent) if sc.path else None,
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=err,
            start_new_session=True,  # a process group of its own, ended whole with the run
        )
    except OSError as exc:
        err.close()
        raise ScenarioError(f'controller.command cannot start: {exc}') from None
    handle = _Process(proc)
    try:
        deadline = time.monotonic() + spec.start_timeout
        while cell.sim.count_subscribers('/clock') <= before:
            if proc.poll() is not None or time.monotonic() > deadline:
                raise ScenarioError(_command_problem(proc, err, spec, 'before it subscribed'))
            cell.spin_idle()
            time.sleep(0.01)
        yield handle
        if proc.poll() is not None:
            handle.error = _command_problem(proc, err, spec, f'at t = {cell.t:.3f} s')
    finally:
        _end_group(proc)
        err.close()


def _end_group(proc) -> None:
    """
    End the command's process group: SIGTERM, then SIGKILL to whatever is left of it.

    The group is the command and every process it started (that did not leave it with
    setsid): a grandchild that ignores SIGTERM, or outlives a command that
    ended by itself, is ended with it.
    """
    import os
    import signal
    import subprocess

    def signal_group(sig) -> None:
        try:
            os.killpg(proc.pid, sig)
        except (ProcessLookupError, PermissionError):
            pass  # the group is gone

    signal_group(signal.SIGTERM)
    try:
        proc.wait(timeout=COMMAND_STOP_S)
    except subprocess.TimeoutExpired:
        pass
    # the leader may have ended at once; its descendants are given the same grace
    deadline = time.monotonic() + COMMAND_STOP_S
    while _group_alive(proc.pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    signal_group(signal.SIGKILL)
    proc.wait()


def _group_alive(pgid: int) -> bool:
    """Whether any process of group ``pgid`` is still running (not a zombie)."""
    import os

    for entry in os.listdir('/proc'):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f'/proc/{entry}/stat').read_text()
        except OSError:
            continue
        fields = stat.rsplit(')', 1)[-1].split()
        if fields[0] != 'Z' and int(fields[2]) == pgid:
            return True
    return False


def _command_problem(proc, err, spec: ControllerSpec, when: str) -> str:
    err.seek(0)
    tail = (err.read().strip().splitlines() or ['no output'])[-1][:300]
    rc = proc.poll()
    if rc is None:
        return (
            f'controller.command {spec.command[0]!r} did not subscribe to /clock within '
            f'{spec.start_timeout:g} s (it must run on use_sim_time): {tail}'
        )
    return f'controller.command {spec.command[0]!r} ended with exit code {rc} {when}: {tail}'


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
    detail = 'got ' + ', '.join(got)
    if not ok:
        detail += '\n' + cell.explain()
    return Check(f'at {e["at"]:g} s: ' + ', '.join(parts), ok, detail)


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
        if 'cause' in e:
            have = repr(out.cause) if out else 'none'
            ok &= out is not None and out.cause == e['cause']
            parts.append(f'cause {e["cause"]!r}')
            got.append(f'cause {have}')
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


__all__ = [
    'Check',
    'ControllerSpec',
    'refuse_unknown',
    'Scenario',
    'ScenarioError',
    'ScenarioResult',
    'check_scenario',
    'junit_xml',
    'load_scenario',
    'report',
    'run_scenario',
]
