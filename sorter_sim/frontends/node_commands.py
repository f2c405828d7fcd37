"""
What the simulation node takes from a controller: its services, PackML commands and inputs.

``CellCommands`` serves ``diverter/popup``, ``estop``, ``reset``, ``step`` and
``packml/<command>`` (each a ``std_srvs`` service that answers with what it did or
why it refused) and takes the controller's heartbeat and the ``parcels/induct``
requests; ``induct_spec`` turns such a request into a parcel. The disk angle is a
parameter (``alpha_deg``), which the node itself serves.
"""

from __future__ import annotations

import math

from diagnostic_msgs.msg import DiagnosticStatus
from std_msgs.msg import UInt32
from std_srvs.srv import SetBool, Trigger

from sorter_ros.interface import EVENT_QOS, SERVICE_QOS, STREAM_QOS
from sorter_sim.model.description import shown
from sorter_sim.model.packml import COMMANDS as PACKML_COMMANDS
from sorter_sim.runtime.cell import ParcelSpec
from sorter_sim.runtime.params import CellParams, ParamError

# induct message keys -> (ParcelSpec field, conversion)
INDUCT_KEYS = ('label', 'A', 'B', 'm', 'phi0_deg', 'y')


class CellCommands:
    """
    The cell's services and command inputs, created on ``node``.

    Parameters
    ----------
    node : SimNode
        The node that serves them: its cell, its ``params`` (read at each use) and, for
        ``step``, its ``advance``.
    publishers : CellPublishers
        Where what a command changes is published before its reply.

    """

    def __init__(self, node, publishers):
        self._node = node
        self._cell = node.cell
        self._publishers = publishers
        for command in PACKML_COMMANDS:
            node.create_service(
                Trigger,
                f'packml/{command}',
                lambda request, response, c=command: self.packml(c, response),
                qos_profile=SERVICE_QOS,
            )
        node.create_service(SetBool, 'diverter/popup', self.popup, qos_profile=SERVICE_QOS)
        node.create_service(SetBool, 'estop', self.estop, qos_profile=SERVICE_QOS)
        node.create_service(Trigger, 'reset', self.reset, qos_profile=SERVICE_QOS)
        node.create_service(Trigger, 'step', self.step, qos_profile=SERVICE_QOS)
        node.create_subscription(DiagnosticStatus, 'parcels/induct', self._on_induct, EVENT_QOS)
        node.create_subscription(UInt32, 'controller/heartbeat', self._on_heartbeat, STREAM_QOS)

    # ------------------------------------------------------------------ services
    def popup(self, request, response):
        """Raise (``data`` true) or lower the popup wheels (``diverter/popup``)."""
        response.success, response.message = self._cell.popup(bool(request.data))
        return response

    def estop(self, request, response):
        """Engage the e-stop (``estop``); releasing it is the reset service's."""
        if not request.data:
            response.success = False
            response.message = 'refused: an e-stop is released with the reset service (use reset)'
            return response
        self._cell.engage_estop()
        self._publishers.publish_status()
        self._node.get_logger().warning('e-stop engaged: belt stopped, disks dropping')
        response.success = True
        response.message = 'e-stop engaged: belt stopped, disks dropping; reset to resume'
        return response

    def reset(self, request, response):
        """Clear the e-stop and jams (``reset``), publishing what that changes first."""
        cleared = self._cell.faults
        self._publishers.publish_events(self._cell.reset())
        response.success = True
        response.message = ('cleared ' + ', '.join(cleared)) if cleared else 'nothing to clear'
        return response

    def packml(self, command: str, response):
        """Take a PackML command (packml/<command>), or refuse it with the reason."""
        ok, text = self._cell.packml_command(command)
        response.success = ok
        if ok:
            self._publishers.publish_events(self._cell.take_packml_edges())
            response.message = f'{text} (now {self._cell.packml.state})'
        else:
            self._node.get_logger().warning(f'packml/{command} {text}')
            response.message = f'refused: {text}'
        return response

    def step(self, request, response):
        """Advance one control period (``step``), in time_mode lockstep only."""
        node = self._node
        if node.station:
            response.success = False
            response.message = 'refused: this station is part of a line; step the line'
            return response
        if node.params.time_mode != 'lockstep':
            response.success = False
            response.message = (
                f'refused: step works in time_mode lockstep; this cell runs in '
                f'{node.params.time_mode}'
            )
            return response
        node.advance(1)
        response.success = True
        response.message = f't = {self._cell.t:.9f} s'
        return response

    # ------------------------------------------------------------------ inputs
    def _on_heartbeat(self, msg: UInt32) -> None:
        """Take the controller's heartbeat: a counter, which feeds the watchdog when it changes."""
        if self._cell.heartbeat(int(msg.data)):
            self._node.get_logger().info('controller heartbeat back: watchdog cleared')
            self._publishers.publish_status()

    def _on_induct(self, msg: DiagnosticStatus) -> None:
        """Queue an external induct request; bad values are logged and the message dropped."""
        try:
            spec = induct_spec([(kv.key, kv.value) for kv in msg.values], self._node.params)
            self._cell.induct(spec)
        except ParamError as exc:
            self._node.get_logger().warning(f'parcels/induct dropped: {exc}')


def induct_spec(pairs, p: CellParams) -> ParcelSpec:
    """
    Return the parcel a parcels/induct message asks for, from its (key, value) pairs.

    Raises ParamError naming what is wrong: an unknown or repeated key, a value that
    is not a finite number. Missing sizes take the middle of the stream's ranges;
    the parcel itself is checked when it is queued (``Cell.induct``).

    Parameters
    ----------
    pairs : list of (str, str)
        The message's key/value pairs.
    p : CellParams
        The cell's parameters (the stream's ranges, the belt).

    Returns
    -------
    ParcelSpec
        The parcel.

    """
    given = {}
    for key, value in pairs:
        if key not in INDUCT_KEYS:
            raise ParamError(f'unknown key {shown(key)}; allowed: {", ".join(INDUCT_KEYS)}')
        if key in given:
            raise ParamError(f'key {shown(key)} given twice')
        given[key] = value
    numbers = {}
    for key in ('A', 'B', 'm', 'phi0_deg', 'y'):
        if key in given:
            try:
                numbers[key] = float(given[key])
            except ValueError:
                raise ParamError(f'{key} must be a number, got {shown(given[key])}') from None
            if not math.isfinite(numbers[key]):
                raise ParamError(f'{key} must be finite, got {shown(given[key])}')
    # missing sizes take the middle of the configured stream's ranges
    return ParcelSpec(
        A=numbers.get('A', 0.5 * sum(p.parcel_A)),
        B=numbers.get('B', 0.5 * sum(p.parcel_B)),
        m=numbers.get('m', 0.5 * sum(p.parcel_m)),
        phi0=math.radians(numbers.get('phi0_deg', 0.0)),
        y0=numbers.get('y', 0.0),
        label=given.get('label', ''),
    )
