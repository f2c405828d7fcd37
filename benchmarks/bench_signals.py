"""
Benchmark of clean shutdown: both executables, SIGINT, a double SIGINT and SIGTERM.

Not a test: it prints counts. Each run starts the node as its console script
(``sim_node`` or ``controller_node``, standalone: the controller without a cell,
``cell_node:=''``) in a namespace and ROS domain of its own, waits until the node
is in the ROS graph, sends the signal(s) and waits for the process to end. A run
is clean when the exit code is 0 and the output holds no Python traceback and no
"Exception ignored" message. The double SIGINT sends the second signal a random
0-100 ms after the first, so it lands anywhere in the node's stop: during the
spin loop, the controller's last words, or the teardown. The start-up modes
send the signal a random 0-2 s after the executable has installed its handlers
(seen in /proc/<pid>/status), without waiting for the graph, so it lands anywhere
in the loading of its modules, rclpy's set-up and the node's construction (a run
counts as clean there too when the node never got into the graph). Before that
moment there is only the interpreter's own start, a few tens of milliseconds,
where Python's defaults apply; the time to it is printed. The kernels' cache is
filled before the first run, so no start compiles them (that takes longer than
the 20 s a run may take). A process that does not end within 20 s gets SIGABRT
first, so faulthandler (enabled in every child) prints where each thread waits.

    .venv/bin/python benchmarks/bench_signals.py [--runs 100] [--nodes sim_node controller_node]
        [--modes sigint double_sigint sigterm startup_sigint startup_sigterm] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

BIN = Path(sys.executable).parent
MODES = ('sigint', 'double_sigint', 'sigterm')
STARTUP_MODES = ('startup_sigint', 'startup_sigterm')
NODES = ('sim_node', 'controller_node')
NODE_NAMES = {'sim_node': 'sorter_sim', 'controller_node': 'sorter_controller'}
DOMAIN_ID = 113


def _ready(graph_node, namespace: str, name: str, timeout: float = 30.0) -> bool:
    import rclpy

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if (name, namespace) in graph_node.get_node_names_and_namespaces():
            return True
        rclpy.spin_once(graph_node, timeout_sec=0.05)
    return False


def _handlers_installed(pid: int, timeout: float = 10.0) -> float | None:
    """Seconds until ``pid`` catches SIGTERM (its SigCgt mask), None if it never does."""
    t0 = time.monotonic()
    bit = 1 << (signal.SIGTERM - 1)
    while time.monotonic() - t0 < timeout:
        try:
            with open(f'/proc/{pid}/status') as fh:
                for line in fh:
                    if line.startswith('SigCgt:') and int(line.split()[1], 16) & bit:
                        return time.monotonic() - t0
        except OSError:
            return None
        time.sleep(0.001)
    return None


def one_run(graph_node, exe: str, mode: str, k: int, rng: random.Random) -> dict:
    """Start ``exe``, stop it by ``mode``; return its exit code and what it printed."""
    ns = f'/bench_signals_{k}'
    args = [str(BIN / exe), '--ros-args', '-r', f'__ns:={ns}']
    if exe == 'controller_node':
        args += ['-p', "cell_node:=''"]
    else:
        args += ['-p', 'arrival:=none']
    env = dict(os.environ, PYTHONFAULTHANDLER='1')
    proc = subprocess.Popen(
        args, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    installed = None
    if mode in STARTUP_MODES:
        installed = _handlers_installed(proc.pid)
        time.sleep(rng.uniform(0.0, 2.0))
        up = installed is not None  # the node itself need not exist yet
        proc.send_signal(signal.SIGINT if mode == 'startup_sigint' else signal.SIGTERM)
    else:
        up = _ready(graph_node, ns, NODE_NAMES[exe])
        if mode == 'sigterm':
            proc.send_signal(signal.SIGTERM)
        else:
            proc.send_signal(signal.SIGINT)
            if mode == 'double_sigint':
                time.sleep(rng.uniform(0.0, 0.1))
                if proc.poll() is None:
                    proc.send_signal(signal.SIGINT)
    try:
        out, err = proc.communicate(timeout=20)
        hung = False
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGABRT)  # faulthandler prints every thread's stack
        try:
            out, err = proc.communicate(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, err = proc.communicate()
        hung = True
    text = out + err
    clean = (
        up
        and not hung
        and proc.returncode == 0
        and 'Traceback' not in text
        and 'Exception ignored' not in text
    )
    return {
        'up': up,
        'hung': hung,
        'code': proc.returncode,
        'clean': clean,
        'text': text,
        'installed_s': installed,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--runs', type=int, default=100, help='runs per node and mode')
    parser.add_argument('--nodes', nargs='+', default=list(NODES), choices=NODES)
    parser.add_argument(
        '--modes', nargs='+', default=list(MODES + STARTUP_MODES), choices=MODES + STARTUP_MODES
    )
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument('--json', action='store_true', help='print the counts as JSON')
    args = parser.parse_args(argv)
    if args.runs < 1:
        parser.error(f'--runs must be >= 1, got {args.runs}')
    os.environ['ROS_DOMAIN_ID'] = str(DOMAIN_ID)
    if not os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE', '').strip():
        os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    # a start that compiles the kernels would count as a hang
    subprocess.run(
        [sys.executable, '-m', 'sorter_sim.runtime.warmup'], check=True, capture_output=True
    )
    import rclpy

    rclpy.init()
    graph_node = rclpy.create_node('bench_signals_watcher')
    rng = random.Random(args.seed)
    table = {}
    k = 0
    t0 = time.perf_counter()
    try:
        for exe in args.nodes:
            for mode in args.modes:
                failures = []
                clean = 0
                installed = []
                for _ in range(args.runs):
                    k += 1
                    r = one_run(graph_node, exe, mode, k, rng)
                    if r['installed_s'] is not None:
                        installed.append(r['installed_s'])
                    if r['clean']:
                        clean += 1
                    else:
                        last = [ln for ln in r['text'].splitlines() if ln.strip()][-3:]
                        if r['hung']:  # the whole stack dump: where it waited
                            print(f'--- {exe} {mode} hung:\n{r["text"]}', file=sys.stderr)
                        failures.append(
                            {'up': r['up'], 'hung': r['hung'], 'code': r['code'], 'tail': last}
                        )
                table[f'{exe} {mode}'] = {'clean': clean, 'runs': args.runs, 'failures': failures}
                where = (
                    f' (handlers in place {1e3 * max(installed):.0f} ms after the start at most)'
                    if installed
                    else ''
                )
                print(f'{exe:16s} {mode:15s} {clean}/{args.runs} clean{where}', flush=True)
                for f in failures[:3]:
                    print(f'    not clean: {f}', flush=True)
    finally:
        graph_node.destroy_node()
        rclpy.try_shutdown()
    if args.json:
        print(json.dumps({'wall_s': round(time.perf_counter() - t0, 1), 'results': table}))
    ok = all(v['clean'] == v['runs'] for v in table.values())
    return 0 if ok else 1


if __name__ == '__main__':
    raise SystemExit(main())
