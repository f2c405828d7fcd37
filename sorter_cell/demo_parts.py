"""
What ``sorter demo`` and its soft-PLC variant (``demo_soft_plc``) share.

The stream's plan (the least gap the controller reports, the seed's capacity), the
cell's stream values, the controller's values as ``config/controller.yaml`` sets them,
what the paths picture needs of the cell, and the observer node that watches what a
warehouse would.
"""

from __future__ import annotations

from pathlib import Path

from sorter_ros.outcomes import values

LABEL_CYCLE = ["A", "B", "C", "A", "A", "B", "D", "B", "C", "A", "B", "B"]
ROUTING = ["A*=left", "B*=right", "C*=straight"]


def _controller_values(config_dir: Path) -> dict:
    """
    Return the controller's parameter values as controller.yaml sets them.

    The file is checked as the node checks it: unknown names and bad values are a
    ValueError naming the file and the parameter.
    """
    from sorter_control.node import NODE_NAME
    from sorter_control.parameters import SCHEMA, config_from_values
    from sorter_ros.params_file import read_params_file

    path = config_dir / "controller.yaml"
    values = {s.name: s.default for s in SCHEMA}
    given = read_params_file(path, NODE_NAME)
    given.pop("use_sim_time", None)  # rclpy's own parameter, not the controller's
    unknown = sorted(set(given) - set(values))
    if unknown:
        raise ValueError(
            f"{path}: unknown controller parameter(s) {', '.join(map(repr, unknown))}"
        )
    values.update(given)
    try:
        config_from_values(values)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
    values["routing.rules"] = list(ROUTING)
    return values


def stream_plan(parcel_lengths: tuple[float, float], config_dir: Path) -> dict:
    """
    Return the least gap of a mixed stream of these lengths, and the seed's capacity.

    Parameters
    ----------
    parcel_lengths : (float, float)
        The stream's range of parcel lengths [m].
    config_dir : Path
        The folder of cell.yaml and controller.yaml.

    Returns
    -------
    dict
        The least gap, the gap range and the seed's capacity.

    """
    from sorter_control.logic import SorterLogic
    from sorter_control.parameters import config_from_values
    from sorter_control.timing import seed_capacity

    cfg = config_from_values(_controller_values(config_dir))
    logic = SorterLogic(cfg)
    lo, hi = parcel_lengths
    lengths = sorted({lo, 0.5 * (lo + hi), hi})
    worst = max(logic.min_gap(a)["worst"] for a in lengths)
    mean = 0.5 * (lo + hi)
    return {
        "min_gap_m": worst,
        "mean_length_m": mean,
        "seed_capacity_pcs_h": seed_capacity(
            cfg.cell, mean, cfg.belt_speed, abs(cfg.divert_alpha_deg)
        ),
        "belt_speed": cfg.belt_speed,
    }


class _Observer:
    """Watch what a warehouse would, from an ordinary node: outcomes, confirmations, poses."""

    def __init__(self, node, want_paths: bool, cell=None):
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
        from geometry_msgs.msg import PoseArray
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock
        from std_msgs.msg import UInt32MultiArray

        events = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        stream = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        self.node = node
        self.t_sim = 0.0
        self.outcomes: dict[str, dict] = {}  # label -> values
        self.confirmations: dict[str, dict] = {}
        self.ctl_diag: dict = {}
        self.ids_seen: set[int] = set()
        self.paths: dict[int, list] = {}
        self._ids = None
        self._cell = cell
        self._want_paths = want_paths
        node.create_subscription(DiagnosticStatus, "sort/outcomes", self._on_outcome, events)
        node.create_subscription(
            DiagnosticStatus, "sort/confirmations", self._on_confirmation, events
        )
        node.create_subscription(DiagnosticArray, "/diagnostics", self._on_diag, stream)
        if cell is not None:
            # a cell in this process, in lock-step: its time, ids and poses are read from
            # it after each slice (``sample``), as the poses topic would give them; three
            # subscriptions fewer for every slice to serve
            return
        node.create_subscription(Clock, "/clock", self._on_clock, stream)
        node.create_subscription(UInt32MultiArray, "parcels/ids", self._on_ids, stream)
        if want_paths:
            node.create_subscription(PoseArray, "parcels/poses", self._on_poses, stream)

    def sample(self) -> None:
        """Take the ids and poses of the cell in this process (at the pose topic's period)."""
        parcels = self._cell.parcels()
        ids = parcels["id"].tolist()
        self.ids_seen.update(ids)
        if self._want_paths:
            for pid, x, y in zip(ids, parcels["x"].tolist(), parcels["y"].tolist()):
                self.paths.setdefault(int(pid), []).append((x, y))

    def _on_clock(self, msg):
        self.t_sim = msg.clock.sec + 1e-9 * msg.clock.nanosec

    def _on_outcome(self, msg):
        v = values(msg)
        self.outcomes[v.get("label") or msg.name] = v

    def _on_confirmation(self, msg):
        v = values(msg)
        self.confirmations[v.get("label", msg.name)] = v

    def _on_diag(self, msg):
        for st in msg.status:
            if st.name.endswith(": controller"):
                self.ctl_diag = values(st)

    def _on_ids(self, msg):
        self._ids = list(msg.data)
        self.ids_seen.update(self._ids)

    def _on_poses(self, msg):
        ids = self._ids
        if ids is None or len(ids) != len(msg.poses):
            return
        for pid, pose in zip(ids, msg.poses):
            self.paths.setdefault(int(pid), []).append((pose.position.x, pose.position.y))


def cell_params(sim) -> dict:
    """
    Return what ``plot_paths`` needs of the cell, from the simulation node's parameters.

    Parameters
    ----------
    sim : rclpy.node.Node
        The simulation node.

    Returns
    -------
    dict
        The cell's geometry.

    """
    out = {
        k: sim.get_parameter(k).value
        for k in ("belt_width", "disk_field_length", "chute_margin", "induct_x", "exit_x")
    }
    out["photo_eyes.names"] = list(sim.get_parameter("photo_eyes.names").value)
    out["photo_eyes.x"] = list(sim.get_parameter("photo_eyes.x").value)
    return out


def demo_contact(args, cell_values: dict) -> str:
    """
    Return what a touch is in the demo's cell: ``--contact``, or the cell's own setting.

    Unless told, the cell keeps its ``contact`` (config/cell.yaml, else the parameter's
    default, rigid); a stream closer than ``jam`` allows (``--gap 0 0``: parcels end to
    end) is refused under ``jam`` before the run (``_check_args``).
    """
    if args.contact is not None:
        return args.contact
    from sorter_sim.runtime.param_table import SCHEMA

    default = next(spec.default for spec in SCHEMA if spec.name == "contact")
    return str(cell_values.get("contact", default))


def _stream(args, config_dir: Path):
    """Return the plan of the demo's stream (gaps, capacity) and the cell's stream values."""
    from sorter_ros.params_file import read_params_file

    cell = read_params_file(config_dir / "cell.yaml", "sorter_sim")
    lengths = tuple(cell.get("parcel_A", [0.3, 0.7]))
    plan = stream_plan(lengths, config_dir)
    gap = (
        tuple(args.gap)
        if args.gap is not None
        else (round(plan["min_gap_m"] + 0.02, 3), round(plan["min_gap_m"] + 0.4, 3))
    )
    plan["stream_gap_m"] = list(gap)
    plan["contact"] = demo_contact(args, cell)
    return plan, {
        "contact": plan["contact"],
        "arrival": "gap",
        "arrival_gap": list(gap),
        "labels": list(LABEL_CYCLE),
        "seed": int(args.seed),
    }
