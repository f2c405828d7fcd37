"""
The cell's live view: a Foxglove WebSocket server showing the cell as it runs.

Owns what a Foxglove client sees of one cell, with Foxglove's standard schemas:
``<prefix>/scene`` (``foxglove.SceneUpdate``: belt, disk field with its angle α and
pop-up state, chutes, photo-eyes lit while blocked, the scanner, every parcel as a
box with its id and label and the path it has taken, and under ``contact: rigid``
each contact point with an arrow of its normal force), ``<prefix>/tf``
(``foxglove.FrameTransforms``: the cell's frame under ``world``) and
``<prefix>/values`` (JSON, plottable: α, the pop-up stroke, each sensor bit, and per
parcel its speed and its slip on the belt and on the disks, the friction zones'
relative speeds). No ROS and no physics here: the simulation node hands it the
state it already has, and nothing is built while no client subscribes.

Try it: ``sorter demo --foxglove``, then open ws://127.0.0.1:8765 in Foxglove.
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass

import foxglove
from foxglove.channels import FrameTransformsChannel, SceneUpdateChannel
from foxglove.messages import (
    ArrowPrimitive,
    Color,
    CubePrimitive,
    FrameTransform,
    FrameTransforms,
    KeyValuePair,
    LinePrimitive,
    SpherePrimitive,
    Point3,
    Pose,
    Quaternion,
    SceneEntity,
    SceneEntityDeletion,
    SceneEntityDeletionType,
    SceneUpdate,
    TextPrimitive,
    Timestamp,
    Vector3,
)

PARCEL_HEIGHT = 0.2  # m: the model is planar; only for the boxes (live view and markers)
PATH_POINTS = 400  # most points kept of a parcel's path
CLIENT_BACKLOG = 6  # messages queued per client (two frames of the three channels)
STOP_WAIT_S = 0.5  # s the node waits for the server to stop when it shuts down
PATH_STEP = 0.01  # m: a path point is added when the parcel moved this far
CHUTE_WIDTH = 0.5  # m, drawn beside each side wall's opening
# colour (r, g, b) per parcel state (cell.STATE_NAMES), in the live view and the markers
STATE_COLOURS = {
    'on_belt': (0.6, 0.6, 0.6),
    'on_disks': (0.1, 0.4, 1.0),
    'sliding': (1.0, 0.75, 0.0),
    'diverted': (0.1, 0.8, 0.2),
    'straight': (0.55, 0.35, 0.15),
    'jammed': (1.0, 0.0, 0.0),
}

# contacts (contact: rigid): an arrow of the normal force on the parcel, this long per N
# [m/N], at half a parcel's height [m], coloured by what the parcel touches
CONTACT_FORCE_SCALE = 0.005
CONTACT_Z = 0.5 * PARCEL_HEIGHT
CONTACT_COLOURS = {
    'parcel': (1.0, 0.2, 0.8),
    'side wall': (1.0, 0.9, 0.1),
    'rail': (0.1, 0.9, 1.0),
}

VALUES_SCHEMA = {
    'type': 'object',
    'properties': {
        't': {'type': 'number', 'description': 'simulated time [s]'},
        'alpha_deg': {'type': 'number', 'description': 'physical disk angle α [deg]'},
        'stroke': {'type': 'number', 'description': 'pop-up position, 0 down .. 1 up'},
        'sensors': {'type': 'object', 'additionalProperties': {'type': 'integer'}},
        'parcels': {
            'type': 'array',
            'items': {
                'type': 'object',
                'properties': {
                    'id': {'type': 'integer'},
                    'label': {'type': 'string'},
                    'state': {'type': 'string'},
                    'speed': {'type': 'number', 'description': 'speed of the CoG [m/s]'},
                    'slip_belt': {
                        'type': 'number',
                        'description': 'speed of the CoG relative to the belt [m/s]',
                    },
                    'slip_disks': {
                        'type': 'number',
                        'description': 'speed of the CoG relative to the disks [m/s]',
                    },
                },
            },
        },
    },
}


@dataclass(frozen=True)
class CellLayout:
    """Where things are in the cell's frame (x along the belt, x = 0 at the disk field) [m]."""

    frame_id: str
    belt_width: float
    disk_field_length: float
    chute_x_range: tuple[float, float]
    induct_x: float
    exit_x: float
    scanner_x: float
    photo_eyes: tuple[tuple[str, float], ...]
    rails: tuple[tuple[float, float, float, float], ...] = ()  # (x0, y0, x1, y1) segments
    rail_thickness: float = 0.0


def _rgba(rgb, a=1.0) -> Color:
    return Color(r=rgb[0], g=rgb[1], b=rgb[2], a=a)


def _pose(x, y, z, yaw=0.0) -> Pose:
    return Pose(
        position=Vector3(x=x, y=y, z=z),
        orientation=Quaternion(x=0.0, y=0.0, z=math.sin(0.5 * yaw), w=math.cos(0.5 * yaw)),
    )


def _box(x0, x1, y0, y1, z0, z1, rgb, a=1.0) -> CubePrimitive:
    return CubePrimitive(
        pose=_pose(0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.5 * (z0 + z1)),
        size=Vector3(x=x1 - x0, y=y1 - y0, z=z1 - z0),
        color=_rgba(rgb, a),
    )


def _stamp(t_ns: int) -> Timestamp:
    return Timestamp(sec=t_ns // 1_000_000_000, nsec=t_ns % 1_000_000_000)


def contact_colour(second: str) -> tuple:
    """Return the colour of a contact with ``second``: ``parcel <id>``, ``side wall``, ``rail``."""
    return CONTACT_COLOURS['parcel' if second.startswith('parcel') else second]


def contact_entity(stamp, contacts: dict, frame_id: str, ids: str = '') -> SceneEntity:
    """
    Return the contacts of a period as one entity: a sphere per point, an arrow per force.

    Each arrow starts at its point and shows the normal force on the first body (a
    parcel), ``CONTACT_FORCE_SCALE`` m per N long, as on the node's ``contacts`` topic;
    the metadata names both bodies of each point and its force.
    """
    spheres, arrows, meta = [], [], []
    cols = (contacts[k].tolist() for k in ('x', 'y', 'nx', 'ny', 'force', 'a'))
    for (x, y, nx, ny, force, a), second in zip(zip(*cols), contacts['second']):
        colour = _rgba(contact_colour(second))
        spheres.append(
            SpherePrimitive(
                pose=_pose(x, y, CONTACT_Z), size=Vector3(x=0.03, y=0.03, z=0.03), color=colour
            )
        )
        length = CONTACT_FORCE_SCALE * force
        if length > 1e-4:
            head = min(0.03, length)
            arrows.append(
                ArrowPrimitive(
                    pose=_pose(x, y, CONTACT_Z, math.atan2(-ny, -nx)),
                    shaft_length=length - head,
                    shaft_diameter=0.012,
                    head_length=head,
                    head_diameter=0.03,
                    color=colour,
                )
            )
        meta.append(KeyValuePair(key=f'parcel {a} | {second}', value=f'{force:.3f} N'))
    return SceneEntity(
        timestamp=stamp,
        frame_id=frame_id,
        id=f'{ids}contacts',
        spheres=spheres,
        arrows=arrows,
        metadata=meta,
    )


class LiveView:
    """
    A Foxglove server of one cell; ``update`` sends a frame when a client listens.

    ``port`` 1-65535 on ``host`` (127.0.0.1 unless told otherwise). Raises ValueError
    with one line when the server cannot start (port busy, unknown host). Each view has
    its own Foxglove context, so several cells (or tests) in one process do not mix.
    """

    def __init__(
        self,
        layout: CellLayout | None,
        *,
        host: str,
        port: int,
        prefix: str = '',
        max_rate_hz: float = 30.0,
        stations: list | None = None,
    ):
        # a line: (name, layout, x of its frame in the line's) per station, one server;
        # each station's entities in its own frame (their ids prefixed 'S01/' ...), its
        # frame placed along ``world`` on /tf, its values on <prefix>/<name>/values
        self.stations = list(stations) if stations else [('', layout, 0.0)]
        layout = self.layout = self.stations[0][1]
        self.prefix = prefix.rstrip('/')
        self.context = foxglove.Context()
        try:
            self.server = foxglove.start_server(
                name=f'sorter_cell {layout.frame_id}',
                host=host,
                port=port,
                context=self.context,
                # a live view needs the newest frame, not a history: a client that stops
                # reading gets its oldest frames dropped, not the node's memory filled
                # (the SDK's default keeps 1024 messages per client)
                message_backlog_size=CLIENT_BACKLOG,
            )
        except RuntimeError as exc:
            raise ValueError(
                f'cannot serve the live view on {host}:{port}: '
                f'{str(exc).removeprefix("FoxgloveError: ")}'
            ) from None
        self.scene = SceneUpdateChannel(f'{self.prefix}/scene', context=self.context)
        self.tf = FrameTransformsChannel(f'{self.prefix}/tf', context=self.context)
        self.value_channels = {
            name: foxglove.Channel(
                f'{self.prefix}/{name + "/" if name else ""}values',
                schema=VALUES_SCHEMA,
                context=self.context,
            )
            for name, _, _ in self.stations
        }
        self.values = self.value_channels[self.stations[0][0]]
        self.min_wall_interval = 1.0 / max_rate_hz
        self._last_wall = -math.inf
        self._paths: dict[int, deque] = {}
        self.frames_sent = 0

    @property
    def port(self) -> int:
        return self.server.port

    def listening(self) -> bool:
        return (
            self.scene.has_sinks()
            or self.tf.has_sinks()
            or any(c.has_sinks() for c in self.value_channels.values())
        )

    def due(self) -> bool:
        """Return True when a frame should go out now (a client listens, the rate allows)."""
        if not self.listening():
            return False
        return time.monotonic() - self._last_wall >= self.min_wall_interval

    def update(
        self,
        t_ns: int,
        *,
        parcels: dict,
        motion: dict,
        alpha: float,
        stroke: float,
        sensors: dict[str, bool],
        state_names,
        contacts: dict | None = None,
    ) -> None:
        """
        Send one frame: the scene, the frame transform and the plottable values.

        ``parcels`` as ``Cell.parcels()`` gives them, ``motion`` as ``Cell.parcel_motion()``.

        Parameters
        ----------
        t_ns : int
            The simulated time [ns].
        parcels : dict of str to ndarray
            The parcels' columns, as ``Cell.parcels()`` gives them.
        motion : dict
            Their labels, speeds and slips, as ``Cell.parcel_motion()`` gives them.
        alpha : float
            The disk angle [rad].
        stroke : float
            The pop-up position, 0..1.
        sensors : dict
            {sensor name: blocked}.
        state_names : sequence of str
            The parcel states' names.
        contacts : dict of str to ndarray, optional
            The contact points of the period, as ``Cell.contact_points()`` gives them
            (None: the cell has no rigid contact, nothing drawn).

        """
        self.update_stations(
            t_ns,
            [
                {
                    'parcels': parcels,
                    'motion': motion,
                    'alpha': alpha,
                    'stroke': stroke,
                    'sensors': sensors,
                    'contacts': contacts,
                }
            ],
            state_names,
        )

    def update_stations(self, t_ns: int, states: list, state_names) -> None:
        """
        Send one frame of every station: ``states[k]`` holds ``update``'s keyword values.

        Parameters
        ----------
        t_ns : int
            The simulated time [ns].
        states : list of dict
            Per station (in the order given at construction): parcels, motion, alpha,
            stroke, sensors and (optional) contacts, as ``update`` takes them.
        state_names : sequence of str
            The parcel states' names.

        """
        self._last_wall = time.monotonic()
        stamp = _stamp(t_ns)
        if self.tf.has_sinks():
            self.tf.log(
                FrameTransforms(
                    transforms=[
                        FrameTransform(
                            timestamp=stamp,
                            parent_frame_id='world',
                            child_frame_id=lay.frame_id,
                            translation=Vector3(x=offset, y=0.0, z=0.0),
                            rotation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
                        )
                        for _, lay, offset in self.stations
                    ]
                ),
                log_time=t_ns,
            )
        scene = self.scene.has_sinks()
        entities = []
        for (name, lay, _), st in zip(self.stations, states):
            parcels, motion = st['parcels'], st['motion']
            ids = f'{name}/' if name else ''
            self._track_paths(parcels, ids)
            if scene:
                entities += self._static_entities(
                    stamp, st['alpha'], st['stroke'], st['sensors'], lay, ids
                )
                entities += self._parcel_entities(stamp, parcels, motion, state_names, lay, ids)
                if st.get('contacts') is not None:
                    entities.append(contact_entity(stamp, st['contacts'], lay.frame_id, ids))
            values = self.value_channels[name]
            if values.has_sinks():
                values.log(
                    {
                        't': t_ns * 1e-9,
                        'alpha_deg': math.degrees(st['alpha']),
                        'stroke': st['stroke'],
                        'sensors': {k: int(v) for k, v in st['sensors'].items()},
                        'parcels': [
                            {
                                'id': int(pid),
                                'label': motion['label'][i],
                                'state': state_names[int(parcels['state'][i])],
                                'speed': float(motion['speed'][i]),
                                'slip_belt': float(motion['slip_belt'][i]),
                                'slip_disks': float(motion['slip_disks'][i]),
                            }
                            for i, pid in enumerate(parcels['id'].tolist())
                        ],
                    },
                    log_time=t_ns,
                )
        if scene:
            # the frame replaces the previous one whole: parcels that left disappear
            clear = SceneEntityDeletion(timestamp=stamp, type=SceneEntityDeletionType.All)
            self.scene.log(SceneUpdate(deletions=[clear], entities=entities), log_time=t_ns)
        self.frames_sent += 1

    def _track_paths(self, parcels: dict, ids: str = '') -> None:
        """Extend the paths of one station's parcels (keyed ids + parcel id), drop the gone."""
        live = set()
        for pid, x, y in zip(*(parcels[k].tolist() for k in ('id', 'x', 'y'))):
            key = (ids, pid)
            live.add(key)
            path = self._paths.get(key)
            if path is None:
                path = self._paths[key] = deque(maxlen=PATH_POINTS)
            if not path or math.hypot(x - path[-1][0], y - path[-1][1]) >= PATH_STEP:
                path.append((x, y))
        for key in [k for k in self._paths if k[0] == ids and k not in live]:
            del self._paths[key]

    def _static_entities(self, stamp, alpha, stroke, sensors, lay, ids) -> list[SceneEntity]:
        w2, b = 0.5 * lay.belt_width, lay.disk_field_length
        x0, x1 = lay.induct_x - 0.3, lay.exit_x + 0.3
        lo, hi = lay.chute_x_range
        fid = lay.frame_id
        belt = SceneEntity(
            timestamp=stamp,
            frame_id=fid,
            id=f'{ids}belt',
            cubes=[
                _box(x0, 0.0, -w2, w2, -0.03, 0.0, (0.25, 0.25, 0.28)),
                _box(b, x1, -w2, w2, -0.03, 0.0, (0.25, 0.25, 0.28)),
                # side walls, open where the chutes are
                _box(x0, lo, w2, w2 + 0.02, 0.0, 0.15, (0.1, 0.1, 0.1)),
                _box(hi, x1, w2, w2 + 0.02, 0.0, 0.15, (0.1, 0.1, 0.1)),
                _box(x0, lo, -w2 - 0.02, -w2, 0.0, 0.15, (0.1, 0.1, 0.1)),
                _box(hi, x1, -w2 - 0.02, -w2, 0.0, 0.15, (0.1, 0.1, 0.1)),
            ],
        )
        chutes = SceneEntity(
            timestamp=stamp,
            frame_id=fid,
            id=f'{ids}chutes',
            cubes=[
                _box(lo, hi, w2, w2 + CHUTE_WIDTH, -0.2, -0.18, (0.3, 0.6, 0.3), 0.6),
                _box(lo, hi, -w2 - CHUTE_WIDTH, -w2, -0.2, -0.18, (0.3, 0.45, 0.7), 0.6),
            ],
            texts=[
                TextPrimitive(
                    pose=_pose(0.5 * (lo + hi), w2 + 0.5 * CHUTE_WIDTH, 0.0),
                    billboard=True,
                    font_size=14,
                    scale_invariant=True,
                    color=_rgba((1, 1, 1)),
                    text='left chute',
                ),
                TextPrimitive(
                    pose=_pose(0.5 * (lo + hi), -w2 - 0.5 * CHUTE_WIDTH, 0.0),
                    billboard=True,
                    font_size=14,
                    scale_invariant=True,
                    color=_rgba((1, 1, 1)),
                    text='right chute',
                ),
            ],
        )
        up = stroke > 0.5
        disk_rgb = (1.0, 0.55, 0.1) if up else (0.55, 0.45, 0.35)
        disks = SceneEntity(
            timestamp=stamp,
            frame_id=fid,
            id=f'{ids}disk_field',
            metadata=[
                KeyValuePair(key='alpha_deg', value=f'{math.degrees(alpha):.2f}'),
                KeyValuePair(key='stroke', value=f'{stroke:.3f}'),
            ],
            cubes=[_box(0.0, b, -w2, w2, -0.03, -0.03 + 0.03 * stroke + 1e-3, disk_rgb)],
            arrows=[
                ArrowPrimitive(
                    pose=_pose(0.5 * b, 0.0, 0.02, alpha),
                    shaft_length=0.3,
                    shaft_diameter=0.03,
                    head_length=0.1,
                    head_diameter=0.08,
                    color=_rgba((1.0, 1.0, 1.0)),
                )
            ],
            texts=[
                TextPrimitive(
                    pose=_pose(0.5 * b, -w2 + 0.08, 0.05),
                    billboard=True,
                    font_size=14,
                    scale_invariant=True,
                    color=_rgba((1, 1, 1)),
                    text=f'α {math.degrees(alpha):.1f}°, disks {"up" if up else "down"}',
                )
            ],
        )
        sensor_cubes, sensor_texts = [], []
        for name, x in lay.photo_eyes:
            lit = sensors.get(name, False)
            sensor_cubes.append(
                _box(
                    x - 0.008,
                    x + 0.008,
                    -w2 - 0.05,
                    w2 + 0.05,
                    0.0,
                    0.25,
                    (1.0, 0.1, 0.1) if lit else (0.3, 0.3, 0.3),
                    1.0 if lit else 0.5,
                )
            )
            sensor_texts.append(
                TextPrimitive(
                    pose=_pose(x, w2 + 0.1, 0.3),
                    billboard=True,
                    font_size=12,
                    scale_invariant=True,
                    color=_rgba((1, 1, 1)),
                    text=name,
                )
            )
        sx = lay.scanner_x
        sensor_cubes.append(
            _box(sx - 0.02, sx + 0.02, -w2 - 0.05, w2 + 0.05, 0.45, 0.5, (0.2, 0.5, 1.0), 0.8)
        )
        sensor_texts.append(
            TextPrimitive(
                pose=_pose(sx, -w2 - 0.1, 0.55),
                billboard=True,
                font_size=12,
                scale_invariant=True,
                color=_rgba((0.6, 0.8, 1.0)),
                text='scanner',
            )
        )
        sensors_entity = SceneEntity(
            timestamp=stamp,
            frame_id=fid,
            id=f'{ids}sensors',
            cubes=sensor_cubes,
            texts=sensor_texts,
        )
        out = [belt, chutes, disks, sensors_entity]
        if lay.rails:
            # the rails and stoppers, in the colour of a contact with one, as thick as
            # the contact step takes them
            rails = [
                CubePrimitive(
                    pose=_pose(
                        0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.075, math.atan2(y1 - y0, x1 - x0)
                    ),
                    size=Vector3(x=math.hypot(x1 - x0, y1 - y0), y=lay.rail_thickness, z=0.15),
                    color=_rgba(CONTACT_COLOURS['rail']),
                )
                for x0, y0, x1, y1 in lay.rails
            ]
            out.append(SceneEntity(timestamp=stamp, frame_id=fid, id=f'{ids}rails', cubes=rails))
        return out

    def _parcel_entities(self, stamp, parcels, motion, state_names, lay, ids) -> list[SceneEntity]:
        fid = lay.frame_id
        out = []
        cols = (parcels[k].tolist() for k in ('id', 'x', 'y', 'phi', 'A', 'B', 'state'))
        for i, (pid, x, y, phi, A, B, code) in enumerate(zip(*cols)):
            state = state_names[code]
            label = motion['label'][i]
            path = self._paths.get((ids, pid), ())
            out.append(
                SceneEntity(
                    timestamp=stamp,
                    frame_id=fid,
                    id=f'{ids}parcel/{pid}',
                    metadata=[
                        KeyValuePair(key='label', value=label),
                        KeyValuePair(key='state', value=state),
                    ],
                    cubes=[
                        CubePrimitive(
                            pose=_pose(x, y, 0.5 * PARCEL_HEIGHT, phi),
                            size=Vector3(x=A, y=B, z=PARCEL_HEIGHT),
                            color=_rgba(STATE_COLOURS[state]),
                        )
                    ],
                    texts=[
                        TextPrimitive(
                            pose=_pose(x, y, PARCEL_HEIGHT + 0.1),
                            billboard=True,
                            font_size=12,
                            scale_invariant=True,
                            color=_rgba((1, 1, 1)),
                            text=f'{pid} {label}',
                        )
                    ],
                    lines=[
                        LinePrimitive(
                            thickness=2.0,
                            scale_invariant=True,
                            points=[Point3(x=px, y=py, z=0.01) for px, py in path],
                            color=_rgba(STATE_COLOURS[state], 0.8),
                        )
                    ]
                    if len(path) > 1
                    else [],
                )
            )
        return out

    def close(self, wait_s: float = STOP_WAIT_S) -> None:
        """
        Stop the server, waiting at most ``wait_s`` for it.

        The SDK's stop waits for every client's close handshake, which a client that
        stopped reading completes only when the SDK gives up on it, tens of seconds
        later: it runs in a thread of its own, and a node that is shutting down does not
        wait past ``wait_s`` (its process ends the server's threads when it exits).

        Parameters
        ----------
        wait_s : float
            The most to wait [s, wall].

        """
        import threading

        stopper = threading.Thread(target=self.server.stop, name='live-view-stop', daemon=True)
        stopper.start()
        stopper.join(wait_s)
