"""
The sorter cell as hardware, without ROS: parcels, actuators, sensors, and the stream.

``Cell`` holds every parcel's state and advances them all a control period at a
time with ``core.cell_kernels.advance_cell``; it inducts the configured parcel
stream (and parcels asked for from outside), moves the pop-up and the disk angle
at their physical rates, and reports only what a real cell would show a PLC:
sensor edges (exact times on the simulation clock), scanner reads, where parcels
left (a chute, straight on, or jammed), the actuators' positions and the faults.
The node (``sorter_sim/frontends/node.py``) turns these into messages.

Time is an integer count of control periods, so stamps are exact nanoseconds.
Parameters come checked from ``params.CellParams``. What the cell reports and takes
are the records of ``cell_records`` (re-exported here). Its collaborators, one job
each: ``cell_infeed.Infeed`` (which parcel comes in next), ``cell_watchdog.Watchdog``
(the controller's heartbeats), ``cell_packml.PackMLTimers`` (starved and blocked),
``sensor_faults.SensorFaults`` (faults injected into its sensors) and ``cell_view``
(what a camera sees of its parcels).
"""

from __future__ import annotations

import math

import numpy as np

from sorter_sim.model.build import zone_law
from sorter_sim.model.core import cell_kernels as ck
from sorter_sim.model.core.cache import check_kernel_cache
from sorter_sim.model.core.layout import PARCEL_WIDTH, STRIP_WIDTH
from sorter_sim.model.core.simulate import Parcel, parcel_array
from sorter_sim.model.core.stick import GAUGE_CARRY
from sorter_sim.model.core.wrench import gauss_legendre_01
from sorter_sim.model.description import shown
from sorter_sim.model.packml import Conditions, PackMLMachine
from sorter_sim.runtime.cell_records import (
    CHATTER_PERIOD_RANGE,
    NEVER,
    SENSOR_FAULTS,
    WATCHDOG_REFUSAL,
    Handoff,
    LabelRead,
    Outcome,
    ParcelSpec,
    SensorEdge,
    SensorFault,
    WatchdogTrip,
    check_parcel,
)
from sorter_sim.runtime.params import (
    CellParams,
    ParamError,
    format_label,
    parcel_half_extents,
)
from sorter_sim.runtime import cell_view
from sorter_sim.runtime.cell_contacts import (
    N_QUAD,
    cell_contacts,
    configure_contacts,
    fresh_slot,
    jam_cause,
    rail_row,
)
from sorter_sim.runtime.cell_infeed import Infeed
from sorter_sim.runtime.cell_packml import PackMLTimers
from sorter_sim.runtime.cell_watchdog import Watchdog
from sorter_sim.runtime.sensor_faults import SensorFaults

EXIT_NAMES = {ck.EV_LEFT: 'left', ck.EV_RIGHT: 'right', ck.EV_STRAIGHT: 'straight'}
# parcel states for markers, indexed by the kernels' S_* codes
STATE_NAMES = ('on_belt', 'on_disks', 'sliding', 'diverted', 'straight', 'jammed')
CHUTE_SENSORS = ('chute_left', 'chute_right')


class Cell:
    """One sorter cell: belt, disk field, pop-up, walls, chutes, sensors and parcels."""

    def __init__(self, params: CellParams):
        check_kernel_cache()
        self.params = params
        cap = params.max_parcels
        self.sensor_names = list(params.photo_eyes_names) + list(CHUTE_SENSORS)
        n_sens = len(self.sensor_names)
        self.eye_x = np.array(params.photo_eyes_x, dtype=float)
        self.state = np.zeros((cap, 6))
        self.mode = np.full(cap, ck.MODE_SLIDE, dtype=np.int64)
        self.phase = np.zeros(cap, dtype=np.int64)
        self.par = np.zeros((cap, PARCEL_WIDTH))
        self.scanned = np.zeros(cap, dtype=np.bool_)
        self.gauge_xi = np.zeros((cap, GAUGE_CARRY))  # each parcel's stick-gauge warm start
        self.blocked = np.zeros((cap, n_sens), dtype=np.bool_)
        self.counts = np.zeros(n_sens, dtype=np.int64)
        self.ids = np.zeros(cap, dtype=np.int64)
        self.dims = np.zeros((cap, 3))
        self.labels = [''] * cap
        self.jam_cause = [''] * cap
        self.nodes, self.weights = gauss_legendre_01(N_QUAD)
        self.cfg = np.zeros(ck.CFG_WIDTH)
        self.laws = np.zeros((2, 0))
        self._configure(params)
        self.act = np.zeros(ck.ACT_WIDTH)
        self.act[ck.A_ALPHA] = self.act[ck.A_ALPHA_CMD] = params.alpha_rad
        self.act[ck.A_BELT_ON] = 1.0
        self.belt_run = True  # the belt's run command (a fieldbus output); e-stop overrides it
        self.k = 0
        self.estop = False
        self.jam = False
        self.watchdog = Watchdog()
        self._sensor_faults = SensorFaults(self.sensor_names)
        self.n_inducted = 0
        # a station of a line hands each parcel leaving straight to the next one
        # (``runtime.line``): their full states, collected by ``take_handoffs``
        self.keep_handoffs = False
        self._handoffs: list[Handoff] = []
        self.outcome_counts = {'left': 0, 'right': 0, 'straight': 0, 'jammed': 0}
        self.infeed = Infeed(params, self.dt)
        self._pending_edges: list[SensorEdge] = []  # made by a PackML command
        # one period can log per parcel a few sensor changes, a scan, an exit and a jam
        self._ev_reserve = cap * (n_sens + 4) + 8
        self.ev_i = np.zeros((2 * self._ev_reserve + 1024, 4), dtype=np.int64)
        self.ev_f = np.zeros((2 * self._ev_reserve + 1024, 3))
        self.stats = np.zeros(4, dtype=np.int64)
        # the kernel's note of the last period's strips (see ``advance_cell``)
        self._last_strips = np.zeros((ck.MAX_STRIPS, STRIP_WIDTH))
        self._last_info = np.array([-1, 0], dtype=np.int64)
        self.rails: list = [rail_row(*seg) for seg in params.rail_segments]  # and add_rail's
        self.contacts = cell_contacts(params, self.rails)
        self.snapshot_rows = np.zeros((cap, 7))  # cell_view.parcels fills it
        # the machine state (PackML): in automatic mode it resets and starts at once, so a
        # cell that nobody commands runs from period 0 as it always has
        self.packml = PackMLMachine(auto=params.packml_auto)
        self._timers = PackMLTimers((n, self.sensor_names.index(n)) for n in CHUTE_SENSORS)
        # set by whatever can change the machine state's conditions between two advances
        # (commands, faults, parcels from outside); advance evaluates it first then
        self._packml_dirty = True
        self._packml_due_k = 0  # the period a condition's time falls due (starved, ...)
        self.update_packml()
        self._kernel(0)  # compile (or load from numba's cache) now, not in a callback

    # ------------------------------------------------------------------ set-up
    def _configure(self, p: CellParams) -> None:
        # the zones' laws: the parameters are checked already (CellParams), no scene needed
        law_a = zone_law(p.friction_model, p.mu_belt)
        law_b = zone_law(p.friction_model, p.mu_disks)
        self.law_belt, self.law_disks = law_a, law_b
        self.laws = np.vstack([law_a.row(), law_b.row()])
        c = self.cfg
        lo, hi = p.chute_x_range
        c[ck.C_V] = p.belt_speed
        c[ck.C_HALF_W] = 0.5 * p.belt_width
        c[ck.C_B] = p.disk_field_length
        c[ck.C_OPEN_LO] = lo
        c[ck.C_OPEN_HI] = hi
        c[ck.C_EXIT_X] = p.exit_x
        c[ck.C_SCAN_X] = p.scanner_x
        c[ck.C_DT] = p.control_period_ns * 1e-9
        c[ck.C_ALPHA_RATE] = math.radians(p.alpha_slew_rate_deg_s)
        c[ck.C_STROKE_RATE] = math.inf if p.popup_stroke_time == 0.0 else 1.0 / p.popup_stroke_time
        c[ck.C_RTOL] = p.integrator_rtol
        c[ck.C_ATOL] = p.integrator_atol
        c[ck.C_METHOD] = 0.0 if p.integrator == 'accurate' else 1.0
        c[ck.C_LAW_A] = law_a.law_id
        c[ck.C_LAW_B] = law_b.law_id
        configure_contacts(c, p)

    def update_params(self, params: CellParams) -> None:
        """
        Take run-time parameter changes (the disk angle command, the parcel stream).

        Parameters
        ----------
        params : CellParams
            The new set, checked (``CellParams.with_changes``); its structural parameters are
            the running cell's.

        """
        self._packml_dirty = True
        changed_alpha = params.alpha_deg != self.params.alpha_deg
        self.infeed.update_params(params, self.k)
        self.params = params
        if changed_alpha:
            self.act[ck.A_ALPHA_CMD] = params.alpha_rad

    # ------------------------------------------------------------------ time
    @property
    def dt(self) -> float:
        return self.cfg[ck.C_DT]

    @property
    def t_ns(self) -> int:
        return self.k * self.params.control_period_ns

    @property
    def t(self) -> float:
        return self.t_ns * 1e-9

    # ------------------------------------------------------------------ actuators
    @property
    def alpha(self) -> float:
        """Physical disk angle [rad]."""
        return float(self.act[ck.A_ALPHA])

    @property
    def alpha_rate(self) -> float:
        return float(self.act[ck.A_ALPHA_DOT])

    @property
    def stroke(self) -> float:
        """Pop-up position, 0 down .. 1 up."""
        return float(self.act[ck.A_STROKE])

    @property
    def stroke_rate(self) -> float:
        return float(self.act[ck.A_STROKE_DOT])

    @property
    def belt_velocity(self) -> float:
        return self.params.belt_speed if self.act[ck.A_BELT_ON] > 0.5 else 0.0

    def popup(self, up: bool) -> tuple[bool, str]:
        """
        Raise (True) or lower the disks; refused while the e-stop is engaged.

        Parameters
        ----------
        up : bool
            Raise (True) or lower (False); the stroke then moves over ``popup_stroke_time``.

        Returns
        -------
        (bool, str)
            Whether it was taken, and the reason (why not, or what it does).

        """
        if self.estop:
            return False, 'refused: e-stop engaged (call reset first)'
        if up and self.watchdog_tripped:
            return False, WATCHDOG_REFUSAL
        self.act[ck.A_STROKE_TARGET] = 1.0 if up else 0.0
        return True, 'raising the disks' if up else 'lowering the disks'

    def set_alpha(self, alpha_rad: float) -> tuple[bool, str]:
        """
        Command the disk angle; refused while the e-stop or the watchdog holds it.

        Parameters
        ----------
        alpha_rad : float
            The angle [rad]; the disks slew to it at ``alpha_slew_rate_deg_s``.

        Returns
        -------
        (bool, str)
            Whether it was taken, and the reason (why not, or what it does).

        """
        if self.estop:
            return False, 'refused: e-stop engaged (call reset first)'
        if self.watchdog_tripped:
            return False, WATCHDOG_REFUSAL
        if not (math.isfinite(alpha_rad) and abs(alpha_rad) <= math.pi / 2 + 1e-12):
            return (
                False,
                f'disk angle must be finite and in [-90, 90] deg, got {shown(alpha_rad)} rad',
            )
        self.act[ck.A_ALPHA_CMD] = alpha_rad
        return True, ''

    # ------------------------------------------------------------------ machine state
    def packml_conditions(self) -> Conditions:
        """Return what the cell reports to its PackML state machine now."""
        # on every advance (and where a condition falls due): one pass over the phases
        p, k, dt = self.params, self.k, self.dt
        phase = self.phase
        on_cell = bool((phase == ck.PH_CELL).any())
        timers = self._timers
        timers.observe(k, on_cell, self.n_inducted, self.packml.infeed_open, self._shows_blocked)
        blocked = timers.blocked(k, dt, p)
        starved = timers.starved(k, dt, p)
        batch_done = self.stream_closed() and not self.infeed.external
        return Conditions(
            estop=self.estop,
            hold_cause='jam' if self.jam else 'watchdog' if self.watchdog_tripped else '',
            suspend_cause='blocked' if blocked else 'starved' if starved else '',
            batch_done=batch_done,
            empty=not phase.any(),  # PH_FREE is 0
            disks_down=self.act[ck.A_STROKE] <= 0.001,
        )

    def _packml_horizon(self) -> int:
        """
        Return how many periods the kernel may run before a PackML condition can change.

        Exact where the time is known (the disks dropping while Aborting, the starved and
        blocked timers) and period by period where it is not (a parcel leaving empties the
        cell while Stopping or at a batch's end), so that the state moves at the same
        period however the caller slices time. A jam (which shows in the kernel's
        events) moves it at the end of the slice it happens in.
        """
        p, k, dt = self.params, self.k, self.dt
        state = self.packml.state
        out = self._timers.horizon(k, dt, p, state == 'Execute')
        if state == 'Aborting':
            rate = self.cfg[ck.C_STROKE_RATE]
            out = 1 if not math.isfinite(rate) else max(1, math.ceil(self.stroke / (rate * dt)))
        if state == 'Stopping' or (state == 'Execute' and self.stream_closed()):
            out = 1
        elif state == 'Execute' and self.infeed.end_k() is not None:
            out = min(out, max(1, self.infeed.end_k() - k))
        return out

    def stream_closed(self) -> bool:
        """
        Return True once the stream has given all it will: its batch, or its span.

        ``arrival_count`` parcels streamed, or ``arrival_duration_s`` of simulated time
        since it opened: either is a stream of a known size, the same parcels however the
        run is sliced or paced.
        """
        return self.infeed.closed(self.k)

    @property
    def packml_dirty(self) -> bool:
        """Return whether something changed the PackML conditions since the last look."""
        return self._packml_dirty

    def update_packml(self) -> None:
        """Move the PackML state by the cell's conditions now (after a command or a fault)."""
        self.packml.update(self.packml_conditions(), self.t_ns)
        self._packml_dirty = False
        self._packml_due_k = 1 << 62  # until a look ahead finds a condition's time

    def packml_command(self, command: str) -> tuple[bool, str]:
        """
        Take a PackML command from outside (an operator, a line controller, a PLC).

        ``abort`` engages the e-stop; ``clear`` releases it and takes jammed parcels off
        (the cell's reset); ``reset`` takes jammed parcels off. A command the current state
        does not take changes nothing.

        Parameters
        ----------
        command : str
            One of ``sorter_sim.model.packml.COMMANDS``.

        Returns
        -------
        (bool, str)
            Taken and the state it led to, or refused and why.

        """
        ok, text = self.packml.command(command, self.t_ns)
        if ok:
            if command == 'abort':
                self.engage_estop()
            elif command in ('clear', 'reset'):
                self._pending_edges += self.reset()
            self.update_packml()
        return ok, text

    def take_packml_edges(self) -> list:
        """Return the sensor edges a PackML command made (jammed parcels taken off)."""
        out, self._pending_edges = self._pending_edges, []
        return out

    def engage_estop(self) -> None:
        """Belt stops (v = 0 at once), the disks drop at their stroke rate."""
        self._packml_dirty = True
        self.estop = True
        self.act[ck.A_BELT_ON] = 0.0
        self.act[ck.A_STROKE_TARGET] = 0.0

    def reset(self) -> list[SensorEdge]:
        """Clear the e-stop and jams: jammed parcels are taken off, the belt restarts."""
        self._packml_dirty = True
        edges = []
        for i in np.flatnonzero(self.phase == ck.PH_JAMMED):
            edges += self._remove(int(i))
        self.estop = False
        self.jam = False
        self.act[ck.A_BELT_ON] = 1.0 if self.belt_run else 0.0
        return edges

    def run_belt(self, run: bool) -> tuple[bool, str]:
        """
        Run or stop the belt (the run command); while the e-stop holds, it stays stopped.

        Parameters
        ----------
        run : bool
            Run (True) or stop.

        Returns
        -------
        (bool, str)
            Whether it was taken, and the reason (why not, or what it does).

        """
        self._packml_dirty = True
        self.belt_run = bool(run)
        if self.estop:
            return False, 'the belt stays stopped: e-stop engaged (call reset first)'
        self.act[ck.A_BELT_ON] = 1.0 if run else 0.0
        return True, 'belt running' if run else 'belt stopped'

    @property
    def faults(self) -> list[str]:
        """Return the names of the active faults: estop, jam, watchdog."""
        flags = (('estop', self.estop), ('jam', self.jam), ('watchdog', self.watchdog_tripped))
        return [name for name, on in flags if on]

    # ------------------------------------------------------------------ watchdog
    def heartbeat(self, counter: int) -> bool:
        """
        Take a controller heartbeat carrying ``counter``; return True if it cleared a trip.

        Only a changed counter feeds the watchdog (the first one arms it, whatever its
        value): a frozen controller that keeps sending or rewriting its last value is a
        stopped one, and the watchdog must see it as such (``heartbeats_frozen`` counts
        those repeats). A controller that comes back takes over where the safe state left
        the cell: the disks down and at safe_alpha_deg, ready for its next command.

        Parameters
        ----------
        counter : int
            The heartbeat's counter.

        Returns
        -------
        bool
            True if it cleared a watchdog trip.

        """
        cleared = self.watchdog.feed(counter, self.k)
        self._packml_dirty |= cleared  # only a trip cleared changes what PackML sees
        return cleared

    # what the watchdog shows, by the names the node's diagnostics and the tests use
    watchdog_tripped = property(lambda self: self.watchdog.tripped)
    watchdog_trips = property(lambda self: self.watchdog.trips)
    heartbeat_cut = property(lambda self: self.watchdog.cut)
    heartbeats_lost = property(lambda self: self.watchdog.lost)
    heartbeats_frozen = property(lambda self: self.watchdog.frozen)
    watchdog_armed = property(lambda self: self.watchdog.armed(self.params.watchdog_timeout))

    def watchdog_deadline(self) -> int | None:
        """Period index at which the watchdog trips, or None when it cannot."""
        return self.watchdog.deadline(self.params.watchdog_timeout, self.dt)

    def _trip_watchdog(self) -> WatchdogTrip:
        """Fail safe as a diverter does when its PLC stops: disks down, α to its safe value."""
        late_s = self.watchdog.trip(self.k, self.dt)
        self.act[ck.A_STROKE_TARGET] = 0.0
        self.act[ck.A_ALPHA_CMD] = math.radians(self.params.safe_alpha_deg)
        return WatchdogTrip(self.t_ns, late_s)

    # ------------------------------------------------------------------ sensors
    def sensor_states(self) -> dict[str, bool]:
        """Return what each sensor shows now (blocked True), injected faults included."""
        return {n: self._shows_blocked(s, n) for s, n in enumerate(self.sensor_names)}

    def _shows_blocked(self, s: int, name: str) -> bool:
        """Return what sensor ``s`` shows now: its count, or the fault injected into it."""
        return self._sensor_faults.shows_blocked(name, self.k, bool(self.counts[s] > 0))

    @property
    def sensor_faults(self) -> dict[str, SensorFault]:
        """Return the faults injected into sensors now, by sensor name."""
        return self._sensor_faults.active

    def inject_sensor_fault(self, sensor: str, fault: str, period: float = 0.1) -> list:
        """
        Make a sensor show a fault instead of what it sees; ``fault`` 'ok' ends it.

        The physics is untouched: parcels move as before, only the signal is wrong, as
        with a misaligned reflector (held blocked), a dirty or dead eye (held clear) or a
        loose connector (chatter: toggling every period/2).

        Parameters
        ----------
        sensor : str
            The sensor's name (``sensor_names``).
        fault : str
            One of SENSOR_FAULTS, or 'ok' to clear the fault.
        period : float
            The chatter's full period [s], in CHATTER_PERIOD_RANGE.

        Returns
        -------
        list of SensorEdge
            The edge the change shows now, if it shows one.

        Raises
        ------
        ParamError
            An unknown sensor or fault, or a period out of range; nothing changes.

        """
        self._packml_dirty = True
        half_k = self._sensor_faults.check(sensor, fault, period, self.dt)
        before = self.sensor_states()[sensor]
        self._sensor_faults.set(sensor, fault, half_k, self.k)
        after = self.sensor_states()[sensor]
        return [] if after == before else [SensorEdge(self.t_ns, sensor, after)]

    def _faulted_edges(self, events: list, k_from: int) -> list:
        """Replace the faulted sensors' true edges by what they show over (k_from, k]."""
        return self._sensor_faults.edges(events, k_from, self.k, self.params.control_period_ns)

    def cut_heartbeat(self, cut: bool) -> None:
        """
        Cut (True) or mend the controller's heartbeat line, an injected fault.

        While cut, heartbeats are counted (``heartbeats_lost``) but do not reach the
        watchdog, which then trips as it would for a stopped controller.

        Parameters
        ----------
        cut : bool
            Cut or mend.

        """
        self.watchdog.cut = bool(cut)

    def jam_parcel(self, which: str) -> list:
        """
        Jam one parcel where it is now (an injected fault: a snag, a torn parcel).

        Parameters
        ----------
        which : str
            The parcel's label, or its id as a number.

        Returns
        -------
        list of Outcome
            The jam's outcome (exit 'jammed', cause 'injected').

        Raises
        ------
        ParamError
            No parcel of that label or id on the belt or the disks; nothing changes.

        """
        self._packml_dirty = True
        on = np.flatnonzero(self.phase == ck.PH_CELL)
        match = [int(i) for i in on if self.labels[i] == which or str(self.ids[i]) == str(which)]
        if not match:
            raise ParamError(
                f'no parcel {shown(which)} on the belt or the disks to jam ({len(on)} there now)'
            )
        i = match[0]
        self.phase[i] = ck.PH_JAMMED
        self.mode[i] = ck.MODE_SLIDE
        self.state[i, 3:6] = 0.0
        self.jam = True
        self.jam_cause[i] = 'injected'
        self.outcome_counts['jammed'] += 1
        x, y = float(self.state[i, 0]), float(self.state[i, 1])
        return [Outcome(self.t_ns, int(self.ids[i]), self.labels[i], 'jammed', x, y, 'injected')]

    def _remove(self, i: int) -> list[SensorEdge]:
        """Take parcel ``i`` off the cell now; the sensors it blocked may clear."""
        edges = []
        for s in np.flatnonzero(self.blocked[i]):
            self.blocked[i, s] = False
            self.counts[s] -= 1
            name = self.sensor_names[s]
            if self.counts[s] == 0 and name not in self.sensor_faults:
                edges.append(SensorEdge(self.t_ns, name, False))
        self.phase[i], self.mode[i] = ck.PH_FREE, ck.MODE_SLIDE
        return edges

    def add_rail(self, x0: float, y0: float, x1: float, y1: float, thickness: float = 0.02):
        """Declare a rail or a stopper from (x0, y0) to (x1, y1) [m] (contact: rigid)."""
        self.rails.append(rail_row(x0, y0, x1, y1, thickness))
        self.contacts = cell_contacts(self.params, self.rails)

    # ------------------------------------------------------------------ parcels
    def induct(self, spec: ParcelSpec) -> None:
        """
        Queue a parcel from outside; it appears at induct_x as soon as there is room.

        Parameters
        ----------
        spec : ParcelSpec
            Its length A, width B [m], mass [kg], skew [deg], lateral offset [m] and label.

        Raises
        ------
        ParamError
            A size, mass or label out of range, or PENDING_INDUCTS_MAX parcels waiting
            already (as a real infeed refuses parcels when its accumulation conveyor is
            full); nothing is queued then.

        """
        self._packml_dirty = True
        self.infeed.queue(check_parcel(spec, self.params.belt_width))

    def take_handoffs(self) -> list[Handoff]:
        """Return the parcels that left straight since the last call (``keep_handoffs``)."""
        out, self._handoffs = self._handoffs, []
        return out

    def hand_in(self, h: Handoff, dx: float) -> list[SensorEdge]:
        """
        Take a parcel from the station upstream, now, in the state it left that one.

        Parameters
        ----------
        h : Handoff
            The parcel, as the upstream cell gave it.
        dx : float
            The upstream cell's origin minus this one's along the line [m]: its x here
            is ``h.state[0] + dx``.

        Returns
        -------
        list of SensorEdge
            The edges of sensors it blocks at once (none where the line is laid out with
            room: it comes in upstream of the first eye).

        Raises
        ------
        ParamError
            No free slot (``max_parcels`` on this station already).

        """
        self._packml_dirty = True
        free = np.flatnonzero(self.phase == ck.PH_FREE)
        if free.size == 0:
            raise ParamError(
                f'station full: {self.params.max_parcels} parcels on it already (max_parcels)'
            )
        i = int(free[0])
        A, B, m = h.dims
        self.state[i] = h.state
        self.state[i, 0] += dx
        self.mode[i] = h.mode
        self.phase[i] = ck.PH_CELL
        self.par[i] = parcel_array(Parcel(A, B, m), n_quad=N_QUAD)
        self.scanned[i] = True  # the line's scanner read it upstream
        self.gauge_xi[i] = h.gauge
        self.ids[i] = h.parcel_id
        self.dims[i] = h.dims
        self.labels[i] = h.label
        return self._sense_new(i)

    @property
    def pending_inducts(self) -> int:
        """Return the parcels from outside waiting for room on the belt."""
        return len(self.infeed.external)

    @property
    def n_induct_refused(self) -> int:
        """Return the inducts refused because PENDING_INDUCTS_MAX were waiting."""
        return self.infeed.n_refused

    @property
    def n_streamed(self) -> int:
        """Return the parcels placed from the stream (``arrival_count`` counts these)."""
        return self.infeed.n_streamed

    def _upstream_room(self) -> tuple[float, int]:
        """
        Return the free belt length in front of the induct point.

        Free belt length in front of the induct point [m], and the slot whose trailing
        edge limits it (-1: none).
        """
        room, slot = ck.upstream_room(self.state, self.phase, self.par, self.params.induct_x)
        return float(room), int(slot)

    def _place_pending(self) -> list[SensorEdge]:
        edges: list[SensorEdge] = []
        if self.estop or not self.packml.infeed_open:
            return edges
        cand = self.infeed.candidate(self.k)
        if cand is None:
            return edges
        source, spec, gap = cand
        room, _ = self._upstream_room()
        free = np.flatnonzero(self.phase == ck.PH_FREE)
        if room < gap or free.size == 0:
            return edges
        self.infeed.taken(source, self.k)
        i = int(free[0])
        self.n_inducted += 1
        self._packml_dirty = True
        pid = self.n_inducted
        label = spec.label or format_label(
            self.params.label_pattern,
            id=pid,
            n=pid - 1,
            label=self.params.labels[(pid - 1) % len(self.params.labels)],
        )
        hx, _ = parcel_half_extents(spec.A, spec.B, spec.phi0)
        v = self.belt_velocity
        self.state[i] = (self.params.induct_x - hx, spec.y0, spec.phi0, v, 0.0, 0.0)
        self.mode[i] = ck.MODE_BELT
        self.phase[i] = ck.PH_CELL
        self.par[i] = parcel_array(Parcel(spec.A, spec.B, spec.m), n_quad=N_QUAD)
        self.scanned[i] = False
        self.gauge_xi[i] = 0.0
        self.ids[i] = pid
        self.dims[i] = (spec.A, spec.B, spec.m)
        self.labels[i] = label
        return edges + self._sense_new(i)

    def _sense_new(self, i: int) -> list[SensorEdge]:
        """Start the parcel just put in slot ``i`` afresh; return the edges of what it blocks."""
        self.jam_cause[i] = ''
        fresh_slot(self.contacts, i)  # new to the contact step, whatever the slot held
        edges: list[SensorEdge] = []
        for s in range(len(self.sensor_names)):
            on = ck.sensor_blocked(
                s,
                len(self.eye_x),
                self.eye_x,
                self.cfg,
                self.state[i],
                ck.PH_CELL,
                self.par[i, 0],
                self.par[i, 1],
            )
            self.blocked[i, s] = on
            if on:
                self.counts[s] += 1
                name = self.sensor_names[s]
                if self.counts[s] == 1 and name not in self.sensor_faults:
                    edges.append(SensorEdge(self.t_ns, name, True))
        return edges

    def _periods_until_placement(self) -> int:
        """Return a lower bound on the periods before the next induct can happen (>= 1)."""
        if self.estop or not self.packml.infeed_open:
            return NEVER
        cand = self.infeed.candidate(self.k)
        if cand is None:
            return self.infeed.periods_until_due(self.k)
        room, j = self._upstream_room()
        if j < 0 or not np.any(self.phase == ck.PH_FREE):
            return 1
        gap = cand[2]
        v = self.belt_velocity
        moving_with_belt = (
            self.phase[j] == ck.PH_CELL
            and self.mode[j] == ck.MODE_BELT
            and self.state[j, 3] == v
            and v > 0.0
        )
        if not moving_with_belt:
            return 1
        # the limiting parcel moves at v: room grows by v dt per period
        return max(1, math.ceil((gap - room) / (v * self.dt) - 1e-9))

    # ------------------------------------------------------------------ stepping
    def _kernel(self, n: int) -> tuple[int, int]:
        return ck.advance_cell(
            n,
            self.k,
            ck.CellSetup(self.cfg, self.laws, self.nodes, self.weights),
            self.act,
            ck.Parcels(self.state, self.mode, self.phase, self.par, self.scanned, self.gauge_xi),
            ck.Sensors(self.eye_x, self.blocked, self.counts),
            ck.EventLog(self.ev_i, self.ev_f, self._ev_reserve),
            ck.Memo(self.stats, self._last_strips, self._last_info),
            self.contacts,
        )

    def advance(self, n: int = 1) -> list:
        """
        Advance the cell ``n`` control periods.

        Parameters
        ----------
        n : int
            How many control periods.

        Returns
        -------
        list
            What happened, in time order: ``SensorEdge``, ``LabelRead`` and ``Outcome``
            records.

        """
        if n < 0:
            raise ValueError(f'n must be >= 0, got {n}')
        events: list = []
        remaining = n
        k_from = self.k
        while remaining > 0:
            if self._packml_dirty or self.k >= self._packml_due_k:
                # a command or a fault since the last evaluation, or a condition's time
                self.update_packml()
            events += self._place_pending()
            if self._packml_dirty:
                self.update_packml()  # a parcel came in: starved no more
            if remaining == 1:
                m = 1  # one period (the fieldbus's exchange) needs no look ahead
            else:
                ahead = self._packml_horizon()
                self._packml_due_k = self.k + ahead
                m = min(remaining, self._periods_until_placement(), ahead)
            deadline = self.watchdog_deadline()
            if deadline is not None:
                if self.k >= deadline:
                    events.append(self._trip_watchdog())
                    continue
                m = min(m, deadline - self.k)
            done, n_ev = self._kernel(m)
            events += self._collect(n_ev)
            self.k += done
            remaining -= done
        deadline = self.watchdog_deadline()
        if deadline is not None and self.k >= deadline:
            events.append(self._trip_watchdog())
        self.update_packml()
        events = self._faulted_edges(events, k_from)
        events.sort(key=lambda e: e.t_ns)
        return events

    def _collect(self, n_ev: int) -> list:
        out: list = []
        dt_ns = self.params.control_period_ns
        for r in range(min(n_ev, self.ev_i.shape[0])):
            k, kind, a, b = (int(v) for v in self.ev_i[r])
            tau, x, y = (float(v) for v in self.ev_f[r])
            t_ns = k * dt_ns + round(tau * 1e9)
            if kind == ck.EV_EDGE:
                out.append(SensorEdge(t_ns, self.sensor_names[a], bool(b)))
            elif kind == ck.EV_SCAN:
                out.append(LabelRead(t_ns, int(self.ids[a]), self.labels[a]))
            elif kind in EXIT_NAMES:
                name = EXIT_NAMES[kind]
                if kind == ck.EV_STRAIGHT and self.keep_handoffs:
                    # the slot is free now but untouched since the kernel freed it: its
                    # state is the one at the end of the period the parcel left in
                    self._handoffs.append(
                        Handoff(
                            (k + 1) * dt_ns,
                            int(self.ids[a]),
                            self.labels[a],
                            tuple(float(v) for v in self.state[a]),
                            int(self.mode[a]),
                            tuple(float(v) for v in self.gauge_xi[a]),
                            tuple(float(v) for v in self.dims[a]),
                        )
                    )
                self.outcome_counts[name] += 1
                out.append(Outcome(t_ns, int(self.ids[a]), self.labels[a], name, x, y))
            elif kind == ck.EV_JAM:
                self.jam = True
                self.outcome_counts['jammed'] += 1
                cause = jam_cause(b, self.ids)
                self.jam_cause[a] = cause
                out.append(Outcome(t_ns, int(self.ids[a]), self.labels[a], 'jammed', x, y, cause))
        return out

    # ------------------------------------------------------------------ observation
    def parcels(self) -> dict[str, np.ndarray]:
        """Return the parcels in the cell, in id order (``cell_view.parcels``)."""
        return cell_view.parcels(self)

    def parcel_motion(self) -> dict:
        """Return label, speed and slips of each parcel (``cell_view.parcel_motion``)."""
        return cell_view.parcel_motion(self)

    def contact_points(self) -> dict[str, np.ndarray]:
        """Return the last period's contact points and forces (``cell_view.contacts``)."""
        return cell_view.contacts(self)

    @property
    def n_parcels(self) -> int:
        return int(np.count_nonzero(self.phase != ck.PH_FREE))

    @property
    def n_in_flight(self) -> int:
        """Return the parcels on the belt or the disks: those without an outcome yet."""
        return int(np.count_nonzero(self.phase == ck.PH_CELL))


# the records are part of this module's interface, as before they had their own
__all__ = [
    'Cell',
    'CHATTER_PERIOD_RANGE',
    'CHUTE_SENSORS',
    'WATCHDOG_REFUSAL',
    'WatchdogTrip',
    'ParcelSpec',
    'SensorEdge',
    'LabelRead',
    'Outcome',
    'STATE_NAMES',
    'Handoff',
    'SENSOR_FAULTS',
    'SensorFault',
    'check_parcel',
]
