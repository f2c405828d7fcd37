"""
The pytest plugin ``sorter_cell``: the cell and the controller as fixtures.

Installed with the package (entry point ``pytest11``), so any project with
sorter_cell installed can write::

    def test_my_controller_sorts(sorter_cell):
        node = MyController(context=sorter_cell.context)
        sorter_cell.add_node(node)
        sorter_cell.induct('A-1', length=0.4)
        sorter_cell.run(5.0)
        assert sorter_cell.outcome('A-1').exit == 'left'

Fixtures (function scope, a fresh Context each):

- ``sorter_cell``: a ``sorter_cell.testing.SorterCell``; its parameters over
  config/cell.yaml come from the marker ``@pytest.mark.sorter_cell(params={...})``.
- ``sorter_controller``: this project's controller node started in that cell and
  running (parameters from ``@pytest.mark.sorter_controller(params={...})``).
- ``sorter_line``: a ``sorter_cell.testing.SorterLine`` (``@pytest.mark.sorter_line(
  stations=N, plan={...}, params={...})``): N stations, each with this project's
  program unless the test replaces it, and the warehouse node.

A test that uses one of them and fails gets the state of the cell or line in its
report (a section ``sorter``, in the terminal and in JUnit's failure text): the
simulated and wall time, the parcels so far, the faults, the PackML state, and the
recording of the test (every topic on its domain, the test's own nodes' too, as
``ros2 bag record -a`` would: ``sorter_ros.topic_recorder``), kept under the test's
``tmp_path`` by ``--sorter-record``
(``failed``, the default: kept when the test fails; ``all``; ``none``: not recorded).

Each test's ``sorter_cell`` or ``sorter_line`` is on a ROS domain of its own, claimed
for it on the host while it runs with the lock campaigns use
(``sorter_cell.testing.domains``: ``--sorter-domains A-B``, else
``SORTER_TEST_DOMAINS``, else 100-139): two xdist workers, or two runs, never share
a graph, whatever ``ROS_DOMAIN_ID`` the shell exports. That variable is taken only
where the test asks for it, to meet nodes started outside the test: the marker
``@pytest.mark.sorter_ros_domain_id`` or the option ``--sorter-ros-domain-id``.

``--sorter-station-contract MODULE:FACTORY`` adds the station-program contract's
conformance test for that factory to the run (``sorter_cell.testing.contract``).

Nothing here imports ROS until a fixture is used, so the plugin costs a pytest
run that does not use it nothing.
"""

from __future__ import annotations

import os
from contextlib import contextmanager
from pathlib import Path

import pytest


RECORD_MODES = ('failed', 'all', 'none')
HARNESS_FIXTURES = ('sorter_cell', 'sorter_line')


def pytest_addoption(parser):
    """Add ``--sorter-record``, the domain options and ``--sorter-station-contract``."""
    group = parser.getgroup('sorter_cell')
    group.addoption(
        '--sorter-record',
        default='failed',
        choices=RECORD_MODES,
        help="record each sorter_cell/sorter_line test under its tmp_path: keep the "
        "recording of a failed test (failed, the default), of every test (all), or none",
    )
    group.addoption(
        '--sorter-domains',
        metavar='A-B',
        default=None,
        help='the ROS domains the fixtures claim one of for each test, held on this host '
        'while it runs (default: SORTER_TEST_DOMAINS, else 100-139)',
    )
    group.addoption(
        '--sorter-ros-domain-id',
        action='store_true',
        default=False,
        help="put every test's cell or line on the shell's ROS_DOMAIN_ID instead of a "
        'domain of its own (to meet nodes started outside the tests)',
    )
    group.addoption(
        '--sorter-station-contract',
        metavar='MODULE:FACTORY',
        default=None,
        help='check a station program against the line\'s station-program contract',
    )


def pytest_configure(config):
    """Declare the plugin's markers; refuse a bad ``--sorter-domains`` before any test runs."""
    from sorter_cell.testing.domains import fixture_domains

    try:
        fixture_domains(config.getoption('--sorter-domains', None))
    except ValueError as exc:
        raise pytest.UsageError(str(exc)) from None
    config.addinivalue_line(
        'markers',
        "sorter_ros_domain_id: this test's cell or line on the shell's ROS_DOMAIN_ID "
        '(to meet nodes started outside the test), not on a domain of its own',
    )
    config.addinivalue_line(
        'markers',
        'sorter_cell(params, events): cell parameters for the sorter_cell fixture; '
        'events=False: rclpy\'s single-threaded executor (the default is the events executor)',
    )
    config.addinivalue_line(
        'markers',
        'sorter_controller(params): controller parameters for the sorter_controller fixture',
    )
    config.addinivalue_line(
        'markers',
        'sorter_line(stations, plan, params, programs): the sorter_line fixture\'s line',
    )


def _module_file(module_name: str) -> Path | None:
    """Return the file ``module_name`` imports from (the directory pytest runs in first)."""
    import importlib.util
    import sys

    here = str(Path.cwd())
    added = here not in sys.path
    if added:
        sys.path.insert(0, here)
    try:
        found = importlib.util.find_spec(module_name)
    except (ImportError, ValueError):
        found = None
    finally:
        if added:
            sys.path.remove(here)
    origin = getattr(found, 'origin', None)
    return Path(origin) if origin and origin.endswith('.py') else None


def pytest_collection_modifyitems(session, config, items):
    """
    With ``--sorter-station-contract``: add the contract's check of that program.

    Its test id names the program's file, as a test of that file's would
    (``station_program.py::station_contract[station_program:StationProgram]``); a module
    that is not found keeps the bare id, and the check says why it fails.
    """
    spec = config.getoption('--sorter-station-contract', None)
    if not spec:
        return
    name = f'station_contract[{spec}]'
    source = _module_file(spec.split(':')[0]) if spec.count(':') == 1 else None
    if source is None:
        items.append(StationContractItem.from_parent(session, name=name, spec=spec))
        return
    try:
        where = source.relative_to(config.rootpath).as_posix()
    except ValueError:
        where = str(source)
    items.append(
        StationContractItem.from_parent(
            session, name=name, spec=spec, path=source, nodeid=f'{where}::{name}'
        )
    )


class StationContractFailed(AssertionError):
    """A station program that breaks the contract; the message names each clause."""


class StationContractItem(pytest.Item):
    """The station-program contract's check, as a test of its own (``contract``)."""

    def __init__(self, *, spec: str, **kwargs):
        super().__init__(**kwargs)
        self.spec = spec

    def runtest(self):
        from sorter_cell.testing.contract import check_station_program
        from sorter_cell.testing.lockstep import FactoryError, load_node_factory

        try:
            factory = load_node_factory(self.spec, Path.cwd())
        except FactoryError as exc:
            raise StationContractFailed(f'--sorter-station-contract {exc}') from None
        report = check_station_program(factory)
        report.program = self.spec
        if not report:
            raise StationContractFailed(str(report))

    def repr_failure(self, excinfo):
        if isinstance(excinfo.value, StationContractFailed):
            return str(excinfo.value)
        return super().repr_failure(excinfo)

    def reportinfo(self):
        return self.path, None, f'station contract of {self.spec}'


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    """Add the cell's or line's state to a failed test's report, while it still runs."""
    outcome = yield
    rep = outcome.get_result()
    setattr(item, f'sorter_rep_{rep.when}', rep)
    if not rep.failed or rep.when != 'call':
        return
    funcargs = getattr(item, 'funcargs', {})
    harness = next((funcargs[n] for n in HARNESS_FIXTURES if n in funcargs), None)
    if harness is None:
        return
    text = harness.explain('the state when the test failed:')
    longrepr = rep.longrepr
    if hasattr(longrepr, 'addsection'):
        # the failure's own text carries it, so JUnit's <failure> has it too; not also
        # among the report's sections, which the terminal prints after it a second time
        longrepr.addsection('sorter', text)
    else:
        rep.sections.append(('sorter', text))


def _record_path(request, tmp_path, name: str) -> str:
    mode = request.config.getoption('--sorter-record', 'failed')
    return '' if mode == 'none' else str(tmp_path / f'{name}.mcap')


def _drop_recording_if_passed(request, path: str) -> None:
    """``--sorter-record=failed``: a passed test's recording is not kept."""
    if not path or request.config.getoption('--sorter-record', 'failed') != 'failed':
        return
    reps = [getattr(request.node, f'sorter_rep_{w}', None) for w in ('setup', 'call')]
    if all(r is not None and r.passed for r in reps):
        Path(path).unlink(missing_ok=True)


def _marker_params(request, name: str) -> dict:
    marker = request.node.get_closest_marker(name)
    if marker is None:
        return {}
    params = marker.kwargs.get('params', marker.args[0] if marker.args else {})
    if not isinstance(params, dict):
        raise pytest.UsageError(
            f'@pytest.mark.{name}(params=...) takes a dict of parameters, got {params!r}'
        )
    return params


@contextmanager
def _test_domain(request):
    """
    Yield the ROS domain of a test's cell or line, claimed for it alone while it runs.

    The shell's ``ROS_DOMAIN_ID`` only where the test asks for it (the marker
    ``sorter_ros_domain_id``, the option ``--sorter-ros-domain-id``).
    """
    from sorter_cell.testing.domains import DomainClaim, fixture_domains

    if request.config.getoption('--sorter-ros-domain-id', False) or (
        request.node.get_closest_marker('sorter_ros_domain_id') is not None
    ):
        value = os.environ.get('ROS_DOMAIN_ID', '').strip()
        if not (value.isdigit() and 0 <= int(value) <= 232):
            raise pytest.UsageError(
                'sorter_ros_domain_id / --sorter-ros-domain-id: ROS_DOMAIN_ID must be set '
                f'to a ROS domain 0-232, got {value!r}'
            )
        yield int(value)
        return
    with DomainClaim(fixture_domains(request.config.getoption('--sorter-domains', None))) as d:
        yield d


@pytest.fixture
def sorter_cell(request, tmp_path):
    """Return the simulation node in a private Context, in lock-step (``SorterCell``)."""
    from sorter_cell.testing.harness import SorterCell
    from sorter_ros.topic_recorder import record_the_domain

    record = _record_path(request, tmp_path, 'sorter_cell')
    marker = request.node.get_closest_marker('sorter_cell')
    events = bool(marker.kwargs.get('events', True)) if marker is not None else True
    with _test_domain(request) as domain:
        cell = SorterCell(
            _marker_params(request, 'sorter_cell'), domain_id=domain, record=record, events=events
        )
        try:
            record_the_domain(cell, record)
            yield cell
        finally:
            cell.close()
            _drop_recording_if_passed(request, record)


@pytest.fixture
def sorter_line(request, tmp_path):
    """Return a line: stations, their programs and the warehouse, in lock-step (``SorterLine``)."""
    from sorter_cell.testing.line import SorterLine
    from sorter_ros.topic_recorder import record_the_domain

    marker = request.node.get_closest_marker('sorter_line')
    kwargs = dict(marker.kwargs) if marker is not None else {}
    unknown = sorted(set(kwargs) - {'stations', 'plan', 'params', 'programs'})
    if unknown:
        raise pytest.UsageError(
            f'@pytest.mark.sorter_line: unknown argument(s) {", ".join(unknown)} (allowed: '
            'stations, plan, params, programs)'
        )
    record = _record_path(request, tmp_path, 'sorter_line')
    with _test_domain(request) as domain:
        line = SorterLine(**kwargs, domain_id=domain, record=record)
        try:
            record_the_domain(line, record)
            yield line
        finally:
            line.close()
            _drop_recording_if_passed(request, record)


@pytest.fixture
def sorter_controller(sorter_cell, request):
    """Return this project's controller node, started in ``sorter_cell`` and running."""
    return sorter_cell.add_controller(_marker_params(request, 'sorter_controller'))
