"""Benchmark of the controller with the simulation node: decision latency and sortable throughput.

Not a test: it prints figures. Both nodes run in one process, in one
single-threaded executor as in ``sorter demo`` (``--executor events`` for rclpy's
experimental events executor), talking over DDS on this host.

latency     sensor edge -> controller decision -> service accepted, wall time, at
            real-time factor 1. The cell is the default one with the scanner
            photo-eye moved to 0.45 m before the disk field and 0.25 m parcels
            all routed left, so that a parcel's divert is decided in the first
            scan after its trailing edge clears the scanner eye (the length is
            known only then, and the decision is already due): that edge starts
            the clock. It stops when the cell's answer to the raise command
            arrives. The edge's wall time is the physical one: its simulation
            time mapped through the cell's real-time anchor (so the cell's own
            tick and DDS delivery count). Target: p99 below one scan period + 2 ms.
throughput  the default cell and controller, 0.4 x 0.3 m parcels at 1.5 m/s,
            a stream at a fixed belt gap, labels cycling through left, right and
            straight (a mixed stream) or all left (one side); for each gap, the
            parcels delivered to the destination their label asks for, per hour,
            and the mis-sorts and jams. The highest rate with zero mis-sorts and
            zero jams is the figure. The cell runs as fast as possible, as in the
            demo (``--rtf F`` for real time at factor F).

    .venv/bin/python benchmarks/bench_controller.py [--parcels 60] [--sim-s 40] [--rtf fast]
        [--skip-latency] [--skip-throughput] [--executor single|events]
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

from sorter_sim.ros_env import apply_ros_env_defaults  # noqa: E402

apply_ros_env_defaults()
os.environ.setdefault("ROS_DOMAIN_ID", str(100 + os.getpid() % 100))

import numpy as np  # noqa: E402
from sensor_msgs.msg import TimeReference  # noqa: E402

from sorter_control.demo import RunningCell  # noqa: E402
from sorter_control.node import EVENT_QOS  # noqa: E402

MIXED = ["A", "B", "C", "A", "A", "B", "C", "B", "B", "A", "C", "A"]
ROUTING = ["A*=left", "B*=right", "C*=straight"]


def bench_latency(parcels: int, executor: str) -> dict:
    sim = {"arrival": "gap", "arrival_gap": [1.6, 1.6], "labels": ["A"], "parcel_A": [0.25, 0.25],
           "parcel_B": [0.25, 0.25], "induct_x": -0.7, "scanner_x": -0.45,
           "photo_eyes.names": ["pe_scan", "pe_divert", "pe_exit"], "photo_eyes.x": [-0.45, -0.3, 2.0]}
    # the scanner is too close to see a follower before deciding: allow the divert anyway
    ctl = {"routing.rules": ROUTING, "open_chains": True}
    edges = []          # (edge wall time from the cell's anchor, wall time received)
    with RunningCell(sim_params=sim, controller_params=ctl, rtf=1.0, want_paths=False,
                     executor=executor) as rc:
        dt = rc.sim.cell.dt

        def on_edge(msg):
            if msg.header.frame_id != "pe_scan" or msg.source != "falling":
                return
            t_sim = msg.time_ref.sec + 1e-9 * msg.time_ref.nanosec
            wall0, k0 = rc.sim._wall_ref           # the cell's wall <-> simulation-time anchor
            edges.append((wall0 + (t_sim - k0 * dt) / rc.sim.params.real_time_factor, time.monotonic()))
        rc.watcher.create_subscription(TimeReference, "sensors/edges", on_edge, EVENT_QOS)
        t_sim = 0.6 + parcels * (0.25 + 1.6) / 1.5 + 1.0
        wall = rc.run_for(t_sim)
        rc.finish()
        raises = [e for e in rc.ctl.command_log if e[0] == "popup" and e[1] is True and e[3] is not None]
        results = list(rc.ctl.confirmations)
    decision, accepted, via_rx, round_trip, in_scan = [], [], [], [], []
    for kind, value, scan_wall, answered, ok, sent in raises:
        before = [e for e in edges if e[0] <= scan_wall]
        if not before:
            continue
        edge_wall, rx_wall = before[-1]
        if scan_wall - edge_wall > 0.1:
            continue       # not decided at this edge (a decision that was due later)
        decision.append(scan_wall - edge_wall)
        accepted.append(answered - edge_wall)
        via_rx.append(answered - rx_wall)
        in_scan.append(sent - scan_wall)
        round_trip.append(answered - sent)

    def pct(xs, q):
        return float(np.percentile(np.array(xs) * 1e3, q)) if xs else float("nan")
    sorted_ok = sum(1 for c in results if c.result == "sorted")
    return {"samples": len(accepted), "parcels_confirmed": len(results), "sorted": sorted_ok, "wall_s": wall,
            "edge_to_decision_ms": {"p50": pct(decision, 50), "p99": pct(decision, 99), "max": pct(decision, 100)},
            "edge_to_accepted_ms": {"p50": pct(accepted, 50), "p99": pct(accepted, 99), "max": pct(accepted, 100)},
            "received_edge_to_accepted_ms": {"p50": pct(via_rx, 50), "p99": pct(via_rx, 99)},
            "scan_to_sent_ms": {"p50": pct(in_scan, 50), "p99": pct(in_scan, 99)},
            "service_round_trip_ms": {"p50": pct(round_trip, 50), "p99": pct(round_trip, 99),
                                      "max": pct(round_trip, 100)}}


def run_stream(gap: float, labels: list[str], sim_s: float, rtf, executor: str) -> dict:
    sim = {"arrival": "gap", "arrival_gap": [gap, gap], "labels": labels, "parcel_A": [0.4, 0.4],
           "parcel_B": [0.3, 0.3], "belt_speed": 1.5}
    with RunningCell(sim_params=sim, controller_params={"routing.rules": ROUTING,
                                                         "nominal_parcel_width": 0.3},
                     rtf=rtf, want_paths=False, executor=executor) as rc:
        wall = rc.run_for(sim_s)
        t_end = rc.finish()
        obs = rc.obs
        late = int(obs.ctl_diag.get("late", 0))
    t0 = rc.t_start + 3.0      # the first parcel reaches the disk field ~2 s after the stream starts
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
        intended = c["destination_asked"] if c["result"] in ("sorted", "rejected", "mis-sorted", "missed") \
            else "straight"
        if o["exit"] != intended:
            mis += 1
        elif c["result"] == "sorted":
            ok += 1
        else:
            flagged += 1
    span = rc.t_start + t_end - t0
    return {"gap_m": gap, "offered_pcs_h": 3600.0 * 1.5 / (0.4 + gap), "sorted_pcs_h": 3600.0 * ok / span,
            "sorted": ok, "flagged": flagged, "mis_sorted": mis, "jams": jams, "late_decisions": late,
            "rtf": t_end / wall}


def bench_throughput(sim_s: float, rtf, executor: str) -> dict:
    out = {}
    for name, labels, gaps in (("mixed", MIXED, [1.6, 1.45, 1.42, 1.3, 1.0, 0.75]),
                               ("one side", ["A"], [1.0, 0.8, 0.75, 0.7, 0.6, 0.45])):
        rows = [run_stream(g, labels, sim_s, rtf, executor) for g in gaps]
        clean = [r for r in rows if r["mis_sorted"] == 0 and r["jams"] == 0]
        best = max(clean, key=lambda r: r["sorted_pcs_h"]) if clean else None
        out[name] = {"rows": rows, "best": best}
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--parcels", type=int, default=60, help="parcels for the latency run")
    ap.add_argument("--sim-s", type=float, default=40.0, help="simulated seconds per throughput run")
    ap.add_argument("--rtf", default="fast", help="real-time factor of the throughput runs, or fast")
    ap.add_argument("--executor", choices=("single", "events"), default="single")
    ap.add_argument("--skip-latency", action="store_true")
    ap.add_argument("--skip-throughput", action="store_true")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    import rclpy
    report = {"machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cpus, "
                         f"Python {platform.python_version()}, rclpy {_version('ros-jazzy-rclpy')}, "
                         f"load average before {os.getloadavg()[0]:.2f}",
              "executor": args.executor}
    if not args.skip_latency:
        report["latency"] = bench_latency(args.parcels, args.executor)
    if not args.skip_throughput:
        report["throughput"] = bench_throughput(args.sim_s, args.rtf, args.executor)
    del rclpy
    if args.json:
        print(json.dumps(report))
        return 0
    print(f"machine: {report['machine']}; executor: {args.executor}")
    if "latency" in report:
        lat = report["latency"]
        print(f"latency at real-time factor 1 ({lat['samples']} edge-triggered raises, scan period 10 ms):")
        for key, what in (("edge_to_decision_ms", "edge -> decision (scan)"),
                          ("edge_to_accepted_ms", "edge -> service accepted"),
                          ("received_edge_to_accepted_ms", "edge received -> accepted"),
                          ("scan_to_sent_ms", "scan start -> call sent"),
                          ("service_round_trip_ms", "call sent -> accepted")):
            v = lat[key]
            extra = f", max {v['max']:.2f}" if "max" in v else ""
            print(f"  {what:<28} p50 {v['p50']:6.2f} ms, p99 {v['p99']:6.2f} ms{extra}")
    if "throughput" in report:
        print(f"throughput, 0.4 x 0.3 m parcels at 1.5 m/s, {args.sim_s:g} s simulated per gap, "
              f"cell time: {args.rtf}:")
        for name, res in report["throughput"].items():
            print(f"  {name} stream:")
            print("    gap [m]  offered [pcs/h]  sorted [pcs/h]  sorted  flagged  mis-sorted  jams  late  rtf")
            for r in res["rows"]:
                print(f"    {r['gap_m']:7.3f}  {r['offered_pcs_h']:15.0f}  {r['sorted_pcs_h']:14.0f}  "
                      f"{r['sorted']:6d}  {r['flagged']:7d}  {r['mis_sorted']:10d}  {r['jams']:4d}  "
                      f"{r['late_decisions']:4d}  {r['rtf']:4.1f}")
            b = res["best"]
            if b:
                print(f"    best with zero mis-sorts and jams: {b['sorted_pcs_h']:.0f} pcs/h at a {b['gap_m']:g} m gap")
    return 0


def _version(dist: str) -> str:
    from importlib import metadata
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return "?"


if __name__ == "__main__":
    sys.exit(main())
