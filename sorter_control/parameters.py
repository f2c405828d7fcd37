"""
The controller's parameters: the declared schema, and the configuration built from it.

``SCHEMA`` lists every parameter with its type, default, range and meaning (the
cell's quantities take theirs from the cell description); ``descriptor`` turns an
entry into its ROS ``ParameterDescriptor``; ``config_from_values`` checks a complete
set of values and builds the PLC program's ``ControllerConfig``, raising ValueError
naming the parameter and what is allowed.
"""

from __future__ import annotations

import math

from rcl_interfaces.msg import ParameterDescriptor, ParameterType, ParameterValue

from sorter_control.logic import ControllerConfig, RoutingError, RoutingTable
from sorter_control.timing import CellModel
from sorter_ros.interface import descriptor as ros_descriptor
from sorter_ros.param_spec import (
    BOOL,
    DOUBLE,
    DOUBLE_ARRAY,
    STRING,
    STRING_ARRAY,
    ParamSpec,
    quantity_spec,
)
from sorter_sim.model.description import Q

D, B, S, SA, DA = DOUBLE, BOOL, STRING, STRING_ARRAY, DOUBLE_ARRAY


# The controller's parameters. The cell group is what the PLC knows of the machine;
# with cell_node set it is taken from the simulation node instead (names there match).
SCHEMA = (
    ParamSpec(
        "scan_period", D, 0.01, "PLC scan period on the simulation clock [s]", lo=0.001, hi=0.1
    ),
    ParamSpec(
        "heartbeat_period",
        D,
        0.0,
        "period of controller/heartbeat on the simulation clock [s]: a beat at the first "
        "scan at or after it is due; 0: every scan. At most a quarter of the cell's "
        "watchdog_timeout: read from cell_node, a longer one is shortened to that, said "
        "in a warning",
        lo=0.0,
        hi=1.0,
    ),
    ParamSpec(
        "cell_node",
        S,
        "sorter_sim",
        "node whose get_parameters gives the cell's geometry and "
        "actuator times (same namespace); empty: use this node's cell parameters",
    ),
    ParamSpec(
        "cell_timeout",
        D,
        10.0,
        "how long to wait for cell_node's parameters from the first spin, wall [s]",
        lo=0.1,
        hi=600.0,
    ),
    quantity_spec(
        "belt_speed", Q["belt.speed"], extra="the encoder scale", unit_in_description=True
    ),
    quantity_spec("belt_width", Q["belt.width"], unit_in_description=True),
    quantity_spec(
        "disk_field_length", Q["disk_field.length"], extra="finite here", unit_in_description=True
    ),
    quantity_spec("chute_margin", Q["disk_field.chute_margin"], unit_in_description=True),
    ParamSpec(
        "photo_eyes.names",
        SA,
        ["pe_scan", "pe_divert", "pe_exit"],
        "photo-eye names (topics sensors/<name>)",
    ),
    quantity_spec(
        "photo_eyes.x",
        Q["sensors.x"],
        DA,
        [-2.0, -0.3, 2.0],
        "one per name",
        unit_in_description=True,
    ),
    ParamSpec(
        "scan_eye", S, "pe_scan", "the photo-eye on the scanner line (tracking starts there)"
    ),
    ParamSpec("divert_eye", S, "pe_divert", "the photo-eye just upstream of the disk field"),
    quantity_spec("popup_stroke_time", Q["diverter.stroke_time"], unit_in_description=True),
    quantity_spec(
        "alpha_slew_rate_deg_s", Q["diverter.alpha_slew_rate"], unit_in_description=True
    ),
    ParamSpec("friction_model", S, "const1", "friction law for the divert prediction (Fig. 3)"),
    quantity_spec(
        "mu_belt",
        Q["friction.mu"],
        extra="parcel/belt, for the prediction",
        unit_in_description=True,
    ),
    quantity_spec(
        "mu_disks",
        Q["friction.mu"],
        extra="parcel/disks, for the prediction",
        unit_in_description=True,
    ),
    quantity_spec(
        "nominal_parcel_width",
        Q["parcel.width"],
        default=0.4,
        extra="assumed by the prediction: the photo-eyes measure only the length",
        unit_in_description=True,
    ),
    quantity_spec(
        "nominal_parcel_length",
        Q["parcel.length"],
        default=0.4,
        extra="the length the minimum gap is reported for",
        unit_in_description=True,
    ),
    ParamSpec(
        "warm_lengths",
        DA,
        [0.2, 0.8],
        "[min, max] parcel lengths to predict at start-up, so scans "
        "find the model's answers ready [m]",
        lo=0.0,
        hi=10.0,
    ),
    ParamSpec(
        "divert_alpha_deg",
        D,
        90.0,
        "disk angle for a divert (+ to left, - to right) [deg]",
        lo=1.0,
        hi=90.0,
    ),
    ParamSpec(
        "commit_margin",
        D,
        0.05,
        "the centre of gravity must be this far past the chute entry line "
        "before the disks drop [m]",
        lo=0.0,
        hi=1.0,
    ),
    ParamSpec(
        "routing.rules",
        SA,
        ["A*=left", "B*=right", "C*=straight"],
        "routing table: "
        "'label=destination' or 'prefix*=destination' (destinations left, right, straight)",
        read_only=False,
    ),
    ParamSpec(
        "routing.default",
        S,
        "",
        "destination of labels no rule matches; empty: the reject destination",
        read_only=False,
    ),
    ParamSpec(
        "reject_destination",
        S,
        "straight",
        "destination of unknown labels and no-reads",
        read_only=False,
    ),
    ParamSpec(
        "service_timeout",
        D,
        0.5,
        "a service call without an answer after this long fails (not retried), on the wall "
        "clock and the controller's own [s]",
        lo=0.005,
        hi=60.0,
    ),
    ParamSpec(
        "service_latency",
        D,
        0.005,
        "allowance for a command to reach the cell, sim [s]",
        lo=0.0,
        hi=1.0,
    ),
    ParamSpec(
        "timing_margin", D, 0.02, "extra lead for a scan that comes late, sim [s]", lo=0.0, hi=1.0
    ),
    ParamSpec(
        "tracking_tolerance",
        D,
        0.05,
        "half width of a photo-eye's transit window [m]",
        lo=0.001,
        hi=2.0,
    ),
    ParamSpec(
        "label_window",
        D,
        0.1,
        "a label belongs to the scanner eye's edge this close in time [s]",
        lo=0.001,
        hi=2.0,
    ),
    ParamSpec(
        "jam_margin",
        D,
        0.5,
        "an eye may stay blocked this much longer than its parcel explains [s]",
        lo=0.01,
        hi=60.0,
    ),
    quantity_spec(
        "max_parcel_length",
        Q["parcel.length"],
        default=1.2,
        extra="the longest the cell takes",
        unit_in_description=True,
    ),
    ParamSpec(
        "missed_divert_margin",
        D,
        0.3,
        "a diverted parcel must reach its chute sensor this soon after the predicted time [s]",
        lo=0.01,
        hi=60.0,
    ),
    ParamSpec(
        "clearance",
        D,
        0.02,
        "least distance between parcels the spacing rules keep [m]",
        lo=0.0,
        hi=1.0,
    ),
    ParamSpec("estop_on_jam", B, True, "stop the belt (the cell's e-stop) on a jam"),
    ParamSpec(
        "open_chains",
        B,
        False,
        "divert a same-side chain even when the scanner cannot see what "
        "follows it (more throughput, risk of a forced divert)",
    ),
    ParamSpec(
        "gap_rules",
        B,
        True,
        "refuse a divert whose gap to the parcel ahead or behind is too short (sent "
        "straight, gap_too_short); false: every divert the model allows is made "
        "whatever the spacing (to show what the rules prevent: mis-sorts, shoves, jams)",
    ),
    ParamSpec(
        "diagnostics_period",
        D,
        1.0,
        "period of the diagnostics message, wall [s]",
        lo=0.05,
        hi=60.0,
    ),
    ParamSpec(
        "record_path",
        S,
        "",
        "MCAP file (.mcap) that records every message this node publishes, as ROS 2 CDR "
        "stamped with the node's clock (the cell's in the demo, which shares the file); "
        "empty: no recording",
    ),
)
SPECS = {s.name: s for s in SCHEMA}
# the cell's parameters as the simulation node names them
CELL_KEYS = (
    "belt_speed",
    "belt_width",
    "disk_field_length",
    "chute_margin",
    "photo_eyes.names",
    "photo_eyes.x",
    "popup_stroke_time",
    "alpha_slew_rate_deg_s",
    "friction_model",
    "mu_belt",
    "mu_disks",
)
ROUTING_KEYS = ("routing.rules", "routing.default", "reject_destination")


def descriptor(spec: ParamSpec) -> ParameterDescriptor:
    """
    Return the ROS descriptor of a controller parameter.

    Parameters
    ----------
    spec : ParamSpec
        A schema entry.

    Returns
    -------
    ParameterDescriptor
        The descriptor.

    """
    ranged = spec.type == D and spec.lo is not None
    return ros_descriptor(
        spec.name,
        spec.type,
        spec.description,
        lo=spec.lo,
        hi=spec.hi,
        read_only=spec.read_only,
        constraints=spec.allowed if ranged else "",
    )


def _value(pv: ParameterValue):
    t = pv.type
    if t == ParameterType.PARAMETER_DOUBLE:
        return pv.double_value
    if t == ParameterType.PARAMETER_INTEGER:
        return float(pv.integer_value)
    if t == ParameterType.PARAMETER_STRING:
        return pv.string_value
    if t == ParameterType.PARAMETER_BOOL:
        return pv.bool_value
    if t == ParameterType.PARAMETER_DOUBLE_ARRAY:
        return list(pv.double_array_value)
    if t == ParameterType.PARAMETER_STRING_ARRAY:
        return list(pv.string_array_value)
    return None


def config_from_values(values: dict) -> ControllerConfig:
    """
    Return a ControllerConfig from parameter values.

    ValueError names the parameter that is wrong.

    Parameters
    ----------
    values : dict
        Parameter values by name.

    Returns
    -------
    ControllerConfig
        The configuration.

    """
    for name, v in values.items():
        spec = SPECS.get(name)
        if spec is None:
            continue
        if spec.type == D:
            if (
                isinstance(v, bool)
                or not isinstance(v, (int, float))
                or not math.isfinite(v)
                or (spec.lo is not None and not spec.in_range(v))
            ):
                raise ValueError(f"parameter {name!r} must be {spec.allowed}, got {v!r}")
        elif spec.type == DA:
            if not isinstance(v, (list, tuple)) or not all(
                isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
                for x in v
            ):
                raise ValueError(f"parameter {name!r} must be a list of finite numbers, got {v!r}")
            if spec.lo is not None and not all(spec.in_range(float(x)) for x in v):
                raise ValueError(
                    f"parameter {name!r}: every entry must be {spec.entry_allowed}, got {v!r}"
                )
        elif spec.type == SA:
            if not isinstance(v, (list, tuple)) or not all(isinstance(x, str) for x in v):
                raise ValueError(f"parameter {name!r} must be a list of strings, got {v!r}")
    warm = list(values["warm_lengths"])
    if len(warm) != 2 or not 0.0 <= warm[0] <= warm[1]:
        raise ValueError(
            f"parameter 'warm_lengths' must be [min, max] with 0 <= min <= max, got {warm!r}"
        )
    names, xs = list(values["photo_eyes.names"]), list(values["photo_eyes.x"])
    if len(names) != len(xs):
        raise ValueError(
            f"parameters 'photo_eyes.names' and 'photo_eyes.x' must have the same length, "
            f"got {len(names)} names and {len(xs)} positions"
        )
    try:
        RoutingTable(
            values["routing.rules"], values["routing.default"], values["reject_destination"]
        )
    except RoutingError as exc:
        raise ValueError(f"parameter 'routing.*' / 'reject_destination': {exc}") from None
    try:
        cell = CellModel(
            belt_width=values["belt_width"],
            disk_field_length=values["disk_field_length"],
            chute_margin=values["chute_margin"],
            mu_belt=values["mu_belt"],
            mu_disks=values["mu_disks"],
            friction_model=values["friction_model"],
            parcel_width=values["nominal_parcel_width"],
            commit_margin=values["commit_margin"],
        )
        return ControllerConfig(
            scan_period=values["scan_period"],
            belt_speed=values["belt_speed"],
            photo_eyes=tuple(zip(names, (float(x) for x in xs))),
            scan_eye=values["scan_eye"],
            divert_eye=values["divert_eye"],
            divert_alpha_deg=values["divert_alpha_deg"],
            popup_stroke_time=max(values["popup_stroke_time"], 1e-6),
            alpha_slew_rate_deg_s=values["alpha_slew_rate_deg_s"],
            service_latency=values["service_latency"],
            timing_margin=values["timing_margin"],
            routing_rules=tuple(values["routing.rules"]),
            routing_default=values["routing.default"],
            reject_destination=values["reject_destination"],
            tracking_tolerance=values["tracking_tolerance"],
            label_window=values["label_window"],
            jam_margin=values["jam_margin"],
            max_parcel_length=values["max_parcel_length"],
            missed_divert_margin=values["missed_divert_margin"],
            clearance=values["clearance"],
            estop_on_jam=values["estop_on_jam"],
            open_chains=values["open_chains"],
            gap_rules=values["gap_rules"],
            cell=cell,
        )
    except ValueError as exc:
        raise ValueError(f"controller parameters: {exc}") from None
