"""
Newton's method for the minimum of a smooth function of a twist, in a 2-D tangent plane.

Two solves of the stick law are this one problem: the limit set's gauge (``stick``)
minimises the patch's dissipation D(ξ) on the plane W·ξ = 1, and the pull direction
after a break (``layer``) maximises W_o·σ - D_k(σ) on the unit sphere of slips. Both
objectives have an exact gradient (the closed-form or quadrature wrench) and no cheap
Hessian, so both take Newton steps in a 2-D tangent basis (p, q) with the Hessian
differenced forward from the exact gradient, and a backtracking line search. The
Hessian is only Newton's metric (the minimiser is where the exact gradient vanishes):
it is carried from solve to solve (``metric``), a solve next to the last one starting
without differences, and differenced anew wherever a step with it backtracks or fails
to cut the gradient tenfold.

``make_plane_newton(objective, sphere)`` compiles the solver for an objective
``objective(z, ctx, g) -> value`` (fills the ambient gradient ``g``; it must allocate
nothing, as ``jit.borrowing`` kernels do; a maximisation
returns the negated function and gradient). ``sphere`` False: the affine plane through
the start with normal ``normal`` (z moves along p, q ⊥ normal); True: the unit sphere
(the basis is rebuilt at each z, a step is retracted onto the sphere, and the Hessian
is the Riemannian one: the ambient Hessian less the radial derivative), on its great
circle in (x, y) where ``planar``.
"""

from __future__ import annotations

import math

from sorter_sim.model.core.jit import borrowing, kernel

NEWTON_ITERATIONS = 60
LINE_SEARCH_HALVINGS = 40
ARMIJO = 1e-4  # sufficient decrease, relative to the step's predicted one
HESSIAN_STEP = 1e-5  # the forward difference's step, relative to |z|
METRIC_REFRESH = 0.1  # a carried metric serves while each step cuts the gradient this much
DEFINITE = 1e-12  # a 2 x 2 metric with det below this x h00 h11 is not definite
# the gradient's quadrature is exact to ~1e-10 of the wrenches it sums (its point sets move
# with the pose): a reduced gradient below this share of its scale is the minimum
CONVERGED = 1e-9
ROUNDING = 1e-15  # a predicted decrease or a move below this (relative) is rounding


@kernel
def _basis(z, normal, sphere, planar, p, q):
    """Fill an orthonormal basis (p, q) of the tangent plane; return the axis it is built on."""
    n = z if sphere else normal
    k = 0
    for i in range(1, 3):
        if abs(n[i]) < abs(n[k]):
            k = i
    n2 = n[0] * n[0] + n[1] * n[1] + n[2] * n[2]
    nn = math.sqrt(n2)
    dot = n[k] / n2
    for i in range(3):
        p[i] = (1.0 if i == k else 0.0) - dot * n[i]
    if planar:
        p[0] = -n[1]
        p[1] = n[0]
        p[2] = 0.0
    pn = math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
    for i in range(3):
        p[i] /= pn
    q[0] = (n[1] * p[2] - n[2] * p[1]) / nn
    q[1] = (n[2] * p[0] - n[0] * p[2]) / nn
    q[2] = (n[0] * p[1] - n[1] * p[0]) / nn
    return k


def make_plane_newton(objective, sphere):  # noqa: PLR0915 — its statements are the solver's below
    """
    Compile Newton's method in a tangent plane for ``objective``.

    Parameters
    ----------
    objective : numba function
        ``objective(z, ctx, g) -> value``: the function at the twist ``z`` (3,), its
        ambient gradient written to ``g`` (3,).
    sphere : bool
        False: minimise on the affine plane through the start with normal ``normal``;
        True: on the unit sphere (``normal`` unused).

    Returns
    -------
    numba function
        ``solve(z, ctx, normal, planar, scale_floor, metric, f, g, work) -> value``. ``z``
        (in: the start, on the plane or the sphere; out: the minimiser), ``f`` and ``g``
        (in: the objective and its gradient at the start, which the caller has evaluated
        to choose the start; out, ``g``: the gradient at the minimiser), ``planar``
        (sphere only: stay on the great circle of the (x, y) plane, a 1-D problem),
        ``scale_floor`` (a floor under the gradient's scale, which
        convergence is measured against), ``metric`` (4, in/out: [axis + 1 (0: none),
        h00, h01, h11] x |z|, the carried Hessian in the basis built on that axis),
        ``work`` (4, 3): scratch. Returns the minimum. A non-positive-definite metric
        (rounding near a kink) gives a gradient step of Newton's scale instead.

    Notes
    -----
    The solver is compiled without numba's runtime (``jit.borrowing``): it allocates
    nothing (the caller's ``work`` holds its vectors), so no call of it, or of the
    objective, counts references to the arrays it is handed, which a solve next to the
    last one would spend a third of its time on.

    """

    @borrowing
    def solve(z, ctx, normal, planar, scale_floor, metric, f, g, work):  # noqa: PLR0912, PLR0915 — one Newton iteration read as one loop
        gp = work[0]
        zt = work[1]
        p = work[2]
        q = work[3]
        ndim = 1 if planar else 2
        # the plane's basis is fixed; the sphere's is built at each z
        k = 0 if sphere else _basis(z, normal, sphere, planar, p, q)
        gn_last = math.inf
        carried = False
        for _ in range(NEWTON_ITERATIONS):
            if sphere:
                k = _basis(z, normal, sphere, planar, p, q)
            zn = math.sqrt(z[0] * z[0] + z[1] * z[1] + z[2] * z[2])
            g0 = g[0] * p[0] + g[1] * p[1] + g[2] * p[2]
            g1 = (g[0] * q[0] + g[1] * q[1] + g[2] * q[2]) if ndim == 2 else 0.0
            radial = (g[0] * z[0] + g[1] * z[1] + g[2] * z[2]) / zn
            scale = max(math.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]), scale_floor)
            gn = math.hypot(g0, g1)
            if gn <= CONVERGED * scale:
                break
            if carried and gn > METRIC_REFRESH * gn_last:
                metric[0] = 0.0  # the carried metric no longer converges fast: difference
            gn_last = gn
            carried = metric[0] == k + 1.0
            if carried:
                h00 = metric[1] / zn
                h01 = metric[2] / zn
                h11 = metric[3] / zn
            else:
                hstep = HESSIAN_STEP * zn
                h00 = 0.0
                h01 = 0.0
                h10 = 0.0
                h11 = 0.0
                for j in range(ndim):
                    # a forward difference of the exact gradient, at half the cost of a
                    # central one: the Hessian only shapes Newton's step
                    for i in range(3):
                        zt[i] = z[i] + hstep * (p[i] if j == 0 else q[i])
                    objective(zt, ctx, gp)
                    c0 = (gp[0] - g[0]) * p[0] + (gp[1] - g[1]) * p[1] + (gp[2] - g[2]) * p[2]
                    c1 = (gp[0] - g[0]) * q[0] + (gp[1] - g[1]) * q[1] + (gp[2] - g[2]) * q[2]
                    if j == 0:
                        h00 = c0 / hstep
                        h10 = c1 / hstep
                    else:
                        h01 = c0 / hstep
                        h11 = c1 / hstep
                h01 = 0.5 * (h01 + h10)
                metric[0] = k + 1.0
                metric[1] = h00 * zn
                metric[2] = h01 * zn
                metric[3] = h11 * zn
            if sphere:
                # the Riemannian Hessian: the ambient one less the radial derivative
                h00 -= radial
                h11 -= radial
            newton = False
            if ndim == 1:
                s1 = 0.0
                if h00 > 0.0:
                    s0 = -g0 / h00
                    newton = True
                else:
                    s0 = -g0 * zn / scale
            else:
                det = h00 * h11 - h01 * h01
                if h00 > 0.0 and h11 > 0.0 and det > DEFINITE * h00 * h11:
                    s0 = -(h11 * g0 - h01 * g1) / det
                    s1 = -(h00 * g1 - h01 * g0) / det
                    newton = True
                else:
                    # not positive definite (rounding near a kink): a gradient step of
                    # Newton's scale (the functions are 1-homogeneous: curvature ~ |g|/|z|)
                    s0 = -g0 * zn / scale
                    s1 = -g1 * zn / scale
            slope = g0 * s0 + g1 * s1
            if newton and -0.5 * slope <= ROUNDING * scale * zn:
                # Newton's predicted decrease is below the objective's rounding: no line
                # search can resolve the rest, and the value, stationary here, is exact
                # to second order
                break
            step = 1.0
            ft = f
            for _ls in range(LINE_SEARCH_HALVINGS):
                for i in range(3):
                    zt[i] = z[i] + step * (s0 * p[i] + s1 * q[i])
                if sphere:
                    tn = math.sqrt(zt[0] * zt[0] + zt[1] * zt[1] + zt[2] * zt[2])
                    for i in range(3):
                        zt[i] /= tn
                ft = objective(zt, ctx, gp)
                if ft <= f + ARMIJO * step * slope:
                    break
                step *= 0.5
            if carried and step < 1.0:
                metric[0] = 0.0
            if not ft <= f:
                break  # no descent left at rounding level: z is the minimiser
            moved = step * math.hypot(s0, s1)
            for i in range(3):
                z[i] = zt[i]
                g[i] = gp[i]
            f = ft
            if moved <= ROUNDING * zn:
                break
        return f

    return solve
