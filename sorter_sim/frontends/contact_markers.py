"""
The cell's contacts as markers: what the ``contacts`` topic carries, from plain arrays.

Under ``contact: rigid`` the simulation node publishes the contact points of the
period it reached (``Cell.contact_points``: points, normals, normal forces, the two
bodies) as a ``visualization_msgs/MarkerArray``: a DELETEALL, then per contact point
an ARROW from the point along the normal force on the first body named (a parcel),
``CONTACT_FORCE_SCALE`` m per N long, as the live view draws it, its ``text`` naming
both bodies and the force in N to the last digit (``outcomes.contact_text``, read
back by ``outcomes.parse_contact_text``): a subscriber or a recording's reader gets
the numbers, not only a picture. No physics here: the node hands over the cell's
arrays.
"""

from __future__ import annotations

import struct

from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point
from rclpy.serialization import serialize_message
from visualization_msgs.msg import Marker, MarkerArray

from sorter_ros.outcomes import contact_text
from sorter_sim.frontends.cdr import stamp as sec_nsec
from sorter_sim.frontends.live_view import (
    CONTACT_FORCE_SCALE,
    CONTACT_Z,
    contact_colour,
)

NS = 'contacts'
ARROW_SHAFT = 0.012  # m: the arrows' shaft and head diameters
ARROW_HEAD = 0.03


def contact_marker_array(contacts: dict, frame_id: str, stamp) -> MarkerArray:
    """
    Return the contact markers of one period.

    Parameters
    ----------
    contacts : dict
        The contact points, as ``Cell.contact_points`` gives them.
    frame_id : str
        The cell's frame.
    stamp : builtin_interfaces.msg.Time
        The simulated time of the period.

    Returns
    -------
    MarkerArray
        A DELETEALL of the namespace, then one ARROW per contact point.

    """
    markers = [_clear(frame_id, stamp)]
    cols = (contacts[k].tolist() for k in ('x', 'y', 'nx', 'ny', 'force', 'a'))
    for i, ((x, y, nx, ny, force, a), second) in enumerate(zip(zip(*cols), contacts['second'])):
        m = Marker(ns=NS, id=i, type=Marker.ARROW, action=Marker.ADD)
        m.header.frame_id = frame_id
        m.header.stamp = stamp
        m.pose.orientation.w = 1.0
        # the force on the first body (a parcel) is against the normal, which points
        # from it to the other body
        length = CONTACT_FORCE_SCALE * force
        m.points = [
            Point(x=x, y=y, z=CONTACT_Z),
            Point(x=x - length * nx, y=y - length * ny, z=CONTACT_Z),
        ]
        m.scale.x, m.scale.y, m.scale.z = ARROW_SHAFT, ARROW_HEAD, ARROW_HEAD
        m.color.r, m.color.g, m.color.b = contact_colour(second)
        m.color.a = 1.0
        m.text = contact_text(a, second, force)
        markers.append(m)
    return MarkerArray(markers=markers)


def _clear(frame_id: str, stamp) -> Marker:
    clear = Marker(action=Marker.DELETEALL, ns=NS)
    clear.header.frame_id = frame_id
    clear.header.stamp = stamp
    return clear


_NO_CONTACTS: dict[str, bytes] = {}  # frame -> a period without contacts, at t = 0
# its CDR: the encapsulation (4 bytes), the array's length (4), then the DELETEALL's
# header.stamp, sec (int32) and nanosec (uint32)
_STAMP_AT = slice(8, 16)
_STAMP = struct.Struct('<iI')


def no_contacts_cdr(frame_id: str, t_ns: int) -> bytes:
    """
    Return the CDR of a period without contacts: the DELETEALL alone, stamped ``t_ns``.

    Most periods have none: the message is serialized once per frame and only its stamp
    is written again (a MarkerArray built and serialized in Python costs some 30 us).

    Parameters
    ----------
    frame_id : str
        The cell's frame.
    t_ns : int
        The simulated time of the period [ns], >= 0.

    Returns
    -------
    bytes
        The same bytes rclpy serializes ``contact_marker_array`` of no contacts to.

    """
    template = _NO_CONTACTS.get(frame_id)
    if template is None:
        array = MarkerArray(markers=[_clear(frame_id, Time())])
        template = _NO_CONTACTS[frame_id] = serialize_message(array)
    return template[: _STAMP_AT.start] + _STAMP.pack(*sec_nsec(t_ns)) + template[_STAMP_AT.stop :]
