"""
Parcels that touch (``contact: rigid``): the contact step against closed forms and invariants.

Every case runs the cell's own period loop (the seed's floor friction under each
footprint, the accurate method) with the contact step at each period's end. The belt
law is const1 (μ independent of the slip), so a parcel translating over the belt
feels the floor force μ m g against its slip, wherever the contacts hold it.
Each test fails under the old rule (``contact: jam``: a touch stops both parcels)
or under a wrong solver (a missing friction cone, a wrong sign of restitution, an
unconverged chain, a projection that adds velocity).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from sorter_sim.model.core import cell_kernels as ck
from sorter_sim.model.core.contact import CF_PN, CF_SEP, N_CT, N_SWEEPS
from sorter_sim.model.core.contact_solve import PGS_MAX_SWEEPS
from sorter_sim.runtime.cell import Cell, Outcome
from sorter_sim.runtime.cell_contacts import place_parcel
from sorter_sim.runtime.params import CellParams

G = 9.81
MU = 0.6
V = 1.5
RAIL_T = 0.02  # the rails' thickness [m]


def rigid_cell(**changes) -> Cell:
    """Return a cell under contact: rigid, no stream, disks down, no jam in the test's time."""
    values = {
        'arrival': 'none',
        'contact': 'rigid',
        'jam_time': 60.0,
        'mu_belt': MU,
        'belt_speed': V,
        **changes,
    }
    return Cell(CellParams.defaults().with_changes(values, runtime=False))


def place(cell, i, x, y, size, vel=(0.0, 0.0, 0.0), phi=0.0):
    """Put parcel slot i at (x, y, φ) with velocity ``vel``; ``size`` is (A, B, m)."""
    place_parcel(cell, i, (x, y, phi), size, vel)


def stopper_across(cell, x):
    """Put a stopper across the whole belt, its upstream face at x [m]; its obstacle index."""
    hw = 0.5 * cell.params.belt_width
    cell.add_rail(x + 0.5 * RAIL_T, -hw, x + 0.5 * RAIL_T, hw, RAIL_T)
    return cell.contacts.obstacles.shape[0] - 1


def kinetic_energy_rel_belt(cell, v_belt):
    e = 0.0
    for i in np.flatnonzero(cell.phase == ck.PH_CELL):
        m = cell.par[i, 2]
        inertia = cell.par[i, 3]
        s = cell.state[i]
        e += 0.5 * m * ((s[3] - v_belt) ** 2 + s[4] ** 2) + 0.5 * inertia * s[5] ** 2
    return e


@pytest.mark.parametrize('n', [1, 2, 5, 10])
def test_queue_against_a_stopper_carries_the_belt_friction_of_all(n):
    """
    N parcels queued end to end against a stopper on a running belt.

    Each parcel is at rest while the belt slides under it at v: the floor pushes it
    downstream with μ m_i g (const1: μ at any slip), the parcel ahead pushes back.
    At rest every parcel is in equilibrium, so the contact in front of parcel i carries
    the floor force of it and of all behind it, and the stopper carries
    F = Σ μ m_i g. Masses differ (1.5 ... 6 kg) so an equal split would fail.
    Steady: the velocities stay below 1e-9 m/s, the gaps neither open nor close
    beyond the projection's tolerance (1e-9 m) from period to period.
    """
    cell = rigid_cell()
    ob = stopper_across(cell, -0.6)
    a, b = 0.3, 0.2
    masses = 1.5 + 0.5 * np.arange(n)
    for i in range(n):
        place(cell, i, -0.6 - 0.5 * a - i * a, 0.0, (a, b, masses[i]))
    expected = MU * G * masses.sum()
    events = cell.advance(300)
    assert not [e for e in events if isinstance(e, Outcome)]
    gaps0 = -np.diff(cell.state[:n, 0]) - a
    for _ in range(50):
        cell.advance(1)
        force = cell.contacts.ob_force[ob, 0]
        assert abs(force - expected) <= 1e-3 * expected, (force, expected)
        assert np.max(np.abs(cell.state[:n, 3:6])) < 1e-9
        gaps = -np.diff(cell.state[:n, 0]) - a
        assert np.all(gaps >= -2e-9)
        assert np.all(np.abs(gaps - gaps0) <= 1e-9)
    assert np.all(cell.phase[:n] == ck.PH_CELL)


def test_touching_parcels_at_belt_speed_ride_on_without_force():
    """
    Two parcels touching end to end, both stuck to the running belt at v.

    Nothing pushes them apart or together: no contact impulse, no relative motion
    (the gap stays exactly 0), no fault.
    """
    cell = rigid_cell()
    a, b, m = 0.4, 0.3, 4.0
    for i in range(2):
        place(cell, i, -2.0 - i * a, 0.0, (a, b, m), (V, 0.0, 0.0))
        cell.mode[i] = ck.MODE_BELT
    events = cell.advance(500)
    assert not cell.faults
    assert not [e for e in events if isinstance(e, Outcome)]
    assert cell.state[0, 0] - cell.state[1, 0] == pytest.approx(a, abs=1e-12)
    assert np.all(cell.state[:2, 3] == V)
    assert cell.contacts.counts[N_CT] > 0
    assert np.all(cell.contacts.ct_f[: cell.contacts.counts[N_CT], CF_PN] == 0.0)


@pytest.mark.parametrize('contact', ['rigid', 'jam'])
def test_a_parcel_that_catches_up_pushes_the_one_ahead(contact):
    """
    A parcel at rest on the running belt with a parcel riding at v touching it behind.

    Rigid: the one behind pushes; the impact (e = 0) gives both m1 v / (m0 + m1),
    then the belt takes both to v; after a second both ride at v, stuck, touching
    (gap 0 within 1e-9 m), no fault. The old rule (``contact: jam``): the one behind
    runs into the one ahead and both jam, the cause naming the other parcel.
    """
    cell = rigid_cell(contact=contact)
    a, b = 0.4, 0.3
    place(cell, 0, -2.0, 0.0, (a, b, 4.0))
    place(cell, 1, -2.0 - a, 0.0, (a, b, 6.0), (V, 0.0, 0.0))
    cell.mode[1] = ck.MODE_BELT
    events = cell.advance(1000)
    outs = [e for e in events if isinstance(e, Outcome)]
    if contact == 'jam':
        assert 'jam' in cell.faults
        assert sorted(o.cause for o in outs) == ['parcel 100', 'parcel 101']
        return
    assert not outs and not cell.faults
    assert np.all(cell.state[:2, 3] == V) and np.all(cell.mode[:2] == ck.MODE_BELT)
    assert cell.state[0, 0] - cell.state[1, 0] == pytest.approx(a, abs=MU * G * cell.dt**2)


@pytest.mark.parametrize('restitution', [0.0, 0.5])
def test_impact_on_a_stopped_belt(restitution):
    """
    On a stopped belt parcel 1 slides at u0 into parcel 2 at rest, a gap d ahead.

    Closed form (floor μ, equal footprints, central impact along x):
    it arrives at u = sqrt(u0² - 2 μ g d); momentum and restitution e give
    v1 = (m1 - e m2) u / (m1 + m2), v2 = (1 + e) m1 u / (m1 + m2); then each slides
    to rest after v²/(2 μ g) (with e = 0 they slide together). Rest positions:
    x1 = x1_0 + d + v1²/(2μg), x2 = x2_0 + v2²/(2μg).
    The step's error: the impact is resolved at the period's end, its bodies moved as
    if it had acted at the touch and their floor friction since the touch replayed
    from it (``_replay_floor``); what remains is the touch's place, taken back along
    the new velocity, O(½ μ g h²) per parcel: within μ g h², i.e. 1e-6 m at
    h = 0.1 ms (5.9e-8 m) and 5.9e-6 m at the default 1 ms. Momentum, restitution
    and the slides to rest are otherwise exact.
    """
    for h in (1e-4, 1e-3):
        cell = rigid_cell(control_period=h, restitution=restitution)
        cell.run_belt(False)
        a, b = 0.3, 0.2
        m1, m2 = 3.0, 5.0
        u0, d = 1.0, 0.05
        x1, x2 = -2.0, -2.0 + a + d
        place(cell, 0, x1, 0.0, (a, b, m1), (u0, 0.0, 0.0))
        place(cell, 1, x2, 0.0, (a, b, m2))
        cell.advance(int(round(1.0 / h)))
        u = math.sqrt(u0**2 - 2 * MU * G * d)
        v1 = (m1 - restitution * m2) * u / (m1 + m2)
        v2 = (1 + restitution) * m1 * u / (m1 + m2)
        rest1 = x1 + d + math.copysign(v1**2, v1) / (2 * MU * G)
        rest2 = x2 + v2**2 / (2 * MU * G)
        assert np.max(np.abs(cell.state[:2, 3:6])) == 0.0  # both at rest
        err = max(abs(cell.state[0, 0] - rest1), abs(cell.state[1, 0] - rest2))
        assert err <= MU * G * h**2, (h, err)
        assert cell.state[1, 0] - cell.state[0, 0] >= a - 1e-9
        if h == 1e-4:
            assert err <= 1e-6


def test_momentum_across_an_oblique_impact_is_conserved():
    """
    A frictionless floor (μ = 0, belt stopped): only the contact acts between two parcels.

    Parcel 1, turned and spinning, strikes parcel 2 off centre with friction at the
    contact (mu_parcel 0.5, e = 0.3): the linear momentum Σ m v is the same before
    and after every period, the impact's included, to 1e-12 (relative), since the
    contact impulses are equal and opposite. (The angular momentum about a fixed
    point is not checked: the positions' corrections after the solve move the
    centres without a velocity.) The spin is exchanged too: a wrong lever arm in the
    solve would still conserve Σ m v, so the test also asks that parcel 2 turns.
    """
    cell = rigid_cell(mu_belt=0.0, mu_disks=0.0, mu_parcel=0.5, restitution=0.3)
    cell.run_belt(False)
    place(cell, 0, -2.0, 0.05, (0.3, 0.2, 3.0), (1.2, 0.1, 2.0), phi=0.3)
    place(cell, 1, -1.62, -0.02, (0.4, 0.25, 7.0), (0.0, 0.0, 0.0), phi=-0.2)

    def momentum():
        return sum(cell.par[i, 2] * cell.state[i, 3:5] for i in range(2))

    p0 = momentum()
    hit = False
    for _ in range(400):
        cell.advance(1)
        n = cell.contacts.counts[N_CT]
        hit = hit or (n > 0 and cell.contacts.ct_f[:n, CF_PN].max() > 0.0)
        p = momentum()
        assert np.all(np.abs(p - p0) <= 1e-12 * np.abs(p0).max()), (p, p0)
    assert hit
    assert cell.state[1, 5] != 0.0
    assert not cell.faults


def test_kinetic_energy_relative_to_the_belt_never_grows():
    """
    With e = 0, friction at the floor and the contacts and the impacts only dissipate.

    Eight parcels thrown at random onto the running belt between its side walls, turned
    and spinning, colliding with each other and the walls: the kinetic energy relative
    to the belt (translation relative to v, and rotation) never grows from one period
    to the next (the belt's velocity is constant throughout).
    """
    cell = rigid_cell(mu_parcel=0.5, mu_wall=0.3)
    rng = np.random.default_rng(7)
    for i in range(8):
        place(
            cell,
            i,
            -4.0 + 0.45 * i,
            rng.uniform(-0.15, 0.15),
            (0.3, 0.2, rng.uniform(1.0, 8.0)),
            (rng.uniform(-1.0, 3.0), rng.uniform(-1.5, 1.5), rng.uniform(-8.0, 8.0)),
            phi=rng.uniform(-0.5, 0.5),
        )
    e_prev = kinetic_energy_rel_belt(cell, V)
    touched = 0
    for _ in range(600):
        cell.advance(1)
        e = kinetic_energy_rel_belt(cell, V)
        assert e <= e_prev * (1 + 1e-12) + 1e-15, (e, e_prev)
        e_prev = e
        n = cell.contacts.counts[N_CT]
        touched += n > 0 and cell.contacts.ct_f[:n, CF_PN].max() > 0.0
        assert n == 0 or cell.contacts.ct_f[:n, CF_SEP].min() > -0.01
    assert touched > 10
    assert not np.isnan(cell.state).any()


@pytest.mark.parametrize('theta_deg, mu_wall', [(30.0, 0.3), (20.0, 1.0), (75.0, 0.3)])
def test_parcel_along_a_fence(theta_deg, mu_wall):
    """
    A fence at angle θ to the belt; the belt carries a parcel into it, flat against it.

    Let t = (cos θ, sin θ) run along the fence and n its normal toward the parcel. The
    parcel translates along the fence at u: its slip over the belt is u t - v ex, the
    floor force -μ m g (slip)/|slip|, the fence's normal force N >= 0 and friction
    -μ_w N against u. Across the fence: N = μ m g v sin θ / |slip|; along it:
    μ m g (v cos θ - u) / |slip| = μ_w N, so
        u = v (cos θ - μ_w sin θ)   where that is > 0,
    else it sticks (u = 0: tan θ >= 1/μ_w). The floor's μ drops out. The parcel starts
    at that speed, flat on the fence, and must keep it over 0.3 s. (The fence's
    friction tilts the parcel against the fence: both of its corners stay pressed
    while μ_w B <= A.)
    """
    cell = rigid_cell(mu_wall=mu_wall)
    hw = 0.5 * cell.params.belt_width
    th = math.radians(theta_deg)
    x0 = -3.0
    x1 = x0 + 2 * hw / math.tan(th)
    cell.add_rail(x0, -hw, x1, hw, RAIL_T)
    a, b, m = 0.3, 0.12, 4.0
    t = np.array([math.cos(th), math.sin(th)])
    n = np.array([-math.sin(th), math.cos(th)])
    centre = np.array([x0, -hw]) + 0.3 * t + (0.5 * b + 0.5 * RAIL_T) * n
    u_closed = max(0.0, V * (math.cos(th) - mu_wall * math.sin(th)))
    # started at the closed form's speed along the fence: a wrong balance drifts off
    # it (the speed relaxes at a rate μ g / |slip|, a time constant of 0.13 s here)
    vel = (u_closed * t[0], u_closed * t[1], 0.0)
    place(cell, 0, centre[0], centre[1], (a, b, m), vel, phi=th)
    cell.advance(250)
    before = cell.state[0].copy()
    cell.advance(50)
    s = cell.state[0]
    assert s[2] == pytest.approx(th, abs=1e-9)
    u = s[3:5] @ t
    assert abs(s[3:5] @ n) < 1e-9
    if u_closed > 0.0:
        assert u == pytest.approx(u_closed, rel=1e-6)
        assert (s[:2] - before[:2]) @ t == pytest.approx(u_closed * 50 * cell.dt, rel=1e-6)
    else:
        assert abs(u) < 1e-9
        assert np.linalg.norm(s[:2] - before[:2]) < 1e-9


def _law_names():
    from sorter_sim.model.core.friction import LAW_NAMES

    return sorted(LAW_NAMES)


@pytest.mark.parametrize('integrator', ['accurate', 'implicit'])
@pytest.mark.parametrize('law', _law_names())
def test_a_queue_at_a_stopper_holds_still_under_every_method_and_friction_law(integrator, law):
    """
    Every combination a user can choose: three parcels against a stopper, still.

    Whatever the law's μ(v) and however the off-belt parcels are integrated, parcels
    held at rest by a stopper while the belt slides under them at v stay at rest to
    below 1e-9 m/s (the belt's slip is the same v for each, so the floor force is
    constant), keep their order without overlap (beyond the projection's 1e-9 m),
    raise no fault, and the stopper's force is steady and positive: the floor's pull
    of all three.
    """
    cell = rigid_cell(integrator=integrator, friction_model=law)
    ob = stopper_across(cell, -0.6)
    a, b = 0.3, 0.2
    for i in range(3):
        place(cell, i, -0.6 - 0.5 * a - i * a, 0.0, (a, b, 2.0 + i))
    cell.advance(300)
    forces = []
    for _ in range(30):
        cell.advance(1)
        forces.append(cell.contacts.ob_force[ob, 0])
        assert np.all(np.isfinite(cell.state[:3]))
        assert np.max(np.abs(cell.state[:3, 3:6])) < 1e-9
        assert np.all(-np.diff(cell.state[:3, 0]) - a >= -2e-9)
    assert not cell.faults and np.all(cell.phase[:3] == ck.PH_CELL)
    assert min(forces) > 0.0
    assert max(forces) - min(forces) <= 1e-6 * max(forces)


@pytest.mark.parametrize('integrator', ['accurate', 'implicit'])
@pytest.mark.parametrize('n', [1, 4, 10, 20])
def test_a_queue_of_long_parcels_at_a_stopper_settles_still(integrator, n):
    """
    Up to twenty long parcels (0.7 x 0.2 m) pressed by the belt against a stopper settle still.

    The chain's faces each touch at two points, coupled through the parcels' turn: solved
    point by point the solve did not converge within its sweeps on a chain of 20 and the
    queue crept; solved face by face it converges every period. After 0.5 s every speed
    stays below 1e-9 m/s, the solve converges in every period and the stopper carries
    Σ μ m_i g to 1e-9 (relative) over 0.1 s, under each integrator.
    """
    cell = rigid_cell(integrator=integrator)
    ob = stopper_across(cell, -0.6)
    a, b = 0.7, 0.2
    masses = 4.0 + 0.25 * np.arange(n)
    for i in range(n):
        place(cell, i, -0.6 - 0.5 * a - i * a, 0.0, (a, b, masses[i]))
    cell.advance(500)
    expected = MU * G * masses.sum()
    for _ in range(100):
        cell.advance(1)
        assert np.max(np.abs(cell.state[:n, 3:6])) < 1e-9
        assert abs(cell.contacts.ob_force[ob, 0] - expected) <= 1e-9 * expected
        assert cell.contacts.counts[N_SWEEPS] < PGS_MAX_SWEEPS
    assert not cell.faults and np.all(cell.phase[:n] == ck.PH_CELL)
