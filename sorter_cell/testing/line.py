"""
The line under test: N stations, their programs and the warehouse node, in lock-step.

``SorterLine`` starts the real line node (``sorter_sim.frontends.line_node.LineNode``,
``time_mode: lockstep``), one PLC program per station (this project's controller in
the station's namespace ``/S01`` ..., with the warehouse's routing only) and the
warehouse node (``sorter_control.wcs_node.WcsNode``) with a sort plan, all in one
rclpy Context, advanced by the test as ``SorterCell`` is (``LockStep``). Any
station's program can be the user's (``programs={k: factory}`` at the start, or
``station(k).replace_program(...)``); it then talks to its station and to the
warehouse over DDS exactly as the project's does (the station-program contract,
docs/testing.md).

Parcels are inducted at station 1 by label and destination (``induct``: the
destination is the warehouse's request for the label); what the test reads is
``dispositions``: one per parcel as it leaves the line, with its code (``sorted``,
``no_read``, ..., ``lost``), the station and the chute.
"""

from __future__ import annotations

from sorter_ros.outcomes import LineDisposition, read_disposition, read_exit
from sorter_cell.testing.lockstep import (
    SLICE_S,
    LockStep,
    exits_text,
    load_node_factory,
    PARCEL_DEFAULTS,
    make_user_nodes,
    parcel_spec,
)

MAX_STATIONS = 64


def default_plan(chutes: list) -> dict:
    """Return D01 .. D(2N) -> the line's chutes in order (left then right, station by station)."""
    names = [name for pair in chutes for name in pair]
    return {f'D{j + 1:02d}': name for j, name in enumerate(names)}


class Station:
    """One station of a ``SorterLine``: its cell node and its program."""

    def __init__(self, line: SorterLine, index: int):
        self._line = line
        self.index = index  # 0-based

    @property
    def name(self) -> str:
        """Return what the station is called on the line (S01 ...)."""
        from sorter_sim.model.description import station_name

        return station_name(self.index)

    @property
    def namespace(self) -> str:
        """Return the namespace its program must be created in (``/S01``, ...)."""
        return f'/{self.name}'

    @property
    def sim(self):
        """Return the station's simulation node."""
        return self._line.line.stations[self.index]

    @property
    def program(self) -> list:
        """Return the station's program: its node(s)."""
        return list(self._line.programs[self.index])

    @property
    def chutes(self) -> tuple:
        """Return the station's left and right chute."""
        return tuple(self._line.wcs.wcs.chutes[self.index])

    def replace_program(self, program, parameters: dict | None = None) -> list:
        """
        Replace the station's program by the user's.

        Parameters
        ----------
        program : rclpy.node.Node, list of nodes, callable or str
            Node(s) already made in ``line.context`` and the station's ``namespace``; or
            a factory (or ``"module:callable"``) called with ``context=``,
            ``namespace=`` and ``parameter_overrides=`` (``use_sim_time`` and
            ``parameters``).
        parameters : dict, optional
            The factory's parameter overrides.

        Returns
        -------
        list of rclpy.node.Node
            The new program's nodes.

        """
        from rclpy.node import Node

        line = self._line
        if isinstance(program, str):
            program = load_node_factory(program)
        if isinstance(program, (list, tuple)):
            nodes = list(program)
        elif isinstance(program, Node):
            nodes = [program]
        elif callable(program):
            nodes = make_user_nodes(program, line.context, parameters, namespace=self.namespace)
        else:
            raise ValueError(f'a program is a node, a list of nodes or a factory, got {program!r}')
        for node in nodes:
            if node.get_namespace() != self.namespace:
                raise ValueError(
                    f'node {node.get_name()!r} is in namespace {node.get_namespace()!r}: a '
                    f'program for station {self.name} must be in {self.namespace!r}'
                )
        for old in line.programs[self.index]:
            line.remove_node(old)
        line.programs[self.index] = nodes
        line.add_node(nodes)
        return nodes

    # the spelling of the example
    replace_controller = replace_program


class SorterLine(LockStep):
    """
    A line of ``stations`` diverters, their programs and the warehouse (see the module).

    Parameters
    ----------
    stations : int
        1-64.
    plan : dict, optional
        The sort plan, destination -> chute (a chute's name or ``straight_end``);
        default ``default_plan``: D01 -> S01L, D02 -> S01R, D03 -> S02L, ...
    params : dict, optional
        Every station's cell parameters over config/cell.yaml.
    programs : dict, optional
        Station number (1-based) -> the user's program for it (as ``replace_program``
        takes it); the other stations run this project's.
    domain_id, slice_s, grace_s, record
        As ``SorterCell``'s.
    start_timeout_s : float
        The most wall time the project's programs may take to start.
    line_key : str, optional
        A line key file (``sorter line-key``): the line and the warehouse seal their
        exits with it; default ``SORTER_LINE_KEY``'s file, or none.

    """

    what = 'the line'

    def __init__(
        self,
        stations: int = 2,
        *,
        plan: dict | None = None,
        params: dict | None = None,
        programs: dict | None = None,
        domain_id: int | None = None,
        slice_s: float = SLICE_S,
        grace_s: float | None = None,
        record: str | None = None,
        start_timeout_s: float = 120.0,
        line_key: str | None = None,
    ):
        from rclpy.parameter import Parameter

        from sorter_cell.line_segment import station_controller
        from sorter_control.wcs_node import WcsNode
        from sorter_ros.line_key import read_key_file
        from sorter_sim.frontends.line_node import LineNode

        if isinstance(stations, bool) or not (
            isinstance(stations, int) and 1 <= stations <= MAX_STATIONS
        ):
            raise ValueError(f'stations must be an integer in [1, 64], got {stations!r}')
        key = read_key_file(line_key) if line_key else None  # a LineKeyError is a ValueError
        programs = dict(programs or {})
        bad = [k for k in programs if not (isinstance(k, int) and 1 <= k <= stations)]
        if bad:
            raise ValueError(f'programs: stations are numbered 1..{stations}, got {bad}')
        # the single-threaded executor walks every entity of every node on each pass
        # (about 110 a station): the events executor keeps a line's slices cheap
        self._start_context(domain_id, slice_s, grace_s, events=True)
        self.record_path = str(record or '')
        self.dispositions_seen: list[LineDisposition] = []
        self.exits_seen: list[tuple] = []
        try:
            self.line = LineNode(
                context=self.context,
                line_key=key,
                parameter_overrides=[
                    Parameter('stations', value=stations),
                    Parameter('time_mode', value='lockstep'),
                    Parameter('record_path', value=self.record_path),
                ],
                station_params={'arrival': 'none', **(params or {})},
            )
            self._stepper, self._timebase = self.line, self.line.line
            self.add_node(self.line.nodes)
            self.wcs = WcsNode(
                context=self.context,
                line_key=key,
                parameter_overrides=[
                    Parameter('stations', value=stations),
                    Parameter('use_sim_time', value=True),
                    Parameter('record_path', value=self.record_path),
                ],
            )
            self.add_node(self.wcs)
            self.programs: list[list] = [[] for _ in range(stations)]
            for k in range(stations):
                if k + 1 not in programs:
                    self.programs[k] = [self.add_node(station_controller(self.context, k))]
            for k, program in programs.items():
                self.station(k).replace_program(program)
            self._observe()
            self.set_plan(default_plan(self.wcs.wcs.chutes) if plan is None else plan)
            self._wait_for_programs(start_timeout_s)
        except BaseException:
            self.close()
            raise

    # ------------------------------------------------------------------ set-up
    def _observe(self) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticStatus

        from sorter_ros.interface import EVENT_QOS

        def on_disposition(msg):
            self.dispositions_seen.append(read_disposition(msg))

        def on_exit(msg):
            e = read_exit(msg)
            self.exits_seen.append((e.label, e.exit, e.t))

        node = self.add_node(rclpy.create_node('sorter_line_observer', context=self.context))
        node.create_subscription(DiagnosticStatus, 'wcs/dispositions', on_disposition, EVENT_QOS)
        node.create_subscription(DiagnosticStatus, 'line/exits', on_exit, EVENT_QOS)

    def _wait_for_programs(self, timeout_s: float) -> None:
        """Run the empty line until this project's programs sort (geometry asked, model warm)."""
        from sorter_control.node import ControllerNode

        ours = [n for p in self.programs for n in p if isinstance(n, ControllerNode)]
        self.wait_started(
            lambda: all(c.logic is not None and c.logic.state == 'running' for c in ours),
            timeout_s,
            "the stations' programs did not start",
        )
        # the warehouse's routing tables reach every program that has subscribed
        self.spin_idle()

    def _graph_settled(self) -> bool:
        # and the warehouse has sent each program that subscribed its whole table (its
        # resync timer notes the readers it served)
        wcs = self.wcs
        served = all(
            pub.get_subscription_count() == seen
            for pub, seen in zip(wcs._pub_routing, wcs._readers)
        )
        return served and super()._graph_settled()

    def set_plan(self, plan: dict, version: str | None = None) -> None:
        """
        Make ``plan`` (destination -> chute) the warehouse's sort plan.

        Raises
        ------
        ValueError
            The warehouse refused it; its reason is the message.

        """
        if not isinstance(plan, dict):
            raise ValueError(f'plan must be a mapping destination -> chute, got {plan!r}')
        self._plans = getattr(self, '_plans', 0) + 1
        why = self.wcs.take_plan(version or f'v{self._plans}', list(plan.items()))
        if why:
            raise ValueError(why)
        self.spin_idle()

    def station(self, k: int) -> Station:
        """
        Return station ``k`` (1-based).

        Parameters
        ----------
        k : int
            1 .. stations.

        """
        n = len(self.line.stations)
        if isinstance(k, bool) or not (isinstance(k, int) and 1 <= k <= n):
            raise ValueError(f'station must be an integer in [1, {n}], got {k!r}')
        return Station(self, k - 1)

    @property
    def stations(self) -> list[Station]:
        """Return every station, in order."""
        return [Station(self, k) for k in range(len(self.line.stations))]

    # ------------------------------------------------------------------ parcels
    def induct(self, label: str, destination: str | None = None, **dims) -> None:
        """
        Request ``label`` to ``destination`` and queue the parcel at station 1's induction.

        Parameters
        ----------
        label : str
            Its label ('' for a parcel without one: a no-read).
        destination : str, optional
            A destination of the sort plan (None: no request, the parcel is
            ``no_destination``).
        **dims
            ``length``, ``width``, ``mass``, ``skew_deg``, ``y``, as ``SorterCell.induct``.

        Raises
        ------
        ValueError
            A refused request or a parcel value out of range, named; nothing is queued.

        """
        unknown = sorted(set(dims) - set(PARCEL_DEFAULTS))
        if unknown:
            raise ValueError(
                f'induct: unknown argument(s) {", ".join(unknown)} (allowed: '
                f'{", ".join(PARCEL_DEFAULTS)})'
            )
        spec = parcel_spec(label, **{**PARCEL_DEFAULTS, **dims})
        if destination is not None:
            why = self.wcs.take_request(label, destination)
            if why:
                raise ValueError(why)
        self.line.stations[0].cell.induct(spec)
        self.spin_idle()

    @property
    def dispositions(self) -> list[LineDisposition]:
        """Return the dispositions so far, in the order the warehouse gave them."""
        return list(self.dispositions_seen)

    def disposition(self, label: str) -> LineDisposition | None:
        """Return the disposition of ``label``, or None while it has none."""
        return next((d for d in self.dispositions_seen if d.label == label), None)

    def state_lines(self) -> list[str]:
        """Return the report's parcels, faults and PackML state (``LockStep.explain``)."""
        first = self.line.stations[0].cell
        disp = [
            (d.label, f'{d.code} ({d.station} {d.chute or "-"})', d.t)
            for d in self.dispositions_seen
        ]
        lines = [
            f'parcels: {first.n_inducted} inducted, {self.line.line.n_in_flight} on the line, '
            f'{first.pending_inducts} waiting at the induction, {len(self.exits_seen)} out',
            'dispositions: ' + exits_text(disp),
        ]
        for st in self.stations:
            c = st.sim.cell
            names = ', '.join(n.get_name() for n in self.programs[st.index]) or 'none'
            lines.append(
                f'{st.name}: faults {", ".join(c.faults) or "none"}, PackML {c.packml.state}, '
                f'program {names}'
            )
        return lines

    def close(self) -> None:
        """Destroy the programs, the warehouse and the line, then the Context."""
        line = getattr(self, 'line', None)
        if line is not None:
            # the line node destroys its stations itself
            self.nodes = [n for n in self.nodes if n not in line.stations]
        super().close()


__all__ = ['LineDisposition', 'SorterLine', 'Station', 'default_plan']
