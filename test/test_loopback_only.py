"""
No DDS traffic leaves loopback by default, with the discovery range unset or set but empty.

The simulation node runs as its console script with ``ROS_AUTOMATIC_DISCOVERY_RANGE``
empty, then set to LOCALHOST; a raw packet socket counts the UDP datagrams to this
ROS domain's ports (7400 + 250 x domain + offsets, SPDP multicast included) that
leave on any interface but ``lo``. SUBNET, the user's explicit choice, is the
control that shows the capture sees such traffic at all. Needs Linux, the right to
open a packet socket (root or CAP_NET_RAW) and a network interface besides lo.
"""

import os
import signal
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]

DOMAIN = 141  # this test's own: the sniffer counts its ports only
PORTS = range(7400 + 250 * DOMAIN, 7400 + 250 * (DOMAIN + 1))
BIN = Path(sys.executable).parent
ETH_P_ALL = 0x0003


def _packet_socket():
    if not hasattr(socket, 'AF_PACKET'):
        pytest.skip('no packet sockets on this system')
    try:
        s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.ntohs(ETH_P_ALL))
    except PermissionError:
        pytest.skip('opening a packet socket needs root or CAP_NET_RAW')
    if not [n for _, n in socket.if_nameindex() if n != 'lo']:
        pytest.skip('no network interface besides lo')
    s.settimeout(0.2)
    return s


def _datagrams_off_loopback(discovery_range: str, seconds: float = 4.0) -> int:
    """Run sim_node with this range for a few seconds; count its DDS datagrams off lo."""
    sniffer = _packet_socket()
    env = dict(
        os.environ, ROS_DOMAIN_ID=str(DOMAIN), ROS_AUTOMATIC_DISCOVERY_RANGE=discovery_range
    )
    node = subprocess.Popen(
        [str(BIN / 'sim_node'), '--ros-args', '-p', 'arrival:=none'],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    count = 0
    try:
        deadline = time.monotonic() + seconds + 3.0  # start-up, then a few SPDP periods
        while time.monotonic() < deadline:
            try:
                frame, addr = sniffer.recvfrom(65535)
            except socket.timeout:
                continue
            if addr[0] == 'lo' or frame[12:14] != b'\x08\x00':
                continue
            ip = frame[14:]
            if len(ip) < 28 or ip[9] != 17:  # UDP only
                continue
            ihl = (ip[0] & 0x0F) * 4
            (dport,) = struct.unpack('!H', ip[ihl + 2 : ihl + 4])
            if dport in PORTS:
                count += 1
    finally:
        node.send_signal(signal.SIGINT)
        node.wait(timeout=20)
        sniffer.close()
    return count


@pytest.mark.parametrize('value', ['', 'LOCALHOST'], ids=['empty', 'LOCALHOST'])
def test_no_dds_traffic_leaves_loopback(value):
    control = _datagrams_off_loopback('SUBNET')
    assert control > 0, 'the capture saw no DDS traffic even with SUBNET: it proves nothing'
    assert _datagrams_off_loopback(value) == 0
