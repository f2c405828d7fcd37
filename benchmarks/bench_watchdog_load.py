"""
The cell and its controller in two processes, real time, on a loaded machine.

Starts ``sim_node`` (config/cell.yaml, real time) and ``controller_node``
(config/controller.yaml) as a user would, under a defined load: two busy loops (one
process each) and a burst every 3 s (two more processes busy for 0.4 s). Runs for
``--seconds`` of wall time and counts, from the nodes' own logs and diagnostics:
watchdog trips, simulated time dropped, and the faults the controller latched.

    .venv/bin/python benchmarks/bench_watchdog_load.py --seconds 240

Prints one JSON object: trips and latched faults, each also per hour.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent


def _busy(stop_at: float) -> None:
    while time.monotonic() < stop_at:
        pass


def _bursts(stop_at: float, period: float = 3.0, length: float = 0.4) -> None:
    while time.monotonic() < stop_at:
        time.sleep(period - length)
        end = time.monotonic() + length
        procs = [mp.Process(target=_busy, args=(end,)) for _ in range(2)]
        for p in procs:
            p.start()
        for p in procs:
            p.join()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--seconds', type=float, default=240.0, help='wall time to run (240)')
    ap.add_argument('--no-load', action='store_true', help='run on an idle machine')
    ap.add_argument(
        '--stall-sim',
        type=float,
        default=0.0,
        metavar='S',
        help='also stop the simulation process for S seconds every 5 s (SIGSTOP/SIGCONT), '
        'as a host that deschedules it does',
    )
    ap.add_argument(
        '--stall-controller',
        type=float,
        default=0.0,
        metavar='S',
        help='stop the controller process for S seconds every 5 s: a PLC that freezes',
    )
    args = ap.parse_args()
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
    env.setdefault('ROS_DOMAIN_ID', str(40 + os.getpid() % 50))
    cfg = ROOT / 'config'
    sim = subprocess.Popen(
        [str(BIN / 'sim_node'), '--ros-args', '--params-file', str(cfg / 'cell.yaml')],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    ctl = subprocess.Popen(
        [
            str(BIN / 'controller_node'),
            '--ros-args',
            '--params-file',
            str(cfg / 'controller.yaml'),
        ],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    time.sleep(15.0)  # both up and running before the load and the count start
    stop_at = time.monotonic() + args.seconds
    load = []
    if not args.no_load:
        load = [mp.Process(target=_busy, args=(stop_at,)) for _ in range(2)]
        load.append(mp.Process(target=_bursts, args=(stop_at,)))
        for p in load:
            p.start()
    t0 = time.monotonic()
    stalls = 0
    while time.monotonic() < stop_at:
        stall, victim = (
            (args.stall_sim, sim) if args.stall_sim > 0 else (args.stall_controller, ctl)
        )
        if stall > 0:
            time.sleep(min(5.0, max(0.0, stop_at - time.monotonic())))
            if time.monotonic() >= stop_at:
                break
            victim.send_signal(signal.SIGSTOP)
            time.sleep(stall)
            victim.send_signal(signal.SIGCONT)
            stalls += 1
        else:
            time.sleep(max(0.0, stop_at - time.monotonic()))
    wall = time.monotonic() - t0
    for p in load:
        p.join()
    for proc in (ctl, sim):
        proc.send_signal(signal.SIGINT)
    sim_log = sim.communicate(timeout=30)[0]
    ctl_log = ctl.communicate(timeout=30)[0]
    trips = len(re.findall(r'watchdog: no controller heartbeat', sim_log))
    dropped = sum(float(x) for x in re.findall(r'dropping ([0-9.]+) s of simulated time', sim_log))
    drops = len(re.findall(r'dropping [0-9.]+ s of simulated time', sim_log))
    # a fault the controller latches: '<kind>: <why>; no diverts until reset'
    faults = [line for line in ctl_log.splitlines() if 'no diverts until reset' in line]
    cleared = [line for line in ctl_log.splitlines() if 'cleared' in line.lower()]
    # what the controller took as a consequence of the cell's watchdog trip, not latched
    consequences = [line for line in ctl_log.splitlines() if 'not latched' in line]
    per_hour = 3600.0 / wall
    out = {
        'wall_s': round(wall, 1),
        'load': 'none' if args.no_load else 'two busy loops + 2x0.4 s bursts every 3 s',
        'stalls': (
            f'{stalls} x {args.stall_sim or args.stall_controller:g} s of the '
            f'{"simulation" if args.stall_sim else "controller"}'
            if stalls
            else 'none'
        ),
        'cpus': os.cpu_count(),
        'watchdog_trips': trips,
        'watchdog_trips_per_hour': round(trips * per_hour, 1),
        'drop_warnings': drops,
        'simulated_s_dropped_logged': round(dropped, 3),
        'controller_fault_lines': len(faults),
        'controller_fault_lines_per_hour': round(len(faults) * per_hour, 1),
        'faults_cleared_lines': len(cleared),
        'consequences_not_latched': len(consequences),
        'first_faults': [f.split(']: ', 1)[-1][:160] for f in faults[:6]],
        'log_lines': [len(sim_log.splitlines()), len(ctl_log.splitlines())],
    }
    print(json.dumps(out, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
