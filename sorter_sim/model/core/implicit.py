"""
The implicit method: fixed-step backward Euler in velocity with set-valued friction.

The step M (W+ - W)/h = wrench(W+) with set-valued Coulomb friction is the minimiser
of ½ (W+ - W)ᵀ M (W+ - W)/h + D(W+), D the footprint's dissipation rate, a strongly
convex problem: one solution for any h, exact sticking (the minimiser sits on the
kink at a surface's velocity when the limit set holds the wrench), no chatter. This
is Kikuuwe et al.'s (2005) implicit friction step carried to the planar footprint
(``implicit_step``). With constant μ, D and its gradient come from the exact wrench
(no quadrature floor, about two wrench evaluations a step); where μ depends on the
speed it is lagged one step at the Gauss points of the footprint,
D = Σ_k c_k |u_k(W+)|. Positions follow with the new velocity (symplectic Euler).
"""

from __future__ import annotations

import math
from collections import namedtuple

import numpy as np

from sorter_sim.model.core.common import (
    EV_BREAK,
    EV_STICK,
    EV_TARGET,
    N_EVENTS,
    N_OUT,
    N_REJECTED,
    N_RHS,
    N_STEPS,
    ST_END,
    ST_MAX_STEPS,
    ST_NONFINITE,
    ST_TARGET,
    _alone_on,
    _log_event,
    _record,
    _take_fixed_step,
    n_surf_of,
    surface_velocity,
)
from sorter_sim.model.core.friction import law_is_constant, mu_kinetic, mu_static
from sorter_sim.model.core.geometry import (
    MAX_VERTS,
    box_corners,
    clip_to_strip,
    polygon_area_centroid,
)
from sorter_sim.model.core.jit import allocating, kernel, kernel_step
from sorter_sim.model.core.layout import (
    MODE_SLIDE,
    P_GRAV,
    P_HALF_A,
    P_HALF_B,
    P_INERTIA,
    P_MASS,
    P_ROTATION,
    P_STICK,
    S_LAW,
    S_PARAMS,
    S_SURF,
    S_VX,
    S_VY,
    S_WEIGHT,
    S_XHI,
    S_XLO,
)
from sorter_sim.model.core.stick import GAUGE_CARRY, STICK_RTOL, inside_limit_set, limit_gauge
from sorter_sim.model.core.wrench import (
    add_slip_curvature,
    clip_scratch,
    dissipation_hessian,
    evaluate_surfaces,
)

# what an implicit step carries to the next: the footprint's point set, the twist guess,
# the Newton metric, and each surface's limit-set gauge twist
Carry = namedtuple('Carry', ['pts', 'guess', 'hess', 'xis'])
# each surface's kinetic wrench, static limits, contact area and slip
Loads = namedtuple('Loads', ['kin', 'stat', 'area', 'slip'])

F_NOISE = 1e-13  # relative rounding of a sum of wrench-based dissipations (closed form)
SOLVE_RATIO = 1e-2  # the implicit solve's error bound, relative to how far it moved
# the fewest steps a zone border's passage under the footprint is resolved with: the
# moment a parcel turns by comes from the difference of the zones' frictions while it
# straddles a border, and a step that jumps it from one zone into the next loses it
CROSSING_STEPS = 16
MAX_SUBSTEPS = 4096  # a net: h at most 0.1 s, a 2 cm parcel at 10 m/s needs 800


# ---------------------------------------------------------------- implicit step
# columns of the implicit step's point set (``_build_points``)
PT_X, PT_Y, PT_C, PT_SURF, PT_VX, PT_VY = 0, 1, 2, 3, 4, 5


@kernel
def _build_points(y, contact, pts, stat, pull, area):
    """
    Quadrature points of the footprint (centroid fans, Gauss n x n per triangle).

    ``pts`` (rows, one per point; columns PT_*): its position, surface and that
    surface's velocity, and c = weight · μ_k · pressure with μ_k the kinetic
    coefficient at the point's current slip (the 'lag' that keeps the implicit
    problem convex). Per surface: stat = (F_max, T_max) its static limits, pull the
    most its kinetic friction can pull (Σ ck, Σ ck |r|), area its share of the
    footprint. Returns the number of points.
    """
    strips, parcel, nodes, weights = contact
    corners = np.empty((4, 2))
    poly = np.empty((MAX_VERTS, 2))
    work = np.empty((MAX_VERTS, 2))
    half_a = parcel[P_HALF_A]
    half_b = parcel[P_HALF_B]
    box_corners(y[0], y[1], y[2], half_a, half_b, corners)
    p_unit = parcel[P_MASS] * parcel[P_GRAV] / (4.0 * half_a * half_b)
    nq = nodes.shape[0]
    npt = 0
    stat[:, :] = 0.0
    pull[:, :] = 0.0
    area[:] = 0.0
    for k in range(strips.shape[0]):
        w = strips[k, S_WEIGHT]
        if w <= 0.0:
            continue
        n = clip_to_strip(corners, strips[k, S_XLO], strips[k, S_XHI], poly, work)
        a, qx, qy = polygon_area_centroid(poly, n)
        if a <= 0.0:
            continue
        s_id = int(strips[k, S_SURF])
        law = int(strips[k, S_LAW])
        params = strips[k, S_PARAMS:]
        pressure = p_unit * w
        mus = mu_static(law, params)
        area[s_id] += w * a
        # a parcel that does not turn slips alike at every point of a strip: μ once then
        # (a b-spline law's μ is a Newton inversion, most of a step's cost otherwise)
        sp_known = -1.0
        mu = 0.0
        for i in range(n):
            j = (i + 1) % n
            e0x = poly[i, 0] - qx
            e0y = poly[i, 1] - qy
            dex = poly[j, 0] - poly[i, 0]
            dey = poly[j, 1] - poly[i, 1]
            det = e0x * dey - e0y * dex
            for aa in range(nq):
                ex = e0x + nodes[aa] * dex
                ey = e0y + nodes[aa] * dey
                for bb in range(nq):
                    s = nodes[bb]
                    xk = qx + s * ex
                    yk = qy + s * ey
                    wk = weights[aa] * weights[bb] * s * det
                    ux = y[3] - y[5] * (yk - y[1]) - strips[k, S_VX]
                    uy = y[4] + y[5] * (xk - y[0]) - strips[k, S_VY]
                    sp = max(math.sqrt(ux * ux + uy * uy), 1e-12)
                    if sp != sp_known:
                        mu = mu_kinetic(law, params, sp)
                        sp_known = sp
                    c = wk * mu * pressure
                    pts[npt, PT_X] = xk
                    pts[npt, PT_Y] = yk
                    pts[npt, PT_C] = c
                    pts[npt, PT_SURF] = s_id
                    pts[npt, PT_VX] = strips[k, S_VX]
                    pts[npt, PT_VY] = strips[k, S_VY]
                    rr = math.sqrt((xk - y[0]) ** 2 + (yk - y[1]) ** 2)
                    stat[s_id, 0] += wk * mus * pressure
                    stat[s_id, 1] += wk * mus * pressure * rr
                    pull[s_id, 0] += c
                    pull[s_id, 1] += c * rr
                    npt += 1
    return npt


@kernel
def _points_wrench(st, npt, pts, skip, kin):
    """Kinetic wrench per surface of the point set at the twist in ``st`` (``skip``: zero)."""
    kin[:, :] = 0.0
    for k in range(npt):
        s = int(pts[k, PT_SURF])
        if s == skip:
            continue
        rx = pts[k, PT_X] - st[0]
        ry = pts[k, PT_Y] - st[1]
        ux = st[3] - st[5] * ry - pts[k, PT_VX]
        uy = st[4] + st[5] * rx - pts[k, PT_VY]
        # sqrt, not hypot: speeds are O(1) m/s, and libm's hypot costs several times more
        sp = math.sqrt(ux * ux + uy * uy)
        if sp > 0.0:
            fx = -pts[k, PT_C] * ux / sp
            fy = -pts[k, PT_C] * uy / sp
            kin[s, 0] += fx
            kin[s, 1] += fy
            kin[s, 2] += rx * fy - ry * fx


@kernel
def _points_hessian(st, npt, pts, out):
    """Put the point set's dissipation Hessian Σ c_k Jᵀ(I - ûûᵀ)J / |u_k| at ``st`` in ``out``."""
    out[:, :] = 0.0
    for k in range(npt):
        rx = pts[k, PT_X] - st[0]
        ry = pts[k, PT_Y] - st[1]
        ux = st[3] - st[5] * ry - pts[k, PT_VX]
        uy = st[4] + st[5] * rx - pts[k, PT_VY]
        sp = max(math.sqrt(ux * ux + uy * uy), 1e-12)
        add_slip_curvature(out, pts[k, PT_C], ux, uy, sp, rx, ry)
    out[1, 0] = out[0, 1]
    out[2, 0] = out[0, 2]
    out[2, 1] = out[1, 2]


# inlined: a call would count references to the point set and the other arrays at every
# evaluation, a tenth of an exact step's cost
@kernel_step
def _step_wrenches(exact, st, skip, need, contact, npt, pts, loads):
    """
    Every surface's kinetic wrench at the twist in ``st`` (``skip`` left out) into ``kin``.

    The exact wrench (``evaluate_surfaces``; with ``need`` also the static limits and
    areas) or the step's point set (whose limits and areas come with it).
    """
    kin, stat, area, slip = loads.kin, loads.stat, loads.area, loads.slip
    if exact:
        # (evaluate_surfaces clears the limits it is not asked for: keep them)
        lim = stat if need else np.empty((0, 2))
        evaluate_surfaces(st, contact, skip, need, kin, lim, area, slip)
    else:
        _points_wrench(st, npt, pts, skip, kin)


@kernel
def _solve_spd(H, grad, nvar):
    """-H⁻¹ grad for the 2x2 or 3x3 symmetric positive-definite Newton system (Cramer)."""
    out = np.zeros(3)
    if nvar == 2:
        det = H[0, 0] * H[1, 1] - H[0, 1] * H[1, 0]
        out[0] = -(H[1, 1] * grad[0] - H[0, 1] * grad[1]) / det
        out[1] = -(H[0, 0] * grad[1] - H[1, 0] * grad[0]) / det
        return out
    c00 = H[1, 1] * H[2, 2] - H[1, 2] * H[2, 1]
    c01 = H[1, 2] * H[2, 0] - H[1, 0] * H[2, 2]
    c02 = H[1, 0] * H[2, 1] - H[1, 1] * H[2, 0]
    det = H[0, 0] * c00 + H[0, 1] * c01 + H[0, 2] * c02
    c11 = H[0, 0] * H[2, 2] - H[0, 2] * H[2, 0]
    c12 = H[0, 1] * H[2, 0] - H[0, 0] * H[2, 1]
    c22 = H[0, 0] * H[1, 1] - H[0, 1] * H[1, 0]
    # H symmetric: the adjugate is symmetric too
    out[0] = -(c00 * grad[0] + c01 * grad[1] + c02 * grad[2]) / det
    out[1] = -(c01 * grad[0] + c11 * grad[1] + c12 * grad[2]) / det
    out[2] = -(c02 * grad[0] + c12 * grad[1] + c22 * grad[2]) / det
    return out


@kernel
def _ratio(load, limit):
    """Return load / limit, where a zero limit holds a zero load only."""
    if limit > 0.0:
        return load / limit
    return 0.0 if load == 0.0 else math.inf


@kernel
def _stick_load(y, contact, s, rfx, rfy, rt, stat, xi, clip):
    """
    How far the wrench (rfx, rfy, rt) that surface ``s`` must supply loads its stick.

    At most 1 (within STICK_RTOL) iff the stick holds: the wrench lies in the patch's
    limit set (exact stick, ``limit_gauge``: the value is the gauge) or within the
    seed's decoupled force and moment limits ``stat[s]`` (seed stick; also without
    rotation, where φ̇ = 0 is a constraint). Above 1 it is the larger of the decoupled
    ratios, or the gauge where those hold. The gauge's Newton solve runs only where
    ``inside_limit_set`` cannot tell the wrench is inside.
    """
    strips, parcel = contact.strips, contact.parcel
    rot = parcel[P_ROTATION] > 0.5
    tol = 1.0 + STICK_RTOL
    load = _ratio(math.hypot(rfx, rfy), stat[s, 0] * tol)
    if rot:
        load = max(load, _ratio(abs(rt), stat[s, 1] * tol))
    # the decoupled limits are necessary for the limit set too (|F| <= μN, and |T|
    # about g at most the pure spin's): the gauge runs only where they hold
    if load <= 1.0 and rot and parcel[P_STICK] > 0.5:
        if not inside_limit_set(y, strips, parcel, s, rfx, rfy, rt):
            gamma = limit_gauge(y, contact, s, rfx, rfy, rt, xi, clip)
            load = gamma / tol
    return load


@kernel
def _implicit_objective(W, W0, mass, h, kin, nsurf, strips, rot, grad):
    """
    f(W) = ½ (W-W0)ᵀM(W-W0)/h + Σ_s D_s(W) and its gradient, from the surfaces' wrenches at W.

    With a constant μ each D_s is 1-homogeneous in the twist ξ_s = W - W_s relative to
    surface s (moments about g), so D_s = -ξ_s·wrench_s (Euler's relation) and the
    gradient of D is minus the wrench: no integral of its own.
    """
    f = 0.0
    for i in range(3):
        grad[i] = mass[i] * (W[i] - W0[i]) / h
        f += 0.5 * mass[i] * (W[i] - W0[i]) ** 2 / h
    for s in range(nsurf):
        vsx, vsy = surface_velocity(strips, s)
        f -= (W[0] - vsx) * kin[s, 0] + (W[1] - vsy) * kin[s, 1] + W[2] * kin[s, 2]
        grad[0] -= kin[s, 0]
        grad[1] -= kin[s, 1]
        grad[2] -= kin[s, 2]
    if not rot:
        grad[2] = 0.0
    return f


@kernel
def _scaled(ratio, x):
    """Return ratio · x for x >= 0, with 0 for x = 0 even where ratio is inf."""
    return ratio * x if x > 0.0 else 0.0


@kernel
def _bfgs_update(hess, sv, yv, nvar, hs):
    """
    BFGS update of ``hess`` (its leading nvar x nvar block) by the secant pair (sv, yv).

    Skipped where the pair's curvature sv·yv is not clearly positive (a convex
    function's never is negative; zero at rounding), so the matrix stays positive
    semidefinite. ``hs``: scratch (3).
    """
    sy = 0.0
    shs = 0.0
    ss = 0.0
    yy = 0.0
    for i in range(nvar):
        hs[i] = 0.0
        for j in range(nvar):
            hs[i] += hess[i, j] * sv[j]
        sy += sv[i] * yv[i]
        shs += sv[i] * hs[i]
        ss += sv[i] * sv[i]
        yy += yv[i] * yv[i]
    if sy > 1e-12 * math.sqrt(ss * yy):
        for i in range(nvar):
            for j in range(nvar):
                hess[i, j] += yv[i] * yv[j] / sy
                if shs > 0.0:
                    hess[i, j] -= hs[i] * hs[j] / shs


@kernel
def _set_twist(state, w):
    """Put the twist w = (ẋ, ẏ, φ̇) into ``state``'s velocities."""
    state[3] = w[0]
    state[4] = w[1]
    state[5] = w[2]


@kernel
def _stuck_step(y, h, vsx, vsy, y_out):
    """Take a step stuck to a surface moving at (vsx, vsy): rigid translation with it."""
    y_out[0] = y[0] + h * vsx
    y_out[1] = y[1] + h * vsy
    y_out[2] = y[2]
    y_out[3] = vsx
    y_out[4] = vsy
    y_out[5] = 0.0


@kernel
def _stick_test(y, h, mode, contact, exact, points, xis, twist, loads, scratch):
    """
    Test the implicit step for a stick: the surface it stays on, or -1 and a Newton start W.

    Stuck to a surface s, the step's momentum balance M (v_s - W0)/h = W_s + Σ_o W_o
    (o the other surfaces) needs the wrench W_s within its patch's limit set
    (``_stick_load`` <= 1). Tested first on the surface stuck to, then on any other
    the step could bring to rest (the change of momentum within its static limits and
    the most the others can pull, ``pull``). Where a stick fails off a kink, the
    Newton start W moves to about where the surplus takes the parcel in one step.
    ``points`` is (npt, pts, clip): the step's point set and a footprint scratch;
    ``twist`` is (W, W0, mass); ``loads`` holds the wrenches at W (updated);
    ``scratch`` is (st, others, pull): a state, the other surfaces' wrenches and each
    surface's most pull.

    Returns
    -------
    (int, int)
        The surface stuck to (-1: none) and the friction evaluations taken.

    """
    npt, pts, clip = points
    W, W0, mass = twist
    st, others, pull = scratch
    kin, stat, area, slip = loads.kin, loads.stat, loads.area, loads.slip
    strips = contact.strips
    m = mass[0]
    rot = contact.parcel[P_ROTATION] > 0.5
    nsurf = xis.shape[0]
    n_eval = 0
    pull_f = 0.0
    pull_t = 0.0
    for s in range(nsurf):
        pull_f += pull[s, 0]
        pull_t += pull[s, 1]
    # --- stick: first the surface stuck to, then any other the step could bring to rest
    for s in range(-1, nsurf):
        cand = mode if s < 0 else s
        if cand < 0 or (s >= 0 and s == mode) or area[cand] <= 0.0:
            continue
        vsx, vsy = surface_velocity(strips, cand)
        dfx = m * (vsx - W0[0]) / h
        dfy = m * (vsy - W0[1]) / h
        dt_ = -mass[2] * W0[2] / h
        if cand != mode:
            # necessary: the change of momentum to rest on cand within cand's static
            # limits and the most the others can pull
            reach_f = stat[cand, 0] + pull_f - pull[cand, 0]
            reach_t = stat[cand, 1] + pull_t - pull[cand, 1]
            if math.hypot(dfx, dfy) > reach_f * (1.0 + 1e-9) or (
                rot and abs(dt_) > reach_t * (1.0 + 1e-9)
            ):
                continue
            st[3] = vsx
            st[4] = vsy
            st[5] = 0.0
            _step_wrenches(
                exact,
                st,
                cand,
                False,
                contact,
                npt,
                pts,
                Loads(others, stat, area, slip),
            )
            n_eval += 1
            src = others
        else:
            src = kin
        wfx = dfx
        wfy = dfy
        wt = dt_
        for o in range(nsurf):
            if o != cand:
                wfx -= src[o, 0]
                wfy -= src[o, 1]
                wt -= src[o, 2]
        load = _stick_load(y, contact, cand, wfx, wfy, wt, stat, xis[cand], clip)
        if load <= 1.0:
            return cand, n_eval
        # no stick: the surplus the patch cannot hold moves the parcel off its velocity
        # by about b in one step. A start within 1 % of that from the velocity sits on
        # the kink of its friction (just stuck, or a slip just broken away), where
        # Newton's steps shrink to nothing: start at b instead (Newton and its line
        # search take it from there).
        excess = 1.0 - 1.0 / load if load < math.inf else 1.0
        bx = -excess * h * wfx / m
        by = -excess * h * wfy / m
        bt = -excess * h * wt / mass[2] if rot else 0.0
        off = m * ((W[0] - vsx) ** 2 + (W[1] - vsy) ** 2) + mass[2] * W[2] ** 2
        if cand == mode or off < 1e-4 * (m * (bx * bx + by * by) + mass[2] * bt * bt):
            W[0] = vsx + bx
            W[1] = vsy + by
            W[2] = bt
            _set_twist(st, W)
            _step_wrenches(
                exact,
                st,
                -1,
                False,
                contact,
                npt,
                pts,
                Loads(kin, stat, area, slip),
            )
            n_eval += 1
    return -1, n_eval


@kernel
def _newton_slide(twist, h, contact, exact, fresh, model, st, loads, f_all):
    """
    Newton on the step's objective f(W) = ½ (W-W0)ᵀM(W-W0)/h + D(W), from W (updated).

    A backtracking (Armijo) line search on f, or on the gradient where the gain is
    below f's rounding; stops where the (M/h)-strong convexity bound h |∇f|_M⁻¹ falls
    below SOLVE_RATIO of how far W has moved, or the gradient reaches the wrenches'
    rounding (``f_all`` the static limits' sum). ``twist`` is (W, W0, mass); ``model``
    is (npt, pts, hess), hess the Hessian model of D: the point set's own, or for the
    exact wrench a BFGS-updated model refreshed where ``fresh`` or where it misled a
    step. ``loads`` and ``st`` are scratch.

    Returns
    -------
    int
        The friction evaluations taken.

    """
    W, W0, mass = twist
    npt, pts, hess = model
    kin = loads.kin
    strips, parcel = contact.strips, contact.parcel
    m = mass[0]
    rot = parcel[P_ROTATION] > 0.5
    nvar = 3 if rot else 2
    nsurf = kin.shape[0]
    n_eval = 0
    grad = np.empty(3)
    gt = np.empty(3)
    Wt = np.empty(3)
    H = np.empty((3, 3))
    _set_twist(st, W)
    if exact and fresh:
        dissipation_hessian(st, strips, parcel, hess)
    fval = _implicit_objective(W, W0, mass, h, kin, nsurf, strips, rot, grad)
    # f is (M/h)-strongly convex: |W - W+|_M <= h |grad|_M⁻¹ whatever the Hessian
    # model. The solve stops where that bound falls below SOLVE_RATIO of how far W has
    # moved from its start (from a guess: about the step's local error), or the
    # gradient reaches the wrenches' rounding. Not relative to the first gradient: a
    # start at a kink (a slip just broken away) has the whole jump of a surface's
    # friction in it. Not on f's rounding: at small h the velocity errors a gain below
    # it leaves add up over the many steps.
    g_round = 1e-12 * f_all / math.sqrt(m)
    w_start = W.copy()
    sv = np.empty(3)
    yv = np.empty(3)
    hs = np.empty(3)
    for _ in range(60):
        gnorm = 0.0
        moved = 0.0
        for i in range(nvar):
            gnorm += grad[i] ** 2 / mass[i]
            moved += mass[i] * (W[i] - w_start[i]) ** 2
        gnorm = math.sqrt(gnorm)
        moved = math.sqrt(moved)
        if not exact:
            _set_twist(st, W)
            _points_hessian(st, npt, pts, hess)
        for i in range(3):
            for j in range(3):
                H[i, j] = hess[i, j]
            H[i, i] += mass[i] / h
        dW = _solve_spd(H, grad, nvar)
        if h * gnorm <= SOLVE_RATIO * moved or gnorm <= g_round:
            # the model's Newton step costs nothing, and as H >= M/h it moves W by at
            # most the bound that was just accepted
            for i in range(nvar):
                W[i] += dW[i]
            break
        f_noise = F_NOISE * abs(fval)
        slope = grad[0] * dW[0] + grad[1] * dW[1] + grad[2] * dW[2]
        step = 1.0
        ok = False
        ft = fval
        for _ls in range(30):
            for i in range(3):
                Wt[i] = W[i] + step * dW[i]
            _set_twist(st, Wt)
            _step_wrenches(exact, st, -1, False, contact, npt, pts, loads)
            n_eval += 1
            ft = _implicit_objective(Wt, W0, mass, h, kin, nsurf, strips, rot, gt)
            if -step * slope > f_noise:
                ok = ft <= fval + 1e-4 * step * slope
            else:
                # a gain below f's rounding (small steps h): the gradient decides
                gt_norm = 0.0
                for i in range(nvar):
                    gt_norm += gt[i] ** 2 / mass[i]
                ok = math.sqrt(gt_norm) <= (1.0 - 0.5 * step) * gnorm
            if ok:
                break
            step *= 0.5
        if not ok:
            if fresh:
                break  # no descent left at rounding level
            # the carried model misled the step: start again from a fresh one
            _set_twist(st, W)
            dissipation_hessian(st, strips, parcel, hess)
            fresh = True
            continue
        if exact:
            # D's part of the accepted step's secant pair
            for i in range(nvar):
                sv[i] = Wt[i] - W[i]
                yv[i] = gt[i] - grad[i] - mass[i] * sv[i] / h
            _bfgs_update(hess, sv, yv, nvar, hs)
        for i in range(3):
            W[i] = Wt[i]
            grad[i] = gt[i]
        fval = ft
    return n_eval


@kernel
def implicit_step(
    y,
    h,
    mode,
    contact,
    exact,
    mu_ratio,
    carry,
    fresh,
    y_out,
):
    """
    One backward-Euler velocity step; returns (mode, friction evaluations).

    W+ minimises f(W) = ½ (W-W0)ᵀM(W-W0)/h + D(W), D the footprint's dissipation rate
    at the step's pose. With constant μ everywhere (``exact``) D and its gradient come
    from the exact wrench (``evaluate_surfaces``), so the method has no quadrature
    floor; otherwise from the point set of ``_build_points`` (``pts``, μ lagged). Both
    ways each D_s is 1-homogeneous in the twist relative to its surface, so
    ``_implicit_objective`` has f from the wrenches alone.

    A stick is tested first (``_stick_load``): on the surface stuck to, then on any
    other the step could bring to rest (the change of momentum within all the limits:
    the others' pull bounded by ``mu_ratio`` times their static limits, or by the
    point set's own sums); a parcel riding a surface alone under it needs no more
    than a clip. Then Newton on f from ``guess`` (the caller's prediction of W+,
    about the step's local error off), moved off the kink of a surface that does not
    hold where it sits on one, with a backtracking line search. Its Hessian: the
    point set's own, exactly, or for the exact wrench a model (``dissipation_hessian``,
    where ``fresh``) that BFGS updates carry from step to step in ``hess`` (3 x 3):
    about 1.5 wrench evaluations a step on Fig. 9a. ``xis`` (nsurf x
    GAUGE_CARRY): each surface's limit-set gauge twist and Newton metric, carried from
    step to step.

    Parameters
    ----------
    y : ndarray, shape (6,)
        The state (``layout``).
    h : float
        The step [s].
    mode : int
        The mode: MODE_SLIDE, or the surface stuck to.
    contact : Contact
        What the parcel slides on (``layout.Contact``).
    exact : bool
        Constant μ: the exact wrench; else the lagged point set.
    mu_ratio : ndarray
        Each surface's μ_k/μ_s, lagged one step.
    carry : Carry
        What a step carries to the next (point set, guess, metric, gauge twists).
    fresh : bool
        Recompute the point set.
    y_out : ndarray, shape (6,)
        Receives the state after the step.

    Returns
    -------
    (int, int)
        The mode after the step and the friction evaluations it took.

    """
    pts, guess, hess, xis = carry.pts, carry.guess, carry.hess, carry.xis
    strips, parcel = contact.strips, contact.parcel
    m = parcel[P_MASS]
    rot = parcel[P_ROTATION] > 0.5
    nsurf = xis.shape[0]
    mass = np.array([m, m, parcel[P_INERTIA] if rot else 1.0])
    W0 = np.array([y[3], y[4], y[5] if rot else 0.0])
    kin = np.empty((nsurf, 3))
    others = np.empty((nsurf, 3))
    stat = np.empty((nsurf, 2))
    pull = np.empty((nsurf, 2))
    area = np.empty(nsurf)
    slip = np.empty(nsurf)
    clip = clip_scratch()
    if mode >= 0:
        vsx, vsy = surface_velocity(strips, mode)
        # riding a surface alone under the parcel: it must supply no wrench at all,
        # which every limit set holds (the clip alone tells)
        if (
            W0[0] == vsx
            and W0[1] == vsy
            and W0[2] == 0.0
            and _alone_on(y, strips, parcel, clip, mode, area)
        ):
            _stuck_step(y, h, vsx, vsy, y_out)
            return mode, 0
    st = y.copy()
    npt = 0 if exact else _build_points(y, contact, pts, stat, pull, area)
    # the Newton start and the wrenches there: the guess, or while stuck the surface's
    # velocity (the stuck surface's own wrench left out: zero slip, and the stick test
    # needs the others' alone)
    W = np.empty(3)
    if mode >= 0:
        W[0], W[1] = surface_velocity(strips, mode)
        W[2] = 0.0
    else:
        for i in range(3):
            W[i] = guess[i]
        if not rot:
            W[2] = 0.0
    _set_twist(st, W)
    loads = Loads(kin, stat, area, slip)
    _step_wrenches(exact, st, mode, True, contact, npt, pts, loads)
    n_eval = 1
    if exact:
        for s in range(nsurf):
            pull[s, 0] = _scaled(mu_ratio, stat[s, 0])
            pull[s, 1] = _scaled(mu_ratio, stat[s, 1])
    f_all = 0.0
    for s in range(nsurf):
        f_all += stat[s, 0]
    # --- stick: first the surface stuck to, then any other the step could bring to rest
    twist = (W, W0, mass)
    stuck, n_stick = _stick_test(
        y, h, mode, contact, exact, (npt, pts, clip), xis, twist, loads, (st, others, pull)
    )
    n_eval += n_stick
    if stuck >= 0:
        vsx, vsy = surface_velocity(strips, stuck)
        _stuck_step(y, h, vsx, vsy, y_out)
        return stuck, n_eval
    # --- slide: Newton on f with a backtracking line search
    fresh = fresh or mode >= 0 or not exact  # the point set's Hessian is exact anyway
    n_eval += _newton_slide(twist, h, contact, exact, fresh, (npt, pts, hess), st, loads, f_all)
    y_out[3] = W[0]
    y_out[4] = W[1]
    y_out[5] = W[2] if rot else 0.0
    y_out[0] = y[0] + h * y_out[3]
    y_out[1] = y[1] + h * y_out[4]
    y_out[2] = y[2] + h * y_out[5]
    return MODE_SLIDE, n_eval


@kernel
def _constant_friction(strips):
    """
    (every loaded strip has a constant μ, the largest μ_k / μ_s among them).

    The ratio is inf where a strip holds nothing at rest but rubs while sliding.
    """
    constant = True
    ratio = 1.0
    for k in range(strips.shape[0]):
        if strips[k, S_WEIGHT] <= 0.0:
            continue
        law = int(strips[k, S_LAW])
        if not law_is_constant(law):
            constant = False
            continue
        params = strips[k, S_PARAMS:]
        mus = mu_static(law, params)
        muk = mu_kinetic(law, params, 1.0)
        if mus > 0.0:
            ratio = max(ratio, muk / mus)
        elif muk > 0.0:
            ratio = math.inf
    return constant, ratio


@kernel
def crossing_substeps(y, h, strips, parcel):
    """
    Return how many equal sub-steps a step h from ``y`` takes near a zone border.

    1 unless a strip border lies within the footprint's x-extent widened by the most a
    corner can move in the step (|ẋ| + |φ̇| r, r the half diagonal); then enough that
    the footprint's x-extent is passed in at least CROSSING_STEPS steps. Far from the
    borders, or where the step is already that fine, the step is taken whole.
    """
    half_a = parcel[P_HALF_A]
    half_b = parcel[P_HALF_B]
    c = abs(math.cos(y[2]))
    s = abs(math.sin(y[2]))
    half_ext = half_a * c + half_b * s
    speed = abs(y[3]) + abs(y[5]) * math.sqrt(half_a * half_a + half_b * half_b)
    reach = speed * h
    if reach <= 0.0:
        return 1
    lo = y[0] - half_ext - reach
    hi = y[0] + half_ext + reach
    near = False
    for k in range(strips.shape[0]):
        for edge in (strips[k, S_XLO], strips[k, S_XHI]):
            if lo < edge < hi:
                near = True
    if not near:
        return 1
    n = math.ceil(CROSSING_STEPS * reach / (2.0 * half_ext))
    return int(min(max(n, 1), MAX_SUBSTEPS))


@allocating
def run_implicit(y0, mode0, t0, t_end, y_target, contact, h, trail, log):
    """
    Integrate at a fixed step by backward Euler in velocity (``implicit_step``).

    A step near a zone border is split into equal sub-steps (``crossing_substeps``) so
    that a border's passage under the footprint takes at least CROSSING_STEPS of them:
    a small fast parcel that one step would carry from one zone into the next keeps
    the turn the zones' different frictions give it while it straddles the border.
    The trail still records one state per step h.

    Parameters
    ----------
    y0 : ndarray, shape (6,)
        The start.
    mode0 : int
        The start's mode.
    t0, t_end : float
        The span [s].
    y_target : float
        The scrap line [m], located inside a step by linear interpolation.
    contact : Contact
        What the parcel slides on.
    h : float
        The step [s].
    trail : Trail
        Receives a record per step.
    log : Log
        Receives the events and the counters.

    Returns
    -------
    (int, float, int)
        The status, the time reached and the mode there.

    """
    ev, counters = log.ev, log.counters
    ts = trail.ts
    strips, nodes = contact.strips, contact.nodes
    nsurf = n_surf_of(strips)
    # constant μ everywhere: the exact step (no point set); its bound on the others' pull
    exact, mu_ratio = _constant_friction(strips)
    cap = 1 if exact else 4 * nodes.shape[0] * nodes.shape[0] * MAX_VERTS * strips.shape[0] + 1
    pts = np.empty((cap, 6))
    xis = np.zeros((nsurf, GAUGE_CARRY))
    guess = np.empty(3)
    w_last = np.empty(3)
    h_last = 0.0
    hess = np.zeros((3, 3))
    y = y0.copy()
    y_new = np.empty(6)
    t = t0
    mode = mode0
    n_out = _record(trail, 0, t, y, mode)
    n_ev = 0
    n_steps = 0
    n_rhs = 0
    status = ST_END
    # step times as t0 + i h, so round-off never adds a sliver of a last step
    n_total = max(1, int(math.ceil((t_end - t0) / h - 1e-9)))
    for i_step in range(n_total):
        t_next = t_end if i_step == n_total - 1 else t0 + (i_step + 1) * h
        n_sub = crossing_substeps(y, t_next - t, strips, contact.parcel)
        t_step0 = t
        for i_sub in range(n_sub):
            t_sub = (
                t_next
                if i_sub == n_sub - 1
                else t_step0 + (i_sub + 1) * (t_next - t_step0) / n_sub
            )
            hh = t_sub - t
            # W+ predicted by the last step's change of velocity, where it slid throughout
            for i in range(3):
                guess[i] = y[3 + i]
                if mode < 0 and h_last > 0.0:
                    guess[i] += (y[3 + i] - w_last[i]) * (hh / h_last)
                w_last[i] = y[3 + i]
            new_mode, its = implicit_step(
                y,
                hh,
                mode,
                contact,
                exact,
                mu_ratio,
                Carry(pts, guess, hess, xis),
                h_last == 0.0,
                y_new,
            )
            h_last = hh if new_mode < 0 else 0.0
            n_rhs += its
            n_steps += 1
            if new_mode != mode:
                n_ev = _log_event(
                    ev,
                    n_ev,
                    t + hh,
                    EV_STICK if new_mode >= 0 else EV_BREAK,
                    new_mode if new_mode >= 0 else mode,
                )
            if not np.all(np.isfinite(y_new)):
                status = ST_NONFINITE
                break
            mode = new_mode
            t, crossed = _take_fixed_step(y, y_new, t, t_sub, y_target)
            if crossed:
                status = ST_TARGET
                break
        if status == ST_NONFINITE:
            break
        n_out = _record(trail, n_out, t, y, mode)
        if status == ST_TARGET:
            n_ev = _log_event(ev, n_ev, t, EV_TARGET, -1)
            break
        if n_out >= ts.shape[0]:
            status = ST_MAX_STEPS
            break
    counters[N_STEPS] = n_steps
    counters[N_RHS] = n_rhs
    counters[N_REJECTED] = 0  # a fixed step is never rejected
    counters[N_OUT] = n_out
    counters[N_EVENTS] = n_ev
    return status, t, mode
