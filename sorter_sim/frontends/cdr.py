"""
geometry_msgs/PoseArray serialized straight from numpy arrays, for the pose stream.

Building a PoseArray of a hundred rosidl Pose objects and converting them to C
costs about 0.7 ms per message in Python (most of it one attribute access per
field), which alone would cap the cell near 15x real time at 100 Hz. rclpy's
``Publisher.publish`` also takes the serialized bytes (what rosbag2 replays),
so the pose stream is written here as CDR (XCDR1, little endian, the encoding
rmw_fastrtps uses) in a few microseconds. Subscribers receive an ordinary
PoseArray; test_sim_node.py checks this encoder against rclpy's own
deserializer. No ROS imports: this is plain byte layout.

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
