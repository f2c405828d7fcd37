"""
Test your own controller or WCS against the cell: the harness and the pytest plugin.

``SorterCell`` (``harness``) is the simulation node in a private rclpy Context,
advanced in lock-step by the test; the pytest plugin (``plugin``, registered as
``sorter_cell`` through the ``pytest11`` entry point) gives it as the fixture
``sorter_cell``, with ``sorter_controller`` adding this project's controller.
Scenario files (``scenario``) describe a run, its faults and what must come of
it, for ``sorter scenario run`` and ``sorter scenario campaign``.
"""

from sorter_cell.testing.harness import OutcomeRecord, SorterCell, WaitTimedOut, pick_domain_id

__all__ = ['OutcomeRecord', 'SorterCell', 'WaitTimedOut', 'pick_domain_id']
