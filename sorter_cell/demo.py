"""
``sorter demo``: the running cell, simulation node and controller, talking over ROS 2.

Starts the simulation node (config/cell.yaml) and the controller (config/controller.yaml)
in this process, on the project's run loop (``sorter_ros.run_loop``: one rclpy
context, rclpy's events executor), plus an observer node that watches what a
warehouse would: the cell's outcomes, the controller's sort confirmations and
diagnostics, the parcels' poses. The two nodes talk only over topics and services.

By default the cell runs as fast as possible: the run loop advances it (``time_mode:
lockstep``) in slices of 5 ms of simulated time and, after each, serves every
callback until the controller has caught up (taken the clock, run its 10 ms scan if
one fell due, had its service calls answered), so the controller sees each sensor
edge and its commands reach the cell in the slice they were given in however fast or
slow the machine is: a PLC that is never late, at whatever real-time factor the
machine allows, and the same run on every machine. ``--rtf F`` runs the cell on the
wall clock at factor F instead (as a real cell would run with F = 1).

The parcel stream is the cell's, with a cycle of labels the routing table sends
left, right, straight and (label D, unknown) to the reject destination, and belt
gaps just above the least gap the controller reports for the longest parcel in
a mixed stream, so every divert is feasible. At the end: a summary table
(``--json``: one JSON object) and a PNG of the parcels' paths over the cell.
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

from sorter_cell.demo_parts import (  # noqa: F401 (the demo's public names, as before)
    LABEL_CYCLE,
    ROUTING,
    _controller_values,
    _Observer,
    _stream,
    cell_params,
    stream_plan,
)
from sorter_cell.demo_summary import exit_code, exits_by_id, plot_paths, print_table, summarize
from sorter_ros.run_loop import RunLoop
from sorter_sim.model.description import Q
from sorter_sim.runtime.params import JAM_CONTACT_MIN_GAP
from sorter_sim.studies.outpaths import file_problem

FOXGLOVE_PORT = 8765  # Foxglove's usual WebSocket port
# the longest slice of the run loop in fast mode [s of simulated time]; each ends at the
# controller's next scan (align_to_timers), so this bounds only a run without one
FAST_SLICE = 0.05
PROGRESS_S = 0.1  # s of simulated time between two looks at the progress bar and Ctrl-C


def add_arguments(parser) -> None:
    """
    Add the verb's arguments to its parser.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The verb's parser.

    """
    parser.add_argument(
        "--stations",
        type=int,
        default=1,
        metavar="N",
        help="diverter stations on the line, 1-64 (default 1: one cell); N > 1 runs the line "
        "node, a controller per station and the warehouse node",
    )
    parser.add_argument(
        "--executor",
        choices=("events", "single"),
        default=None,
        help="with --stations N > 1: rclpy's executor for the line's nodes, the events "
        "executor (events, the default: no per-pass walk over every entity) or the "
        "single-threaded one (single)",
    )
    parser.add_argument(
        "--segments",
        type=int,
        default=1,
        metavar="K",
        help="with --stations N: run the line as K segment processes (1..N, default 1), "
        "parcels handed between them over ROS 2",
    )
    parser.add_argument(
        "--sync",
        choices=("conservative", "barrier"),
        default=None,
        help="with --segments K > 1 in fast mode: each segment behind its upstream "
        "neighbour (conservative, the default) or all within one slice of each other "
        "(barrier)",
    )
    parser.add_argument(
        "--restart",
        type=int,
        default=0,
        metavar="R",
        help="with --segments K > 1: start a segment process after station 1's that "
        "ended again, up to R times in all (default 0: a segment that ends ends the demo, "
        "exit 2)",
    )
    parser.add_argument(
        "--parcels",
        type=int,
        default=0,
        metavar="M",
        help="with --stations N: a batch of M parcels, run until each has its disposition "
        "(in place of --sim-time)",
    )
    parser.add_argument(
        "--no-drain",
        action="store_true",
        help="with --stations N: stop at --sim-time, the parcels still on the line "
        "counted in in_cell_at_end (default: the line runs empty first)",
    )
    parser.add_argument(
        "--dispositions",
        default=None,
        metavar="FILE.jsonl",
        help="with --stations N > 1: write every parcel's disposition (label, code, "
        "destination, chute, station, t), one JSON object a line",
    )
    parser.add_argument(
        "--sim-time",
        type=float,
        default=60.0,
        metavar="S",
        help="simulated seconds to run (default 60)",
    )
    parser.add_argument(
        "--rtf",
        default="fast",
        metavar="F|fast",
        help="run the cell on the wall clock at real-time factor F, or as fast as possible "
        "(fast, the default)",
    )
    parser.add_argument(
        "--gap",
        type=float,
        nargs=2,
        default=None,
        metavar=("MIN", "MAX"),
        help="belt gap range of the stream [m] (default: just above the controller's "
        "least gap for a mixed stream)",
    )
    parser.add_argument(
        "--contact",
        choices=("jam", "rigid"),
        default=None,
        help="what a touch is in the cell (at every station of a line): jam (two parcels "
        "that touch stop and jam) or rigid (parcels push and ride on as rigid boxes); "
        "default: the cell's (rigid), "
        f"and a --gap below {JAM_CONTACT_MIN_GAP:g} m (0 0: parcels end to end) needs rigid",
    )
    parser.add_argument(
        "--seed", type=int, default=1, help="seed of the parcel stream (default 1)"
    )
    parser.add_argument(
        "--out",
        default="out/demo_paths.png",
        help="PNG of the parcels' paths (default out/demo_paths.png)",
    )
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    parser.add_argument(
        "--verbose", action="store_true", help="show the nodes' informational log lines"
    )
    parser.add_argument(
        "--record",
        default=None,
        metavar="FILE.mcap",
        help="record every topic of the cell and the controller to MCAP (ROS 2 CDR, "
        "simulation time); read it back with sorter replay",
    )
    parser.add_argument(
        "--foxglove",
        nargs="?",
        type=int,
        const=FOXGLOVE_PORT,
        default=0,
        metavar="PORT",
        help=f"serve the live view to Foxglove on ws://127.0.0.1:PORT (default {FOXGLOVE_PORT})",
    )
    parser.add_argument(
        "--quiet",
        action="store_true",
        help="no progress bar (there is none either when stderr is not a terminal)",
    )
    parser.add_argument(
        "--io",
        choices=("ros", "modbus", "opcua", "s7"),
        default="ros",
        help="how the controller reaches the cell: ROS topics and services (ros, the default), "
        "or as a soft PLC scanning the cell's I/O image over Modbus TCP, OPC UA or S7",
    )


def _check_args(args) -> str | None:
    if not (math.isfinite(args.sim_time) and 0.0 < args.sim_time <= 3600.0):
        return f"--sim-time must be in (0, 3600] s, got {args.sim_time}"
    if args.rtf != "fast":
        try:
            value = float(args.rtf)
        except ValueError:
            return f"--rtf must be a number in [0.01, 100] or fast, got {args.rtf!r}"
        if not (math.isfinite(value) and 0.01 <= value <= 100.0):
            return f"--rtf must be a number in [0.01, 100] or fast, got {args.rtf!r}"
    if args.gap is not None:
        lo, hi = args.gap
        q = Q["stream.gap"]
        if not (q.contains(lo) and q.contains(hi) and lo <= hi):
            return f"--gap MIN MAX: each must be {q.allowed}, with MIN <= MAX; got {lo} {hi}"
        if lo < JAM_CONTACT_MIN_GAP and args.contact == "jam":
            return (
                f"--gap MIN below {JAM_CONTACT_MIN_GAP:g} m needs --contact rigid (or no "
                f"--contact): under jam parcels that close up or touch jam; got --gap {lo} {hi}"
            )
    if not 0 <= args.seed < 2**31:
        return f"--seed must be in [0, 2^31), got {args.seed}"
    if not 0 <= args.foxglove <= 65535:
        return f"--foxglove PORT must be in [1, 65535], got {args.foxglove}"
    if args.record is not None:
        from sorter_ros.recording import recording_problem

        problem = recording_problem(args.record)
        if problem:
            return f"--record {problem}"
    out = Path(args.out)
    if out.suffix.lower() != ".png":
        return f"--out must name a .png file, got {args.out!r}"
    problem = file_problem(out)
    if problem:
        return problem
    return None


class RunningCell(RunLoop):
    """
    The simulation node, the controller and an observer on one run loop.

    Parameters come from config/cell.yaml and config/controller.yaml, then
    ``sim_params`` / ``controller_params`` override them. ``rtf`` is the cell's
    real-time factor on the wall clock, or "fast": as fast as possible, the cell in
    ``lockstep`` time mode advanced by the run loop slice by slice, each slice ending
    when the controller has caught up with it (``sorter_ros.run_loop``). Use as a
    context manager: ``run_for(t)`` runs t simulated seconds of the stream,
    ``finish()`` stops the cell's clock and lets the last messages arrive.
    """

    def __init__(
        self,
        *,
        sim_params: dict,
        controller_params: dict,
        rtf="fast",
        want_paths: bool = True,
        executor: str = "events",
        log_level: str = "warn",
    ):
        self.log_level = log_level
        self.sim_params = sim_params
        self.controller_params = controller_params
        self.time_mode = "fast" if rtf == "fast" else "realtime"
        self.rtf = None if rtf == "fast" else float(rtf)
        self.want_paths = want_paths
        self.executor_kind = executor
        self.nodes = []
        self.context = None
        self.stop = None  # SIGINT/SIGTERM, once the cell is up (sorter_ros.env.StopSignals)
        self.started = False

    def __enter__(self) -> "RunningCell":
        import rclpy
        from rclpy.parameter import Parameter

        from sorter_control.node import ControllerNode
        from sorter_ros.env import StopSignals
        from sorter_sim.frontends.node import SimNode

        # Ctrl-C ends the run early, cleanly: the first one stops the stream where it is
        # and the summary covers what ran; a second one hurries (KeyboardInterrupt)
        self.stop = StopSignals().install()
        self._start_context(
            None,
            FAST_SLICE,
            None,
            events=self.executor_kind == "events",
            log_level=self.log_level,
        )
        self.ctx = self.context
        # the controller acts in its scans only: a slice may run from one to the next
        self.align_to_timers = True
        try:
            timing = (
                {"time_mode": "lockstep"}
                if self.rtf is None
                else {"time_mode": "realtime", "real_time_factor": self.rtf, "wall_tick": 0.001}
            )
            sim_values = {**timing, "pose_rate_hz": 50.0, **self.sim_params}
            # the stream starts once the controller runs (no parcel passes it untracked)
            self.arrival = sim_values.get("arrival", "none")
            sim_values["arrival"] = "none"
            self.sim = SimNode(
                context=self.context,
                parameter_overrides=[Parameter(k, value=v) for k, v in sim_values.items()],
            )
            self._stepper, self._timebase = self.sim, self.sim.cell
            self.add_node(self.sim)
            ctl_values = {
                "use_sim_time": True,
                "diagnostics_period": 0.5,
                **self.controller_params,
            }
            self.ctl = ControllerNode(
                context=self.context,
                parameter_overrides=[Parameter(k, value=v) for k, v in ctl_values.items()],
            )
            self.add_node(self.ctl)
            self.watcher = rclpy.create_node("sorter_demo", context=self.context)
            self.obs = _Observer(
                self.watcher,
                want_paths=self.want_paths,
                cell=self.sim.cell if self.rtf is None else None,
            )
            self.add_node(self.watcher)
            running = lambda: self.obs.ctl_diag.get("state") == "running"  # noqa: E731
            if self.rtf is None:
                # the clock stands still while the controller starts: the stream starts at
                # the same simulated time on any machine
                running = lambda: self.ctl.logic is not None and self.ctl.logic.state == "running"  # noqa: E731,E501
            if not self._spin_until(running, 60.0):
                raise RuntimeError("the controller did not start within 60 s")
            self.t_start = self.sim.cell.t if self.rtf is None else self.obs.t_sim
            if self.arrival != "none":
                self._set_sim("arrival", self.arrival)
            self.started = True
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def _advance(self, n: int) -> None:
        k0 = self.sim.cell.k
        super()._advance(n)
        stride = self.sim.params.pose_stride
        if self.started and self.rtf is None and self.sim.cell.k // stride != k0 // stride:
            self.obs.sample()  # the pose period the slice reached, as the topic gives it

    def _set_sim(self, name: str, value: str) -> None:
        """Set a string parameter of the cell over its set_parameters service."""
        from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
        from rcl_interfaces.srv import SetParameters

        client = self.watcher.create_client(SetParameters, "sorter_sim/set_parameters")
        if not self._spin_until(client.service_is_ready, 10.0):
            raise RuntimeError("the cell's set_parameters service is not there")
        future = client.call_async(
            SetParameters.Request(
                parameters=[
                    Parameter(
                        name=name,
                        value=ParameterValue(
                            type=ParameterType.PARAMETER_STRING, string_value=value
                        ),
                    )
                ]
            )
        )
        self._spin_until(future.done, 10.0)
        result = future.result().results[0] if future.done() else None
        if result is None or not result.successful:
            raise RuntimeError(
                f"the cell refused {name} = {value}: {result.reason if result else 'no answer'}"
            )

    def _spin_until(self, predicate, timeout_wall: float) -> bool:
        """Spin without advancing simulated time until ``predicate()``; a Ctrl-C ends it."""
        if not self.spin_until(predicate, timeout_wall, stop=self.stop) and self.stop.is_set():
            if not self.started:
                raise KeyboardInterrupt  # stopped while starting: nothing to report
        return predicate()

    def run_for(self, sim_time: float, quiet: bool = True) -> float:
        """
        Run ``sim_time`` simulated seconds after the stream started.

        Returns the wall time. Unless ``quiet``, a progress bar on a terminal shows the
        simulated seconds.

        Parameters
        ----------
        sim_time : float
            Simulated seconds.
        quiet : bool
            No progress bar.

        Returns
        -------
        float
            The wall time it took [s].

        """
        from sorter_sim.studies.progress import progress_bar

        wall0 = time.monotonic()
        bar = progress_bar(round(sim_time, 3), "sorter demo", "s", quiet=quiet)
        shown = 0.0
        t_end = self.t_start + sim_time

        def now() -> float:
            return self.sim.cell.t if self.rtf is None else self.obs.t_sim

        def reached() -> bool:
            nonlocal shown
            t = min(now() - self.t_start, sim_time)
            if t - shown >= 0.1:
                bar.update(round(t - shown, 3))
                shown = t
            return now() >= t_end - 1e-12

        try:
            if self.rtf is None:
                while not reached() and not self.stop.is_set():
                    self.run(min(PROGRESS_S, t_end - now()))
            else:
                self.spin_until(reached, stop=self.stop)
        finally:
            bar.close()
        return time.monotonic() - wall0

    def finish(self) -> float:
        """
        Stop the cell's clock and return the simulated time of the stream.

        Stop the cell's clock, let the last confirmations arrive; returns the simulated time
        since the stream started.
        """
        if self.rtf is None:
            t_end = self.sim.cell.t - self.t_start
            self.spin_idle()  # the clock stands still: what is under way arrives
        else:
            t_end = self.obs.t_sim - self.t_start
            self.executor.remove_node(self.sim)
            deadline = time.monotonic() + 0.6
            while time.monotonic() < deadline:
                self.executor.spin_once(timeout_sec=0.05)
        self.obs.ctl_diag = {
            **self.obs.ctl_diag,
            **{k: str(v) for k, v in _diag_values(self.ctl).items()},
        }
        return t_end

    def __exit__(self, *exc) -> None:
        if self.stop is not None:
            self.stop.quiet = True  # the teardown is short: it finishes whatever comes now
        self.close()
        if self.stop is not None:
            self.stop.restore()


def run(args) -> int | str:
    """
    ``sorter demo``.

    Parameters
    ----------
    args : list of str or argparse.Namespace
        The command line, or the parsed arguments.

    Returns
    -------
    int or str
        The exit code, or a message for a refused input (exit 2).

    """
    if args.stations != 1:
        if not 1 <= args.stations <= 64:
            return f"--stations must be in [1, 64], got {args.stations}"
        if args.io != "ros":
            return (
                "--stations N > 1: the line's controllers talk ROS; its fieldbus (a Modbus "
                "unit id and an OPC UA folder per station) is line_node's, not the demo's --io"
            )
        err = _check_args(args)
        if err:
            return err
        problem = args.dispositions and file_problem(args.dispositions, "--dispositions")
        if problem:
            return problem
        from sorter_cell.line_demo import run_line

        return run_line(args)
    if (
        args.executor
        or args.dispositions
        or args.segments != 1
        or args.sync
        or args.restart
        or args.parcels
        or args.no_drain
    ):
        return (
            "--executor, --segments, --sync, --restart, --parcels, --no-drain and "
            "--dispositions are "
            "the line's: use them with --stations N > 1"
        )
    err = _check_args(args)
    if err:
        return err
    if args.io != "ros":
        if args.rtf != "fast" or args.foxglove or args.record:
            return (
                "--io modbus|opcua|s7 runs the cell and the soft PLC in step: no --rtf, "
                "--foxglove or --record with it"
            )
        from sorter_cell.demo_soft_plc import run_soft_plc

        return run_soft_plc(args)
    from sorter_ros.env import find_config_dir

    plan, sim_params = _stream(args, find_config_dir())
    controller_params = {"routing.rules": list(ROUTING)}
    if args.record:
        # both nodes write into the one file (sorter_ros.recording shares it in a process)
        sim_params["record_path"] = controller_params["record_path"] = args.record
    if args.foxglove:
        sim_params["foxglove_port"] = args.foxglove
    try:
        rc = RunningCell(
            sim_params=sim_params,
            controller_params=controller_params,
            rtf=args.rtf,
            log_level="info" if args.verbose else "warn",
        ).__enter__()
    except ValueError as exc:
        # a node refused its start-up values (a busy live-view port, an unwritable file)
        return str(exc)
    if args.foxglove:
        print(
            f"sorter demo: live view on ws://127.0.0.1:{args.foxglove} (open it in Foxglove)",
            file=sys.stderr,
        )
    try:
        with rc.stop.hurry_interrupts():  # a second Ctrl-C mid-spin: exit 130
            wall = rc.run_for(args.sim_time, quiet=args.quiet)
            t_end = rc.finish()
        summary = summarize(rc.obs, plan, t_end, wall, rc.time_mode)
        summary["png"] = str(args.out)
        try:
            title = (
                f"sorter demo: {summary['inducted']} parcels in {summary['sim_time_s']:g} s, "
                f"{summary['throughput_pcs_h']:.0f} pcs/h, mis-sorted {summary['mis_sorted']}, "
                f"jams {summary['jams']}"
            )
            exit_of = exits_by_id(rc.obs.outcomes.values())
            plot_paths(rc.obs.paths, exit_of, cell_params(rc.sim), title, Path(args.out))
        except OSError as exc:
            # checked before the run, yet gone since (a full disk): the summary still counts
            summary["png"] = None
            why = exc.strerror or exc
            print(f"sorter demo: cannot write {args.out!r}: {why}", file=sys.stderr)
    finally:
        rc.__exit__(None, None, None)
    if args.json:
        print(json.dumps(summary, sort_keys=True))
    else:
        print_table(summary)
        print(f"  paths                      {args.out}")
        if args.record:
            print(f"  recording                  {args.record} (sorter replay {args.record})")
    return exit_code(summary)


def _diag_values(ctl) -> dict:
    """Return the controller's final diagnostic values (the same the diagnostics topic carries)."""
    from sorter_ros.outcomes import values

    return values(ctl.diagnostic_status())
