"""
What a cell and a line under test share: a private Context, lock-step time, waits that explain.

``LockStep`` owns the rclpy Context (initialised with the shipped params files, found
through ``sorter_ros.env.find_config_dir``), the executor that spins the simulation
with every node the test adds, the slice loop of ``run`` and ``run_until``, and the
report a wait that times out gives: simulated and wall time, the parcels inducted, on
the belt and out with their exits, the active faults and PackML state, and where the
recording is. ``SorterCell`` (``harness``) and ``SorterLine`` (``line``) fill in
what a cell or a line has of each.

``load_node_factory`` and ``make_user_nodes`` turn ``"module:callable"`` into the
user's nodes, for scenario files and the station-contract check alike.
"""

from __future__ import annotations

import importlib
import math
import os
import sys
from contextlib import contextmanager
from pathlib import Path

from sorter_ros.run_loop import (  # noqa: F401 (GRACE_S, SLICE_S, WaitTimedOut: as before)
    GRACE_S,
    SLICE_S,
    RunLoop,
    WaitTimedOut,
)


def pick_domain_id() -> int:
    """
    Return the ROS domain this process's cells use: ``ROS_DOMAIN_ID``, else one of 100-199.

    A test run should keep to a domain of its own so that concurrent runs (and any ROS
    graph on the machine) stay apart; above 232 Fast DDS fails, so the default is
    taken from the process id in 100-199.
    """
    value = os.environ.get('ROS_DOMAIN_ID', '').strip()
    if value.isdigit() and 0 <= int(value) <= 232:
        return int(value)
    return 100 + os.getpid() % 100


class LockStep(RunLoop):
    """
    The run loop of a cell or line under test: its own domain, and a report on a time-out.

    ``SorterCell`` and ``SorterLine`` fill in what a cell or a line has of each; the
    Context, the executor and the slice loop are ``sorter_ros.run_loop.RunLoop``'s.
    """

    what = 'the cell'

    def _start_context(
        self, domain_id: int | None, slice_s: float, grace_s: float | None, events: bool = False
    ) -> None:
        super()._start_context(
            pick_domain_id() if domain_id is None else domain_id, slice_s, grace_s, events=events
        )


# a parcel a test inducts without saying more (SorterCell.induct's defaults)
PARCEL_DEFAULTS = {'length': 0.4, 'width': 0.3, 'mass': 5.0, 'skew_deg': 0.0, 'y': 0.0}


def parcel_spec(label: str, length: float, width: float, mass: float, skew_deg: float, y: float):
    """Return the cell's ``ParcelSpec`` of a parcel a test inducts (see ``SorterCell.induct``)."""
    from sorter_sim.runtime.cell import ParcelSpec

    return ParcelSpec(length, width, mass, math.radians(skew_deg), y, label)


def exits_text(records, limit: int = 12) -> str:
    """Return ``label exit at t`` for the first ``limit`` of (label, exit, t) records."""
    parts = [f'{label or "(no label)"} {exit} at {t:.3f} s' for label, exit, t in records[:limit]]
    if len(records) > limit:
        parts.append(f'... {len(records) - limit} more')
    return ', '.join(parts) or 'none'


# ---------------------------------------------------------------------- user nodes
class FactoryError(ValueError):
    """A ``module:callable`` that cannot be used: the message says what is wrong."""


@contextmanager
def _importable_from(folder):
    added = folder is not None and str(folder) not in sys.path
    if added:
        sys.path.insert(0, str(folder))
    try:
        yield
    finally:
        if added:
            sys.path.remove(str(folder))


def load_node_factory(spec: str, folder: str | Path | None = None):
    """
    Return the callable ``"module:callable"`` names, importing the module from ``folder`` first.

    Parameters
    ----------
    spec : str
        ``module:callable`` (a dotted module, a dotted attribute path).
    folder : str or Path, optional
        A folder tried before ``sys.path`` (a scenario file's).

    Returns
    -------
    callable
        The factory.

    Raises
    ------
    FactoryError
        A malformed spec, a module that does not import, a name it does not have.

    """
    if not isinstance(spec, str) or spec.count(':') != 1 or not all(spec.split(':')):
        raise FactoryError(f'must be "module:callable", got {spec!r}')
    module_name, attr = spec.split(':')
    with _importable_from(folder):
        try:
            obj = importlib.import_module(module_name)
        except Exception as exc:  # noqa: BLE001 - any import error is the user's to see
            raise FactoryError(
                f'cannot import {module_name!r} (from {folder or "sys.path"}): '
                f'{type(exc).__name__}: {exc}'
            ) from None
    for part in attr.split('.'):
        if not hasattr(obj, part):
            raise FactoryError(f'{module_name!r} has no {attr!r}')
        obj = getattr(obj, part)
    if not callable(obj):
        raise FactoryError(f'{spec!r} is not callable')
    return obj


def make_user_nodes(factory, context, parameters: dict | None = None, **kwargs) -> list:
    """
    Call ``factory(context=..., parameter_overrides=[...], **kwargs)`` and return its nodes.

    ``use_sim_time`` is always among the overrides: a node under test runs on the
    simulation's clock (the test's), or it would run on the wall clock beside it.

    Parameters
    ----------
    factory : callable
        Returns a node or a list of nodes.
    context : rclpy.context.Context
        The simulation's.
    parameters : dict, optional
        Parameter overrides, name -> value.
    **kwargs
        More keyword arguments (``namespace`` for a station's program).

    Returns
    -------
    list of rclpy.node.Node
        The nodes.

    """
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    values = {'use_sim_time': True, **(parameters or {})}
    overrides = [Parameter(k, value=v) for k, v in values.items()]
    made = factory(context=context, parameter_overrides=overrides, **kwargs)
    nodes = list(made) if isinstance(made, (list, tuple)) else [made]
    if not nodes or not all(isinstance(n, Node) for n in nodes):
        for n in nodes:
            if isinstance(n, Node):
                n.destroy_node()
        raise FactoryError(f'{factory!r} must return a node or a list of nodes, got {made!r}')
    return nodes
