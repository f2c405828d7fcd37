"""
The sorter PLC, with no ROS: its program and the parts it is made of, one per PLC concern.

- ``image``: the input image a scan reads, what it returns, edge detection;
- ``routing``: the routing table and its grammar;
- ``tracking``: the parcels on the belt, the photo-eyes, the scanner's labels;
- ``faults``: the controller's state and the supervision that raises faults;
- ``sequencing``: decisions, spacing and the diverter's outputs;
- ``config``: what the PLC is configured with;
- ``program``: ``SorterLogic``, the scan that runs them in order.
"""

from sorter_control.logic.config import ControllerConfig
from sorter_control.logic.faults import FAULT_STATES, STATES
from sorter_control.logic.image import (
    Command,
    Confirmation,
    DiverterState,
    Edge,
    EdgeDetector,
    InputImage,
    Reply,
    ScanOutput,
)
from sorter_control.logic.program import SorterLogic
from sorter_control.logic.routing import GRAMMAR, RoutingError, RoutingTable
from sorter_control.logic.tracking import (
    R_ABORTED,
    R_CANNOT,
    R_FAULT,
    R_NOT_EXECUTING,
    R_GAP,
    R_LATE,
    R_MISSED,
    R_MISSORT,
    R_REJECTED,
    R_SORTED,
    EyeState,
    Tracked,
)

__all__ = [
    "FAULT_STATES",
    "GRAMMAR",
    "R_ABORTED",
    "R_CANNOT",
    "R_FAULT",
    "R_NOT_EXECUTING",
    "R_GAP",
    "R_LATE",
    "R_MISSED",
    "R_MISSORT",
    "R_REJECTED",
    "R_SORTED",
    "STATES",
    "Command",
    "Confirmation",
    "ControllerConfig",
    "DiverterState",
    "Edge",
    "EdgeDetector",
    "EyeState",
    "InputImage",
    "Reply",
    "RoutingError",
    "RoutingTable",
    "ScanOutput",
    "SorterLogic",
    "Tracked",
]
