"""
A picture of the live view as a Foxglove client receives it.

Runs a cell (lock-step, the default stream, disks up at α = 45°) with its live view
on, connects a WebSocket client speaking the Foxglove protocol, takes one
``foxglove.SceneUpdate`` as it arrives, decodes it with protobuf from the schema
the server advertises, and draws it from above into a PNG: belt, disk field with
its angle arrow, chutes, photo-eyes (red while blocked), scanner, parcels with
their ids, labels and paths, and (``contact: rigid``) the contact points with their
normal-force arrows. The README's picture of the live view comes from here:
it shows what the server sends, drawn by the project, not a photo of a GUI.

    .venv/bin/python -m sorter_cell.live_snapshot [--out docs/img/live_view.png]
"""

from __future__ import annotations

import argparse
import base64
import json
import math
import socket
import struct
import sys
import time
from pathlib import Path


def _client_scene(port: int, advance, frames: int = 1, timeout: float = 20.0):
    """Connect to the live view, subscribe to its scene, return its ``frames``-th SceneUpdate."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
    from websockets.sync.client import connect

    with connect(f'ws://127.0.0.1:{port}', subprotocols=['foxglove.sdk.v1']) as ws:
        deadline = time.monotonic() + timeout
        channel = None
        while channel is None and time.monotonic() < deadline:
            msg = json.loads(ws.recv(timeout=timeout))
            if msg.get('op') == 'advertise':
                channel = next(c for c in msg['channels'] if c['topic'].endswith('/scene'))
        fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel['schema']))
        pool = descriptor_pool.DescriptorPool()
        for f in fds.file:
            pool.Add(f)
        cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(channel['schemaName']))
        ws.send(
            json.dumps(
                {'op': 'subscribe', 'subscriptions': [{'id': 1, 'channelId': channel['id']}]}
            )
        )
        while time.monotonic() < deadline:
            advance()
            try:
                frame = ws.recv(timeout=0.05)
            except TimeoutError:
                continue
            if isinstance(frame, bytes) and frame[0] == 1:
                (sub,) = struct.unpack_from('<I', frame, 1)
                frames -= sub == 1
                if frames == 0:
                    return cls.FromString(frame[13:])
    raise RuntimeError('no scene from the live view')


def _yaw(q) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def draw_scene(scene, out: Path, title: str) -> None:
    """
    Draw a decoded foxglove.SceneUpdate from above (x right, y up) into a PNG.

    Parameters
    ----------
    scene : SceneUpdate
        A decoded foxglove.SceneUpdate.
    out : Path
        The PNG.
    title : str
        The picture's title.

    """
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from matplotlib.patches import Polygon

    fig, ax = plt.subplots(figsize=(12, 4.6))
    ax.set_facecolor('#1e1e24')
    cubes = []
    for e in scene.entities:
        for c in e.cubes:
            cubes.append((c.pose.position.z + 0.5 * c.size.z, c))
    for _, c in sorted(cubes, key=lambda zc: zc[0]):
        p, s, yaw = c.pose.position, c.size, _yaw(c.pose.orientation)
        cs, sn = math.cos(yaw), math.sin(yaw)
        corners = [
            (p.x + cs * dx - sn * dy, p.y + sn * dx + cs * dy)
            for dx, dy in (
                (-s.x / 2, -s.y / 2),
                (s.x / 2, -s.y / 2),
                (s.x / 2, s.y / 2),
                (-s.x / 2, s.y / 2),
            )
        ]
        col = (c.color.r, c.color.g, c.color.b, max(c.color.a, 0.2))
        ax.add_patch(Polygon(corners, closed=True, facecolor=col, edgecolor=(0, 0, 0, 0.6)))
    for e in scene.entities:
        for line in e.lines:
            if len(line.points) > 1:
                ax.plot(
                    [q.x for q in line.points],
                    [q.y for q in line.points],
                    color=(line.color.r, line.color.g, line.color.b),
                    lw=1.2,
                    alpha=0.9,
                )
        for a in e.arrows:
            yaw = _yaw(a.pose.orientation)
            length = a.shaft_length + a.head_length
            ax.annotate(
                '',
                xy=(
                    a.pose.position.x + length * math.cos(yaw),
                    a.pose.position.y + length * math.sin(yaw),
                ),
                xytext=(a.pose.position.x, a.pose.position.y),
                arrowprops=dict(arrowstyle='-|>', color=(a.color.r, a.color.g, a.color.b), lw=2),
            )
        for sp in e.spheres:
            ax.plot(
                sp.pose.position.x,
                sp.pose.position.y,
                'o',
                ms=4,
                color=(sp.color.r, sp.color.g, sp.color.b),
            )
        for t in e.texts:
            ax.text(
                t.pose.position.x,
                t.pose.position.y,
                t.text,
                color=(t.color.r, t.color.g, t.color.b),
                fontsize=7,
                ha='center',
                va='center',
            )
    ax.set_aspect('equal')
    ax.autoscale_view()
    ax.set_xlabel('x along the belt [m]')
    ax.set_ylabel('y [m]')
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)


def main(argv=None) -> int:
    """
    Run the command.

    Parameters
    ----------
    argv : list of str, optional
        The arguments (default: the process's).

    Returns
    -------
    int
        The exit code.

    """
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument('--out', default='docs/img/live_view.png', help='PNG to write')
    ap.add_argument('--sim-time', type=float, default=9.0, help='simulated seconds before it')
    args = ap.parse_args(argv)
    import rclpy
    from rclpy.context import Context
    from rclpy.parameter import Parameter

    from sorter_ros.env import apply_ros_env_defaults
    from sorter_sim.frontends.node import SimNode

    apply_ros_env_defaults()
    with socket.socket() as probe:
        probe.bind(('127.0.0.1', 0))
        port = probe.getsockname()[1]
    ctx = Context()
    rclpy.init(context=ctx, args=['--ros-args', '--log-level', 'warn'])
    try:
        values = {
            'time_mode': 'lockstep',
            'arrival': 'gap',
            'arrival_gap': [0.45, 0.9],
            'alpha_deg': 45.0,
            'induct_x': -3.0,
            'foxglove_port': port,
            'foxglove_rate_hz': 200.0,
        }
        node = SimNode(
            context=ctx, parameter_overrides=[Parameter(k, value=v) for k, v in values.items()]
        )
        node.cell.popup(True)
        node.advance(round(args.sim_time / node.cell.dt))
        # watched for a second of simulated time, so the paths show
        scene = _client_scene(port, lambda: node.advance(node.params.pose_stride), frames=100)
        n = sum(1 for e in scene.entities if e.id.startswith('parcel/'))
        draw_scene(
            scene,
            Path(args.out),
            f'live view as a Foxglove client receives it: t = {node.cell.t:.2f} s, '
            f'{n} parcels, α = 45°, disks up',
        )
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)
    print(f'wrote {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
