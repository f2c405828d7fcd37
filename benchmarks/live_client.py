"""
A Foxglove WebSocket client of the live view, in a process of its own (bench_cell.py).

Subscribes to every channel the live view advertises, as Foxglove does, prints
``ready`` once subscribed, reads every frame until SIGTERM, then prints how many
binary frames it received.

    python benchmarks/live_client.py PORT
"""

from __future__ import annotations

import json
import signal
import sys


def main() -> int:
    from websockets.sync.client import connect

    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    frames = 0
    with connect(f'ws://127.0.0.1:{sys.argv[1]}', subprotocols=['foxglove.sdk.v1']) as ws:
        while True:
            msg = json.loads(ws.recv(timeout=10))
            if msg['op'] == 'advertise':
                break
        subs = [{'id': c['id'], 'channelId': c['id']} for c in msg['channels']]
        ws.send(json.dumps({'op': 'subscribe', 'subscriptions': subs}))
        print('ready', flush=True)
        while not stop:
            try:
                frame = ws.recv(timeout=0.2)
            except TimeoutError:
                continue
            except Exception:  # the server went away
                break
            if isinstance(frame, bytes):
                frames += 1
    print(f'frames={frames}', flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main())
