"""
Benchmark of the controller with the simulation node: decision latency and sortable throughput.

Not a test: it prints figures. Both nodes run in one process and one executor,
talking over DDS on this host: for the latency run on the wall clock rclpy's
experimental events executor (``--executor single`` for the SingleThreadedExecutor;
``--processes 2`` puts the cell in a sim_node process of its own), for the
throughput runs the SingleThreadedExecutor with the cell as fast as possible, as
``sorter demo`` runs it.

latency     sensor edge -> controller decision -> service accepted, wall time, at
            real-time factor 1. The cell is the default one with the scanner
            photo-eye moved to 0.45 m before the disk field and 0.25 m parcels
            all routed left, so that a parcel's divert is decided in the first
            scan after its trailing edge clears the scanner eye (the length is
            known only then, and the decision is already due): that edge starts
            the clock. It stops when the cell's answer to the raise command
            arrives. The edge's wall time is the physical one: its simulation
            time mapped to the wall clock through the cell's /clock (so the
            cell's own tick and DDS delivery count). Target: p99 below one scan
            period + 2 ms.
throughput  the default cell and controller, 0.4 x 0.3 m parcels at 1.5 m/s,
            a stream at a fixed belt gap, labels cycling through left, right and
            straight (a mixed stream) or all left (one side); for each gap, the
            parcels delivered to the destination their label asks for, per hour,
            and the mis-sorts and jams. The highest rate with zero mis-sorts and
            zero jams is the figure. The cell runs as fast as possible, as in the
            demo (``--rtf F`` for real time at factor F).

    .venv/bin/python benchmarks/bench_controller.py [--parcels 60] [--sim-s 40] [--rtf fast]
        [--skip-latency] [--skip-throughput] [--executor events|single] [--processes 1|2]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sorter_ros.env import apply_ros_env_defaults  # noqa: E402

apply_ros_env_defaults()
os.environ.setdefault("ROS_DOMAIN_ID", str(100 + os.getpid() % 100))

import numpy as np  # noqa: E402
from sensor_msgs.msg import TimeReference  # noqa: E402

from sorter_cell.demo import RunningCell  # noqa: E402
from sorter_ros.interface import EVENT_QOS  # noqa: E402

MIXED = ["A", "B", "C", "A", "A", "B", "C", "B", "B", "A", "C", "A"]
ROUTING = ["A*=left", "B*=right", "C*=straight"]


LATENCY_CELL = {
    "arrival": "gap",
    "arrival_gap": [1.6, 1.6],
    "labels": ["A"],
    "parcel_A": [0.25, 0.25],
    "parcel_B": [0.25, 0.25],
    "induct_x": -0.7,
    "scanner_x": -0.45,
    "photo_eyes.names": ["pe_scan", "pe_divert", "pe_exit"],
    "photo_eyes.x": [-0.45, -0.3, 2.0],
}
# the scanner is too close to see a follower before deciding: allow the divert anyway
LATENCY_CONTROLLER = {"routing.rules": ROUTING, "open_chains": True}


class _EdgeClock:
    """
    Time sensor edges on the wall clock.

    Edge times on the wall clock, from the cell's own clock: every /clock message received
    at wall time w for simulation time t says the cell's anchor (wall time of t = 0 at factor
    1) is at most w - t; the smallest such bound over the last second is the anchor.
    """

    def __init__(self, node):
        from rosgraph_msgs.msg import Clock
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        self.clock = []  # (wall received, sim time)
        self.edges = []  # (sim time, wall received) of the scanner eye's falling edges
        node.create_subscription(
            Clock,
            "/clock",
            self._on_clock,
            QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE),
        )
        node.create_subscription(TimeReference, "sensors/edges", self._on_edge, EVENT_QOS)

    def _on_clock(self, msg):
        self.clock.append((time.monotonic(), msg.clock.sec + 1e-9 * msg.clock.nanosec))

    def _on_edge(self, msg):
        if msg.header.frame_id.rpartition("/")[2] == "pe_scan" and msg.source == "falling":
            self.edges.append((msg.time_ref.sec + 1e-9 * msg.time_ref.nanosec, time.monotonic()))

    def edge_walls(self) -> list[tuple[float, float]]:
        """(physical edge wall time, wall time received) per edge."""
        c = np.array(self.clock)
        out = []
        for t_sim, rx in self.edges:
            recent = c[(c[:, 0] <= rx) & (c[:, 0] >= rx - 1.0)]
            if len(recent):
                out.append((float(np.min(recent[:, 0] - recent[:, 1])) + t_sim, rx))
        return out


def bench_latency(parcels: int, executor: str, processes: int) -> dict:
    t_run = 0.6 + parcels * (0.25 + 1.6) / 1.5 + 1.0
    if processes == 1:
        with RunningCell(
            sim_params=LATENCY_CELL,
            controller_params=LATENCY_CONTROLLER,
            rtf=1.0,
            want_paths=False,
            executor=executor,
        ) as rc:
            probe = _EdgeClock(rc.watcher)
            wall = rc.run_for(t_run)
            rc.finish()
            log, results = list(rc.ctl.command_log), list(rc.ctl.confirmations)
        _stop_if_asked(rc)
    else:
        log, results, probe, wall = _latency_two_processes(t_run, executor)
    return _latency_figures(log, results, probe.edge_walls(), wall)


def _stop_if_asked(rc) -> None:
    """End the benchmark after a run a Ctrl-C cut short, not only that run."""
    if rc.stop is not None and rc.stop.is_set():
        raise KeyboardInterrupt


def _latency_two_processes(t_run: float, executor: str):
    """Return the cell in a process of its own (sim_node), the controller and probe in this one."""
    import signal
    import subprocess

    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter

    from sorter_control.node import ControllerNode
    from sorter_ros.env import find_config_dir
    from sorter_ros.run_loop import make_executor

    config = find_config_dir()
    args = [
        str(Path(sys.executable).with_name("sim_node")),
        "--ros-args",
        "--params-file",
        str(config / "cell.yaml"),
        "--log-level",
        "warn",
        "-p",
        "time_mode:=realtime",
        "-p",
        "real_time_factor:=1.0",
        "-p",
        "wall_tick:=0.001",
    ]
    for k, v in LATENCY_CELL.items():
        args += ["-p", f"{k}:={json.dumps(v) if isinstance(v, list) else v}"]
    sim = subprocess.Popen(args)
    ctx = Context()
    rclpy.init(
        context=ctx,
        args=[
            "--ros-args",
            "--params-file",
            str(config / "controller.yaml"),
            "--log-level",
            "warn",
        ],
    )
    nodes = []
    try:
        ctl = ControllerNode(
            context=ctx,
            parameter_overrides=[
                Parameter(k, value=v)
                for k, v in {"use_sim_time": True, **LATENCY_CONTROLLER}.items()
            ],
        )
        nodes.append(ctl)
        watcher = rclpy.create_node("latency_probe", context=ctx)
        nodes.append(watcher)
        probe = _EdgeClock(watcher)
        ex = make_executor(ctx, executor == "events")
        for n in nodes:
            ex.add_node(n)
        deadline = time.monotonic() + 60.0
        while ctl.logic is None and time.monotonic() < deadline:
            ex.spin_once(timeout_sec=0.05)
        if ctl.logic is None:
            raise RuntimeError("the controller did not get the cell's parameters within 60 s")
        wall0 = time.monotonic()
        t0 = ctl._now()
        while ctl._now() < t0 + t_run:
            ex.spin_once(timeout_sec=0.05)
        wall = time.monotonic() - wall0
        return list(ctl.command_log), list(ctl.confirmations), probe, wall
    finally:
        sim.send_signal(signal.SIGINT)
        try:
            sim.wait(timeout=10)
        except subprocess.TimeoutExpired:
            sim.kill()
        for n in nodes:
            n.destroy_node()
        rclpy.try_shutdown(context=ctx)


def _latency_figures(log, results, edges, wall) -> dict:
    raises = [e for e in log if e[0] == "popup" and e[1] is True and e[3] is not None]
    decision, accepted, via_rx, round_trip, in_scan = [], [], [], [], []
    for kind, value, scan_wall, answered, ok, sent in raises:
        before = [e for e in edges if e[0] <= scan_wall]
        if not before:
            continue
        edge_wall, rx_wall = before[-1]
        if scan_wall - edge_wall > 0.1:
            continue  # not decided at this edge (a decision that was due later)
        decision.append(scan_wall - edge_wall)
        accepted.append(answered - edge_wall)
        via_rx.append(answered - rx_wall)
        in_scan.append(sent - scan_wall)
        round_trip.append(answered - sent)

    def pct(xs, q):
        return float(np.percentile(np.array(xs) * 1e3, q)) if xs else float("nan")

    sorted_ok = sum(1 for c in results if c.result == "sorted")
    return {
        "samples": len(accepted),
        "parcels_confirmed": len(results),
        "sorted": sorted_ok,
        "wall_s": wall,
        "edge_to_decision_ms": {
            "p50": pct(decision, 50),
            "p99": pct(decision, 99),
            "max": pct(decision, 100),
        },
        "edge_to_accepted_ms": {
            "p50": pct(accepted, 50),
            "p99": pct(accepted, 99),
            "max": pct(accepted, 100),
        },
        "received_edge_to_accepted_ms": {"p50": pct(via_rx, 50), "p99": pct(via_rx, 99)},
        "scan_to_sent_ms": {"p50": pct(in_scan, 50), "p99": pct(in_scan, 99)},
        "service_round_trip_ms": {
            "p50": pct(round_trip, 50),
            "p99": pct(round_trip, 99),
            "max": pct(round_trip, 100),
        },
    }


def run_stream(gap: float, labels: list[str], sim_s: float, rtf, executor: str) -> dict:
    sim = {
        "arrival": "gap",
        "arrival_gap": [gap, gap],
        "labels": labels,
        "parcel_A": [0.4, 0.4],
        "parcel_B": [0.3, 0.3],
        "belt_speed": 1.5,
    }
    with RunningCell(
        sim_params=sim,
        controller_params={"routing.rules": ROUTING, "nominal_parcel_width": 0.3},
        rtf=rtf,
        want_paths=False,
        executor=executor,
    ) as rc:
        wall = rc.run_for(sim_s)
        t_end = rc.finish()
        obs = rc.obs
        late = int(obs.ctl_diag.get("late", 0))
    _stop_if_asked(rc)
    t0 = rc.t_start + 3.0  # the first parcel reaches the disk field ~2 s after the stream starts
    ok = mis = jams = flagged = 0
    for label, o in obs.outcomes.items():
        if float(o["t"]) < t0:
            continue
        if o["exit"] == "jammed":
            jams += 1
            continue
        c = obs.confirmations.get(label)
        if c is None:
            continue
        intended = (
            c["destination_asked"]
            if c["result"] in ("sorted", "rejected", "mis-sorted", "missed")
            else "straight"
        )
        if o["exit"] != intended:
            mis += 1
        elif c["result"] == "sorted":
            ok += 1
        else:
            flagged += 1
    span = rc.t_start + t_end - t0
    return {
        "gap_m": gap,
        "offered_pcs_h": 3600.0 * 1.5 / (0.4 + gap),
        "sorted_pcs_h": 3600.0 * ok / span,
        "sorted": ok,
        "flagged": flagged,
        "mis_sorted": mis,
        "jams": jams,
        "late_decisions": late,
        "rtf": t_end / wall,
    }


def bench_throughput(sim_s: float, rtf, executor: str) -> dict:
    out = {}
    for name, labels, gaps in (
        ("mixed", MIXED, [1.6, 1.45, 1.42, 1.3, 1.0, 0.75]),
        ("one side", ["A"], [1.0, 0.8, 0.75, 0.7, 0.6, 0.45]),
    ):
        rows = [run_stream(g, labels, sim_s, rtf, executor) for g in gaps]
        clean = [r for r in rows if r["mis_sorted"] == 0 and r["jams"] == 0]
        best = max(clean, key=lambda r: r["sorted_pcs_h"]) if clean else None
        out[name] = {"rows": rows, "best": best}
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--parcels", type=int, default=60, help="parcels for the latency run")
    ap.add_argument(
        "--sim-s", type=float, default=40.0, help="simulated seconds per throughput run"
    )
    ap.add_argument(
        "--rtf", default="fast", help="real-time factor of the throughput runs, or fast"
    )
    ap.add_argument(
        "--executor",
        choices=("events", "single"),
        default="events",
        help="executor of the latency run (the throughput runs use the single-threaded one)",
    )
    ap.add_argument(
        "--processes",
        type=int,
        choices=(1, 2),
        default=1,
        help="latency run: the cell in this process (1) or in a sim_node process of its own (2)",
    )
    ap.add_argument("--skip-latency", action="store_true")
    ap.add_argument("--skip-throughput", action="store_true")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    import rclpy

    report = {
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cpus, "
        f"Python {platform.python_version()}, rclpy {_version('ros-jazzy-rclpy')}, "
        f"load average before {os.getloadavg()[0]:.2f}",
        "executor": args.executor,
    }
    if not args.skip_latency:
        report["latency"] = bench_latency(args.parcels, args.executor, args.processes)
    if not args.skip_throughput:
        report["throughput"] = bench_throughput(args.sim_s, args.rtf, "single")
    del rclpy
    if args.json:
        print(json.dumps(report))
        return 0
    print(f"machine: {report['machine']}")
    if "latency" in report:
        lat = report["latency"]
        where = "one process" if args.processes == 1 else "the cell in a process of its own"
        print(
            f"latency at real-time factor 1, {where}, {args.executor} executor ({lat['samples']} "
            f"edge-triggered raises, scan period 10 ms):"
        )
        for key, what in (
            ("edge_to_decision_ms", "edge -> decision (scan)"),
            ("edge_to_accepted_ms", "edge -> service accepted"),
            ("received_edge_to_accepted_ms", "edge received -> accepted"),
            ("scan_to_sent_ms", "scan start -> call sent"),
            ("service_round_trip_ms", "call sent -> accepted"),
        ):
            v = lat[key]
            extra = f", max {v['max']:.2f}" if "max" in v else ""
            print(f"  {what:<28} p50 {v['p50']:6.2f} ms, p99 {v['p99']:6.2f} ms{extra}")
    if "throughput" in report:
        print(
            f"throughput, 0.4 x 0.3 m parcels at 1.5 m/s, {args.sim_s:g} s simulated per gap, "
            f"cell time: {args.rtf}:"
        )
        for name, res in report["throughput"].items():
            print(f"  {name} stream:")
            print(
                "    gap [m]  offered [pcs/h]  sorted [pcs/h]  sorted  flagged  mis-sorted  jams  "
                "late  rtf"
            )
            for r in res["rows"]:
                print(
                    f"    {r['gap_m']:7.3f}  {r['offered_pcs_h']:15.0f}  "
                    f"{r['sorted_pcs_h']:14.0f}  "
                    f"{r['sorted']:6d}  {r['flagged']:7d}  {r['mis_sorted']:10d}  {r['jams']:4d}  "
                    f"{r['late_decisions']:4d}  {r['rtf']:4.1f}"
                )
            b = res["best"]
            if b:
                print(
                    f"    best with zero mis-sorts and jams: {b['sorted_pcs_h']:.0f} pcs/h at a "
                    f"{b['gap_m']:g} m gap"
                )
    return 0


def _version(dist: str) -> str:
    from importlib import metadata

    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "?"


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:  # Ctrl-C: stop where it is, as the shell's 130
        sys.exit(130)
