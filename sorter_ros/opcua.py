"""
The project's OPC UA servers, made the same way: anonymous sessions only, closed fast.

The cell's fieldbus (``sorter_sim.frontends.fieldbus``) and the line's warehouse node
(``sorter_control.wcs_opcua``) each serve an address space with asyncua. What they
share is here: a server no client identity makes an administrator (``new_server``),
its endpoint URL for any host, a stop bounded in time (``close_server``), and a thread
of its own with an asyncio loop (``ServerThread``) for a node whose executor must not
wait on OPC UA clients.
"""

from __future__ import annotations

import asyncio
import logging
import threading


class AnonymousOnly:
    """
    The OPC UA user manager: every session is an anonymous client, none an administrator.

    asyncua's default manager makes any client that logs in as 'admin' (with any
    password) an administrator, who may write inputs and add or delete nodes. Here the
    server takes anonymous identity tokens alone (a user name or a certificate token is
    BadIdentityTokenRejected before this is asked), and a user name that reaches this
    all the same is refused (BadUserAccessDenied); ``certificate`` is the secure
    channel's, which does not make a session anyone in particular. An anonymous session
    reads and writes what the address space's access levels allow, and never more.
    """

    def get_user(self, iserver, username=None, password=None, certificate=None):
        from asyncua.crypto.permission_rules import User, UserRole

        if username is None and password is None:
            return User(role=UserRole.User, name='anonymous')
        return None


def endpoint_url(host: str, port: int, path: str) -> str:
    """Return ``opc.tcp://host:port/path/``; an IPv6 host in brackets (RFC 3986)."""
    return f'opc.tcp://{f"[{host}]" if ":" in host else host}:{port}/{path}/'


async def new_server(host: str, port: int, path: str, name: str):
    """
    Return an initialised asyncua Server (not started) that only anonymous sessions use.

    Parameters
    ----------
    host, port : str, int
        Where it will listen.
    path : str
        The endpoint's path (``opc.tcp://host:port/path/``).
    name : str
        The server's application name.

    Returns
    -------
    (asyncua.Server, str)
        The server and its endpoint URL.

    """
    from asyncua import Server, ua

    for logger in ('asyncua', 'asyncua.server', 'asyncua.server.uaprocessor'):
        logging.getLogger(logger).setLevel(logging.CRITICAL)
    server = Server(user_manager=AnonymousOnly())
    await server.init()
    # sessions are anonymous or refused: no identity a client offers (a user name,
    # 'admin' with any password, a certificate) buys more than the access levels give;
    # the server's own internal session alone administers
    server.set_identity_tokens([ua.AnonymousIdentityToken])
    server.iserver.allow_remote_admin = False
    endpoint = endpoint_url(host, port, path)
    server.set_endpoint(endpoint)
    server.set_server_name(name)
    return server, endpoint


async def close_server(server, wait_s: float) -> None:
    """
    Stop ``server`` within about ``wait_s``: the listening socket and every connection first.

    asyncua's own stop waits on every session's subscriptions; a node shutting down
    must not wait on its clients.
    """
    bserver = getattr(server, 'bserver', None)
    if bserver is not None and getattr(bserver, '_server', None) is not None:
        bserver._server.close()
    for transport in list(getattr(server.iserver, 'asyncio_transports', [])):
        transport.abort()
    try:
        await asyncio.wait_for(server.stop(), wait_s)
    except Exception:  # a stop that overruns its bound, or fails: the loop ends it
        pass


class ServerThread:
    """
    An asyncio loop in a daemon thread, serving one OPC UA server that ``build`` makes.

    ``build`` is a coroutine function returning a started server; ``start()`` returns
    once it listens, or raises ValueError with one line saying why it cannot.
    """

    def __init__(self, build, what: str = 'OPC UA'):
        self._build = build
        self._what = what
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._run, name='opcua', daemon=True)
        self._ready = threading.Event()
        self._error: str | None = None
        self.server = None

    def start(self) -> None:
        self._thread.start()
        if not self._ready.wait(60.0):
            raise ValueError(f'the {self._what} server did not start within 60 s')
        if self._error:
            self.stop()
            raise ValueError(self._error)

    def _run(self) -> None:
        asyncio.set_event_loop(self.loop)
        try:
            self.server = self.loop.run_until_complete(self._build())
        except Exception as exc:  # reported by start() in one line
            text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            self._error = f'cannot serve {self._what}: {text}'
            self._ready.set()
            return
        self._ready.set()
        self.loop.run_forever()

    def call_soon(self, coro_fn, *args) -> None:
        """Run ``coro_fn(*args)`` on the server's loop, from any thread; never wait."""
        if self.loop.is_running():
            asyncio.run_coroutine_threadsafe(coro_fn(*args), self.loop)

    def stop(self, wait_s: float = 1.0) -> None:
        """Stop the server and the thread (idempotent), in at most about ``wait_s``."""
        if self._thread.is_alive() and self.loop.is_running():
            if self.server is not None:
                fut = asyncio.run_coroutine_threadsafe(
                    close_server(self.server, 0.6 * wait_s), self.loop
                )
                try:
                    fut.result(0.8 * wait_s)
                except Exception:  # the loop's end takes the server with it
                    pass
                self.server = None
            self.loop.call_soon_threadsafe(self.loop.stop)
            self._thread.join(0.2 * wait_s)
