"""
A PLC's load on the cell's fieldbus, in a process of its own (used by bench_cell.py).

A Modbus TCP, an OPC UA and an S7 client, each in a thread, read every input of the
cell's I/O image every 10 ms of wall time until SIGTERM; then it prints the number
of reads each made. A port of 0 (an endpoint of '-') leaves that client out.

    python benchmarks/fieldbus_clients.py MODBUS_PORT OPCUA_ENDPOINT S7_PORT SENSOR ...
"""

from __future__ import annotations

import signal
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> int:
    from sorter_control.soft_plc import ModbusIO, OpcUaIO, S7IO

    port, endpoint, s7_port = int(sys.argv[1]), sys.argv[2], int(sys.argv[3])
    sensors = sys.argv[4:]
    ios = {}
    if port:
        ios['modbus'] = ModbusIO('127.0.0.1', port, sensors)
    if endpoint != '-':
        ios['opcua'] = OpcUaIO(endpoint, 'cell', sensors)
    if s7_port:
        ios['s7'] = S7IO('127.0.0.1', s7_port, sensors)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    reads = {k: 0 for k in ios}

    def poll(name):
        next_t = time.monotonic()
        while not stop.is_set():
            ios[name].read_inputs()
            reads[name] += 1
            next_t += 0.01
            time.sleep(max(0.0, next_t - time.monotonic()))

    threads = [threading.Thread(target=poll, args=(k,)) for k in ios]
    for t in threads:
        t.start()
    print('ready', flush=True)
    while not stop.is_set():
        stop.wait(0.1)
    for t in threads:
        t.join(5)
    for io in ios.values():
        io.close()
    print(' '.join(f'{k}={v}' for k, v in reads.items()), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
