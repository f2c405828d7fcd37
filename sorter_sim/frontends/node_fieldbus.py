"""
The simulation node's fieldbus bridge: the cell's I/O image, exchanged once an I/O cycle.

``FieldbusBridge`` works the image the way a PLC's process image works (docs/fieldbus.md):
what the PLC wrote (the outputs) is applied to the cell at the start of a cycle, and
the cell's state is latched into the inputs at its end. A cell serves its image itself,
from a process of its own (``FieldbusProcess``: Modbus TCP, OPC UA, S7) so that a
client's request never holds the physics; a line's stations hand theirs to the line's
servers (``LineNode``), which exchange them every period.
"""

from __future__ import annotations

import math

from rclpy.parameter import Parameter

from sorter_sim.frontends.fieldbus import IOImage, ScannerQueue
from sorter_sim.frontends.fieldbus_process import FieldbusProcess
from sorter_sim.model.io_map import io_map
from sorter_sim.model.packml import COMMAND_BY_NUMBER as PACKML_BY_NUMBER
from sorter_sim.runtime.cell import LabelRead, SensorEdge
from sorter_sim.runtime.params import ParamError


class FieldbusBridge:
    """
    The cell's fieldbus I/O image and, for a cell, the servers that serve it.

    Parameters
    ----------
    node : SimNode
        The node whose cell the image belongs to; its ``params`` are read at each use,
        and what the PLC's writes cause is published by its ``publisher_set`` (made
        after the servers are open: a node refused for a busy port leaves no publisher).

    """

    def __init__(self, node):
        self._node = node
        self._cell = node.cell
        self.io_image = None  # the I/O image, when a server is on
        self.fieldbus = None  # the cell's own servers (FieldbusProcess)

    def attach_io_image(self) -> IOImage:
        """
        Give the cell a fieldbus I/O image, exchanged every period, and return it.

        A cell serves it itself (``modbus_port`` / ``opcua_port``); a line's stations
        are served together by the line's servers (``LineNode``).
        """
        self.io_image = IOImage(io_map(self._cell.sensor_names), self._initial_outputs())
        self._start_io_image()
        return self.io_image

    def _initial_outputs(self) -> dict:
        return {
            'diverter.popup': False,
            'cell.reset': False,
            'belt.run': True,
            'scanner.ack': False,
            'cell.estop': False,
            'diverter.alpha_setpoint': self._node.params.alpha_deg,
            'plc.heartbeat': 0,
            'packml.command': 0,  # none yet; a write issues one
        }

    def _start_io_image(self) -> None:
        self._scanner = ScannerQueue()
        self._belt_travel = 0.0
        self._io_events = []  # what the periods of the current I/O cycle reported so far
        self._unlatched = False  # periods run since the inputs were last latched
        self.refused = 0  # outputs the cell refused (a popup while e-stopped, ...)
        self._servers_ended_said = False
        self._refresh_io([])

    def open_servers(self) -> None:
        """
        Serve the image on the Modbus, OPC UA and S7 ports the parameters ask for.

        Raises
        ------
        ParamError
            A server cannot be started (naming its port's parameter).

        """
        node, p = self._node, self._node.params
        # the servers run in a process of their own, sharing the image: a client's request
        # never holds the physics (sorter_sim/frontends/fieldbus_process.py)
        self.fieldbus = FieldbusProcess(
            io_map(self._cell.sensor_names),
            self._initial_outputs(),
            modbus=(p.modbus_host, p.modbus_port) if p.modbus_port else None,
            opcua=(p.opcua_host, p.opcua_port) if p.opcua_port else None,
            s7=(p.s7_host, p.s7_port) if p.s7_port else None,
            cell_name=node.get_namespace().strip('/').replace('/', '_') or 'cell',
        )
        self.io_image = self.fieldbus.image
        self._start_io_image()
        try:
            self.fieldbus.start()
        except ValueError as exc:
            self.fieldbus = None
            text = str(exc)
            key = (
                'modbus_port' if 'Modbus' in text else 's7_port' if 'S7' in text else 'opcua_port'
            )
            raise ParamError(f'parameter {key!r}: {exc}') from None
        served = []
        if self.fieldbus.modbus_port:
            served.append(f'Modbus TCP on {p.modbus_host}:{self.fieldbus.modbus_port}')
        if self.fieldbus.opcua_endpoint:
            served.append(f'OPC UA on {self.fieldbus.opcua_endpoint}')
        if self.fieldbus.s7_port:
            served.append(f'S7 on {p.s7_host}:{self.fieldbus.s7_port} (DB1 inputs, DB2 outputs)')
        node.get_logger().info('fieldbus I/O image: ' + ', '.join(served))

    def close_servers(self) -> None:
        """Stop the servers, if they run (each within its bound, whatever clients do)."""
        if self.fieldbus is not None:
            self.fieldbus.stop()
            self.fieldbus = None

    # ------------------------------------------------------------------ exchange
    def before_period(self) -> None:
        """Apply the outputs the PLC wrote, at the start of a period (a line's station)."""
        self._node.publisher_set.publish_events(self._apply_io())
        self._belt_travel += self._cell.belt_velocity * self._cell.dt

    def after_period(self, events) -> None:
        """Latch the inputs at the end of a period (a line's station)."""
        self._refresh_io(events)

    def advance(self, m: int, cycle: int) -> list:
        """
        Advance the cell ``m`` periods, exchanging the image every ``cycle`` periods.

        The chunk of ``m`` periods ends no later than the I/O cycle does, when ``cycle``
        is more than one period (the node splits its runs at the cycle's strides).

        Parameters
        ----------
        m : int
            How many control periods.
        cycle : int
            The I/O cycle (``io_stride``) [periods].

        Returns
        -------
        list
            What the cell reported, with the edges the PLC's writes caused, in order.

        """
        c = self._cell
        if cycle == 1 and self.io_image.on_demand:
            # a cycle of one period, latched when a read asks for it (and at the end of
            # the run: ``end_run``): the kernel runs the chunk in one call; the outputs
            # written meanwhile are applied at its start, the inputs latched at the end of
            # the chunk a read came in, with every edge's own time
            events = self._apply_io()
            chunk = self._run_chunk(m)
            if self.io_image.read_asked():
                self._latch()
            return events + chunk
        if cycle == 1:
            # an image in this process (a line's station): exchanged every period; what
            # the periods report is published together after them, as without a fieldbus
            events = []
            for _ in range(m):
                events += self._apply_io()
                self._belt_travel += c.belt_velocity * c.dt
                period = c.advance(1)
                self._refresh_io(period)
                events += period
            return events
        # an I/O cycle of several periods, run by the kernel in one go: the outputs
        # at its start, the inputs latched at its end with what the whole cycle
        # reported (a cycle may span several of these chunks: strides split it)
        events = self._apply_io() if c.k % cycle == 0 else []
        chunk = self._run_chunk(m)
        if c.k % cycle == 0:
            self._latch()
        return events + chunk

    def _run_chunk(self, m: int) -> list:
        """Run ``m`` periods in one kernel call; keep what they reported for the next latch."""
        c = self._cell
        v_dt = c.belt_velocity * c.dt  # the belt is set between calls
        for _ in range(m):
            self._belt_travel += v_dt  # summed per period, as an exchange per period does
        chunk = c.advance(m)
        self._io_events += chunk
        self._unlatched = True
        return chunk

    def _latch(self) -> None:
        """Latch the inputs with what the periods since the last latch reported."""
        self._refresh_io(self._io_events)
        self._io_events = []
        self._unlatched = False

    def start_run(self, cycle: int) -> None:
        """
        Say the node runs periods now: a read asks for the inputs (a cycle of one period).

        Parameters
        ----------
        cycle : int
            The I/O cycle (``io_stride``) [periods].

        """
        if cycle == 1 and self.io_image.on_demand:
            self.io_image.running(True)

    def end_run(self, cycle: int) -> None:
        """
        Latch the end of the periods just run (a cycle of one period); reads need not ask.

        Parameters
        ----------
        cycle : int
            The I/O cycle (``io_stride``) [periods].

        """
        if cycle == 1 and self.io_image.on_demand:
            if self._unlatched:
                self._latch()
            self.io_image.running(False)

    def _apply_io(self) -> list:
        """
        Apply what the PLC wrote since the last period (outputs of the I/O image).

        Returns the sensor edges that follow (jammed parcels a reset or a PackML command
        took off), to be published in order with the period's own.
        """
        out, rises = self.io_image.take_outputs()
        if not out:
            return []
        c = self._cell
        log = self._node.get_logger()
        edges = []
        for name, value in out.items():
            ok = True
            if name == 'diverter.popup':
                ok, _ = c.popup(bool(value))
            elif name == 'belt.run':
                ok, _ = c.run_belt(bool(value))
            elif name == 'plc.heartbeat':
                # a rewrite of the same value reaches here too: the cell feeds its watchdog
                # only with a changed counter
                if c.heartbeat(int(value)):
                    log.info('PLC heartbeat back: watchdog cleared')
                    self._node.publisher_set.publish_status()
            elif name == 'diverter.alpha_setpoint':
                # through the parameter, which checks it as any change of alpha_deg
                result = self._node.set_parameters([Parameter('alpha_deg', value=float(value))])
                ok = result[0].successful
            elif name == 'packml.command':
                ok, text = c.packml_command(PACKML_BY_NUMBER[int(value)])
                if ok:
                    edges += c.take_packml_edges()
                else:
                    log.warning(f'packml.command from the PLC: {text}')
            self.refused += not ok
        if 'cell.estop' in rises:
            c.engage_estop()
            self._node.publisher_set.publish_status()
            log.warning('e-stop engaged by the PLC: belt stopped, disks dropping')
        if 'cell.reset' in rises:
            edges += c.reset()
        if 'scanner.ack' in rises:
            self._scanner.ack()
        return edges

    def _refresh_io(self, events) -> None:
        """Latch the cell's state into the inputs of the I/O image (end of a period)."""
        c = self._cell
        values = {}
        for e in events:
            if isinstance(e, SensorEdge):
                values[f'sensor.{e.sensor}'] = e.blocked
                edge = 'rise' if e.blocked else 'fall'
                values[f'sensor.{e.sensor}.{edge}_time'] = e.t_ns * 1e-9
            elif isinstance(e, LabelRead):
                self._scanner.read(e.label)
        if not events and c.k == 0:
            values.update({f'sensor.{n}': b for n, b in c.sensor_states().items()})
        q = self._scanner
        stroke = c.stroke
        values.update(
            {
                'scanner.ready': bool(q.waiting),
                'scanner.label': q.waiting[0] if q.waiting else '',
                'scanner.sequence': q.sequence,
                'diverter.up': stroke >= 0.999,
                'diverter.down': stroke <= 0.001,
                'diverter.alpha': math.degrees(c.alpha),
                'diverter.stroke': stroke,
                'status.estop': c.estop,
                'status.jam': c.jam,
                'status.watchdog': c.watchdog_tripped,
                'status.fault': bool(c.faults),
                'packml.state': c.packml.number,
                'belt.encoder': self._belt_travel,
                'cell.time': c.t_ns * 1e-9,
            }
        )
        self.io_image.refresh_inputs(values)

    # ------------------------------------------------------------------ diagnostics
    def diagnostics(self) -> dict:
        """
        Return the fieldbus's entries of the node's /diagnostics report; none without an image.

        Says once, as an error, that the servers' process ended.
        """
        if self.io_image is None:
            return {}
        st = self.io_image.stats
        servers = 'running'
        if isinstance(self.fieldbus, FieldbusProcess) and not self.fieldbus.alive:
            servers = 'ended'
            if not self._servers_ended_said:
                self._servers_ended_said = True
                self._node.get_logger().error(
                    'the fieldbus servers\' process ended: no client is served; the cell '
                    'runs on (restart the node to serve again)'
                )
        return {
            'fieldbus_servers': servers,
            'fieldbus_writes': str(st['writes']),
            'fieldbus_writes_refused': str(st['refused']),
            # Modbus reads refused (an address or count no table has), function codes the
            # image does not serve, frames dropped (wrong protocol id, impossible length)
            'fieldbus_reads_refused': str(st['reads_refused']),
            'fieldbus_illegal_functions': str(st['illegal_functions']),
            'fieldbus_frames_dropped': str(st['frames_dropped']),
            # OPC UA warehouse method calls refused for their arguments
            'fieldbus_calls_refused': str(self.fieldbus.warehouse.refused if self.fieldbus else 0),
            # outputs a newer write replaced before the cell applied them: lost updates
            'fieldbus_outputs_lost': str(st['overwritten']),
            'fieldbus_outputs_refused_by_cell': str(self.refused),
            'fieldbus_labels_dropped': str(self._scanner.dropped),
        }
