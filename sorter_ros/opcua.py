"""
The project's OPC UA servers, made the same way: anonymous sessions only, closed fast.

The cell's fieldbus (``sorter_sim.frontends.fieldbus``) and the line's warehouse node
(``sorter_control.wcs_opcua``) each serve an address space with asyncua. What they
share is here: a server no client identity makes an administrator (``new_server``),
its endpoint URL for any host, a stop bounded in time (``close_server``), and a thread
of its own with an asyncio loop (``ServerThread``) for a node whose executor must not
wait on OPC UA clients. Each server says what it is as OPC UA Part 4 and 5 ask: its
own ApplicationUri (``urn:<host name>:sorter_cell:<application>``) and the product's
BuildInfo (``PRODUCT_URI``, the package's version and build date); and the nodes both
add are typed as a generic client browses them (``add_variable``: a type definition,
ValueRank and ArrayDimensions for arrays; ``argument``: a method argument with its
name and description, OPC UA Part 3, 8.6; ``add_method``: a method whose argument
properties are declared arrays).
"""

from __future__ import annotations

import asyncio
import logging
import socket
import threading
from datetime import datetime, timezone
from pathlib import Path

DISTRIBUTION = 'sorter_cell'
PRODUCT_URI = 'urn:sorter_cell:product'
MANUFACTURER = 'sorter_cell'


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


def build_identity() -> tuple[str, datetime]:
    """
    Return the installed package's version and build date (UTC).

    The build date is when the distribution's metadata was written (``pip install`` or
    ``colcon build``); without metadata (a source tree on sys.path) the version is
    'unknown' and the date that of this module's file.
    """
    from importlib import metadata

    stamp, version = None, 'unknown'
    # the newest of the installed metadata: ``python -m`` from a source tree also finds
    # the tree's own egg-info, written when the install began, not when it ended
    for dist in metadata.distributions(name=DISTRIBUTION):
        for f in dist.files or ():
            if f.name in ('METADATA', 'PKG-INFO'):
                try:
                    written = Path(f.locate()).stat().st_mtime
                except OSError:
                    continue
                if stamp is None or written > stamp:
                    stamp, version = written, dist.version
    if stamp is None:
        stamp = Path(__file__).stat().st_mtime
    return version, datetime.fromtimestamp(stamp, timezone.utc)


def application_uri(application: str) -> str:
    """Return the ApplicationUri of one server: unique per machine (OPC UA Part 6, 6.2.2)."""
    return f'urn:{socket.gethostname()}:{DISTRIBUTION}:{application}'


async def new_server(host: str, port: int, path: str, name: str, application: str = ''):
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
    application : str
        What distinguishes this server's ApplicationUri from the project's others
        (``cell:<name>``, ``line:<name>``, ``wcs``); ``name`` when empty.

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
    # a client (a SCADA's server list, a historian's connection) tells servers apart by
    # ApplicationUri and the product by BuildInfo: not the library's defaults
    server.product_uri = PRODUCT_URI
    server.manufacturer_name = MANUFACTURER
    await server.set_application_uri(application_uri(application or name))
    version, built = build_identity()
    await server.set_build_info(PRODUCT_URI, MANUFACTURER, DISTRIBUTION, version, version, built)
    return server, endpoint


def argument(name: str, vtype, description: str, array: bool = False):
    """
    Return a method's Argument (OPC UA Part 3, 8.6): named, described, scalar or 1-D.

    Parameters
    ----------
    name : str
        The argument's name, as a client's call dialog shows it.
    vtype : asyncua.ua.VariantType
        Its built-in type.
    description : str
        What it is and what it takes.
    array : bool
        A one-dimensional array of any length (ValueRank 1, ArrayDimensions [0]).

    """
    from asyncua import ua

    return ua.Argument(
        Name=name,
        DataType=ua.NodeId(vtype.value),
        ValueRank=ua.ValueRank.OneDimension if array else ua.ValueRank.Scalar,
        ArrayDimensions=[0] if array else [],
        Description=ua.LocalizedText(description),
    )


async def add_method(parent, idx: int, name: str, callback, inputs: list, outputs: list):
    """
    Add a method under ``parent`` with its arguments declared as the standard's methods are.

    asyncua's ``add_method`` leaves the ``InputArguments`` and ``OutputArguments``
    properties ValueRank 0 (one or more dimensions) without ArrayDimensions; each is a
    one-dimensional array of Argument, as every method of the standard's own address
    space declares it (OPC UA Part 3, 5.7: ValueRank 1, ArrayDimensions its count).

    Returns
    -------
    asyncua.Node
        The method.

    """
    from asyncua import ua

    method = await parent.add_method(idx, name, callback, inputs, outputs)
    for prop, args in (('InputArguments', inputs), ('OutputArguments', outputs)):
        if args:
            node = await method.get_child([f'0:{prop}'])
            await node.write_attribute(
                ua.AttributeIds.ValueRank, ua.DataValue(ua.Variant(1, ua.VariantType.Int32))
            )
            await node.write_attribute(
                ua.AttributeIds.ArrayDimensions,
                ua.DataValue(ua.Variant([len(args)], ua.VariantType.UInt32)),
            )
    return method


async def add_variable(parent, idx: int, name: str, variant, description: str, typedef=None):
    """
    Add a read-only variable under ``parent`` as a generic client expects to find it.

    Its Description is ``description``; an array value is declared one-dimensional
    (ValueRank 1, ArrayDimensions [0]: any length) even while it is empty; its type
    definition is ``typedef`` (a standard ObjectIds number, e.g. AnalogItemType) or
    BaseDataVariableType.

    Returns
    -------
    asyncua.Node
        The variable.

    """
    from asyncua import Node, ua

    attrs = ua.VariableAttributes()
    attrs.DisplayName = ua.LocalizedText(name)
    attrs.Description = ua.LocalizedText(description)
    attrs.DataType = ua.NodeId(variant.VariantType.value)
    attrs.Value = variant
    is_array = variant.is_array or isinstance(variant.Value, list)
    attrs.ValueRank = ua.ValueRank.OneDimension if is_array else ua.ValueRank.Scalar
    attrs.ArrayDimensions = [0] if is_array else None
    attrs.AccessLevel = attrs.UserAccessLevel = ua.AccessLevel.CurrentRead.mask
    attrs.WriteMask = attrs.UserWriteMask = 0
    item = ua.AddNodesItem(
        RequestedNewNodeId=ua.NodeId(0, idx),
        BrowseName=ua.QualifiedName(name, idx),
        NodeClass=ua.NodeClass.Variable,
        ParentNodeId=parent.nodeid,
        ReferenceTypeId=ua.NodeId(ua.ObjectIds.HasComponent),
        TypeDefinition=ua.NodeId(typedef or ua.ObjectIds.BaseDataVariableType),
        NodeAttributes=attrs,
    )
    (result,) = await parent.session.add_nodes([item])
    result.StatusCode.check()
    return Node(parent.session, result.AddedNodeId)


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
