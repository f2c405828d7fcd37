"""
``sorter demo --stations N`` (N > 1): a line of N diverters, its PLCs and its WCS, over ROS 2.

In one process, one rclpy context and one executor: the line node (``sorter_line``,
N stations in namespaces S01 ..), one controller node per station (this project's
PLC program, in the station's namespace), the warehouse node (``sorter_wcs``: the
sort plan, the requests, the tracking between stations, the dispositions) and an
observer. The sort plan sends destinations D01 .. D(2N) to the 2N chutes in order;
each parcel (labels P00001, P00002, ...) is requested to a destination drawn
uniformly, before it reaches the scanner. The line runs as fast as possible in
5 ms slices (``time_mode: fast``), or on the wall clock at ``--rtf F``; ``--foxglove``
serves the whole line's live view, ``--record`` records it into one MCAP file. After
``--sim-time`` the infeed stops and the line runs empty, so that every parcel has its
disposition (``--dispositions FILE.jsonl`` writes them, one a line).

The summary (``--json``: one object) has ``stations``, ``inducted``, ``mis_sorted``,
``jams``, ``in_cell_at_end``, ``exits`` (chute -> count), ``dispositions`` (code ->
count), ``throughput_pcs_h``, ``real_time_factor`` and the wall and simulated times.
"""

from __future__ import annotations

import json
import math
import time
from collections import Counter

FAST_SLICE = 0.005


def run_line(args) -> int | str:
    """
    Run the line demo.

    Parameters
    ----------
    args : argparse.Namespace
        ``sorter demo``'s arguments (``stations``, ``sim_time``, ``seed``, ``json``, ``quiet``).

    Returns
    -------
    int or str
        0 when nothing was mis-sorted or jammed and every disposition is counted, 1
        otherwise; a message for a refused input.

    """
    import numpy as np
    import rclpy
    from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
    from rclpy.context import Context
    from rclpy.parameter import Parameter
    from rclpy.signals import SignalHandlerOptions

    from sorter_control.node import ControllerNode
    from sorter_control.wcs_node import WcsNode
    from sorter_ros.env import apply_ros_env_defaults, find_config_dir
    from sorter_ros.interface import EVENT_QOS, SENSOR_QOS
    from sorter_sim.frontends.line_node import LineNode
    from sorter_sim.model.description import station_name

    n = args.stations
    if not (isinstance(n, int) and 1 <= n <= 64):
        return f'--stations must be an integer in [1, 64], got {n}'
    apply_ros_env_defaults()
    config = find_config_dir()
    ctx = Context()
    rclpy.init(
        context=ctx,
        signal_handler_options=SignalHandlerOptions.NO,
        args=[
            '--ros-args',
            '--params-file',
            str(config / 'cell.yaml'),
            '--params-file',
            str(config / 'controller.yaml'),
            '--log-level',
            'error',
        ],
    )
    nodes = []
    fast = args.rtf == 'fast'
    try:
        line = LineNode(
            context=ctx,
            parameter_overrides=[
                Parameter('stations', value=n),
                Parameter('time_mode', value='fast' if fast else 'realtime'),
                Parameter('fast_slice', value=FAST_SLICE),
                Parameter('real_time_factor', value=1.0 if fast else float(args.rtf)),
                Parameter('record_path', value=args.record or ''),
                Parameter('foxglove_port', value=int(args.foxglove or 0)),
            ],
            station_params={
                'arrival': 'none',
                'labels': ['P'],
                'label_pattern': '{label}{id:05d}',
                'seed': int(args.seed),
                'pose_rate_hz': 50.0,
                **({'arrival_gap': [float(g) for g in args.gap]} if args.gap else {}),
            },
        )
        nodes += line.nodes
        ctls = [
            ControllerNode(
                context=ctx,
                namespace=f'/{station_name(k)}',
                parameter_overrides=[
                    Parameter('use_sim_time', value=True),
                    # a station's routing table is the WCS's alone (the single cell's rules
                    # would divert labels that happen to match them)
                    Parameter('routing.rules', Parameter.Type.STRING_ARRAY, []),
                    Parameter('diagnostics_period', value=5.0),
                    Parameter('record_path', value=args.record or ''),
                ],
            )
            for k in range(n)
        ]
        nodes += ctls
        wcs = WcsNode(
            context=ctx,
            parameter_overrides=[
                Parameter('stations', value=n),
                Parameter('use_sim_time', value=True),  # its recording on the line's clock
                Parameter('record_path', value=args.record or ''),
            ],
        )
        nodes.append(wcs)
        obs = rclpy.create_node('sorter_line_demo', context=ctx)
        nodes.append(obs)
        disp: dict[str, str] = {}
        records: list[dict] = []  # every disposition, in the order the WCS gave them
        exits: dict[str, str] = {}

        def on_disposition(m):
            disp[m.name] = m.message
            records.append({kv.key: kv.value for kv in m.values})

        obs.create_subscription(DiagnosticStatus, 'wcs/dispositions', on_disposition, EVENT_QOS)
        obs.create_subscription(
            DiagnosticStatus,
            'line/exits',
            lambda m: exits.__setitem__({kv.key: kv.value for kv in m.values}['label'], m.message),
            EVENT_QOS,
        )
        active = []
        obs.create_subscription(
            DiagnosticStatus, 'wcs/sort_plan/active', active.append, SENSOR_QOS
        )
        pub_plan = obs.create_publisher(DiagnosticStatus, 'wcs/sort_plan', EVENT_QOS)
        pub_req = obs.create_publisher(KeyValue, 'wcs/requests', EVENT_QOS)
        ex = _executor(ctx, args.executor or 'events')
        for node in nodes:
            ex.add_node(node)

        def spin_until(pred, wall_s):
            end = time.monotonic() + wall_s
            while not pred():
                if time.monotonic() > end:
                    return False
                ex.spin_once(timeout_sec=0.02)
            return True

        if not spin_until(
            lambda: all(c.logic is not None and c.logic.state == 'running' for c in ctls), 120.0
        ):
            return 'the stations\' controllers did not start within 120 s'
        chutes = [c.name for c in line.line.chutes]
        dests = [f'D{j + 1:02d}' for j in range(len(chutes))]
        spin_until(lambda: pub_plan.get_subscription_count() > 0, 10.0)
        pub_plan.publish(
            DiagnosticStatus(
                name='v1', values=[KeyValue(key=d, value=c) for d, c in zip(dests, chutes)]
            )
        )
        if not spin_until(lambda: active, 10.0):
            return 'the warehouse node did not take the sort plan'
        rng = np.random.default_rng(int(args.seed))
        expected = math.ceil(args.sim_time * 1.5) + 10  # more than the infeed can send
        want = {}
        for i in range(1, expected + 1):
            label = f'P{i:05d}'
            want[label] = dests[int(rng.integers(len(dests)))]
            pub_req.publish(KeyValue(key=label, value=want[label]))
            if i % 50 == 0:  # within the subscription's queue (depth 100)
                spin_until(lambda i=i: len(wcs.wcs.requests) >= i, 10.0)
        if not spin_until(lambda: len(wcs.wcs.requests) == expected, 10.0):
            return f'the warehouse node took {len(wcs.wcs.requests)} of {expected} requests'
        spin_until(lambda: False, 0.3)  # the routing updates reach the stations
        t0, wall0 = line.line.t, time.monotonic()
        line.cost = {'physics_s': 0.0, 'publish_s': 0.0}
        scans0 = [c.logic.scan_wall_total for c in ctls]
        line.stations[0].set_parameters([Parameter('arrival', value='gap')])
        spin_until(lambda: line.line.t >= t0 + args.sim_time, math.inf)
        wall = time.monotonic() - wall0
        sim = line.line.t - t0
        n_out = len(exits)
        ctl_s = sum(c.logic.scan_wall_total - w0 for c, w0 in zip(ctls, scans0))
        cost = dict(line.cost)
        # the infeed stops and the line runs empty, so that every parcel inducted gets
        # its disposition: at most the belt's transit over the whole line, twice, + 10 s
        line.stations[0].set_parameters([Parameter('arrival', value='none')])
        p0 = line.stations[0].params
        transit = (line.line.layout.positions[-1] + p0.exit_x - p0.induct_x) / p0.belt_speed
        t_drain = line.line.t + 2.0 * transit + 10.0
        spin_until(lambda: line.line.n_parcels == 0 or line.line.t >= t_drain, math.inf)
        ex.remove_node(line)  # stop the clock; let the last messages in
        inducted = line.stations[0].cell.n_inducted
        spin_until(lambda: len(disp) + line.line.n_parcels >= inducted, 5.0)
        on_line = line.line.n_parcels
        exit_counts = Counter(exits.values())
        codes = Counter(r['code'] for r in records)
        if args.dispositions:
            with open(args.dispositions, 'w', encoding='utf-8') as f:
                for r in records:
                    f.write(json.dumps(r, sort_keys=True) + '\n')
        summary = {
            'stations': n,
            'inducted': inducted,
            'mis_sorted': codes.get('mis_sorted', 0),
            'jams': codes.get('jammed', 0),
            'in_cell_at_end': on_line,
            'exits': dict(sorted(exit_counts.items())),
            'dispositions': dict(sorted(codes.items())),
            'throughput_pcs_h': 3600.0 * n_out / sim if sim > 0 else 0.0,
            'real_time_factor': sim / wall if wall > 0 else 0.0,
            'sim_time_s': sim,
            'executor': type(ex).__name__,
            'wall_s': wall,
            'chutes_reached': sum(1 for c in chutes if exit_counts.get(c)),
            'chutes': len(chutes),
            # where the wall time went: the line's physics, the stations' publishing, the
            # PLC programs' scans; the rest is DDS, the executor and the callbacks around them
            'cost_s': {
                'physics': round(cost['physics_s'], 3),
                'publishing': round(cost['publish_s'], 3),
                'controllers': round(ctl_s, 3),
                'other': round(wall - cost['physics_s'] - cost['publish_s'] - ctl_s, 3),
            },
        }
        ok = (
            summary['mis_sorted'] == 0
            and summary['jams'] == 0
            and sum(codes.values()) + on_line == inducted
        )
        if args.json:
            print(json.dumps(summary, sort_keys=True))
        else:
            for k, v in summary.items():
                print(f'  {k:<22} {v}')
        return 0 if ok else 1
    finally:
        for node in nodes:
            try:
                node.destroy_node()
            except Exception:  # noqa: BLE001 - teardown goes on
                pass
        rclpy.try_shutdown(context=ctx)


def _executor(ctx, kind: str):
    """
    Return the line's executor: rclpy's events executor, or the single-threaded one.

    The single-threaded executor builds a new wait set from every entity of every node
    on each pass (about 110 a station: the station's and its controller's publishers,
    subscriptions, services, timers and their QoS event handlers), in Python: with 24
    stations a pass costs more wall time than the 5 ms of simulated time it serves.
    The events executor (``rclpy.experimental``, in C++) queues each entity's events as
    they happen and walks nothing. The line's results do not depend on the choice (a
    test runs both and compares every parcel's exit); the single-threaded one stays
    for an rclpy without the events executor.
    """
    if kind == 'events':
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:
            pass
        else:
            return EventsExecutor(context=ctx)
    from rclpy.executors import SingleThreadedExecutor

    return SingleThreadedExecutor(context=ctx)
