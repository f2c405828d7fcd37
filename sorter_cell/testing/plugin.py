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

Nothing here imports ROS until a fixture is used, so the plugin costs a pytest
run that does not use it nothing.
"""

from __future__ import annotations

import pytest


def pytest_configure(config):
    """Declare the plugin's markers."""
    config.addinivalue_line(
        'markers', 'sorter_cell(params): cell parameters for the sorter_cell fixture'
    )
    config.addinivalue_line(
        'markers',
        'sorter_controller(params): controller parameters for the sorter_controller fixture',
    )


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


@pytest.fixture
def sorter_cell(request):
    """Return the simulation node in a private Context, in lock-step (``SorterCell``)."""
    from sorter_cell.testing.harness import SorterCell

    cell = SorterCell(_marker_params(request, 'sorter_cell'))
    try:
        yield cell
    finally:
        cell.close()


@pytest.fixture
def sorter_controller(sorter_cell, request):
    """Return this project's controller node, started in ``sorter_cell`` and running."""
    return sorter_cell.add_controller(_marker_params(request, 'sorter_controller'))
