"""
Benchmark of the fieldbus round trip: a sensor edge in the cell to the pop-up command in it.

Over Modbus TCP, OPC UA or S7, with a PLC scanning every 10 ms. Not a test: it prints
figures. The cell (``sim_node``, config/cell.yaml) runs in its own process on the
wall clock (real-time factor 1) with a dense stream of short parcels; this process
is the PLC: every ``--scan`` seconds of wall time it reads the inputs, and when
``pe_scan``'s latched rising-edge time has changed it writes ``diverter.popup`` = 1
(and 0 again at the falling edge). The cell's side of the round trip is measured on
the cell's own clock: the stroke rises at 1/stroke_time from the period the command
was applied, so t_applied = cell.time - stroke x stroke_time, read while the disks
move; round trip = t_applied - t_edge. It holds the edge's wait for the next scan,
the PLC's read, its write and the image's one-period exchange.

    .venv/bin/python benchmarks/bench_fieldbus.py [--edges 200] [--scan 0.01] [--io s7]
"""

from __future__ import annotations

import argparse
import os
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
BIN = Path(sys.executable).parent
STROKE_TIME = 0.1


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument('--edges', type=int, default=200, help='rising edges to measure')
    ap.add_argument('--scan', type=float, default=0.01, help='PLC scan period, wall [s]')
    ap.add_argument('--io', choices=('modbus', 'opcua', 's7'), default='modbus')
    args = ap.parse_args()
    from sorter_control.soft_plc import ModbusIO, OpcUaIO, S7IO
    from sorter_sim.runtime.cell import CHUTE_SENSORS
    from sorter_sim.model.io_map import by_name

    port = _free_port()
    env = dict(os.environ, ROS_DOMAIN_ID=str(150 + os.getpid() % 50))
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    cell = subprocess.Popen(
        [
            str(BIN / 'sim_node'),
            '--ros-args',
            '--params-file',
            str(ROOT / 'config' / 'cell.yaml'),
            '-p',
            'time_mode:=realtime',
            '-p',
            f'{args.io}_port:={port}',
            '-p',
            'alpha_deg:=0.0',
            '-p',
            f'popup_stroke_time:={STROKE_TIME}',
            '-p',
            'parcel_A:=[0.3, 0.3]',
            '-p',
            'arrival_gap:=[0.5, 0.6]',
            '--log-level',
            'warn',
        ],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    sensors = ['pe_scan', 'pe_divert', 'pe_exit', *CHUTE_SENSORS]
    io = None
    try:
        deadline = time.monotonic() + 60
        while io is None:
            try:
                if args.io == 'modbus':
                    io = ModbusIO('127.0.0.1', port, sensors)
                elif args.io == 's7':
                    io = S7IO('127.0.0.1', port, sensors)
                else:
                    io = OpcUaIO(f'opc.tcp://127.0.0.1:{port}/sorter_cell/', 'cell', sensors)
            except Exception:
                if time.monotonic() > deadline or cell.poll() is not None:
                    raise SystemExit(f'the cell did not serve {args.io}: {cell.stderr.read()}')
                time.sleep(0.5)
        sig = by_name(io.signals)
        popup = sig['diverter.popup']
        last_rise = last_fall = None
        pending = None  # cell time of the edge whose command is on its way
        trips, scan_walls = [], []
        next_scan = time.monotonic()
        while len(trips) < args.edges:
            next_scan += args.scan
            time.sleep(max(0.0, next_scan - time.monotonic()))
            w0 = time.perf_counter()
            x = io.read_inputs()
            rise, fall = x['sensor.pe_scan.rise_time'], x['sensor.pe_scan.fall_time']
            stroke = x['diverter.stroke']
            if pending is not None and 0.0 < stroke < 1.0:
                t_applied = x['cell.time'] - stroke * STROKE_TIME
                trips.append(t_applied - pending)
                pending = None
            if last_rise is not None and rise != last_rise and pending is None:
                io.write(popup, True)
                pending = rise
            elif last_fall is not None and fall != last_fall:
                io.write(popup, False)
            last_rise, last_fall = rise, fall
            scan_walls.append(time.perf_counter() - w0)
        q = statistics.quantiles([1e3 * t for t in trips], n=100)
        w = statistics.quantiles([1e3 * t for t in scan_walls], n=100)
        print(
            f'# fieldbus round trip over {args.io}: sensor edge in the cell -> PLC scan '
            f'({args.scan * 1e3:g} ms) -> pop-up command applied in the cell; '
            f'{len(trips)} edges, cell at real-time factor 1, {os.cpu_count()} cpus, '
            f'load average {os.getloadavg()[0]:.2f}'
        )
        print(
            f'round trip  p50 {statistics.median(trips) * 1e3:6.2f} ms   p99 {q[98]:6.2f} ms   '
            f'max {max(trips) * 1e3:6.2f} ms   min {min(trips) * 1e3:6.2f} ms'
        )
        print(
            f'PLC scan (read all inputs, maybe one write)  p50 {statistics.median(w):.2f} ms   '
            f'p99 {w[98]:.2f} ms'
        )
    finally:
        if io is not None:
            io.close()
        cell.terminate()
        cell.wait(20)
    return 0


if __name__ == '__main__':
    sys.exit(main())
