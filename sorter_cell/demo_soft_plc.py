"""
``sorter demo --io modbus|opcua|s7``: the PLC program as a soft PLC on the cell's fieldbus.

The cell runs in this process with its Modbus TCP, OPC UA or S7 server; the soft PLC
(``sorter_control.soft_plc``) connects to it as a client, as a real PLC would, and
scans the I/O image once every scan period of simulated time. Its steps: start the
cell's node and an observer (``_start_nodes``), connect the soft PLC (``_connect``),
scan for the run's time (``_scan``), and sum up what the observer saw (``_summary``).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from sorter_cell.demo_parts import _controller_values, _Observer, _stream, cell_params
from sorter_cell.demo_summary import exit_code, exits_by_id, plot_paths, print_table, summarize


def run_soft_plc(args) -> int | str:
    """
    ``sorter demo --io modbus|opcua|s7``: the PLC program as a soft PLC on the cell's fieldbus.

    The cell runs in this process with its Modbus TCP or OPC UA server; the soft PLC
    (``sorter_control.soft_plc``) connects to it as a client, as a real PLC would, and
    scans the I/O image once every scan period of simulated time: the cell advances a
    scan period, the PLC reads its inputs, decides and writes its outputs, and so on
    (the two step together, so the run is as fast as the machine and as repeatable as
    the ROS demo). An observer node watches the cell's outcomes over ROS, as a
    warehouse would.

    Parameters
    ----------
    args : list of str or argparse.Namespace
        The command line, or the parsed arguments.

    Returns
    -------
    int or str
        The exit code, or a message.

    """
    from sorter_control.parameters import config_from_values
    from sorter_control.soft_plc import FieldbusError, SoftPLC
    from sorter_ros.env import StopSignals, find_config_dir
    from sorter_ros.run_loop import RunLoop

    config_dir = find_config_dir()
    plan, stream = _stream(args, config_dir)
    cfg = config_from_values(_controller_values(config_dir))
    # Ctrl-C ends the stream where it is, as in the ROS demo; rclpy's own handler stays out
    stop = StopSignals().install()
    loop = RunLoop(params_files=("cell.yaml",), log_level="info" if args.verbose else "warn")
    io = None
    try:
        sim, obs = _start_nodes(args, loop, _free_port(), stream)
        try:
            io = _connect(args.io, sim)
        except FieldbusError as exc:
            return str(exc)
        plc = SoftPLC(cfg, io)
        t_end, wall = _scan(args, sim, plc, cfg, loop, stop)
        summary = _summary(args, sim, plc, obs, plan, (t_end, wall), io)
    finally:
        stop.quiet = True
        if io is not None:
            io.close()
        loop.close()
        stop.restore()
    if args.json:
        print(json.dumps(summary, sort_keys=True))
    else:
        print_table(summary)
        print(
            f"  fieldbus                   {args.io}: {summary['io_requests']} requests, "
            f"{summary['io_write_errors']} refused writes"
        )
        print(f"  paths                      {args.out}")
    return exit_code(summary)


def _free_port() -> int:
    """Return a free loopback port for the cell's fieldbus server."""
    import socket

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _start_nodes(args, loop, port: int, stream: dict):
    """
    Start the cell's node serving ``port`` in lock-step, and an observer node, on ``loop``.

    Returns
    -------
    (SimNode, _Observer)
        The cell's node and the observer.

    """
    import rclpy
    from rclpy.parameter import Parameter

    from sorter_sim.frontends.node import SimNode

    sim = SimNode(
        context=loop.context,
        parameter_overrides=[
            Parameter(k, value=v)
            for k, v in {
                "time_mode": "lockstep",
                "pose_rate_hz": 50.0,
                f"{args.io}_port": port,
                **stream,
                "arrival": "none",
            }.items()
        ],
    )
    loop.add_node(sim)
    loop._stepper, loop._timebase = sim, sim.cell
    watcher = rclpy.create_node("sorter_demo", context=loop.context)
    obs = _Observer(watcher, want_paths=True)
    loop.add_node(watcher)
    return sim, obs


def _connect(kind: str, sim):
    """Connect a soft PLC's I/O client of ``kind`` (modbus, s7, opcua) to the cell's server."""
    from sorter_control.soft_plc import S7IO, ModbusIO, OpcUaIO

    sensors = sim.cell.sensor_names
    if kind == "modbus":
        return ModbusIO("127.0.0.1", sim.fieldbus.modbus_port, sensors)
    if kind == "s7":
        return S7IO("127.0.0.1", sim.fieldbus.s7_port, sensors)
    return OpcUaIO(sim.fieldbus.opcua_endpoint, "cell", sensors)


def _scan(args, sim, plc, cfg, loop, stop) -> tuple[float, float]:
    """
    Step the cell a scan period, let the PLC scan, for ``args.sim_time`` of simulated time.

    The two step together, so the run is as fast as the machine and as repeatable as the
    ROS demo; the run loop serves the observer's callbacks after each scan.

    Returns
    -------
    (float, float)
        The simulated time run [s] and the wall time it took [s].

    """
    from rclpy.parameter import Parameter

    from sorter_sim.studies.progress import progress_bar

    lo, hi = sim.params.parcel_A
    plc.logic.warm_up(plc.logic.warm_lengths(lo, hi))
    sim.set_parameters([Parameter("arrival", value="gap")])
    per_scan = max(1, round(cfg.scan_period / sim.cell.dt))
    t0, wall0 = sim.cell.t, time.monotonic()
    bar = progress_bar(
        round(args.sim_time, 3), f"sorter demo --io {args.io}", "s", quiet=args.quiet
    )
    shown = 0.0
    while sim.cell.t - t0 < args.sim_time and not stop.is_set():
        sim.advance(per_scan)
        plc.scan()
        loop.spin_idle()
        if sim.cell.t - t0 - shown >= 0.1:
            bar.update(round(sim.cell.t - t0 - shown, 3))
            shown = sim.cell.t - t0
    bar.close()
    wall = time.monotonic() - wall0
    t_end = sim.cell.t - t0
    loop.spin_idle()
    return t_end, wall


def _summary(args, sim, plc, obs, plan, times, io) -> dict:
    """Return the run's summary with the fieldbus's figures (``summarize``); plot the paths."""
    t_end, wall = times
    for c in plc.confirmations:
        obs.confirmations[c.label] = {
            "label": c.label,
            "destination_asked": c.destination_asked,
            "destination_reached": c.destination_reached,
            "result": c.result,
        }
    st = plc.logic.status()
    obs.ctl_diag = {
        "state": st["state"],
        **{k: str(v) for k, v in st["counts"].items()},
        **{f"fault_{k}": str(v) for k, v in st["faults"].items()},
        "scan_wall_p99_ms": f"{st['scan_wall_p99_ms']:.3f}",
    }
    summary = summarize(obs, plan, t_end, wall, f"soft PLC over {args.io}")
    summary["io"] = args.io
    summary["io_requests"] = io.requests
    summary["io_write_errors"] = plc.write_errors
    summary["png"] = str(args.out)
    params = cell_params(sim)
    title = (
        f"sorter demo, soft PLC over {args.io}: {summary['inducted']} parcels in "
        f"{summary['sim_time_s']:g} s, mis-sorted {summary['mis_sorted']}, "
        f"jams {summary['jams']}"
    )
    try:
        plot_paths(obs.paths, exits_by_id(obs.outcomes.values()), params, title, Path(args.out))
    except OSError as exc:
        summary["png"] = None
        print(f"sorter demo: cannot write {args.out!r}: {exc.strerror or exc}", file=sys.stderr)
    return summary


__all__ = ["run_soft_plc"]
