"""
What both nodes' ROS interfaces are made of: QoS profiles and parameter descriptors.

The simulation node and the controller talk over the same topics, so they must
agree on their QoS; both declare their parameters from a schema, so they build
descriptors the same way. Both take these from here rather than keeping copies.
"""

from __future__ import annotations

import copy

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.event_handler import PublisherEventCallbacks
from rclpy.parameter import Parameter
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


def quiet_publisher_events() -> PublisherEventCallbacks:
    """
    Return publisher event callbacks without rclpy's default handlers.

    rclpy gives every publisher a default handler of QoS events (an incompatible
    subscriber, an incompatible type), and every handler is a waitable the executor
    adds to its wait set at each pass: a node with twenty publishers (the simulation
    node has about as many) took ~74 us an executor pass with them and ~19 us without
    (measured), the largest overhead of fast mode. The subscribing side reports a
    mismatch to its owner all the same: rclpy's and rclcpp's subscriptions warn of an
    incompatible publisher by default.
    """
    return PublisherEventCallbacks(use_default_callbacks=False)


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

    Parameters
    ----------
    name : str
        The parameter.
    kind : str
        Its type (a key of PARAMETER_TYPES).
    description : str
        Its meaning.
    lo, hi : float, optional
        Its range.
    read_only : bool
        Fixed once the node runs.
    constraints : str
        What is allowed, in words.

    Returns
    -------
    ParameterDescriptor
        The descriptor.

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
    """
    Return a parameter value as plain Python (rclpy may hold arrays as array.array).

    Parameters
    ----------
    value : object
        A parameter value as rclpy holds it.

    Returns
    -------
    object
        The value as plain Python (lists for arrays).

    """
    if value is None or isinstance(value, (str, bool, int, float)):
        return value
    return list(value)


def parameter_problem(node, parameters) -> str | None:
    r"""
    Say why a set_parameters request cannot be taken, whatever the node's own rules.

    rclpy lets a parameter named '' through to exist afterwards, undeclared, and
    passes strings with NUL characters that the middleware then cuts at the NUL
    ('A\\0B' is stored as 'A'): both are refused here, with a reason.

    Parameters
    ----------
    node : rclpy.node.Node
        The node.
    parameters : list of rclpy.parameter.Parameter
        The request.

    Returns
    -------
    str or None
        Why it cannot be taken, or None.

    """
    for p in parameters:
        if not p.name or not node.has_parameter(p.name):
            return (
                f'no parameter named {p.name[:60]!r} on this node (see ros2 param list); '
                'nothing was changed'
            )
        value = p.value
        texts = [value] if isinstance(value, str) else []
        if isinstance(value, (list, tuple)) and value and isinstance(value[0], str):
            texts = list(value)
        if any('\x00' in t for t in texts):
            return f'parameter {p.name!r}: a string may not hold NUL characters'
    return None


def _widened(param, declared_type: int):
    """Return ``param`` as a double (array) when it is an integer (array) given for one."""
    t = param.type_
    if declared_type == ParameterType.PARAMETER_DOUBLE and t == Parameter.Type.INTEGER:
        return Parameter(param.name, value=float(param.value))
    if declared_type == ParameterType.PARAMETER_DOUBLE_ARRAY and t == Parameter.Type.INTEGER_ARRAY:
        return Parameter(param.name, value=[float(v) for v in param.value])
    return param


_ARRAY_TYPES = {
    ParameterType.PARAMETER_BOOL_ARRAY,
    ParameterType.PARAMETER_INTEGER_ARRAY,
    ParameterType.PARAMETER_DOUBLE_ARRAY,
    ParameterType.PARAMETER_STRING_ARRAY,
}


def _empty_sequence(value) -> bool:
    return not isinstance(value, (str, bool, int, float)) and len(value) == 0


def declare_checked(node, name: str, default, allowed: str, desc=None, error=ValueError):
    """
    Declare a parameter (``declare_typed``); a value of another type is ``error``, in words.

    rclpy refuses an override whose type is not the default's with an exception that
    names the types, not what the parameter allows (``-p stations:=x``); this one names
    the parameter, what it allows and what it was given, as the range checks do.
    ``node``, ``name``, ``default`` and ``desc`` (optional here) are ``declare_typed``'s;
    ``allowed`` says in words what the parameter allows, ``error`` is the exception
    raised (a ``ValueError``). Return the declared parameter.
    """
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException

    try:
        return declare_typed(node, name, default, desc or ParameterDescriptor())
    except (InvalidParameterTypeException, InvalidParameterValueException):
        given = node._parameter_overrides[name]
        raise error(
            f'parameter {name!r} must be {allowed}, got {plain(given.value)!r} '
            f'({given.type_.name.lower()})'
        ) from None


def declare_typed(node, name: str, default, desc):
    """
    Declare a parameter as ``node.declare_parameter`` does, taking an empty array for an array.

    rclpy infers an override's type from its value when it declares the parameter, and
    an empty list reads as a byte array (``-p routing.rules:=[]``), and an empty list in a
    params file comes unset, which would keep the default. Here an empty override of a
    declared array, either way, is taken as that array, empty.

    Parameters
    ----------
    node : rclpy.node.Node
        The node.
    name : str
        The parameter.
    default : object
        Its default.
    desc : ParameterDescriptor
        Its descriptor (its type says whether it is an array).

    Returns
    -------
    rclpy.parameter.Parameter
        The declared parameter.

    """
    override = node._parameter_overrides.get(name)
    if desc.type not in _ARRAY_TYPES:
        return node.declare_parameter(name, default, desc)
    # rcl's params-file parser cannot type an empty sequence and hands it over unset
    # (NOT_SET, value None); the command line's ``[]`` arrives as an empty byte array
    # (a scalar given for an array is left to rclpy, which refuses its type)
    if override is not None and (override.value is None or _empty_sequence(override.value)):
        return _declare_empty(node, name, default, desc)
    if _empty_sequence(default):
        # rclpy types a parameter by its default, and reads [] as a byte array: an
        # override is checked against the declared type instead, and no override
        # leaves the array declared empty, of its type
        if override is None:
            return _declare_empty(node, name, default, desc)
        return node.declare_parameter(name, Parameter.Type(desc.type), desc)
    return node.declare_parameter(name, default, desc)


_PLACEHOLDER = {
    ParameterType.PARAMETER_BOOL_ARRAY: [False],
    ParameterType.PARAMETER_INTEGER_ARRAY: [0],
    ParameterType.PARAMETER_DOUBLE_ARRAY: [0.0],
    ParameterType.PARAMETER_STRING_ARRAY: [''],
}


def _declare_empty(node, name: str, default, desc):
    """Declare an array parameter empty, of its declared type, read-only if it is."""
    import copy

    writable = copy.copy(desc)
    writable.read_only = False
    first = default if not _empty_sequence(default) else _PLACEHOLDER[desc.type]
    node.declare_parameter(name, first, writable, ignore_override=True)
    result = node.set_parameters([Parameter(name, Parameter.Type(desc.type), [])])[0]
    if not result.successful:
        raise ValueError(result.reason)
    if desc.read_only:
        node.set_descriptor(name, desc)
    return node.get_parameter(name)


def accept_integers_for_doubles(node, declared: dict[str, int]) -> None:
    """
    Take an integer given for a double parameter as that double, as ROS users type them.

    ``declared``: {name: ParameterType} of the node's parameters. rclpy refuses
    ``-p alpha_deg:=45`` and ``ros2 param set ... alpha_deg 45`` ('expected DOUBLE, got
    INTEGER'); here the start-up overrides (command line, params files) are widened
    before the node declares its parameters, and a run-time change before rclpy checks
    its type (a pre-set callback), so 45 is 45.0 everywhere. Ranges are untouched: the
    widened value is checked as any double would be. Call before declaring.

    Parameters
    ----------
    node : rclpy.node.Node
        The node, before it declares its parameters.
    declared : dict
        {name: ParameterType} of the parameters it will declare.

    """
    overrides = node._parameter_overrides
    for name, param in list(overrides.items()):
        if name in declared:
            overrides[name] = _widened(param, declared[name])

    def widen(parameters):
        return [_widened(p, declared[p.name]) if p.name in declared else p for p in parameters]

    node.add_pre_set_parameters_callback(widen)


def declare_options(node, table: dict, error=ValueError) -> dict:
    """
    Declare a node's options from its table; return their values, each checked.

    ``table``: {name: (default, check, what it allows in words)}. A list default is a
    string array (an empty one given is that, empty: ``declare_typed``); an integer
    given for a double is that double (``accept_integers_for_doubles``). A value of
    another type, or one ``check`` refuses, is ``error``, naming the parameter, what it
    allows and what it was given.
    """
    doubles = [name for name, (default, _, _) in table.items() if isinstance(default, float)]
    if doubles:
        accept_integers_for_doubles(node, dict.fromkeys(doubles, ParameterType.PARAMETER_DOUBLE))
    values = {}
    for name, (default, check, allowed) in table.items():
        desc = ParameterDescriptor(
            type=ParameterType.PARAMETER_STRING_ARRAY
            if isinstance(default, list)
            else ParameterType.PARAMETER_NOT_SET
        )
        value = plain(declare_checked(node, name, default, allowed, desc, error).value)
        if isinstance(default, float) and isinstance(value, int):
            value = float(value)
        if not check(value):
            raise error(f'parameter {name!r} must be {allowed}, got {value!r}')
        values[name] = value
    return values


def fix_at_start(node, allowed: dict) -> None:
    """
    Make parameters the node reads once, at start-up, read-only, each described in words.

    Without this rclpy takes ``ros2 param set`` of any value for them (no callback says
    no), and ``ros2 param get`` and ``param dump`` then show a value the node does not
    run with. They are declared writable first, so that ``declare_typed`` can set an
    empty array; here each gets its descriptor again, read-only, and ``ros2 param
    describe`` says what it allows. ``allowed``: {name: what it allows, in words},
    rclpy's own ``use_sim_time`` among them where the node reads its clock once.
    """
    for name, words in allowed.items():
        desc = copy.deepcopy(node.describe_parameter(name))
        desc.read_only = True
        desc.description = desc.description or f'{words}; read at start-up'
        node.set_descriptor(name, desc)


_KNOWN_TYPES = frozenset(t.value for t in Parameter.Type)  # ParameterType's, NOT_SET included
_PARAMETER_TYPES = ', '.join(f'{t.value} {t.name.lower()}' for t in Parameter.Type)


def answer_every_parameter_request(node) -> None:
    """
    Have the node's ``set_parameters`` services answer a request they cannot read.

    rclpy's parameter service raises on a value whose type is none of ParameterType's
    (``{type: 99}``), and the client never hears back; and it refuses a name the node
    does not have with ``Invalid access to undeclared parameter(s): []``, naming none.
    Here such a value is refused, naming its type and the types there are, and an unknown
    name is named; the rest goes to rclpy as before, one parameter at a time as it does.
    """
    from rcl_interfaces.msg import SetParametersResult
    from rcl_interfaces.srv import SetParameters, SetParametersAtomically

    def problem(p) -> str | None:
        if p.value.type not in _KNOWN_TYPES:
            return (
                f'parameter {p.name!r}: type {p.value.type} is not a parameter type '
                f'(the types: {_PARAMETER_TYPES})'
            )
        return None

    def named(p, result):
        if not result.successful and result.reason.startswith('Invalid access to undeclared'):
            result.reason = f'no parameter {p.name!r} on this node (ros2 param list names them)'
        return result

    for service in node.services:
        if service.srv_type is SetParameters:
            rclpy_set = service.callback

            def set_each(request, response, rclpy_set=rclpy_set):
                for p in request.parameters:
                    why = problem(p)
                    if why is not None:
                        response.results.append(SetParametersResult(successful=False, reason=why))
                        continue
                    one = rclpy_set(
                        SetParameters.Request(parameters=[p]), SetParameters.Response()
                    )
                    response.results.append(named(p, one.results[0]))
                return response

            service.callback = set_each
        elif service.srv_type is SetParametersAtomically:
            rclpy_atomic = service.callback

            def set_all(request, response, rclpy_atomic=rclpy_atomic):
                why = next(filter(None, map(problem, request.parameters)), None)
                if why is not None:
                    response.result = SetParametersResult(successful=False, reason=why)
                    return response
                return rclpy_atomic(request, response)

            service.callback = set_all
