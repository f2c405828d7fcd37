"""
Benchmark of the run loop's floor: what one call to rclpy's executor costs, doing nothing.

Not a test: it prints microseconds. After each slice the run loop drains this
process's nodes by sending itself a marker on a hidden topic and serving the
executor until the marker comes back, then a second marker (``sorter_ros.run_loop``);
however little a slice causes, it pays for those calls. Measured here on one node of
its own (no simulation), ``--calls`` times each:

* ``spin_once(0)`` with nothing queued;
* a marker's round trip: publish to the node itself, ``spin_until_future_complete``
  with no timeout (a timeout costs the events executor a timer of its own);
* a marker published and served by one ``spin_once`` (the drain's second look: its
  timeout, never waited for, costs less than a timeout of 0);

for the events executor and, for comparison, the single-threaded one.

    .venv/bin/python benchmarks/bench_executor.py [--calls 2000] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import time


def measure(executor_kind: str, calls: int, domain_id: int) -> dict:
    """Return the three figures [us per call] for one executor."""
    import rclpy
    from rclpy.context import Context
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.task import Future
    from std_msgs.msg import Empty

    from sorter_ros.run_loop import make_executor

    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain_id)
    try:
        node = rclpy.create_node('bench_executor', context=ctx)
        qos = QoSProfile(
            history=HistoryPolicy.KEEP_LAST, depth=4, reliability=ReliabilityPolicy.RELIABLE
        )
        served = [None]

        def on_marker(_msg):
            if served[0] is not None:
                served[0].set_result(True)

        pub = node.create_publisher(Empty, '~/_marker', qos)
        node.create_subscription(Empty, '~/_marker', on_marker, qos)
        ex = make_executor(ctx, events=executor_kind == 'events')
        ex.add_node(node)
        for _ in range(50):  # discovery of its own reader, caches warm
            ex.spin_once(timeout_sec=0.01)
        out = {'executor': type(ex).__name__}
        t0 = time.perf_counter()
        for _ in range(calls):
            ex.spin_once(timeout_sec=0.0)
        out['spin_once_idle_us'] = (time.perf_counter() - t0) / calls * 1e6
        msg = Empty()
        t0 = time.perf_counter()
        for _ in range(calls):
            served[0] = Future()
            pub.publish(msg)
            ex.spin_until_future_complete(served[0])  # as the drain: no timeout's timer
        out['marker_round_us'] = (time.perf_counter() - t0) / calls * 1e6
        late = 0
        t0 = time.perf_counter()
        for _ in range(calls):
            served[0] = Future()
            pub.publish(msg)
            ex.spin_once(timeout_sec=5.0)  # as the drain: serves what is queued at once
            if not served[0].done():
                late += 1
                ex.spin_until_future_complete(served[0], timeout_sec=5.0)
        out['marker_one_call_us'] = (time.perf_counter() - t0) / calls * 1e6
        out['marker_not_in_one_call'] = late
        ex.shutdown()
        node.destroy_node()
        return out
    finally:
        rclpy.try_shutdown(context=ctx)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--calls', type=int, default=2000, help='calls per figure, 10-100000')
    ap.add_argument('--domain', type=int, default=int(os.environ.get('ROS_DOMAIN_ID', '0')))
    ap.add_argument('--json', action='store_true', help='one JSON object')
    args = ap.parse_args(argv)
    if not 10 <= args.calls <= 100_000:
        ap.error(f'--calls must be in [10, 100000], got {args.calls}')
    from sorter_ros.env import apply_ros_env_defaults

    apply_ros_env_defaults()
    rows = [measure(kind, args.calls, args.domain) for kind in ('events', 'single')]
    load = os.getloadavg()[0]
    if args.json:
        print(json.dumps({'load_average': load, 'calls': args.calls, 'rows': rows}))
        return 0
    print(f'{args.calls} calls each, load average {load:.2f}')
    print('| executor | spin_once(0), idle | marker round trip | marker in one spin_once |')
    print('|---|---|---|---|')
    for r in rows:
        print(
            f'| {r["executor"]} | {r["spin_once_idle_us"]:.0f} us | '
            f'{r["marker_round_us"]:.0f} us | {r["marker_one_call_us"]:.0f} us '
            f'({r["marker_not_in_one_call"]} not) |'
        )
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
