"""
What the fieldbus tests share: the sensors, the I/O map, a cell serving it and its clients.

A plain module, imported by ``test_fieldbus_*.py`` and ``test_opcua_model.py``: the
fixtures ``cell`` (a lock-step cell serving Modbus TCP and OPC UA on free ports),
``modbus`` and ``opcua`` (clients of it), and small readers of what the cell shows.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
from asyncua.sync import Client as OpcClient
from pymodbus.client import ModbusTcpClient
from rclpy.parameter import Parameter
from ros_harness import free_port
from test_sim_node import SHORT_CELL

from sorter_sim.frontends.node import SimNode
from sorter_sim.model.core import cell_kernels as ck
from sorter_sim.model.io_map import by_name, io_map

BIN = Path(sys.executable).parent
SENSORS = ['pe_scan', 'pe_divert', 'pe_exit', 'chute_left', 'chute_right']
MAP = by_name(io_map(SENSORS))


def modbus_image():
    """Return an I/O image of the cell's map with its outputs as shipped, no cell behind it."""
    from sorter_sim.frontends.fieldbus import IOImage

    return IOImage(
        io_map(SENSORS),
        {
            'diverter.popup': False,
            'cell.reset': False,
            'belt.run': True,
            'scanner.ack': False,
            'cell.estop': False,
            'diverter.alpha_setpoint': 45.0,
            'plc.heartbeat': 0,
        },
    )


def serving_cell(ros, **ports):
    """
    Return a lock-step short cell serving its I/O image on ``ports`` (modbus_port=..., ...).

    Parcels 1 s apart and the disks at α = 60°, so that a test knows what the image must
    show: the first parcel reaches the scanner at about 2.6 s.
    """
    node = SimNode(
        context=ros.context,
        parameter_overrides=[
            Parameter(k, value=v)
            for k, v in {
                **SHORT_CELL,
                'arrival': 'gap',
                'arrival_gap': [1.0, 1.0],
                'alpha_deg': 60.0,
                **ports,
            }.items()
        ],
    )
    ros.add(node)
    return node


@pytest.fixture
def cell(ros):
    return serving_cell(ros, modbus_port=free_port(), opcua_port=free_port())


@pytest.fixture
def modbus(cell):
    client = ModbusTcpClient('127.0.0.1', port=cell.fieldbus.modbus_port, timeout=5, retries=0)
    assert client.connect()
    yield client
    client.close()


@pytest.fixture
def opcua(cell):
    client = OpcClient(cell.fieldbus.opcua_endpoint, timeout=10)
    client.connect()
    idx = client.get_namespace_index('urn:sorter_cell')
    root = client.nodes.objects.get_child([f'{idx}:cell'])

    def node(name):
        folder = 'Outputs' if MAP[name].direction == 'output' else 'Inputs'
        return root.get_child([f'{idx}:{folder}', f'{idx}:{name}'])

    yield node
    client.disconnect()


def u32(regs, address):
    """Return the uint32 at ``address`` of input registers read from 0 (high word first)."""
    return (regs[address] << 16) | regs[address + 1]


def cell_state(cell):
    """Return what a refused write must leave as it was (α, stroke, e-stop, belt, PackML ...)."""
    c = cell.cell
    return (
        cell.get_parameter('alpha_deg').value,
        float(c.act[ck.A_STROKE_TARGET]),
        c.estop,
        c.belt_run,
        c.watchdog_armed,
        c.packml.state,
    )


def diagnostics(cell):
    """Return the fieldbus counters the node reports in its diagnostics."""
    return cell.fieldbus_bridge.diagnostics()


def refused_login(endpoint: str, user: str, password: str) -> Exception | None:
    """
    Log in to ``endpoint`` as ``user`` with asyncua's synchronous client; return its refusal.

    None if the login was accepted. The client's own event-loop thread is stopped either
    way: a failed ``connect`` leaves it running, and it would keep pytest from exiting.
    """
    client = OpcClient(endpoint, timeout=10)
    client.set_user(user)
    client.set_password(password)
    try:
        client.connect()
    except Exception as exc:  # the refusal is what the caller checks
        client.tloop.stop()
        return exc
    client.disconnect()
    return None
