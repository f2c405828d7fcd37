"""
The messages published every pose period, serialized straight from the cell's numbers.

Building a PoseArray of a hundred rosidl Pose objects and converting them to C
costs about 0.7 ms per message in Python (most of it one attribute access per
field), which alone would cap the cell near 15x real time at 100 Hz. rclpy's
``Publisher.publish`` also takes the serialized bytes (what rosbag2 replays),
so the pose stream is written here as CDR (XCDR1, little endian, the encoding
rmw_fastrtps uses) in a few microseconds. The other messages of every period
(the parcels' ids, the diverter's joint state, /clock, the sensors' Bool) are
small, but rclpy's conversion of a message object costs 5 to 12 us each, as much
as publishing it: they are written here too. Subscribers receive ordinary
messages; test_sim_node.py checks each encoder against rclpy's own deserializer
(and rosbags, which insists on the exact size, reads them all). No ROS imports:
this is plain byte layout.

Layout (offsets relative to the body after the 4-byte encapsulation header):
header.stamp.sec int32, header.stamp.nanosec uint32, header.frame_id string
(uint32 length including the NUL, bytes, NUL), then the poses sequence: uint32
count aligned to 4, and count x 7 float64 (position x y z, orientation x y z w)
aligned to 8.
"""

from __future__ import annotations

import struct

import numpy as np

_ENCAPSULATION_CDR_LE = b'\x00\x01\x00\x00'


def stamp(t_ns: int) -> tuple[int, int]:
    """
    (sec, nanosec) of a non-negative time in integer nanoseconds.

    Parameters
    ----------
    t_ns : int
        A time [ns], >= 0.

    Returns
    -------
    (int, int)
        Seconds and nanoseconds.

    """
    return t_ns // 1_000_000_000, t_ns % 1_000_000_000


def pose_array_cdr(
    t_ns: int, frame_id: str, x: np.ndarray, y: np.ndarray, phi: np.ndarray, z: float = 0.0
) -> bytes:
    """
    Serialize PoseArray of planar poses (x, y [m], yaw φ [rad]) at height z [m].

    Parameters
    ----------
    t_ns : int
        The stamp [ns].
    frame_id : str
        The frame.
    x, y, phi : ndarray
        The poses.
    z : float
        Their height [m].

    Returns
    -------
    bytes
        The message's CDR serialization.

    """
    sec, nsec = stamp(t_ns)
    fid = frame_id.encode('utf-8') + b'\x00'
    body = bytearray(struct.pack('<iII', sec, nsec, len(fid)))
    body += fid
    body += b'\x00' * (-len(body) % 4)
    n = int(len(x))
    body += struct.pack('<I', n)
    if n:
        body += b'\x00' * (-len(body) % 8)
        poses = np.zeros((n, 7))
        poses[:, 0] = x
        poses[:, 1] = y
        poses[:, 2] = z
        half = 0.5 * np.asarray(phi, dtype=float)
        poses[:, 5] = np.sin(half)
        poses[:, 6] = np.cos(half)
        body += poses.astype('<f8', copy=False).tobytes()
    return _ENCAPSULATION_CDR_LE + bytes(body)


def _align(body: bytearray, n: int) -> None:
    # CDR aligns each primitive to its size, counted from the start of the body
    body += b'\x00' * (-len(body) % n)


def _string(body: bytearray, text: str) -> None:
    data = text.encode('utf-8') + b'\x00'
    _align(body, 4)
    body += struct.pack('<I', len(data))
    body += data


def _float64_sequence(body: bytearray, values) -> None:
    values = np.asarray(values, dtype='<f8')
    _align(body, 4)
    body += struct.pack('<I', len(values))
    if len(values):
        _align(body, 8)
        body += values.tobytes()


def bool_cdr(value: bool) -> bytes:
    """
    Serialize std_msgs/Bool.

    Parameters
    ----------
    value : bool
        Its data.

    Returns
    -------
    bytes
        The message's CDR serialization.

    """
    return _ENCAPSULATION_CDR_LE + (b'\x01' if value else b'\x00')


def clock_cdr(t_ns: int) -> bytes:
    """
    Serialize rosgraph_msgs/Clock at ``t_ns``.

    Parameters
    ----------
    t_ns : int
        The time [ns], >= 0.

    Returns
    -------
    bytes
        The message's CDR serialization.

    """
    return _ENCAPSULATION_CDR_LE + struct.pack('<iI', *stamp(t_ns))


def uint32_array_cdr(values: np.ndarray) -> bytes:
    """
    Serialize std_msgs/UInt32MultiArray of ``values`` with an empty layout.

    Parameters
    ----------
    values : ndarray
        The data, each in 0 .. 2**32 - 1.

    Returns
    -------
    bytes
        The message's CDR serialization.

    """
    n = int(len(values))
    # layout.dim (an empty sequence), layout.data_offset, then the data's count
    head = struct.pack('<III', 0, 0, n)
    return _ENCAPSULATION_CDR_LE + head + np.asarray(values).astype('<u4', copy=False).tobytes()


def joint_state_cdr(t_ns: int, frame_id: str, names, position, velocity=(), effort=()) -> bytes:
    """
    Serialize sensor_msgs/JointState.

    Parameters
    ----------
    t_ns : int
        The stamp [ns].
    frame_id : str
        The header's frame.
    names : sequence of str
        The joints.
    position, velocity, effort : sequence of float
        Per joint, or empty.

    Returns
    -------
    bytes
        The message's CDR serialization.

    """
    body = bytearray(struct.pack('<iI', *stamp(t_ns)))
    _string(body, frame_id)
    _align(body, 4)
    body += struct.pack('<I', len(names))
    for name in names:
        _string(body, name)
    for values in (position, velocity, effort):
        _float64_sequence(body, values)
    return _ENCAPSULATION_CDR_LE + bytes(body)


class JointStateCdr:
    """
    ``joint_state_cdr`` for fixed frame, joints and fields: a template, stamped and filled.

    The node's diverter state is the same two joints every period: only the stamp, the
    positions and the velocities change, written into a copy of the template (about a
    quarter of ``joint_state_cdr``'s cost).

    Parameters
    ----------
    frame_id : str
        The header's frame.
    names : sequence of str
        The joints.

    """

    def __init__(self, frame_id: str, names):
        n = len(names)
        body = bytearray(struct.pack('<iI', 0, 0))
        _string(body, frame_id)
        _align(body, 4)
        body += struct.pack('<I', n)
        for name in names:
            _string(body, name)
        offsets = []
        for _ in range(2):  # position, velocity
            _align(body, 4)
            body += struct.pack('<I', n)
            if n:
                _align(body, 8)
            offsets.append(len(body) + len(_ENCAPSULATION_CDR_LE))
            body += b'\x00' * (8 * n)
        _float64_sequence(body, ())  # effort: empty
        self._template = _ENCAPSULATION_CDR_LE + bytes(body)
        self._stamp_at = len(_ENCAPSULATION_CDR_LE)
        self._values = struct.Struct(f'<{n}d')
        self._offsets = offsets

    def __call__(self, t_ns: int, position, velocity) -> bytes:
        """Return the message at ``t_ns`` with these positions and velocities (effort empty)."""
        out = bytearray(self._template)
        struct.pack_into('<iI', out, self._stamp_at, *stamp(t_ns))
        self._values.pack_into(out, self._offsets[0], *position)
        self._values.pack_into(out, self._offsets[1], *velocity)
        return bytes(out)
