"""
Test your own controller, station program or WCS against the cell or a line.

``SorterCell`` (``harness``) is the simulation node in a private rclpy Context,
advanced in lock-step by the test; ``SorterLine`` (``line``) is a line of stations,
their programs and the warehouse node, advanced the same way (``lockstep`` holds what
they share: the slices, the waits and the report a failed wait gives). The pytest
plugin (``plugin``, registered as ``sorter_cell`` through the ``pytest11`` entry
point) gives them as the fixtures ``sorter_cell`` and ``sorter_line``, with
``sorter_controller`` adding this project's controller. Scenario files
(``scenario``, ``line_scenario``) describe a run, its faults and what must come of
it, for ``sorter scenario run`` and ``sorter scenario campaign`` (whose runs claim
their ROS domains through ``domains``); ``contract`` checks a station program
against the station-program contract.
"""

from sorter_cell.testing.contract import ContractReport, check_station_program
from sorter_cell.testing.harness import (
    ConfirmationRecord,
    OutcomeRecord,
    SorterCell,
    WaitTimedOut,
    pick_domain_id,
)
from sorter_cell.testing.line import LineDisposition, SorterLine

__all__ = [
    'ConfirmationRecord',
    'ContractReport',
    'LineDisposition',
    'OutcomeRecord',
    'SorterCell',
    'SorterLine',
    'WaitTimedOut',
    'check_station_program',
    'pick_domain_id',
]
