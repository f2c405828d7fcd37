"""
What both nodes' ROS interfaces are made of: QoS profiles and parameter descriptors.

The simulation node and the controller talk over the same topics, so they must
agree on their QoS; both declare their parameters from a schema, so they build
descriptors the same way. Both take these from here rather than keeping copies.
"""

from __future__ import annotations

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

# a sensor's or a state bit's current value: latched, so a late subscriber gets it
SENSOR_QOS = QoSProfile(
    depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)
# events that must all arrive (edges, labels, outcomes, inducts, routing updates)
EVENT_QOS = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
# periodic streams where the newest message matters (poses, diverter state, clock)
STREAM_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
# service requests: a reliable queue deep enough for any burst a cell meets (rclpy's
# default keeps 10, so the 11th request of a burst was dropped without an answer); each
# request is served in turn, a refusal is an answer with its reason
SERVICE_QUEUE = 1000
SERVICE_QOS = QoSProfile(depth=SERVICE_QUEUE, reliability=ReliabilityPolicy.RELIABLE)

PARAMETER_TYPES = {
    'double': ParameterType.PARAMETER_DOUBLE,
    'integer': ParameterType.PARAMETER_INTEGER,
    'string': ParameterType.PARAMETER_STRING,
    'bool': ParameterType.PARAMETER_BOOL,
    'double_array': ParameterType.PARAMETER_DOUBLE_ARRAY,
    'string_array': ParameterType.PARAMETER_STRING_ARRAY,
}


def descriptor(
    name: str,
    kind: str,
    description: str,
    *,
    lo: float | None = None,
    hi: float | None = None,
    read_only: bool = True,
    constraints: str = '',
) -> ParameterDescriptor:
    """
    Return the descriptor of one declared parameter.

    ``kind`` is a key of PARAMETER_TYPES; ``lo``/``hi`` become the range of a double
    or an integer (rclpy refuses values outside it before any callback runs).
    """
    d = ParameterDescriptor(
        name=name,
        type=PARAMETER_TYPES[kind],
        description=description,
        additional_constraints=constraints,
        read_only=read_only,
    )
    if kind == 'double' and lo is not None:
        d.floating_point_range = [
            FloatingPointRange(from_value=float(lo), to_value=float(hi), step=0.0)
        ]
    elif kind == 'integer' and lo is not None:
        d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=0)]
    return d


def plain(value):
    """Return a parameter value as plain Python (rclpy may hold arrays as array.array)."""
    if value is None or isinstance(value, (str, bool, int, float)):
        return value
    return list(value)
