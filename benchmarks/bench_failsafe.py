"""
Benchmark of the fail-safe: a controller stopped with the disks up leaves them lowered.

Not a test: it prints counts and times. One ``sim_node`` runs on the wall clock
(config/cell.yaml, no parcel stream); then, ``--runs`` times, a ``controller_node``
(config/controller.yaml) starts, the disks are raised from outside (as a divert
under way would have them), and the controller gets SIGINT (or ``--signal
TERM``). A run counts when the controller exits with code 0 and the disks are
down within the cell's watchdog timeout plus one stroke time of the signal;
the time from the signal to the stroke reaching 0 is measured on the cell's
``diverter/state``. Last, a fresh controller takes over and three parcels are
inducted; their exits must be where the routing sends them.

    .venv/bin/python benchmarks/bench_failsafe.py [--runs 20] [--signal INT|TERM] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
NS = '/failsafe'
DOMAIN_ID = 117


def _start(exe: str, params_file: str, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [str(BIN / exe), '--ros-args', '-r', f'__ns:={NS}', '--params-file']
        + [str(ROOT / 'config' / params_file), *extra],
        env=dict(os.environ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--runs', type=int, default=20)
    ap.add_argument('--signal', choices=['INT', 'TERM'], default='INT')
    ap.add_argument('--json', action='store_true')
    args = ap.parse_args(argv)
    if args.runs < 1:
        ap.error(f'--runs must be >= 1, got {args.runs}')
    os.environ['ROS_DOMAIN_ID'] = str(DOMAIN_ID)
    if not os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE', '').strip():
        os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    import rclpy
    from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
    from sensor_msgs.msg import JointState
    from std_msgs.msg import UInt32
    from std_srvs.srv import SetBool

    from sorter_ros.interface import EVENT_QOS, STREAM_QOS
    from sorter_ros.outcomes import values

    rclpy.init()
    node = rclpy.create_node('failsafe_watcher')
    stroke = []  # (wall, stroke)
    beats = []
    outcomes = {}
    node.create_subscription(
        JointState,
        f'{NS}/diverter/state',
        lambda m: stroke.append((time.monotonic(), m.position[1])),
        STREAM_QOS,
    )
    node.create_subscription(
        UInt32, f'{NS}/controller/heartbeat', lambda m: beats.append(time.monotonic()), STREAM_QOS
    )
    node.create_subscription(
        DiagnosticStatus,
        f'{NS}/sort/outcomes',
        lambda m: outcomes.update({m.name: values(m)}),
        EVENT_QOS,
    )
    popup = node.create_client(SetBool, f'{NS}/diverter/popup')
    induct = node.create_publisher(DiagnosticStatus, f'{NS}/parcels/induct', EVENT_QOS)

    def spin_until(pred, timeout):
        deadline = time.monotonic() + timeout
        while not pred():
            if time.monotonic() > deadline:
                return False
            rclpy.spin_once(node, timeout_sec=0.01)
        return True

    sim = _start('sim_node', 'cell.yaml', '-p', 'arrival:=none')
    runs = []
    try:
        if not spin_until(lambda: popup.service_is_ready() and stroke, 60.0):
            print('the cell did not start', file=sys.stderr)
            return 2
        sig = signal.SIGINT if args.signal == 'INT' else signal.SIGTERM
        for k in range(args.runs):
            ctl = _start('controller_node', 'controller.yaml')
            n_beats = len(beats)
            up = spin_until(lambda: len(beats) > n_beats + 20, 60.0)  # it scans
            future = popup.call_async(SetBool.Request(data=True))
            raised = spin_until(future.done, 5.0) and future.result().success
            raised = raised and spin_until(lambda: stroke[-1][1] == 1.0, 5.0)
            t_sig = time.monotonic()
            ctl.send_signal(sig)
            lowered = spin_until(lambda: stroke[-1][1] == 0.0, 5.0)
            t_down = next((t for t, s in stroke if t >= t_sig and s == 0.0), None)
            out, err = ctl.communicate(timeout=20)
            text = out + err
            runs.append(
                {
                    'started': up,
                    'raised': raised,
                    'lowered': lowered,
                    'down_after_s': None if t_down is None else round(t_down - t_sig, 4),
                    'exit': ctl.returncode,
                    'by_controller': 'stopping: disks lowered' in text,
                    'traceback': 'Traceback' in text,
                }
            )
            print(f'run {k + 1}: {runs[-1]}', flush=True)
        # a fresh controller takes over, and sorts as routing says
        ctl = _start('controller_node', 'controller.yaml')
        n_beats = len(beats)
        spin_until(lambda: len(beats) > n_beats + 20, 60.0)
        routed = {'A': 'left', 'B': 'right', 'C': 'straight'}
        for label in ('A9001', 'B9002', 'C9003'):
            induct.publish(DiagnosticStatus(values=[KeyValue(key='label', value=label)]))
            spin_until(lambda: False, 1.5)
        spin_until(lambda: len(outcomes) >= 3, 30.0)
        exits = {v.get('label'): v.get('exit') for v in outcomes.values()}
        after = {label: exits.get(label) for label in ('A9001', 'B9002', 'C9003')}
        ctl.send_signal(signal.SIGINT)
        ctl.communicate(timeout=20)
    finally:
        sim.send_signal(signal.SIGINT)
        sim.communicate(timeout=20)
        node.destroy_node()
        rclpy.try_shutdown()
    limit = 0.3 + 0.1  # the cell's watchdog_timeout + popup_stroke_time (config/cell.yaml)
    good = [
        r
        for r in runs
        if r['raised']
        and r['lowered']
        and r['exit'] == 0
        and not r['traceback']
        and r['down_after_s'] is not None
        and r['down_after_s'] <= limit
    ]
    downs = sorted(r['down_after_s'] for r in runs if r['down_after_s'] is not None)
    as_routed = all(after[label] == routed[label[0]] for label in after)
    summary = {
        'signal': args.signal,
        'lowered_in_time': f'{len(good)}/{len(runs)}',
        'by_the_controller_itself': sum(r['by_controller'] for r in runs),
        'down_after_s_p50': statistics.median(downs) if downs else None,
        'down_after_s_max': downs[-1] if downs else None,
        'limit_s': limit,
        'after_restart': after,
        'after_restart_as_routed': as_routed,
    }
    print(json.dumps(summary) if args.json else '\n'.join(f'{k}: {v}' for k, v in summary.items()))
    return 0 if len(good) == len(runs) and as_routed else 1


if __name__ == '__main__':
    raise SystemExit(main())
