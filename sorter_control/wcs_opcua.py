"""
The line's warehouse interface over OPC UA: the sort plan, requests and dispositions.

``WcsOpcUa`` serves, for the warehouse node (``wcs_node.WcsNode``), an object
``sorter_line`` with a folder ``Warehouse`` (namespace ``urn:sorter_cell:line``):

======================= ========== =====================================================
node                    type       meaning
======================= ========== =====================================================
``SortPlanVersion``     String     the plan in force
``SortPlan``            String[]   its entries, ``destination=chute``
``LastRefusal``         String     why the last plan or request was refused
``RequestCount``        UInt32     requests taken so far
``FullChutes``          String[]   the chutes that are full now
``LastDisposition``     String     the latest parcel's disposition,
                                   ``label;code;destination;chute;station;t``
``DispositionCount``    UInt32     dispositions so far
``Dispositions``        String[]   the latest 256, oldest first
``SetSortPlan``         method     (version String, entries String[] ``dest=chute``)
``RequestDestination``  method     (label String, destination String; '' withdraws)
======================= ========== =====================================================

Variables are read-only; a refused call answers ``BadInvalidArgument`` (the reason in
``LastRefusal``), a wrong type ``BadTypeMismatch``, a wrong count of arguments
``BadArgumentsMissing`` / ``BadTooManyArguments``; nothing changes then. The calls run
the node's own handlers (the same as its ROS topics', under its lock), so a plan set
over OPC UA is the plan on ``wcs/sort_plan/active`` and the other way round. Every
variable is written through the address space when it changes, so OPC UA
subscriptions see each change. Sessions are anonymous only (``sorter_ros.opcua``).
"""

from __future__ import annotations

from collections import deque

from sorter_ros.opcua import ServerThread, add_method, add_variable, argument, new_server

KEEP = 256  # dispositions the Dispositions array holds
MAX_ENTRIES = 10_000  # entries of a plan over OPC UA


class WcsOpcUa:
    """
    The warehouse node's OPC UA server (see the module).

    Parameters
    ----------
    host, port : str, int
        Where to listen (port 0: any free port, ``endpoint`` says which).
    set_plan : callable (version, [(destination, chute)]) -> str
        Takes a plan; returns '' when taken, else why not.
    request : callable (label, destination) -> str
        Takes a request; returns '' when taken, else why not.

    """

    def __init__(self, host: str, port: int, *, set_plan, request):
        self._set_plan = set_plan
        self._request = request
        self._host, self._port = host, port
        self.nodes: dict[str, object] = {}
        self.dispositions: deque = deque(maxlen=KEEP)
        self.n_dispositions = 0
        self.refused = 0
        self.endpoint = ''
        self._thread = ServerThread(self._build, 'OPC UA')

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._thread.stop()

    async def _build(self):
        from asyncua import ua

        server, self.endpoint = await new_server(
            self._host, self._port, 'sorter_line', 'sorter_line', 'wcs'
        )
        idx = await server.register_namespace('urn:sorter_cell:line')
        line = await server.nodes.objects.add_object(idx, 'sorter_line')
        folder = await line.add_folder(idx, 'Warehouse')
        String, UInt32 = ua.VariantType.String, ua.VariantType.UInt32
        variables = {
            'SortPlanVersion': ('', String, 'the sort plan in force'),
            'SortPlan': ([], String, "its entries, 'destination=chute'"),
            'LastRefusal': ('', String, 'why the last plan or request was refused'),
            'RequestCount': (0, UInt32, 'requests taken so far'),
            'FullChutes': ([], String, 'the chutes that are full now'),
            'LastDisposition': (
                '',
                String,
                "the latest: 'label;code;destination;chute;station;t'",
            ),
            'DispositionCount': (0, UInt32, 'dispositions so far'),
            'Dispositions': ([], String, f'the latest {KEEP}, oldest first'),
        }
        for name, (initial, vtype, meaning) in variables.items():
            variant = ua.Variant(initial, vtype, is_array=isinstance(initial, list))
            self.nodes[name] = await add_variable(folder, idx, name, variant, meaning)
        bad = ua.StatusCodes

        def method(arity, body):
            def call(parent, *args):
                if len(args) != arity:
                    self.refused += 1
                    return ua.StatusCode(
                        bad.BadArgumentsMissing if len(args) < arity else bad.BadTooManyArguments
                    )
                return body(*args)

            return call

        def refuse(code, why: str):
            self.refused += 1
            self._write('LastRefusal', why)
            return ua.StatusCode(code)

        def set_sort_plan(version, entries):
            if version.VariantType != String or entries.VariantType != String:
                return refuse(bad.BadTypeMismatch, 'SetSortPlan takes a String and a String array')
            items = entries.Value if isinstance(entries.Value, list) else [entries.Value]
            if len(items) > MAX_ENTRIES:
                return refuse(bad.BadInvalidArgument, f'a plan has at most {MAX_ENTRIES} entries')
            pairs = []
            for e in items:
                if not isinstance(e, str) or e.count('=') != 1:
                    return refuse(
                        bad.BadInvalidArgument,
                        f"a plan entry must read 'destination=chute', got {e!r}",
                    )
                pairs.append(tuple(e.split('=')))
            why = self._set_plan(version.Value or '', pairs)
            return refuse(bad.BadInvalidArgument, why) if why else []

        def request_destination(label, destination):
            if label.VariantType != String or destination.VariantType != String:
                return refuse(bad.BadTypeMismatch, 'RequestDestination takes two Strings')
            why = self._request(label.Value or '', destination.Value or '')
            return refuse(bad.BadInvalidArgument, why) if why else []

        methods = {
            'SetSortPlan': (
                set_sort_plan,
                [
                    argument('version', String, "the plan's name, shown in SortPlanVersion"),
                    argument(
                        'entries',
                        String,
                        f"'destination=chute', one per destination (at most {MAX_ENTRIES})",
                        array=True,
                    ),
                ],
                [],
            ),
            'RequestDestination': (
                request_destination,
                [
                    argument('label', String, "a parcel's label"),
                    argument(
                        'destination',
                        String,
                        "where it goes, a destination of the plan; '' withdraws the request",
                    ),
                ],
                [],
            ),
        }
        for name, (func, inputs, outputs) in methods.items():
            # the arguments' properties declared as the standard's own methods' are
            # (ValueRank 1, ArrayDimensions their count), as the cell's model does
            self.nodes[name] = await add_method(
                folder, idx, name, method(len(inputs), func), inputs, outputs
            )
        try:
            await server.start()
        except (OSError, RuntimeError) as exc:
            where = f'{self._host}:{self._port}'
            raise ValueError(f'on {where}: {getattr(exc, "strerror", None) or exc}') from None
        return server

    # ------------------------------------------------------------------ the node's side
    def _write(self, name: str, value) -> None:
        """Write a variable through the address space (its subscribers see it), from any thread."""
        from asyncua import ua

        var = self.nodes.get(name)
        if var is None:
            return
        vtype = ua.VariantType.UInt32 if isinstance(value, int) else ua.VariantType.String
        variant = ua.Variant(value, vtype, is_array=isinstance(value, list))
        self._thread.call_soon(var.write_value, variant)

    def plan_changed(self, version: str, plan: dict) -> None:
        """Show the plan in force."""
        self._write('SortPlanVersion', version)
        self._write('SortPlan', [f'{d}={c}' for d, c in sorted(plan.items())])

    def refused_change(self, why: str) -> None:
        """Show why a plan or request that came over ROS was refused."""
        self._write('LastRefusal', why)

    def requests_changed(self, count: int) -> None:
        self._write('RequestCount', count)

    def full_changed(self, full: set) -> None:
        self._write('FullChutes', sorted(full))

    def disposition(self, text: str) -> None:
        """Show one more parcel's disposition, ``label;code;destination;chute;station;t``."""
        self.dispositions.append(text)
        self.n_dispositions += 1
        self._write('LastDisposition', text)
        self._write('DispositionCount', self.n_dispositions)
        self._write('Dispositions', list(self.dispositions))
