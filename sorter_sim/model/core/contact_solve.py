"""
The solve of parcels that touch: the contacts' impulses of one period, face by face.

``contact`` finds the contact points (broad and narrow phase) and moves the bodies
after the solve; this module finds the impulses: for every contact point the normal
impulse p_n >= 0 complementary to the normal velocity after the step, v_n+ =
-e min(v_n-, 0), and the friction impulse in the Coulomb cone |p_t| <= μ p_n,
opposing the tangential velocity where it is not zero.

Projected Gauss-Seidel over the *faces*: the two points of a face in contact (edge
on edge, the same two bodies) are one block, their two normal impulses solved
together as a 2x2 linear complementarity problem, exactly (the first of its four
cases that holds: both pressing, either alone, neither), then their two friction
impulses together (both sticking, if that lies in both cones; else each point's
clipped update). Solved point by point, the two points of a face hand a load back
and forth through the bodies' turn: on a chain of long parcels pressed against a
stopper that converges by a factor close to 1 per sweep (thousands of sweeps,
and an unsettled creep where the sweeps run out); solved as a block, a face's
turn is balanced in each sweep and a chain converges in a few sweeps.

Units: SI (m, s, rad, kg); impulses in N s.
"""

from __future__ import annotations

from sorter_sim.model.core.jit import borrowing, kernel_step
from sorter_sim.model.core.layout import P_INERTIA, P_MASS

# ---- a contact point: int row [a, b, feature], float row CF_* ----------------------
CF_PX = 0  # the point [m]
CF_PY = 1
CF_NX = 2  # the unit normal, from body a to body b
CF_NY = 3
CF_SEP = 4  # the separation along the normal (< 0: overlap) [m]
CF_MASS_N = 5  # effective masses along the normal and the tangent [kg]
CF_MASS_T = 6
CF_BIAS = 7  # the normal velocity the step aims at (restitution) [m/s]
CF_PN = 8  # the accumulated impulses [N s]
CF_PT = 9
CF_MU = 10  # the contact's friction coefficient
CF_VN0 = 11  # the normal velocity before the solve [m/s]
CF_NEW = 12  # 1 for a contact the last period did not have, else 0
CF_TO = 13  # an impact: how long before the period's end it touched [s]; else 0
CF_WIDTH = 14

# PGS stops when no impulse changes by more than PGS_TOL of the largest, or after
# PGS_MAX_SWEEPS sweeps; a face's block is solved as a block unless its matrix's
# determinant is below BLOCK_DET of the product of its diagonal (two points at one
# place: a face seen edge on)
PGS_TOL = 1e-13
PGS_MAX_SWEEPS = 20000
BLOCK_DET = 1e-9


# ---------------------------------------------------------------- solve
@kernel_step
def _inverse_mass(i, phase, par, ph_cell):
    """Return a body's inverse mass and moment of inertia (zero: an obstacle, a jammed parcel)."""
    if i < 0 or phase[i] != ph_cell:
        return 0.0, 0.0
    return 1.0 / par[i, P_MASS], 1.0 / par[i, P_INERTIA]


@kernel_step
def _point_velocity(i, state, px, py):
    """Return the velocity of body i's material point (px, py) (zero for an obstacle)."""
    if i < 0:
        return 0.0, 0.0
    return state[i, 3] - state[i, 5] * (py - state[i, 1]), state[i, 4] + state[i, 5] * (
        px - state[i, 0]
    )


@kernel_step
def _relative_velocity(a, b, state, cf):
    """Body b's velocity relative to a's at the contact point, along its normal and tangent."""
    px = cf[CF_PX]
    py = cf[CF_PY]
    vax, vay = _point_velocity(a, state, px, py)
    vbx, vby = _point_velocity(b, state, px, py)
    dvx = vbx - vax
    dvy = vby - vay
    nx = cf[CF_NX]
    ny = cf[CF_NY]
    return dvx * nx + dvy * ny, -dvx * ny + dvy * nx


@kernel_step
def _apply(i, sign, state, px, py, jx, jy, im, ii):
    """Add the impulse sign·(jx, jy) at (px, py) to body i's velocities (none: an obstacle)."""
    if im == 0.0:
        return
    state[i, 3] += sign * im * jx
    state[i, 4] += sign * im * jy
    rx = px - state[i, 0]
    ry = py - state[i, 1]
    state[i, 5] += sign * ii * (rx * jy - ry * jx)


@kernel_step
def _apply_pair(a, b, state, cf, jn, jt, masses):
    """Apply the normal and tangent impulses jn, jt (on b; -them on a) at contact ``cf``."""
    ima, iia, imb, iib = masses
    nx = cf[CF_NX]
    ny = cf[CF_NY]
    jx = jn * nx - jt * ny
    jy = jn * ny + jt * nx
    _apply(a, -1.0, state, cf[CF_PX], cf[CF_PY], jx, jy, ima, iia)
    if b >= 0:
        _apply(b, 1.0, state, cf[CF_PX], cf[CF_PY], jx, jy, imb, iib)


@kernel_step
def _effective_mass(a, b, state, cf, masses, dx, dy):
    """1 / (relative velocity along (dx, dy) per unit impulse along it) [kg]; 0: none moves."""
    ima, iia, imb, iib = masses
    k = ima + imb
    if a >= 0:
        ra = (cf[CF_PX] - state[a, 0]) * dy - (cf[CF_PY] - state[a, 1]) * dx
        k += iia * ra * ra
    if b >= 0:
        rb = (cf[CF_PX] - state[b, 0]) * dy - (cf[CF_PY] - state[b, 1]) * dx
        k += iib * rb * rb
    return 1.0 / k if k > 0.0 else 0.0


@kernel_step
def _masses(a, b, phase, par, ph_cell):
    ima, iia = _inverse_mass(a, phase, par, ph_cell)
    imb, iib = _inverse_mass(b, phase, par, ph_cell)
    return ima, iia, imb, iib


@kernel_step
def _coupling(a, b, state, cf1, cf2, masses, along_t):
    """
    Return a face block's off-diagonal [1/kg]: velocity at point 1 per unit impulse at point 2.

    Both along the normals (``along_t`` false) or both along the tangents.
    """
    ima, iia, imb, iib = masses
    if along_t:
        d1x, d1y, d2x, d2y = -cf1[CF_NY], cf1[CF_NX], -cf2[CF_NY], cf2[CF_NX]
    else:
        d1x, d1y, d2x, d2y = cf1[CF_NX], cf1[CF_NY], cf2[CF_NX], cf2[CF_NY]
    k = (ima + imb) * (d1x * d2x + d1y * d2y)
    if a >= 0:
        k += iia * _arm(state, a, cf1, d1x, d1y) * _arm(state, a, cf2, d2x, d2y)
    if b >= 0:
        k += iib * _arm(state, b, cf1, d1x, d1y) * _arm(state, b, cf2, d2x, d2y)
    return k


@kernel_step
def _arm(state, i, cf, dx, dy):
    """Return the lever arm of body i about a contact's point along (dx, dy): r x d [m]."""
    return (cf[CF_PX] - state[i, 0]) * dy - (cf[CF_PY] - state[i, 1]) * dx


@kernel_step
def _point_normal(a, b, state, cf, masses):
    """One point's normal update: p_n = max(0, p_n + m_n (bias - v_n)); returns the change."""
    vn, _ = _relative_velocity(a, b, state, cf)
    pn_old = cf[CF_PN]
    pn = max(0.0, pn_old + cf[CF_MASS_N] * (cf[CF_BIAS] - vn))
    if pn != pn_old:
        _apply_pair(a, b, state, cf, pn - pn_old, 0.0, masses)
        cf[CF_PN] = pn
    return abs(pn - pn_old)


@kernel_step
def _point_friction(a, b, state, cf, masses):
    """One point's friction update: p_t = clip(p_t - m_t v_t, ±μ p_n); returns the change."""
    _, vt = _relative_velocity(a, b, state, cf)
    pt_old = cf[CF_PT]
    bound = cf[CF_MU] * cf[CF_PN]
    pt = min(bound, max(-bound, pt_old - cf[CF_MASS_T] * vt))
    if pt != pt_old:
        _apply_pair(a, b, state, cf, 0.0, pt - pt_old, masses)
        cf[CF_PT] = pt
    return abs(pt - pt_old)


@kernel_step
def _set_face(a, b, state, cf1, cf2, masses, x1, x2, col):
    """Set a face's two impulses in column ``col`` (CF_PN, CF_PT) to x1, x2; return the change."""
    d1 = x1 - cf1[col]
    d2 = x2 - cf2[col]
    normal = col == CF_PN
    _apply_pair(a, b, state, cf1, d1 if normal else 0.0, 0.0 if normal else d1, masses)
    _apply_pair(a, b, state, cf2, d2 if normal else 0.0, 0.0 if normal else d2, masses)
    cf1[col] = x1
    cf2[col] = x2
    return max(abs(d1), abs(d2))


@kernel_step
def _face_block(a, b, state, cf1, cf2, masses, along_t):
    """
    Return a face's 2x2 block k11, k22, k12, its determinant and the two relative velocities.

    Along the normals, or the tangents (``along_t``). The determinant is 0 where the
    block is singular to BLOCK_DET (or a body does not move along it).
    """
    col = CF_MASS_T if along_t else CF_MASS_N
    if cf1[col] == 0.0 or cf2[col] == 0.0:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    k11 = 1.0 / cf1[col]
    k22 = 1.0 / cf2[col]
    k12 = _coupling(a, b, state, cf1, cf2, masses, along_t)
    det = k11 * k22 - k12 * k12
    if det <= BLOCK_DET * k11 * k22:
        det = 0.0
    vn1, vt1 = _relative_velocity(a, b, state, cf1)
    vn2, vt2 = _relative_velocity(a, b, state, cf2)
    if along_t:
        return k11, k22, k12, det, vt1, vt2
    return k11, k22, k12, det, vn1, vn2


@kernel_step
def _face_normal(a, b, state, cf1, cf2, masses):
    """
    Solve a face's two normal impulses together, exactly; return the larger change.

    With K the face's 2x2 block (relative normal velocity per unit normal impulse),
    r = bias - v_n and p the impulses so far, the new impulses x >= 0 leave
    w = K (x - p) - r >= 0 with x_i w_i = 0: both pressing (w = 0), point 1 alone
    (x_2 = 0, w_1 = 0, w_2 >= 0), point 2 alone, neither (x = 0, w >= 0); the first
    that holds. Returns -1 where none holds to rounding or the block is singular (a
    body that does not move, two points at one place): the caller then updates each
    point on its own, and the next sweep goes on from there.
    """
    k11, k22, k12, det, vn1, vn2 = _face_block(a, b, state, cf1, cf2, masses, False)
    if det == 0.0:
        return -1.0
    r1 = cf1[CF_BIAS] - vn1
    r2 = cf2[CF_BIAS] - vn2
    p1 = cf1[CF_PN]
    p2 = cf2[CF_PN]
    # both pressing
    x1 = p1 + (r1 * k22 - r2 * k12) / det
    x2 = p2 + (r2 * k11 - r1 * k12) / det
    if x1 >= 0.0 and x2 >= 0.0:
        return _set_face(a, b, state, cf1, cf2, masses, x1, x2, CF_PN)
    # point 1 alone, point 2 separating
    x1 = p1 + (r1 + k12 * p2) / k11
    if x1 >= 0.0 and k12 * (x1 - p1) - k22 * p2 - r2 >= 0.0:
        return _set_face(a, b, state, cf1, cf2, masses, x1, 0.0, CF_PN)
    # point 2 alone
    x2 = p2 + (r2 + k12 * p1) / k22
    if x2 >= 0.0 and k12 * (x2 - p2) - k11 * p1 - r1 >= 0.0:
        return _set_face(a, b, state, cf1, cf2, masses, 0.0, x2, CF_PN)
    # neither
    if -k11 * p1 - k12 * p2 - r1 >= 0.0 and -k12 * p1 - k22 * p2 - r2 >= 0.0:
        return _set_face(a, b, state, cf1, cf2, masses, 0.0, 0.0, CF_PN)
    return -1.0


@kernel_step
def _face_friction(a, b, state, cf1, cf2, masses):
    """
    Solve a face's two friction impulses together where both stick; return the larger change.

    Both sticking (zero tangential velocity at both points) is K_t (x - p) = -v_t; it
    holds if x lies in both cones. Returns -1 otherwise (a point slides: the caller
    updates each point on its own, clipped to its cone).
    """
    k11, k22, k12, det, vt1, vt2 = _face_block(a, b, state, cf1, cf2, masses, True)
    if det == 0.0:
        return -1.0
    x1 = cf1[CF_PT] + (-vt1 * k22 + vt2 * k12) / det
    x2 = cf2[CF_PT] + (-vt2 * k11 + vt1 * k12) / det
    if abs(x1) <= cf1[CF_MU] * cf1[CF_PN] and abs(x2) <= cf2[CF_MU] * cf2[CF_PN]:
        return _set_face(a, b, state, cf1, cf2, masses, x1, x2, CF_PT)
    return -1.0


@borrowing
def solve_velocities(state, phase, par, ph_cell, ct_i, ct_f, n_ct):
    """
    Projected Gauss-Seidel over the faces until no impulse changes by more than PGS_TOL.

    A face is two consecutive contacts of the same two bodies (the narrow phase gives
    a pair's points together); a single point (a corner on a face) is its own block.
    Forward and backward in turn (symmetric Gauss-Seidel): a chain's load runs its
    whole length in one pair of sweeps, whichever end holds it. Returns the sweeps made.

    A kernel of its own (not inlined into the cell's loop): the face's block solve is
    long, and the loop calls it once a period that has contacts.
    """
    for sweep in range(PGS_MAX_SWEEPS):
        biggest = 0.0
        change = 0.0
        q = 0
        while q < n_ct:
            if sweep % 2 == 0:
                c = q
                size = 2 if c + 1 < n_ct and _same_bodies(ct_i, c, c + 1) else 1
            else:
                c = n_ct - 1 - q
                size = 2 if c >= 1 and _same_bodies(ct_i, c - 1, c) else 1
                c -= size - 1
            a = ct_i[c, 0]
            b = ct_i[c, 1]
            masses = _masses(a, b, phase, par, ph_cell)
            dn = _solve_block(a, b, state, ct_f, c, size, masses, False)
            dt = _solve_block(a, b, state, ct_f, c, size, masses, True)
            for k in range(size):
                cf = ct_f[c + k]
                biggest = max(biggest, cf[CF_PN], abs(cf[CF_PT]))
            change = max(change, dn, dt)
            q += size
        if change <= PGS_TOL * biggest:
            return sweep + 1
    return PGS_MAX_SWEEPS


@kernel_step
def _solve_block(a, b, state, ct_f, c, size, masses, friction):
    """
    Update a block's normal impulses (or its friction's): a face as one, else point by point.

    The block is the contacts c .. c + size - 1; returns the largest change.
    """
    d = -1.0
    if size == 2:
        if friction:
            d = _face_friction(a, b, state, ct_f[c], ct_f[c + 1], masses)
        else:
            d = _face_normal(a, b, state, ct_f[c], ct_f[c + 1], masses)
    if d < 0.0:
        for k in range(size):
            if friction:
                d = max(d, _point_friction(a, b, state, ct_f[c + k], masses))
            else:
                d = max(d, _point_normal(a, b, state, ct_f[c + k], masses))
    return d


@kernel_step
def _same_bodies(ct_i, c, d):
    """Return whether contacts c and d are between the same two bodies (a face's two points)."""
    return ct_i[c, 0] == ct_i[d, 0] and ct_i[c, 1] == ct_i[d, 1]
