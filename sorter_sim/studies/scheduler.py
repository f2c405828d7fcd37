"""
A Dask client of a running scheduler, for the commands that take ``--scheduler ADDRESS``.

``sorter sweep`` and ``sorter scenario campaign`` send their runs to a scheduler the user
started. Given an address where nothing listens, dask's ``Client`` tries to connect
again and again until its time-out (10 s by default) and then reports a time-out. A
refused connection is an answer, though: this module asks the address once first, so
a scheduler that is not running (or a wrong port) is named at once, and a host that
does not answer still gets the whole time-out.
"""

from __future__ import annotations

import socket


def connect_scheduler(address: str, timeout_s: float):
    """
    Return a ``distributed.Client`` of the scheduler at ``address``.

    Parameters
    ----------
    address : str
        The scheduler's address (``tcp://HOST:PORT``, ``tls://...``, or any form dask takes).
    timeout_s : float
        Wall seconds to wait for it.

    Returns
    -------
    distributed.Client
        The client.

    Raises
    ------
    OSError
        Nothing listens at a TCP or TLS address (said at once), or it did not answer.
    ValueError
        A TCP or TLS address whose port is not in 1-65535.
    Exception
        Whatever dask raises for an address it cannot use or a scheduler it cannot reach.

    """
    from distributed import Client
    from distributed.comm.addressing import parse_address, parse_host_port

    try:
        scheme, location = parse_address(address)
        host, port = parse_host_port(location)
    except (ValueError, TypeError):
        scheme = None  # dask's own message says what is wrong with it
    if scheme in ('tcp', 'tls'):
        if not 0 < port <= 65535:  # the socket layer would wrap it round to another port
            raise ValueError(f'port {port} is not a TCP port: it must be in 1-65535')
        try:
            with socket.create_connection((host, port), timeout=timeout_s):
                pass
        except ConnectionRefusedError:
            raise ConnectionRefusedError(
                f'connection refused: nothing listens on {host} port {port}'
            ) from None
    return Client(address, timeout=f'{timeout_s:g}s')
