"""
Work-precision measurement: run a method at a setting, time it, and measure its error.

This module owns the machinery behind ``sorter bench``, in the manner of SciML's
work-precision diagrams (DiffEqDevTools ``benchmark.jl``): a stated reference, the
warm-up run of a compiled method discarded, the minimum of several timed runs, failures
kept in the table with their reason, and the machine and library versions printed with
the figures.

- ``Trajectory`` and ``compare`` (``trajectory``, re-exported here): what any method
  produced, read at any time, and its errors against a reference trajectory.
- Runners that turn each method into a ``Trajectory``: the core's three methods,
  scipy's ``solve_ivp`` on the same model (``ScipyParcel``: sliding phases by
  ``solve_ivp`` with events, stick phases in closed form), scipy on the seed's
  threshold model, and the same for the Fig. 4 body.
- ``measure``: one table row (``WPRow``) per method and setting.

Units: SI (m, s, rad); errors in m (positions) and s (event times).
"""

from __future__ import annotations

import math
import os
import platform
import time
from dataclasses import dataclass

import numpy as np

from sorter_sim.model.core.common import rhs_slide
from sorter_sim.model.core.layout import Contact
from sorter_sim.model.core.oscillator import Oscillator, exact_phases, run_oscillator
from sorter_sim.model.core.simulate import (
    Parcel,
    initial_mode,
    parcel_array,
    simulate,
    strip_array,
    strip_borders,
)
from sorter_sim.model.core.wrench import clip_scratch, gauss_legendre_01
from sorter_sim.studies.trajectory import EVENT_KINDS, Errors, Trajectory, compare, dp5_pieces


# ------------------------------------------------------------------ machine and versions
def machine_info() -> dict:
    """CPU model, core count and library versions, for the report's header."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    import numba
    import scipy

    info = {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "os": platform.platform(terse=True),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "numba": numba.__version__,
    }
    try:
        import matplotlib

        info["matplotlib"] = matplotlib.__version__
    except ImportError:
        pass
    return info


def machine_line(info: dict | None = None) -> str:
    """
    Return one line describing the machine and the library versions.

    Parameters
    ----------
    info : dict, optional
        The machine's description (``machine_info``).

    Returns
    -------
    str
        The line.

    """
    info = info or machine_info()
    libs = ", ".join(
        f"{k} {info[k]}" for k in ("python", "numpy", "scipy", "numba", "matplotlib") if k in info
    )
    return f"{info['cpu']}, {info['cores']} cores, {info['os']}; {libs}"


def _cpu_now(allowed: set) -> int:
    """Return the CPU this process runs on now, if Linux says so and it is ``allowed``."""
    try:
        # this thread's, the one sched_setaffinity(0) pins
        with open("/proc/thread-self/stat", encoding="ascii") as f:
            cpu = int(f.read().rsplit(")", 1)[1].split()[36])  # field 39, "processor"
    except (OSError, ValueError, IndexError):
        return min(allowed)
    return cpu if cpu in allowed else min(allowed)


class one_core:
    """
    Pin this process to one CPU while timing (the targets are per core).

    The CPU it already runs on, not always the first: two timed runs side by side (two
    test workers, two benchmarks) are then most often on a core each, where pinning both
    to the first made them share it.
    """

    def __enter__(self):
        self._saved = None
        if hasattr(os, "sched_getaffinity"):
            self._saved = os.sched_getaffinity(0)
            os.sched_setaffinity(0, {_cpu_now(self._saved)})
        return self

    def __exit__(self, *exc):
        if self._saved is not None:
            os.sched_setaffinity(0, self._saved)
        return False


# ------------------------------------------------------------------ runners: the core model
def core_trajectory(res, mode0: int | None = None) -> Trajectory:
    """
    Return a ``SimResult`` as a Trajectory, its events named as ``compare`` matches them.

    The threshold method logs the set of 'static' surfaces as a bit mask; it is
    turned into per-surface stick (surface becomes static) and break events.

    Parameters
    ----------
    res : SimResult
        A run.
    mode0 : int, optional
        The start's mode.

    Returns
    -------
    Trajectory
        The trajectory.

    """
    events = []
    if res.method == "threshold":
        prev = 0 if mode0 is None or mode0 < 0 else (1 << mode0)
        for t, kind, code in res.events:
            if kind in ("stick", "break"):
                for s in range(len(res.surfaces)):
                    bit = 1 << s
                    if code & bit and not prev & bit:
                        events.append((t, "stick", s))
                    if prev & bit and not code & bit:
                        events.append((t, "break", s))
                prev = code
            elif kind == "target":
                events.append((t, "scrap", None))
    else:
        for t, kind, info in res.events:
            if kind in ("stick", "break"):
                events.append((t, kind, info))
            elif kind == "target":
                events.append((t, "scrap", None))
    return Trajectory(
        res.t,
        res.y[:, :3],
        res.y[:, 3:],
        events,
        n_steps=res.n_steps,
        n_rhs=res.n_rhs,
        status="ok" if res.success else res.message,
    )


@dataclass
class ParcelCase:
    """One parcel over one set of strips: what every runner of a study needs."""

    parcel: Parcel
    strips: list
    y0: np.ndarray
    t_span: tuple
    y_target: float = math.inf
    rotation: bool = True
    n_quad: int = 8

    @property
    def borders(self) -> np.ndarray:
        return strip_borders(self.strips)

    def run_core(self, method: str, **settings):
        """
        One run of a core method (settings: rtol/atol, dt, v_min, reductions ...).

        Parameters
        ----------
        method : str
            The method.

        """
        settings.setdefault("max_points", _capacity(self.t_span, settings.get("dt")))
        return simulate(
            self.parcel,
            self.strips,
            self.y0,
            self.t_span,
            method,
            y_target=self.y_target,
            rotation=self.rotation,
            n_quad=self.n_quad,
            **settings,
        )

    def trajectory(self, res) -> Trajectory:
        """
        Return a core result as a Trajectory with zone events.

        A core result as a Trajectory with zone events; the accurate method's records
        are read through its own dense output (``dp5_pieces``).

        Parameters
        ----------
        res : SimResult
            A run.

        Returns
        -------
        Trajectory
            The trajectory.

        """
        par = parcel_array(self.parcel, self.rotation, self.n_quad)
        arr = strip_array(self.strips)
        traj = core_trajectory(res, initial_mode(np.asarray(self.y0, float), arr, par))
        if res.method == "accurate":
            nodes, weights = gauss_legendre_01(self.n_quad)
            clip = clip_scratch()

            def f(t, y):
                out = np.empty(6)
                rhs_slide(y, Contact(arr, par, nodes, weights), clip, out)
                return out

            traj.make_pieces = lambda tr: dp5_pieces(
                tr.t, np.hstack([tr.q, tr.dq]), lambda t0, y0: f, 3
            )
        return traj.with_zone_events(self.parcel.A, self.parcel.B, self.borders)

    def core(self, method: str, **settings) -> Trajectory:
        """
        Run the core's method on this case and return its trajectory.

        Parameters
        ----------
        method : str
            The method.

        Returns
        -------
        Trajectory
            The trajectory.

        """
        return self.trajectory(self.run_core(method, **settings))


def _capacity(t_span, dt) -> int:
    if dt is None:
        return 200_000
    return int((t_span[1] - t_span[0]) / dt) + 1000


# ------------------------------------------------------------------ runners: the Fig. 4 body
def oscillator_exact(osc: Oscillator, t_end: float) -> Trajectory:
    """
    Return the exact piecewise Coulomb solution as a Trajectory, read exactly at any time.

    Parameters
    ----------
    osc : Oscillator
        The Fig. 4 body.
    t_end : float
        The end [s].

    Returns
    -------
    Trajectory
        The trajectory.

    """
    from sorter_sim.model.core.oscillator import exact_solution

    phases = exact_phases(osc, t_end)
    starts = [p[0] for p in phases if 0.0 < p[0] < t_end]
    t = np.unique(np.concatenate([np.linspace(0.0, t_end, int(t_end * 100) + 1), starts]))
    ex = exact_solution(osc, t_end, t_eval=t)
    events = [
        (p[0], "break" if p[1] == "slide" else "stick", 0) for p in phases[1:] if p[0] < t_end
    ]

    def exact(tq):
        e = exact_solution(osc, t_end, t_eval=tq)
        return e.x[:, None], e.v[:, None]

    return Trajectory(ex.t, ex.x, ex.v, events, pieces=[(0.0, t_end, exact)])


def _oscillator_rhs(osc: Oscillator):
    """Sliding right-hand side of the Fig. 4 body for a step starting at (t0, y0)."""

    def for_step(t0, y0):
        p0 = osc.k * (osc.v_drive * t0 - y0[0])
        sigma = 1.0 if (y0[1] > 0 or (y0[1] == 0 and p0 > 0)) else -1.0

        def f(t, y):
            return np.array([y[1], (osc.k * (osc.v_drive * t - y[0]) - sigma * osc.F_kin) / osc.m])

        return f

    return for_step


def oscillator_core(osc: Oscillator, t_end: float, method: str, **settings):
    """
    Run the Fig. 4 body with a core method.

    One core run of the Fig. 4 body (``oscillator_trajectory`` reads it); room for every
    fixed step's record (run_oscillator drops records beyond max_points).

    Parameters
    ----------
    osc : Oscillator
        The Fig. 4 body.
    t_end : float
        The end [s].
    method : str
        The method.

    """
    if method != "accurate":
        settings.setdefault("max_points", int(t_end / settings.get("dt", 1e-3)) + 10)
    return run_oscillator(osc, t_end, method, **settings)


def oscillator_trajectory(osc: Oscillator, res) -> Trajectory:
    """
    Return a core oscillator run as a Trajectory.

    A core oscillator run as a Trajectory; eq. 3.1 rows of the threshold method map to
    events as the seed reads them: entering row 3 = leaving rest, entering row 2 = rest.

    Parameters
    ----------
    osc : Oscillator
        The Fig. 4 body.
    res : SimResult
        A run.

    Returns
    -------
    Trajectory
        The trajectory.

    """
    events = []
    for t, kind in res.events:
        k = {"slip": "break", "row3": "break", "stick": "stick", "row2": "stick"}.get(kind)
        if k:
            events.append((t, k, 0))
    traj = Trajectory(res.t, res.x, res.v, events, n_steps=res.n_steps, n_rhs=res.n_rhs)
    if res.method == "accurate":
        traj.make_pieces = lambda tr: dp5_pieces(
            tr.t, np.hstack([tr.q, tr.dq]), _oscillator_rhs(osc), 1
        )
    return traj


def _after_start(event, t0, skip=1e-12):
    """Return an event that cannot fire within ``skip`` of the segment start (where it is 0)."""

    def e(tt, z):
        return event(tt, z) if tt > t0 + skip else 1.0

    e.terminal, e.direction = event.terminal, event.direction
    return e


# ------------------------------------------------------------------ timing and table rows
@dataclass
class WPRow:
    """One method at one setting: wall time (min of n_runs, warm-up discarded), errors."""

    case: str
    family: str
    setting: str
    wall_s: float = math.nan
    n_runs: int = 0
    n_rhs: int = 0
    errors: Errors | None = None
    failure: str = ""
    traj: Trajectory | None = None

    @property
    def ok(self) -> bool:
        return not self.failure


def timed(fn, repeats: int = 3, budget_s: float = 2.0):
    """
    Run ``fn`` repeatedly: returns (last result, min wall time, number of timed runs).

    The caller discards a warm-up run per method beforehand (``measure`` does);
    repeats stop early once ``budget_s`` has been spent, after at least one run.

    Parameters
    ----------
    fn : callable
        What to time.
    repeats : int
        Timed repeats; the best counts.
    budget_s : float
        The most time to spend [s].

    """
    best = math.inf
    out = None
    spent = 0.0
    n = 0
    for _ in range(max(1, repeats)):
        w = time.perf_counter()
        out = fn()
        w = time.perf_counter() - w
        best = min(best, w)
        spent += w
        n += 1
        if spent >= budget_s:
            break
    return out, best, n


_WARM: set = set()


def measure(
    case_name: str,
    family: str,
    setting: str,
    run,
    ref: Trajectory | None,
    finish=None,
    repeats: int = 3,
    budget_s: float = 2.0,
    warm_key=None,
    compiles: bool | None = None,
) -> WPRow:
    """
    Time ``run()`` and compare ``finish(result)`` (a Trajectory) with ``ref``.

    Only ``run`` is timed; ``finish`` turns its result into a Trajectory (dense
    output, zone events) afterwards. The first call for each ``warm_key`` (default:
    the family) of a method that compiles runs once untimed, so compilation never enters
    a figure; a scipy method (a family ``scipy ...``; ``ScipyParcel`` loads its compiled
    right-hand sides when it is made) is timed from its first run. A failure
    (an exception, a non-finite state, an unsuccessful status) is kept in the row
    with its reason.

    Parameters
    ----------
    case_name : str
        The case.
    family : str
        The method family.
    setting : str
        The setting.
    run : Trajectory or callable
        The run, or what makes it.
    ref : Trajectory
        The reference.
    finish : callable, optional
        Turns the run's result into a trajectory.
    repeats : int
        Timed repeats; the best counts.
    budget_s : float
        The most time to spend [s].
    warm_key : object, optional
        Warm up once per key.
    compiles : bool, optional
        Whether the method compiles (default: every family but scipy's, named
        ``scipy ...``); one that does not is timed from its first run.

    Returns
    -------
    WPRow
        The row.

    """
    row = WPRow(case_name, family, setting)
    key = warm_key or family
    if compiles is None:
        compiles = not family.startswith("scipy")  # scipy's first run needs no warm-up
    try:
        if compiles and key not in _WARM:
            run()
            _WARM.add(key)
        out, wall, n = timed(run, repeats, budget_s)
        traj = finish(out) if finish is not None else out
    except Exception as exc:  # kept in the table with its reason, as the report promises
        row.failure = f"{type(exc).__name__}: {exc}".splitlines()[0][:120]
        return row
    row.wall_s, row.n_runs, row.n_rhs, row.traj = wall, n, traj.n_rhs, traj
    if traj.status != "ok":
        row.failure = traj.status
    if not np.all(np.isfinite(traj.q)) or not np.all(np.isfinite(traj.dq)):
        row.failure = "non-finite state"
        return row
    if ref is not None:
        scrapped = any(k == "scrap" for _, k, _ in traj.events)
        if traj.t_end < ref.t_end - 1e-2 and not scrapped:
            row.failure = (
                f"output ends at t = {traj.t_end:.4g} s, before the reference's {ref.t_end:.4g} s"
            )
            return row
        row.errors = compare(traj, ref)
    return row


def cheapest_within(rows: list[WPRow], error: float, attr: str = "final") -> WPRow | None:
    """
    Return the fastest successful row whose error ``attr`` is at most ``error``.

    Parameters
    ----------
    rows : list of WPRow
        Measured rows.
    error : float
        The error level [m].
    attr : str
        Which error: final or max.

    Returns
    -------
    WPRow or None
        The row, or None.

    """
    ok = [r for r in rows if r.ok and r.errors is not None and getattr(r.errors, attr) <= error]
    return min(ok, key=lambda r: r.wall_s) if ok else None


def fmt_e(x: float) -> str:
    """
    Return an error for a table: one significant decimal, '–' where there is none.

    Parameters
    ----------
    x : float
        A number.

    Returns
    -------
    str
        The text.

    """
    return "–" if x is None or not math.isfinite(x) else f"{x:.1e}"


def fmt_ms(x: float) -> str:
    """
    Return a time in ms for a table, '–' where there is none.

    Parameters
    ----------
    x : float
        A number.

    Returns
    -------
    str
        The text.

    """
    if not math.isfinite(x):
        return "–"
    return f"{x * 1e3:.3g}"


def rows_markdown(rows: list[WPRow], kinds=EVENT_KINDS) -> str:
    """
    Return a markdown table of rows: family, setting, time, errors, events, failures.

    Parameters
    ----------
    rows : list of WPRow
        Measured rows.
    kinds : sequence of str
        The event kinds to show.

    Returns
    -------
    str
        The table.

    """
    head = (
        ["method", "setting", "time [ms]", "runs", "rhs", "final CoG err [m]", "max err 1 kHz [m]"]
        + [f"{k} Δt [s]" for k in kinds]
        + ["status"]
    )
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        e = r.errors
        cells = [
            r.family,
            r.setting,
            fmt_ms(r.wall_s),
            str(r.n_runs or "–"),
            str(r.n_rhs or "–"),
            fmt_e(e.final) if e else "–",
            fmt_e(e.grid_max) if e else "–",
        ]
        cells += [e.event_text(k) if e else "–" for k in kinds]
        status = r.failure or "ok"
        if e and e.extra:
            status += "; extra events: " + ", ".join(f"{k} +{n}" for k, n in e.extra.items())
        cells.append(status.replace("|", "/"))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot_work_precision(rows: list[WPRow], path, title: str, attr: str = "final", ax=None) -> None:
    """
    Plot error against wall time.

    Error (log x) against wall time (log y), one line per family; failures left out.
    Draws into ``ax`` when given, else writes a PNG to ``path``.

    Parameters
    ----------
    rows : list of WPRow
        Measured rows.
    path : str or Path
        The path.
    title : str
        The plot's title.
    attr : str
        Which error: final or max.
    ax : matplotlib Axes, optional
        Where to draw.

    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    own = ax is None
    if own:
        fig, ax = plt.subplots(figsize=(7.5, 5.0))
    families: dict = {}
    for r in rows:
        if r.ok and r.errors is not None:
            err = getattr(r.errors, attr)
            if math.isfinite(err) and math.isfinite(r.wall_s):
                families.setdefault(r.family, []).append((max(err, 1e-16), r.wall_s))
    markers = "osD^v<>pP*Xh"
    styles = ("-", "--", ":", "-.")
    for i, (fam, pts) in enumerate(families.items()):
        pts.sort()
        ax.loglog(
            [p[0] for p in pts],
            [p[1] for p in pts],
            marker=markers[i % len(markers)],
            ls=styles[(i // 10) % len(styles)],
            label=fam,
            lw=1.2,
            ms=4,
        )
    ax.set_xlabel(
        "error [m]" + (" (max over 1 kHz grid)" if attr == "grid_max" else " (final CoG position)")
    )
    ax.set_ylabel("wall time [s]")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=6, loc="best")
    if own:
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)


# the trajectory and its comparison are part of this module's interface, as before
__all__ = [
    "EVENT_KINDS",
    "Errors",
    "ParcelCase",
    "Trajectory",
    "WPRow",
    "cheapest_within",
    "compare",
    "core_trajectory",
    "dp5_pieces",
    "fmt_e",
    "fmt_ms",
    "machine_info",
    "machine_line",
    "measure",
    "one_core",
    "oscillator_core",
    "oscillator_exact",
    "oscillator_trajectory",
    "plot_work_precision",
    "rows_markdown",
    "timed",
]
