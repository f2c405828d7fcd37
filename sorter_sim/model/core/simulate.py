"""
One parcel through a set of conveyor strips: the Python face of the model core.

``Parcel`` and ``Strip`` describe the physics, ``three_zone_strips`` builds the
seed's cell (zones a, b, c of Fig. 6), and ``simulate`` runs one of the three
integration methods and returns a ``SimResult`` (scipy ``OdeResult`` style:
``status``, ``message``, ``success`` and counters). Arguments are checked at this
boundary; a bad one raises ``ValueError`` naming it and what is allowed.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field

import numpy as np

from sorter_sim.model.core.accurate import run_accurate, run_accurate_reduced
from sorter_sim.model.core.cache import check_kernel_cache
from sorter_sim.model.core.common import (
    EV_BORDER,
    EV_BREAK,
    EV_LEAVE,
    EV_STICK,
    EV_TARGET,
    METHOD_ACCURATE,
    METHOD_IMPLICIT,
    METHOD_THRESHOLD,
    N_COUNTERS,
    N_EVENTS,
    N_JUMPS,
    N_OUT,
    N_REJECTED,
    N_RHS,
    N_STEPS,
    ST_END,
    ST_MAX_STEPS,
    ST_NONFINITE,
    ST_STEP_FAIL,
    ST_TARGET,
    _contact_surfaces,
    n_surf_of,
)
from sorter_sim.model.core.friction import (
    LAW_BSPLINE,
    LAW_NAMES,
    N_LAW_PARAMS,
    law_is_constant,
    law_row,
)
from sorter_sim.model.core.implicit import run_implicit
from sorter_sim.model.core.layout import (
    MODE_SLIDE,
    P_CLOSED,
    P_GRAV,
    P_HALF_A,
    P_HALF_B,
    P_INERTIA,
    P_MASS,
    P_NQUAD,
    P_ROTATION,
    P_STICK,
    PARCEL_WIDTH,
    S_LAW,
    S_PARAMS,
    S_SURF,
    S_VX,
    S_VY,
    S_WEIGHT,
    S_XHI,
    S_XLO,
    STICK_EXACT,
    STICK_SEED,
    STRIP_WIDTH,
    Contact,
    Log,
    Slide,
    Trail,
)
from sorter_sim.model.core.stick import GAUGE_CARRY
from sorter_sim.model.core.threshold import run_threshold
from sorter_sim.model.core.wrench import clip_scratch, gauss_legendre_01

G_STANDARD = 9.81  # m/s², the seed's g

METHODS = {
    "accurate": METHOD_ACCURATE,
    "implicit": METHOD_IMPLICIT,
    "threshold": METHOD_THRESHOLD,
}

EVENT_NAMES = {
    EV_STICK: "stick",
    EV_BREAK: "break",
    EV_BORDER: "border",
    EV_TARGET: "target",
    EV_LEAVE: "leave",
}

STATUS_MESSAGES = {
    ST_END: "reached the end of the time span",
    ST_TARGET: "the centre of gravity reached the scrap line",
    ST_MAX_STEPS: "ran out of output capacity (raise simulate's max_points)",
    ST_STEP_FAIL: "step size fell below round-off",
    ST_NONFINITE: "a non-finite value appeared",
}


def _finite(name: str, value, lo=-math.inf, hi=math.inf, lo_open=False, allow_inf=False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if math.isnan(v) or (math.isinf(v) and not allow_inf):
        raise ValueError(f"{name} must be finite, got {v}")
    if v < lo or v > hi or (lo_open and v == lo):
        left = "(" if lo_open else "["
        raise ValueError(f"{name} must be in {left}{lo}, {hi}], got {v}")
    return v


@dataclass(frozen=True)
class FrictionLaw:
    """A friction characteristic of Fig. 3 by name and parameter values (see friction.py)."""

    model: str
    values: tuple

    def __post_init__(self):
        if self.model not in LAW_NAMES:
            raise ValueError(
                f"friction model must be one of {sorted(LAW_NAMES)}, got {self.model!r}"
            )
        vals = tuple(float(v) for v in self.values)
        for v in vals:
            if not math.isfinite(v):
                raise ValueError(
                    f"friction.{self.model} parameters must be finite, got {list(vals)}"
                )
        need = {
            "const2": 2,
            "const1": 1,
            "linear": 2,
            "polynomial": None,
            "stribeck": 6,
            "bspline": 12,
        }[self.model]
        if need is not None and len(vals) != need:
            raise ValueError(f"friction.{self.model} takes {need} values, got {len(vals)}")
        if self.model == "polynomial" and not 1 <= len(vals) <= 6:
            raise ValueError(f"friction.polynomial takes 1 to 6 coefficients, got {len(vals)}")
        if (
            self.model in ("const2", "const1", "stribeck")
            and min(vals[:2] if self.model != "const1" else vals) < 0
        ):
            raise ValueError(f"friction.{self.model} coefficients must be >= 0, got {list(vals)}")
        if self.model == "bspline":
            v = vals[:6]
            if any(b <= a for a, b in zip(v, v[1:])) or v[0] < 0:
                raise ValueError(
                    "friction.bspline control speeds must start at >= 0 and increase, "
                    f"got {list(v)}"
                )
            if min(vals[6:]) < 0:
                raise ValueError(
                    f"friction.bspline control coefficients must be >= 0, got {list(vals[6:])}"
                )
        object.__setattr__(self, "values", vals)

    @property
    def law_id(self) -> int:
        return LAW_NAMES[self.model]

    def scaled(self, factor: float) -> "FrictionLaw":
        """
        Return the same shape with every coefficient multiplied by ``factor`` (speeds kept).

        Parameters
        ----------
        factor : float
            The factor.

        Returns
        -------
        FrictionLaw
            The same shape, every coefficient times ``factor``.

        """
        v = list(self.values)
        if self.model in ("const2", "const1", "polynomial"):
            v = [x * factor for x in v]
        elif self.model == "linear":
            v = [v[0] * factor, v[1] * factor]
        elif self.model == "stribeck":
            v = [v[0] * factor, v[1] * factor, v[2], v[3], v[4] * factor, v[5]]
        elif self.model == "bspline":
            v = v[:6] + [x * factor for x in v[6:]]
        return FrictionLaw(self.model, tuple(v))

    def row(self) -> np.ndarray:
        return law_row(self.law_id, self.values)

    @property
    def is_constant(self) -> bool:
        return bool(law_is_constant(self.law_id))


@dataclass(frozen=True)
class Parcel:
    """Rigid box A x B [m] (A along x at φ = 0) of mass m [kg], uniform pressure."""

    A: float
    B: float
    m: float

    def __post_init__(self):
        _finite("parcel.A", self.A, 0.0, 100.0, lo_open=True)
        _finite("parcel.B", self.B, 0.0, 100.0, lo_open=True)
        _finite("parcel.m", self.m, 0.0, 1e5, lo_open=True)

    @property
    def inertia(self) -> float:
        """I = m (A² + B²)/12 about the centre of gravity [kg m²]."""
        return self.m * (self.A**2 + self.B**2) / 12.0

    def leading_edge_offset(self, phi: float) -> float:
        """
        Distance from the centre of gravity to the foremost corner along x [m].

        Parameters
        ----------
        phi : float
            The turn [rad].

        Returns
        -------
        float
            The distance [m].

        """
        return 0.5 * (self.A * abs(math.cos(phi)) + self.B * abs(math.sin(phi)))


@dataclass(frozen=True)
class Strip:
    """A band x_lo <= x <= x_hi of conveyor surface moving at (vx, vy) [m/s]."""

    x_lo: float
    x_hi: float
    vx: float
    vy: float
    law: FrictionLaw
    weight: float = 1.0
    name: str = ""


def three_zone_strips(
    v: float,
    alpha: float,
    b: float,
    law_a: FrictionLaw,
    law_b: FrictionLaw,
    law_c: FrictionLaw | None = None,
    stroke: float = 1.0,
) -> list[Strip]:
    """
    Return the seed's cell (Fig. 6): belt zone a (x < 0), disks b (0..b), belt zone c (x > b).

    Parameters
    ----------
    v : float
        Belt speed [m/s]; the disks turn at the same surface speed.
    alpha : float
        Disk angle [rad]: the disks' surface velocity is v (cos α, sin α).
    b : float
        Disk-field width [m]; ``inf`` for the seed's b -> ∞ (zone c is then absent).
    law_a, law_b, law_c : FrictionLaw
        The friction law of each zone.
    stroke : float
        Pop-up position 0..1: the share of the load the disks carry in zone b (the belt
        between the disks carries the rest; 0 = disks down).

    Returns
    -------
    list of Strip
        The zones, upstream first.

    """
    _finite("belt.v", v, -10.0, 10.0)
    _finite("diverter.alpha", alpha, -math.pi / 2 - 1e-12, math.pi / 2 + 1e-12)
    _finite("zones.b", b, 0.0, math.inf, allow_inf=True)
    _finite("stroke", stroke, 0.0, 1.0)
    law_c = law_c if law_c is not None else law_a
    strips = [Strip(-math.inf, 0.0, v, 0.0, law_a, 1.0, "a")]
    if b > 0.0:
        if stroke > 0.0:
            strips.append(
                Strip(0.0, b, v * math.cos(alpha), v * math.sin(alpha), law_b, stroke, "b")
            )
        if stroke < 1.0:
            strips.append(Strip(0.0, b, v, 0.0, law_a, 1.0 - stroke, "b_belt"))
    if math.isfinite(b):
        strips.append(Strip(b, math.inf, v, 0.0, law_c, 1.0, "c"))
    return strips


def strip_array(strips: list[Strip]) -> np.ndarray:
    """
    Pack strips into the kernels' array (``layout``); strips moving alike share a surface.

    Parameters
    ----------
    strips : list of Strip
        The bands of the conveyor plane.

    Returns
    -------
    ndarray, shape (len(strips), STRIP_WIDTH)
        One row per strip, its surface id numbering the distinct velocities.

    """
    return _strip_array(tuple(strips)).copy()


@functools.lru_cache(maxsize=64)
def _strip_array(strips: tuple[Strip, ...]) -> np.ndarray:
    # strips are frozen: a sweep or a benchmark that runs one layout many times packs
    # it once (a b-spline law's row is fitted on packing)
    arr = np.zeros((len(strips), STRIP_WIDTH))
    velocities: list[tuple[float, float]] = []
    for k, s in enumerate(strips):
        if not (s.x_lo < s.x_hi):
            raise ValueError(
                f"strip {s.name or k}: x_lo must be below x_hi, got {s.x_lo}, {s.x_hi}"
            )
        key = (float(s.vx), float(s.vy))
        surf = None
        for j, w in enumerate(velocities):
            if math.isclose(w[0], key[0], abs_tol=1e-15) and math.isclose(
                w[1], key[1], abs_tol=1e-15
            ):
                surf = j
        if surf is None:
            velocities.append(key)
            surf = len(velocities) - 1
        arr[k, S_XLO] = s.x_lo
        arr[k, S_XHI] = s.x_hi
        arr[k, S_VX] = velocities[surf][0]
        arr[k, S_VY] = velocities[surf][1]
        arr[k, S_WEIGHT] = s.weight
        arr[k, S_SURF] = surf
        arr[k, S_LAW] = s.law.law_id
        arr[k, S_PARAMS : S_PARAMS + N_LAW_PARAMS] = s.law.row()
    arr.flags.writeable = False
    return arr


# the stick laws of ``simulate(stick=...)`` and the scene key model.stick
STICK_LAWS = {"exact": STICK_EXACT, "seed": STICK_SEED}


def parcel_array(
    parcel: Parcel,
    rotation: bool = True,
    n_quad: int = 8,
    closed_form: bool = True,
    g: float = G_STANDARD,
    stick: str = "exact",
) -> np.ndarray:
    """
    Return the parcel row the kernels read (``layout``).

    Parameters
    ----------
    parcel : Parcel
        The box.
    rotation : bool
        The moment of friction forces on.
    n_quad : int
        Gauss points per direction of the footprint's quadrature.
    closed_form : bool
        The exact wrench on constant-μ strips.
    g : float
        Gravity [m/s²].
    stick : {'exact', 'seed'}
        The stick law.

    Returns
    -------
    ndarray, shape (PARCEL_WIDTH,)
        The row.

    """
    if stick not in STICK_LAWS:
        raise ValueError(f"stick must be one of {sorted(STICK_LAWS)}, got {stick!r}")
    arr = np.zeros(PARCEL_WIDTH)
    arr[P_HALF_A] = 0.5 * parcel.A
    arr[P_HALF_B] = 0.5 * parcel.B
    arr[P_MASS] = parcel.m
    arr[P_INERTIA] = parcel.inertia
    arr[P_GRAV] = g
    arr[P_ROTATION] = 1.0 if rotation else 0.0
    arr[P_NQUAD] = n_quad
    arr[P_CLOSED] = 1.0 if closed_form else 0.0
    arr[P_STICK] = STICK_LAWS[stick]
    return arr


def strip_borders(strips: list[Strip]) -> np.ndarray:
    """
    Return the x of every finite strip border.

    Parameters
    ----------
    strips : list of Strip
        The strips.

    Returns
    -------
    ndarray
        The x of every finite strip border [m], sorted.

    """
    xs = sorted({x for s in strips for x in (s.x_lo, s.x_hi) if math.isfinite(x)})
    return np.array(xs, dtype=float)


@dataclass
class SimResult:
    """
    What a run produced, scipy-style.

    t [s], y (n x 6: x, y [m], φ [rad], ẋ, ẏ [m/s], φ̇ [rad/s]) and mode (-1 sliding,
    k >= 0 stuck to surface k) at every recorded step; events as (t, kind, info).
    """

    t: np.ndarray
    y: np.ndarray
    mode: np.ndarray
    events: list
    status: int
    message: str
    method: str
    n_steps: int
    n_rhs: int
    n_rejected: int
    wall_s: float
    reductions: list = field(default_factory=list)
    surfaces: list = field(default_factory=list)

    @property
    def success(self) -> bool:
        return self.status in (ST_END, ST_TARGET)

    @property
    def nfev(self) -> int:
        """Right-hand-side evaluations, scipy's name for ``n_rhs`` (stick tests included)."""
        return self.n_rhs

    @property
    def n_events(self) -> int:
        return len(self.events)

    @property
    def t_target(self) -> float | None:
        for t, kind, _ in self.events:
            if kind == "target":
                return t
        return None

    def first_event(self, kind: str, info=None) -> float | None:
        """
        Return the time of the first event of ``kind`` (and ``info``).

        Parameters
        ----------
        kind : str
            The event's kind ('stick', 'break', 'zone', 'scrap').
        info : int, optional
            The event's info (a surface id), or any.

        Returns
        -------
        float or None
            The first such event's time [s], or None.

        """
        for t, k, i in self.events:
            if k == kind and (info is None or i == info):
                return t
        return None


def surface_velocities(arr: np.ndarray) -> list[tuple[float, float]]:
    """
    Return each surface's velocity (vx, vy), by surface id.

    Parameters
    ----------
    arr : ndarray, shape (n, STRIP_WIDTH)
        The strips (``layout``).

    Returns
    -------
    list of (float, float)
        Each surface's velocity, by surface id.

    """
    velocities: dict[int, tuple[float, float]] = {}
    for row in arr[:, : S_SURF + 1].tolist():
        velocities.setdefault(int(row[S_SURF]), (row[S_VX], row[S_VY]))
    return [velocities[s] for s in range(max(velocities) + 1)]


def initial_mode(y0, arr: np.ndarray, parcel_arr: np.ndarray, velocities=None) -> int:
    """
    Stuck to the surface whose velocity the parcel has (φ̇ = 0) and touches, else sliding.

    Parameters
    ----------
    y0 : ndarray, shape (6,)
        The start's state (``layout``).
    arr : ndarray, shape (n, STRIP_WIDTH)
        The strips (``layout``).
    parcel_arr : ndarray, shape (PARCEL_WIDTH,)
        The parcel's row (``layout``).
    velocities : list of (float, float), optional
        Each surface's velocity; computed from ``arr`` when not given.

    Returns
    -------
    int
        The surface it is stuck to, or MODE_SLIDE.

    """
    if y0[5] != 0.0:
        return MODE_SLIDE
    velocities = velocities or surface_velocities(arr)
    area = np.zeros(len(velocities))
    _contact_surfaces(np.asarray(y0, float), arr, parcel_arr, clip_scratch(), area)
    for s, (vx, vy) in enumerate(velocities):
        if area[s] > 0.0 and y0[3] == vx and y0[4] == vy:
            return s
    return MODE_SLIDE


def simulate(  # noqa: PLR0913 — keyword-only options with defaults, as scipy.integrate.solve_ivp
    parcel: Parcel,
    strips: list[Strip],
    y0,
    t_span,
    method: str = "accurate",
    *,
    rtol: float = 1e-8,
    atol: float = 1e-10,
    dt: float = 1e-3,
    v_min: float = 1e-6,
    y_target: float = math.inf,
    rotation: bool = True,
    reductions: bool = True,
    n_quad: int = 8,
    h_max: float = 0.2,
    max_points: int = 200_000,
    g: float = G_STANDARD,
    stick: str = "exact",
) -> SimResult:
    """
    Run one parcel over ``strips`` from state ``y0`` over ``t_span``.

    Parameters
    ----------
    parcel : Parcel
        The box: its length A, width B and mass.
    strips : list of Strip
        The bands of the conveyor plane it slides on (``three_zone_strips`` for the
        seed's cell), each with its surface velocity and friction law.
    y0 : array_like, shape (6,)
        The start: x, y [m], φ [rad], ẋ, ẏ [m/s], φ̇ [rad/s] of the centre of gravity.
    t_span : (float, float)
        (t0, t_end) [s].
    method : {'accurate', 'implicit', 'threshold'}
        'accurate': event-located Dormand-Prince 5(4) under ``rtol``/``atol``;
        'implicit': backward Euler in velocity at the step ``dt``; 'threshold': the
        seed's model with the threshold speed ``v_min``, RK4 at ``dt``.
    rtol, atol : float
        The accurate method's tolerances.
    dt : float
        The fixed-step methods' step [s].
    v_min : float
        The threshold method's threshold speed [m/s] (eq. 3.1).
    y_target : float
        Stop when the centre of gravity reaches y = y_target [m] (the scrap line).
    rotation : bool
        The moment of friction forces on (the seed's full model) or off (Fig. 7 line 2).
    reductions : bool
        False forces quadrature for constant-μ strips and stepping through sticks on a
        single surface: the full model, for checking the reductions.
    n_quad : int
        Gauss points per direction of the footprint's quadrature.
    h_max : float
        The accurate method's longest step [s], a net under its error estimate (which
        at two or three steps a cycle of an oscillation is no longer to be trusted).
    max_points : int
        Room for the trajectory's records.
    g : float
        Gravity [m/s²].
    stick : {'exact', 'seed'}
        'exact': a stick holds while the wrench the stuck surface must supply is in its
        patch's limit set; 'seed': the paper's decoupled |F| <= F_max, |T| <= T_max. It
        decides the accurate and the implicit method's sticks (the threshold method is
        the seed's model, decoupled by construction).

    Returns
    -------
    SimResult
        The trajectory (t, y, modes), the events (stick, break, zone, scrap), the
        counters and the status; ``t_target`` is when the scrap line was reached.

    Raises
    ------
    ValueError
        An argument out of its range, naming it and what is allowed.

    """
    if method not in METHODS:
        raise ValueError(f"method must be one of {sorted(METHODS)}, got {method!r}")
    check_kernel_cache()
    y0, t0, t_end, tol = _checked(y0, t_span, rtol, atol, dt, v_min, y_target, n_quad)
    if not strips:
        raise ValueError("strips must not be empty")
    arr = strip_array(strips)
    if not rotation and y0[5] != 0.0:
        raise ValueError("y0[5] (omega) must be 0 when rotation is off")
    par = parcel_array(parcel, rotation, int(tol["n_quad"]), reductions, g, stick)
    nodes, weights = gauss_legendre_01(int(tol["n_quad"]))
    trail = Trail(np.empty(max_points), np.empty((max_points, 6)), np.empty(max_points, np.int64))
    log = Log(np.empty((4096, 3)), np.zeros(N_COUNTERS, dtype=np.int64))
    velocities = surface_velocities(arr)
    contact = Contact(arr, par, nodes, weights)
    mode0 = initial_mode(y0, arr, par, velocities)
    borders = strip_borders(strips)
    wall = time.perf_counter()
    status = _run_kernel(
        method, (y0, mode0), (t0, t_end), contact, tol, borders, h_max, reductions, trail, log
    )
    wall = time.perf_counter() - wall
    used = _reductions_used(method, strips, reductions, rotation, log.counters)
    return _result(method, status, trail, log, wall, used, velocities)


def _checked(y0, t_span, rtol, atol, dt, v_min, y_target, n_quad):
    """
    Check ``simulate``'s numeric arguments against their ranges (``ValueError`` if not).

    Returns
    -------
    (ndarray, float, float, dict)
        y0 as 6 floats, t0, t_end, and rtol, atol, dt, v_min, y_target (inf where not
        finite) and n_quad by name.

    """
    y0 = np.asarray(y0, dtype=float)
    if y0.shape != (6,) or not np.all(np.isfinite(y0)):
        raise ValueError(f"y0 must be 6 finite numbers (x, y, phi, vx, vy, omega), got {y0!r}")
    t0 = _finite("t_span[0]", t_span[0])
    t_end = _finite("t_span[1]", t_span[1], t0, math.inf, lo_open=True)
    tol = {
        "rtol": _finite("rtol", rtol, 1e-14, 1e-1),
        "atol": _finite("atol", atol, 1e-16, 1.0),
        "dt": _finite("dt", dt, 0.0, 1.0, lo_open=True),
        "v_min": _finite("v_min", v_min, 0.0, 1.0, lo_open=True),
    }
    y_target = _finite("y_target", y_target, allow_inf=True)
    tol["n_quad"] = int(_finite("n_quad", n_quad, 2, 24))
    tol["y_target"] = y_target if math.isfinite(y_target) else math.inf
    return y0, t0, t_end, tol


def _run_kernel(method, start, span, contact, tol, borders, h_max, reductions, trail, log):
    """Run ``method``'s kernel from ``start`` (y0, mode0) over ``span`` (t0, t_end): its status."""
    y0, mode0 = start
    t0, t_end = span
    if method == "accurate":
        slide = Slide(
            tol["y_target"],
            contact,
            n_surf_of(contact.strips),
            borders,
            tol["rtol"],
            tol["atol"],
            h_max,
        )
        xi = np.zeros(GAUGE_CARRY)
        if reductions:
            # the cell's compiled integrator (see ``run_accurate_reduced``)
            status, _, _ = run_accurate_reduced(y0, mode0, t0, t_end, slide, trail, log, xi)
        else:
            status, _, _ = run_accurate(y0, mode0, t0, t_end, slide, False, trail, log, xi)
    elif method == "implicit":
        status, _, _ = run_implicit(
            y0, mode0, t0, t_end, tol["y_target"], contact, tol["dt"], trail, log
        )
    else:
        status, _, _ = run_threshold(
            y0, mode0, t0, t_end, tol["y_target"], contact, tol["dt"], tol["v_min"], trail, log
        )
    return status


def _reductions_used(method, strips, reductions, rotation, counters) -> list[str]:
    """Return the reductions of the full model a run used (``SimResult.reductions``)."""
    used = []
    if reductions and all(s.law.is_constant for s in strips):
        used.append("closed_form_wrench")
    if method == "accurate" and counters[N_JUMPS] > 0:
        used.append("closed_form_stick")
    if not rotation:
        used.append("no_rotation")
    names = {s.name for s in strips}
    if "a" in names and "c" not in names:
        used.append("zone_c_absent")
    if "a" in names and "b" not in names:
        used.append("zone_b_absent")
    return used


def _result(method, status, trail, log, wall, used, velocities) -> SimResult:
    """Return the ``SimResult`` of a run from its trail and its log."""
    counters, ev = log.counters, log.ev
    max_points = trail.ts.shape[0]
    n_out = min(int(counters[N_OUT]), max_points)
    n_ev = min(int(counters[N_EVENTS]), ev.shape[0])
    events = [
        (float(ev[i, 0]), EVENT_NAMES.get(int(ev[i, 1]), str(int(ev[i, 1]))), int(ev[i, 2]))
        for i in range(n_ev)
    ]
    return SimResult(
        t=trail.ts[:n_out].copy(),
        y=trail.ys[:n_out].copy(),
        mode=trail.ms[:n_out].copy(),
        events=events,
        status=int(status),
        message=STATUS_MESSAGES[int(status)]
        + (
            f" (the trajectory holds the first {max_points - 1} of {int(counters[N_OUT])} records"
            " and the last: raise simulate's max_points for all)"
            if counters[N_OUT] > max_points
            else ""
        ),
        method=method,
        n_steps=int(counters[N_STEPS]),
        n_rhs=int(counters[N_RHS]),
        n_rejected=int(counters[N_REJECTED]),
        wall_s=wall,
        reductions=used,
        surfaces=velocities,
    )


__all__ = [
    "FrictionLaw",
    "Parcel",
    "SimResult",
    "Strip",
    "simulate",
    "three_zone_strips",
    "strip_array",
    "parcel_array",
    "STICK_LAWS",
    "G_STANDARD",
    "METHODS",
    "LAW_BSPLINE",
]
