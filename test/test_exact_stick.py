"""
Exact stick: a stuck parcel holds while its surface can supply the wrench (the limit set).

Two kinds of check. The limit set's gauge against closed forms (its intercepts on
the force and moment axes are the seed's F_max and T_max of eqs. 4.3/4.5, it is
symmetric and positively homogeneous, and combined loads inside the seed's box can
lie outside it). And whole diversions against an independent solution written for
the tests (``regularised_reference``: regularised Coulomb friction on a footprint
grid, scipy's Radau), whose convergence in ε and grid is checked first.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from regularised_reference import RTOL, Scene, footprint_friction, solve

from sorter_sim.model.build import cell_strips, entry_state
from sorter_sim.model.core.accurate import run_accurate
from sorter_sim.model.core.common import EV_BREAK, N_COUNTERS, N_EVENTS, n_surf_of, rhs_slide
from sorter_sim.model.core.layout import P_GRAV, P_INERTIA, P_MASS, Contact, Log, Slide, Trail
from sorter_sim.model.core.simulate import (
    Parcel,
    gauss_legendre_01,
    parcel_array,
    simulate,
    strip_array,
)
from sorter_sim.model.core.stick import GAUGE_CARRY, inside_limit_set, limit_gauge, stick_margin
from sorter_sim.model.core.wrench import clip_scratch, evaluate_surfaces, static_surface_wrench

# ------------------------------------------------------------------ the limit set


def _patch(x_cg=0.3, phi=0.4, stick="exact"):
    """Return a 0.7 x 0.2 m parcel lying partly on the disks (surface 1) at α = 45°."""
    parcel = Parcel(0.7, 0.2, 5.0)
    arr = strip_array(cell_strips(1.5, 45.0, math.inf, 0.6, 0.6, 0.6))
    par = parcel_array(parcel, True, 8, True, stick=stick)
    nodes, weights = gauss_legendre_01(8)
    y = np.array([x_cg, 0.1, phi, 0.0, 0.0, 0.0])
    return parcel, arr, par, nodes, weights, y


def _seed_limits(arr, par, nodes, weights, y, surf):
    nsurf = n_surf_of(arr)
    kin = np.zeros((nsurf, 3))
    stat = np.zeros((nsurf, 2))
    area = np.zeros(nsurf)
    slip = np.zeros(nsurf)
    evaluate_surfaces(y, Contact(arr, par, nodes, weights), -2, True, kin, stat, area, slip)
    return stat[surf, 0], stat[surf, 1]


def _gauge(arr, par, nodes, weights, y, surf, w):
    return limit_gauge(
        y, Contact(arr, par, nodes, weights), surf, w[0], w[1], w[2], np.zeros(3), clip_scratch()
    )


@pytest.mark.parametrize("surf", [0, 1])
def test_the_limit_set_never_reaches_past_the_seeds_limits(surf):
    # pure force: a twist of pure translation dissipates μ p S |v| = F_max |v| (eq. 4.3),
    # pure moment: rotation about g dissipates μ p ∫ r dS |φ̇| = T_max |φ̇| (eq. 4.5,
    # rest row); other twists may dissipate less per unit load, so the set's intercepts
    # are at most F_max and T_max (equal for a patch centred on g, next test)
    _, arr, par, nodes, weights, y = _patch()
    f_max, t_max = _seed_limits(arr, par, nodes, weights, y, surf)
    for direction in (0.0, 1.0, 2.5):
        w = (f_max * math.cos(direction), f_max * math.sin(direction), 0.0)
        assert _gauge(arr, par, nodes, weights, y, surf, w) >= 1.0 - 1e-9
    assert _gauge(arr, par, nodes, weights, y, surf, (0.0, 0.0, t_max)) >= 1.0 - 1e-9
    # a patch off g cannot hold its full T_max about g without a net force
    assert _gauge(arr, par, nodes, weights, y, surf, (0.0, 0.0, t_max)) > 1.0 + 1e-4


def test_a_patch_centred_on_g_has_the_seeds_force_intercept():
    # a parcel wholly on one surface: its patch is the footprint, centroid at g
    _, arr, par, nodes, weights, y = _patch(x_cg=-1.0, phi=0.3)
    f_max, t_max = _seed_limits(arr, par, nodes, weights, y, 0)
    assert f_max == pytest.approx(0.6 * 5.0 * par[P_GRAV])  # μ m g
    for direction in (0.0, 0.7, 2.0):
        w = (f_max * math.cos(direction), f_max * math.sin(direction), 0.0)
        assert _gauge(arr, par, nodes, weights, y, 0, w) == pytest.approx(1.0, abs=1e-9)
    assert _gauge(arr, par, nodes, weights, y, 0, (0.0, 0.0, -t_max)) == pytest.approx(
        1.0, abs=1e-9
    )


def test_the_gauge_is_symmetric_and_homogeneous_and_one_on_the_limit_surface():
    _, arr, par, nodes, weights, y = _patch()
    rng = np.random.default_rng(7)
    rho = math.sqrt(par[P_INERTIA] / par[P_MASS])
    for _ in range(20):
        twist = rng.normal(size=3)
        fx, fy, t = static_surface_wrench(
            y,
            Contact(arr, par, nodes, weights),
            1,
            twist[0],
            twist[1],
            twist[2] / rho,
            clip_scratch(),
        )
        # -F is the patch's limit-surface point with normal `twist` (the friction
        # opposes the twist): its gauge is 1 whatever the twist's size
        w = np.array([-fx, -fy, -t])
        assert _gauge(arr, par, nodes, weights, y, 1, w) == pytest.approx(1.0, abs=1e-8)
        assert _gauge(arr, par, nodes, weights, y, 1, -w) == pytest.approx(1.0, abs=1e-8)
        assert _gauge(arr, par, nodes, weights, y, 1, 0.3 * w) == pytest.approx(0.3, abs=1e-8)


def test_force_and_moment_interact_inside_the_seeds_box():
    # 90 % of F_max together with 90 % of T_max: the decoupled test (seed) holds it,
    # the limit set (strictly inside the box away from the axes) does not
    _, arr, par, nodes, weights, y = _patch(x_cg=-1.0, phi=0.0)
    f_max, t_max = _seed_limits(arr, par, nodes, weights, y, 0)
    w = (0.9 * f_max, 0.0, 0.9 * t_max)
    assert _gauge(arr, par, nodes, weights, y, 0, w) > 1.2
    state = np.array([-1.0, 0.1, 0.0, 1.5, 0.0, 0.0])
    nsurf = 2
    # the stick margin reads the other surfaces' pull; with none there is nothing to break
    for stick in ("exact", "seed"):
        par_s = parcel_array(Parcel(0.7, 0.2, 5.0), True, 8, True, stick=stick)
        m, area, *_ = stick_margin(
            state, Contact(arr, par_s, nodes, weights), nsurf, 0, np.zeros(3)
        )
        assert m < 0.0 and area > 0.0


@pytest.mark.parametrize("surf", [0, 1])
def test_the_inner_bound_of_the_limit_set_never_admits_a_wrench_outside_it(surf):
    """
    Check ``inside_limit_set`` (which spares the implicit step a gauge solve) is sound.

    Wrenches just outside the set (support points of random twists, the boundary, x
    1.001) must never be admitted; of random wrenches inside the seed's box, those it
    admits must have a gauge <= 1, and it must admit a good share of those well inside
    (gauge < 0.2), or it would spare nothing.
    """
    rng = np.random.default_rng(7)
    admitted = well_inside = 0
    for x_cg in (-0.25, -0.05, 0.15, 0.3):
        for phi in (0.0, 0.4, 1.2):
            _, arr, par, nodes, weights, y = _patch(x_cg=x_cg, phi=phi)
            f_max, t_max = _seed_limits(arr, par, nodes, weights, y, surf)
            if f_max <= 0.0:
                continue
            for _ in range(40):
                xi = rng.normal(size=3) * np.array([1.0, 1.0, 5.0])
                w = np.array(
                    static_surface_wrench(
                        y, Contact(arr, par, nodes, weights), surf, *xi, clip_scratch()
                    )
                )
                assert not inside_limit_set(y, arr, par, surf, *(-1.001 * w))
                box = rng.uniform(-1.0, 1.0, size=3) * np.array([f_max, f_max, t_max])
                for scale in (1.0, 0.3, 0.1):
                    v = box * scale
                    if inside_limit_set(y, arr, par, surf, *v):
                        admitted += 1
                        assert _gauge(arr, par, nodes, weights, y, surf, v) <= 1.0
                    well_inside += _gauge(arr, par, nodes, weights, y, surf, v) < 0.2
    assert admitted > 0.3 * well_inside, (admitted, well_inside)


# ------------------------------------------------------------------ diversions

CASES = {
    "α=15°, rotation on": Scene(alpha_deg=15.0),
    "α=30°, rotation on": Scene(alpha_deg=30.0),
    "α=45°, rotation on": Scene(alpha_deg=45.0),
    "α=60°, rotation off": Scene(alpha_deg=60.0, rotation=False),
    "α=90°, rotation on": Scene(alpha_deg=90.0),
    "α=90°, rotation off": Scene(alpha_deg=90.0, rotation=False),
    "three zones, 1.0 x 0.4 m at 0.8 m/s, α=60°, b=1.5 m": Scene(
        A=1.0, B=0.4, v=0.8, alpha_deg=60.0, b=1.5
    ),
}
EPS = (1e-4, 3e-5)  # regularisation speeds [m/s]
GRID = (140, 40)


def _project(scene: Scene, stick: str, method: str = "accurate", **settings):
    parcel = Parcel(scene.A, scene.B, scene.m)
    strips = cell_strips(scene.v, scene.alpha_deg, scene.b, scene.mu, scene.mu, scene.mu)
    res = simulate(
        parcel,
        strips,
        entry_state(parcel, scene.v),
        (0.0, 20.0),
        method,
        y_target=scene.s,
        rotation=scene.rotation,
        stick=stick,
        **settings,
    )
    assert res.status == 1, res.message
    breaks = [e[0] for e in res.events if e[1] == "break" and e[2] == 0]
    sticks = [e[0] for e in res.events if e[1] == "stick" and e[2] == 1]
    return res.t[-1], math.degrees(res.y[-1, 2]), breaks[0], sticks[0]


# the grid's convergence test reads the α = 45° case's coarse reference: one worker solves it
_SHARED = "exact_stick:α=45° reference"


@pytest.mark.slow
@pytest.mark.parametrize(
    "name",
    [
        pytest.param(n, marks=pytest.mark.xdist_group(_SHARED)) if n == "α=45°, rotation on" else n
        for n in CASES
    ],
)
def test_exact_stick_matches_the_regularised_reference(name):
    scene = CASES[name]
    coarse, fine = (solve(scene, e, *GRID) for e in EPS)
    # the reference has converged in ε well inside the tolerances below
    assert abs(coarse.t_scrap - fine.t_scrap) < 0.05e-2 * fine.t_scrap
    assert abs(coarse.phi_deg - fine.phi_deg) < 0.1
    # the reference detects the break-away once the slip reaches 30 ε; for constant μ
    # the slip grows as the square of the time since the break, so the detection lags
    # by a time ∝ √ε: extrapolated to ε = 0 from the two solutions
    r = math.sqrt(EPS[1]) / (math.sqrt(EPS[0]) - math.sqrt(EPS[1]))
    t_break_0 = fine.t_break - r * (coarse.t_break - fine.t_break)
    # both methods: the implicit one's exact step (its minimiser sits on a stick's kink
    # exactly when the limit set holds the wrench) at 0.1 ms, its events within a step
    for method, settings, dt in (("accurate", {}, 0.0), ("implicit", {"dt": 1e-4}, 1e-4)):
        t_scrap, phi, t_break, t_stick = _project(scene, "exact", method, **settings)
        assert t_scrap == pytest.approx(fine.t_scrap, rel=0.5e-2), method
        assert phi == pytest.approx(fine.phi_deg, abs=0.5), method
        assert t_stick == pytest.approx(fine.t_stick, rel=0.5e-2, abs=dt), method
        assert t_break == pytest.approx(t_break_0, rel=1e-2, abs=dt), method
    if scene.rotation:
        # and the seed's decoupled stick misses what the exact one meets
        seed = _project(scene, "seed")
        assert abs(seed[0] - fine.t_scrap) > 0.5e-2 * fine.t_scrap
        assert abs(seed[1] - fine.phi_deg) > 1.0
        assert abs(seed[2] - t_break_0) > 0.02


def test_the_references_jacobian_is_the_derivative_of_its_friction():
    # Radau trusts this Jacobian for its Newton iterations: each column against central
    # differences, at a state sliding on both zones and turning (b = 0.9 m: the far
    # belt too), with ε large enough that the law is smooth at the difference's scale
    A, B, v, alpha, b, eps = 0.7, 0.2, 1.5, math.radians(45.0), 0.9, 3e-3
    xi = (np.arange(70) + 0.5) / 70 * A - 0.5 * A
    eta = (np.arange(20) + 0.5) / 20 * B - 0.5 * B
    XI, ETA = (a.ravel() for a in np.meshgrid(xi, eta, indexing="ij"))
    args = (XI, ETA, b, v, v * math.cos(alpha), v * math.sin(alpha), 0.6 * 5.0 * 9.81 / 1400, eps)
    state = np.array([0.1, 0.2, 0.3, 1.2, 0.5, 0.4])
    _, jac = footprint_friction(state, *args, True)
    assert np.all(footprint_friction(state, *args, False)[1] == 0.0)
    for column, q in enumerate((2, 3, 4, 5)):  # φ, v_x, v_y, ω
        h = np.zeros(6)
        h[q] = 1e-6
        plus = footprint_friction(state + h, *args, False)[0]
        minus = footprint_friction(state - h, *args, False)[0]
        assert jac[:, column] == pytest.approx((plus - minus) / 2e-6, rel=1e-6, abs=1e-9), q


@pytest.mark.slow
@pytest.mark.xdist_group(_SHARED)
def test_the_reference_converges_in_the_grid():
    scene = CASES["α=45°, rotation on"]
    fine = solve(scene, EPS[0], *GRID)
    finer = solve(scene, EPS[0], 200, 56)
    assert abs(fine.t_scrap - finer.t_scrap) < 0.05e-2 * finer.t_scrap
    assert abs(fine.phi_deg - finer.phi_deg) < 0.05
    assert abs(fine.t_stick - finer.t_stick) < 1e-3
    # ... and in Radau's tolerance: a hundredth of it moves the reference by a small
    # part of what ε and the grid do
    tight = solve(scene, EPS[0], *GRID, rtol=RTOL / 100)
    assert abs(fine.t_scrap - tight.t_scrap) < 0.005e-2 * tight.t_scrap
    assert abs(fine.phi_deg - tight.phi_deg) < 0.005
    assert abs(fine.t_break - tight.t_break) < 1e-5
    assert abs(fine.t_stick - tight.t_stick) < 1e-5


# ------------------------------------------------------------------ no stalls
_STALL_STEP_BOUND = 20_000  # far above any case here; a stall takes millions


@pytest.mark.parametrize("rotation", [True, False], ids=["rotation on", "rotation off"])
@pytest.mark.parametrize("v", [0.05, 0.2, 1.5, 3.0])
def test_no_stall_across_belt_speeds_and_angles(v, rotation):
    """
    Check that diversions at belt speeds 0.05-3 m/s and α 0-90° finish in bounded steps.

    Each run goes to the scrap line or to 30 s (α = 0: the disks push along the belt);
    a stall (steps collapsing near a balanced slip, as the accurate method once did at
    0.05 m/s) would exhaust the step budget instead.
    """
    parcel = Parcel(0.7, 0.2, 5.0)
    steps = []
    rhs = []
    for alpha in (0.0, 15.0, 30.0, 45.0, 60.0, 75.0, 90.0):
        strips = cell_strips(v, alpha, math.inf, 0.6, 0.6, 0.6)
        res = simulate(
            parcel,
            strips,
            entry_state(parcel, v),
            (0.0, 30.0),
            "accurate",
            y_target=0.7,
            rotation=rotation,
            max_points=_STALL_STEP_BOUND // 50,
        )
        assert res.success, f"α = {alpha}°: {res.message}"
        steps.append(res.n_steps)
        # right-hand sides count every step (the layer's, and those taken in ln |slip|)
        rhs.append(res.nfev)
    assert max(steps) < _STALL_STEP_BOUND, steps
    assert max(rhs) < 10 * _STALL_STEP_BOUND, rhs


def _balance_pose(stick):
    """
    Return the pose of a parcel stuck to the disks (α = 90°) and partly on the belt at the balance.

    Riding the disks (+y) over the a/b border, the parcel's areas do not change, so the
    belt's pull is constant: at the x where the disks' gauge of the required wrench is 1
    the stick neither holds with margin nor breaks with any growth. Found by bisection
    on the stick margin to rounding.
    """
    parcel = Parcel(0.7, 0.2, 5.0)
    strips = cell_strips(1.5, 90.0, math.inf, 0.6, 0.6, 0.6)
    arr = strip_array(strips)
    par = parcel_array(parcel, True, 8, True, stick=stick)
    nodes, weights = gauss_legendre_01(8)

    def margin(x):
        y = np.array([x, 0.0, 0.3, 0.0, 1.5, 0.0])
        return stick_margin(y, Contact(arr, par, nodes, weights), 2, 1, np.zeros(3))[0]

    lo, hi = 0.3, -0.3  # well on the disks (holds) ... mostly on the belt (breaks)
    assert margin(lo) < 0.0 < margin(hi)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if margin(mid) <= 0.0:
            lo = mid
        else:
            hi = mid
        if abs(hi - lo) < 1e-15:
            break
    return parcel, strips, lo, margin(lo)


@pytest.mark.parametrize("stick", ["exact", "seed"])
def test_near_balanced_sticks_finish_in_bounded_steps(stick):
    """
    Check that a stick with its required wrench on the limit surface (within 1e-9) runs on.

    The parcel starts stuck to the disks at the balance pose and 1e-9 m on either
    side, and sliding with a slip of 1e-9 m/s there: every run ends at t_end in a
    bounded number of steps, and with exact stick none leaves the disks' motion by
    more than the growth its margin allows.
    """
    parcel, strips, x_bal, m_bal = _balance_pose(stick)
    assert abs(m_bal) < 1e-9
    for dx in (-1e-9, 0.0, 1e-9):
        for slip in (0.0, 1e-9):
            y0 = np.array([x_bal + dx, 0.0, 0.3, slip, 1.5, 0.0])
            res = simulate(
                parcel,
                strips,
                y0,
                (0.0, 2.0),
                "accurate",
                stick=stick,
                max_points=_STALL_STEP_BOUND // 50,
            )
            assert res.status == 0, f"dx = {dx}, slip = {slip}: {res.message}"
            assert res.n_steps < 2000, (dx, slip, res.n_steps)
            if stick == "exact":
                # riding the disks: y advances at 1.5 m/s; x stays put to far below a mm
                # (seed stick breaks at the decoupled limits, inside the set the patch
                # can hold, and the parcel then slides as kinetic friction has it)
                assert res.y[-1, 1] == pytest.approx(3.0, abs=1e-3)
                assert abs(res.y[-1, 0] - x_bal) < 1e-3


def test_a_slip_growing_slowly_from_a_near_balance_stays_on_its_layer():
    """
    Check one control period of a slip the belt just fails to hold, against Radau.

    A parcel riding the belt onto disks carrying it across (α = 90°) 1 cm past the pose
    where the belt's stick breaks, slipping 1e-5-2e-5 m/s, below the scale where the
    full model hands a slip to its layer: its slip grows slowly. The layer once handed it
    back after every step and the full model sent it straight back, ~450 right-hand sides
    for one 1 ms period at rtol 1e-6. Now it stays on the layer to that scale: the pose
    after the period matches scipy's Radau on the model's own right-hand side (rtol
    1e-12) within 1e-8 m and the velocity within 10 rtol, in fewer than 150 evaluations.
    """
    from scipy.integrate import solve_ivp

    parcel = Parcel(0.7, 0.2, 5.0)
    strips = cell_strips(1.5, 90.0, 1.2, 0.6, 0.6, 0.6)
    arr = strip_array(strips)
    par = parcel_array(parcel, True, 8, True, stick="exact")
    nodes, weights = gauss_legendre_01(8)
    nsurf = n_surf_of(arr)

    def belt_margin(x):
        y = np.array([x, 0.0, 0.0, 1.5, 0.0, 0.0])
        return stick_margin(y, Contact(arr, par, nodes, weights), nsurf, 0, np.zeros(3))[0]

    lo, hi = -0.34, 0.0  # mostly on the belt (holds) ... half on the disks (breaks)
    assert belt_margin(lo) < 0.0 < belt_margin(hi)
    while hi - lo > 1e-12:
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if belt_margin(mid) <= 0.0 else (lo, mid)
    out = np.empty(6)

    def rhs(t, y):
        rhs_slide(np.ascontiguousarray(y), Contact(arr, par, nodes, weights), clip_scratch(), out)
        return out.copy()

    for slip in (1e-5, 2e-5):
        y0 = np.array([hi + 0.01, 0.0, 0.0, 1.5, slip, 0.0])
        ref = solve_ivp(rhs, (0.0, 1e-3), y0, "Radau", rtol=1e-12, atol=1e-15).y[:, -1]
        res = simulate(parcel, strips, y0, (0.0, 1e-3), "accurate", rtol=1e-6)
        assert res.success, res.message
        assert res.nfev < 150, res.nfev
        rho = math.sqrt(parcel.inertia / parcel.m)
        pose_err = np.abs(res.y[-1, :3] - ref[:3]) * np.array([1.0, 1.0, rho])
        assert pose_err.max() < 1e-8, pose_err
        vel_err = np.abs(res.y[-1, 3:] - ref[3:]) * np.array([1.0, 1.0, rho])
        assert vel_err.max() < 10 * 1e-6 * 1.5, vel_err
        # the belt cannot hold it: the slip grew
        assert math.hypot(res.y[-1, 3] - 1.5, res.y[-1, 4]) > slip


def test_the_gauge_warm_start_changes_nothing_but_the_work():
    """
    Check that a stick's break-away does not depend on the gauge twist it starts from.

    ``run_accurate`` takes the limit-set gauge's twist from its caller (the cell keeps
    each parcel's from period to period); whatever it starts from, converged, cold or
    pointing the wrong way, Newton finds the same minimiser: the parcel riding the belt
    onto the disks (Fig. 9a) breaks away at the same time to 1e-12 s; so does it
    whatever Newton metric it carries (``GAUGE_CARRY``), its own or a wrong one.
    """
    from sorter_sim.model.core.simulate import strip_borders

    parcel = Parcel(0.7, 0.2, 5.0)
    strips = cell_strips(1.5, 90.0, math.inf, 0.6, 0.6, 0.6)
    arr = strip_array(strips)
    par = parcel_array(parcel, True, 8, True, stick="exact")
    nodes, weights = gauss_legendre_01(8)
    y0 = entry_state(parcel, 1.5)

    def break_time(xi):
        ts = np.empty(4000)
        ys = np.empty((4000, 6))
        ms = np.empty(4000, dtype=np.int64)
        ev = np.empty((64, 3))
        counters = np.zeros(N_COUNTERS, dtype=np.int64)
        slide = Slide(
            y_target=math.inf,
            contact=Contact(arr, par, nodes, weights),
            nsurf=n_surf_of(arr),
            borders=strip_borders(strips),
            rtol=1e-8,
            atol=1e-10,
            h_max=0.05,
        )
        run_accurate(y0, 0, 0.0, 0.3, slide, True, Trail(ts, ys, ms), Log(ev, counters), xi)
        breaks = [e[0] for e in ev[: counters[N_EVENTS]] if e[1] == EV_BREAK]
        assert len(breaks) == 1
        return breaks[0]

    xi = np.zeros(3)
    t_cold = break_time(xi)
    assert np.linalg.norm(xi) == pytest.approx(1.0)  # handed back: the break's twist
    assert 0.1 < t_cold < 0.2  # the seed's Fig. 9a parcel leaves the belt after ~0.15 s
    for start in (xi.copy(), -xi, np.array([0.0, 0.0, 1.0])):
        assert break_time(start) == pytest.approx(t_cold, abs=1e-12)
    # with room for it, the gauge's Newton metric is carried too: the run's own, none,
    # or one that points Newton the wrong way (a wrong sign, a scale 1e6 off) all give
    # the same break, the metric being differenced anew where it fails to converge
    carry = np.zeros(GAUGE_CARRY)
    assert break_time(carry) == pytest.approx(t_cold, abs=1e-12)
    assert carry[3] > 0.0  # a metric was carried: its basis axis + 1
    assert np.linalg.norm(carry[:3]) == pytest.approx(1.0)
    for axis in (1.0, 2.0, 3.0):
        for metric in ((-1.0, 0.0, -1.0), (1e6, 0.0, 1e6), (1e-6, 0.0, 1e-6), (1.0, 5.0, 1.0)):
            bad = np.concatenate([carry[:3], [axis], metric])
            assert break_time(bad) == pytest.approx(t_cold, abs=1e-12), (axis, metric)


@pytest.mark.parametrize("alpha", [20.0, 45.0, 70.0, 90.0])
def test_the_break_away_is_the_first_root_of_the_gauge_margin(alpha):
    """
    Check that a stick breaks at the first time the limit set stops holding, no later.

    The accurate method scans a stick with a cheap inner bound of the limit set first
    and runs the gauge only where the bound cannot decide. Independently of that scan,
    the gauge margin along the carried path (belt speed, φ̇ = 0) is sampled here eight
    times as finely and its first sign change located by scipy's brentq: the break
    event must sit on it. A scan that let the bound admit a breaking pose would
    report a later break.
    """
    from scipy.optimize import brentq

    parcel = Parcel(0.7, 0.2, 5.0)
    strips = cell_strips(1.5, alpha, math.inf, 0.6, 0.6, 0.6)
    arr = strip_array(strips)
    par = parcel_array(parcel, True, 8, True, stick="exact")
    nodes, weights = gauss_legendre_01(8)
    y0 = entry_state(parcel, 1.5)
    res = simulate(parcel, strips, y0, (0.0, 0.5), "accurate", rtol=1e-8, atol=1e-10)
    t_break = res.first_event("break", 0)
    assert t_break is not None and 0.0 < t_break < 0.5

    def margin(t):
        y = np.array([y0[0] + 1.5 * t, y0[1], y0[2], 1.5, 0.0, 0.0])
        return stick_margin(y, Contact(arr, par, nodes, weights), 2, 0, np.zeros(3))[0]

    dt = 0.2 / (16.0 * 1.5) / 8.0  # the scan's step over eight
    grid = np.arange(0.0, t_break + 4 * dt, dt)
    values = np.array([margin(t) for t in grid])
    assert values[0] < 0.0
    first = int(np.argmax(values > 0.0))
    assert first > 0, "the stick never breaks on the fine grid"
    root = brentq(margin, grid[first - 1], grid[first], xtol=1e-14)
    assert t_break == pytest.approx(root, abs=1e-10)
