"""
One segment of the demo's line: its line node and its stations' PLC programs, in one process.

``build_segment`` makes the nodes (used in process by ``sorter demo --stations N`` and
here for ``--segments K``); ``main`` runs one segment as a process of its own:

    python -m sorter_cell.line_segment --first 5 --stations 4 --line-stations 12

(``--clock /line/segment2/clock`` for its time's topic, ``--parcels M --start`` for a
batch that starts at once).

It prints ``ready`` once its controllers run, spins until SIGTERM or SIGINT, then
prints one JSON object: its time, its hand-over counts and latencies, its cost. Each
segment publishes its simulated time on a clock topic of its own (``--clock``, by
remapping ``/clock`` in the process): the segments of a lock-step line are at
different times, each behind its upstream neighbour (never ahead), and a controller must
follow its own segment's clock.
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
import signal
import sys
import time
from dataclasses import dataclass

FAST_SLICE = 0.005  # s of simulated time per pass of a line in fast mode
LOCKSTEP_SLICE = 0.05  # s simulated at most per slice of a lock-step line (cut at scans)


@dataclass(frozen=True)
class SegmentStream:
    """
    The parcel stream a line's first station inducts (the other segments' is unused).

    Attributes
    ----------
    seed : int
        The stream's seed (station 1's).
    gap : (float, float), optional
        The stream's gap range [m].
    count : int
        The stream stops after this many parcels (0: never).

    """

    seed: int
    gap: tuple[float, float] | None = None
    count: int = 0


@dataclass(frozen=True)
class SegmentRun:
    """
    How a segment runs: its pace, how it keeps time with the others, what it records.

    Attributes
    ----------
    fast : bool
        As fast as possible (True) or on the wall clock at ``rtf``.
    lockstep : bool
        As fast as possible, advanced by the process's run loop (``time_mode: lockstep``)
        rather than by the line node's own timer: a line wholly in one process.
    rtf : float
        The real-time factor on the wall clock.
    sync : str
        How the segments keep time together: ``conservative`` or ``barrier``.
    record : str
        An MCAP file for the whole segment, or ''.
    foxglove : int
        The live view's port, or 0.
    warehouse : bool
        The line has a warehouse node: the segment's time holds until it reads the
        edges of its stations (``wait_for_warehouse``).
    contact : str
        What a touch is at every station, ``rigid`` or ``jam`` ('': the cell's own,
        config/cell.yaml). Every segment of a line must be given the same.

    """

    fast: bool = True
    lockstep: bool = False
    rtf: float = 1.0
    sync: str = 'conservative'
    record: str = ''
    foxglove: int = 0
    warehouse: bool = False
    contact: str = ''


def build_segment(
    ctx,
    *,
    first: int,
    stations: int,
    line_stations: int,
    stream: SegmentStream,
    run: SegmentRun = SegmentRun(),
):
    """
    Return a segment's line node and one controller per station, in context ``ctx``.

    Parameters
    ----------
    ctx : rclpy.context.Context
        Initialised with the cell's and the controller's params files.
    first : int
        The line's number of the segment's first station (1-based).
    stations : int
        Its stations.
    line_stations : int
        The whole line's.
    stream : SegmentStream
        The parcel stream station 1 inducts.
    run : SegmentRun
        Its pace, time keeping and outputs.

    Returns
    -------
    (LineNode, list of ControllerNode)
        The segment's nodes.

    """
    from rclpy.parameter import Parameter

    from sorter_sim.frontends.line_node import NODE_NAME, LineNode
    from sorter_sim.model.description import station_name

    line = LineNode(
        context=ctx,
        node_name=NODE_NAME if first == 1 else f'{NODE_NAME}_{station_name(first - 1)}',
        parameter_overrides=[
            Parameter('stations', value=stations),
            Parameter('first_station', value=first),
            Parameter('line_stations', value=line_stations),
            Parameter(
                'time_mode',
                value='lockstep' if run.lockstep else 'fast' if run.fast else 'realtime',
            ),
            Parameter('fast_slice', value=FAST_SLICE),
            Parameter('real_time_factor', value=1.0 if run.fast else float(run.rtf)),
            Parameter('record_path', value=run.record),
            Parameter('foxglove_port', value=int(run.foxglove)),
            Parameter('segment_sync', value=run.sync),
            # a segment of a line with a warehouse: its stations' labels come from the edges
            # the warehouse hears, so it runs once the warehouse reads them (at its start,
            # and when it is started again during the run)
            Parameter('wait_for_warehouse', value=run.warehouse),
        ],
        station_params={
            'arrival': 'none',
            'labels': ['P'],
            'label_pattern': '{label}{id:05d}',
            'seed': int(stream.seed),
            'pose_rate_hz': 50.0,
            'arrival_count': int(stream.count),
            **({'arrival_gap': [float(g) for g in stream.gap]} if stream.gap else {}),
            **({'contact': run.contact} if run.contact else {}),
        },
    )
    try:
        ctls = [station_controller(ctx, first - 1 + k, run.record) for k in range(stations)]
    except BaseException:
        line.destroy_node()
        raise
    return line, ctls


def station_controller(ctx, station: int, record: str = ''):
    """
    Return this project's PLC program for a station of a line (0-based), in its namespace.

    Parameters
    ----------
    ctx : rclpy.context.Context
        Initialised with the controller's params file.
    station : int
        The station, 0-based (namespace ``/S01`` for 0).
    record : str
        An MCAP file it records into, or ''.

    Returns
    -------
    sorter_control.node.ControllerNode
        The program, on the line's clock.

    """
    from rclpy.parameter import Parameter

    from sorter_control.node import ControllerNode
    from sorter_sim.model.description import station_name

    return ControllerNode(
        context=ctx,
        namespace=f'/{station_name(station)}',
        parameter_overrides=[
            Parameter('use_sim_time', value=True),
            # a station's routing table is the WCS's alone (the single cell's rules
            # would divert labels that happen to match them)
            Parameter('routing.rules', Parameter.Type.STRING_ARRAY, []),
            Parameter('diagnostics_period', value=5.0),
            Parameter('record_path', value=record),
        ],
    )


def segment_stats(line, ctls) -> dict:
    """Return what a segment reports when it stops (see the module)."""
    link = line.segment
    lat = sorted(link.latencies_ns)

    def pct(q):
        return round(lat[min(len(lat) - 1, int(q * len(lat)))] * 1e-6, 3) if lat else None

    stats = {
        'first_station': line.first + 1,
        'stations': len(line.stations),
        't': line.line.t,
        'parcels': line.line.n_in_flight,
        'handed_on': link.stats['sent'],
        'messages_sent': link.stats['messages'],  # hand-overs and horizons
        'taken': link.stats['received'],
        'late': link.stats['late'],
        'refused': link.stats['refused'],
        'lost': link.stats['lost'],  # handed to it and not taken: said lost, with the cause
        'resent': link.stats['resent'],  # sent again: the segment downstream (re)started
        'duplicates': link.stats['duplicates'],  # copies of parcels it had, dropped
        'in_custody': len(link.outbox),  # handed on, not yet out of the segment downstream
        'exits': dict(Counter(e.exit for e in line.line.exits)),
        'handover_latency_ms_p50': pct(0.5),
        'handover_latency_ms_p99': pct(0.99),
        'cost_s': {
            'physics': round(line.cost['physics_s'], 3),
            'publishing': round(line.cost['publish_s'], 3),
            'controllers': round(sum(c.logic.scan_wall_total for c in ctls if c.logic), 3),
        },
    }
    if line.first == 0:
        stats['inducted'] = line.stations[0].cell.n_inducted  # the line's stream is its
    return stats


def main(argv=None) -> int:
    """Run one segment until SIGTERM (see the module); return the exit code."""
    ap = argparse.ArgumentParser(prog='python -m sorter_cell.line_segment')
    ap.add_argument('--first', type=int, required=True)
    ap.add_argument('--stations', type=int, required=True)
    ap.add_argument('--line-stations', type=int, required=True)
    ap.add_argument('--seed', type=int, default=1)
    ap.add_argument('--gap', type=float, nargs=2, default=None)
    ap.add_argument('--rtf', default='fast')
    ap.add_argument('--sync', choices=('conservative', 'barrier'), default='conservative')
    ap.add_argument('--parcels', type=int, default=0, help='the stream stops after these')
    ap.add_argument(
        '--contact',
        choices=('jam', 'rigid'),
        default='',
        help="what a touch is at every station (default: the cell's, config/cell.yaml)",
    )
    ap.add_argument(
        '--warehouse',
        action='store_true',
        help="hold the segment's time until a warehouse node reads its stations' edges",
    )
    ap.add_argument(
        '--start', action='store_true', help='start the stream at once (station 1 only)'
    )
    ap.add_argument(
        '--clock',
        default='',
        help="the topic it publishes its time on (default /line/S<first>/clock: every "
        "segment's its own)",
    )
    ap.add_argument(
        '--report', type=float, default=0.0, help='print its figures every S wall seconds too'
    )
    args = ap.parse_args(argv)
    stop = []
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.append(True))

    from sorter_ros.run_loop import RunLoop
    from sorter_sim.runtime.params import ParamError

    fast = args.rtf == 'fast'
    loop = RunLoop(
        slice_s=LOCKSTEP_SLICE,
        log_level='error',
        align_to_timers=True,
        ros_args=('-r', f'/clock:={args.clock or f"/line/S{args.first:02d}/clock"}'),
    )
    try:
        try:
            line, ctls = build_segment(
                loop.context,
                first=args.first,
                stations=args.stations,
                line_stations=args.line_stations,
                stream=SegmentStream(seed=args.seed, gap=args.gap, count=args.parcels),
                run=SegmentRun(
                    fast=fast,
                    # a barrier line (kept for comparison) meets its neighbours every 5 ms
                    # slice: in fast mode, as before, its slices are not drained one by one
                    lockstep=fast and args.sync != 'barrier',
                    rtf=1.0 if fast else float(args.rtf),
                    sync=args.sync,
                    warehouse=args.warehouse,
                    contact=args.contact,
                ),
            )
        except ParamError as exc:  # the cell's file and the command line disagree
            print(f"line_segment: the stations refuse their parameters: {exc}", file=sys.stderr)
            return 2
        if args.start:
            from rclpy.parameter import Parameter

            line.stations[0].set_parameters([Parameter('arrival', value='gap')])
        loop.add_node([*line.nodes, *ctls])
        if line.values['time_mode'] == 'lockstep':
            loop._stepper, loop._timebase = line, line.line
        _run_segment(loop, line, ctls, args, stop)
        try:
            print(json.dumps(segment_stats(line, ctls), sort_keys=True), flush=True)
        except BrokenPipeError:  # the demo that reads it is gone (Ctrl-C): nobody to tell
            pass
    finally:
        loop.close()
    return 0


def _run_segment(loop, line, ctls, args, stop) -> None:
    """
    Run the segment until ``stop``: in lock-step when fast, else on its own clock.

    In lock-step, the segment's time stands still until its programs run (then ``ready``), and
    each slice ends at their next scan and is served whole before the next: a program
    starved of the CPU still scans where its period says, so the line's split does not
    change a parcel's chute. A slice the line cannot run (held by its neighbours: the
    segment upstream's horizon, the segment downstream's backlog, the warehouse's
    answer) waits for the next message instead.
    """
    told = False
    next_report = 0.0
    while not stop:
        # the reports follow "ready", never precede it: a reader takes the first line
        # for it, and on a loaded machine the controllers can take longer than a period
        if told and args.report > 0 and time.monotonic() >= next_report:
            print(json.dumps(segment_stats(line, ctls), sort_keys=True), flush=True)
            next_report += args.report
        if not told:
            if all(c.logic is not None and c.logic.state == 'running' for c in ctls):
                print('ready', flush=True)
                told = True
                next_report = time.monotonic() + args.report
                continue
            loop.executor.spin_once(timeout_sec=0.05)
            continue
        if loop._stepper is None:  # fast (barrier) or wall clock: the line node keeps its own
            loop.executor.spin_once(timeout_sec=0.05)
        elif not loop.step():
            loop.serve_one(0.05)  # held: a neighbour's message (or a look again) wakes it


if __name__ == '__main__':
    sys.exit(main())
