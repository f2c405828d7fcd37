"""What the PLC is configured with: the controller's configuration, checked as a whole."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from sorter_control.timing import Actuators, CellModel
from sorter_control.logic.routing import RoutingTable


@dataclass(frozen=True)
class ControllerConfig:
    """
    Everything the PLC is configured with (SI units; angles in degrees).

    Photo-eyes: ``photo_eyes`` maps names to x [m] in the conveyor frame (origin on
    the upstream edge of the disk field); ``scan_eye`` is at the scanner line and
    ``divert_eye`` just upstream of the disk field. ``chute_sensors`` maps a side
    (left/right) to its sensor name.
    """

    scan_period: float = 0.01
    belt_speed: float = 1.5
    photo_eyes: tuple = (("pe_scan", -2.0), ("pe_divert", -0.3), ("pe_exit", 2.0))
    scan_eye: str = "pe_scan"
    divert_eye: str = "pe_divert"
    chute_sensors: tuple = (("left", "chute_left"), ("right", "chute_right"))
    divert_alpha_deg: float = 90.0
    popup_stroke_time: float = 0.1
    alpha_slew_rate_deg_s: float = 360.0
    service_latency: float = 0.005
    timing_margin: float = 0.02
    routing_rules: tuple = ()
    routing_default: str = ""
    reject_destination: str = "straight"
    tracking_tolerance: float = 0.05
    label_window: float = 0.1
    jam_margin: float = 0.5
    max_parcel_length: float = 1.2
    missed_divert_margin: float = 0.3
    clearance: float = 0.02
    estop_on_jam: bool = True
    open_chains: bool = False
    gap_rules: bool = True
    cell: CellModel = field(default_factory=CellModel)

    def __post_init__(self):
        def positive(name):
            v = getattr(self, name)
            if (
                isinstance(v, bool)
                or not isinstance(v, (int, float))
                or not math.isfinite(v)
                or v <= 0
            ):
                raise ValueError(f"{name} must be a finite number > 0, got {v!r}")

        for name in (
            "scan_period",
            "belt_speed",
            "popup_stroke_time",
            "alpha_slew_rate_deg_s",
            "tracking_tolerance",
            "label_window",
            "jam_margin",
            "max_parcel_length",
            "missed_divert_margin",
        ):
            positive(name)
        for name in ("service_latency", "clearance", "timing_margin"):
            v = getattr(self, name)
            if (
                isinstance(v, bool)
                or not isinstance(v, (int, float))
                or not math.isfinite(v)
                or v < 0
            ):
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        if not (0 < abs(self.divert_alpha_deg) <= 90):
            raise ValueError(f"divert_alpha_deg must be in (0, 90], got {self.divert_alpha_deg!r}")
        eyes = dict(self.photo_eyes)
        if len(eyes) != len(self.photo_eyes):
            raise ValueError(f"photo_eyes: names must be unique, got {list(self.photo_eyes)}")
        for name, x in eyes.items():
            if not isinstance(name, str) or not name or not math.isfinite(x):
                raise ValueError(
                    f"photo_eyes: each needs a name and a finite x, got {name!r}: {x!r}"
                )
        for name in (self.scan_eye, self.divert_eye):
            if name not in eyes:
                raise ValueError(f"photo-eye {name!r} is not among photo_eyes {sorted(eyes)}")
        if not eyes[self.scan_eye] < eyes[self.divert_eye] <= 0.0:
            raise ValueError(
                f"photo-eyes must sit scanner < divert eye <= 0 (the disk field's upstream "
                f"edge); got {self.scan_eye} at {eyes[self.scan_eye]} m, "
                f"{self.divert_eye} at {eyes[self.divert_eye]} m"
            )
        chutes = dict(self.chute_sensors)
        if set(chutes) - {"left", "right"}:
            raise ValueError(f"chute_sensors: sides must be left/right, got {sorted(chutes)}")
        # the routing rules must parse
        RoutingTable(self.routing_rules, self.routing_default, self.reject_destination)

    @property
    def eyes(self) -> dict[str, float]:
        return dict(self.photo_eyes)

    @property
    def chutes(self) -> dict[str, str]:
        return dict(self.chute_sensors)

    def actuators(self) -> Actuators:
        return Actuators(
            self.popup_stroke_time,
            self.alpha_slew_rate_deg_s,
            self.scan_period,
            self.service_latency,
            self.timing_margin,
        )
