"""
Parcels that touch at their extremes: stiff contact cases, their error against run time.

Each case runs the cell's own period loop under ``contact: rigid`` (the seed's floor
friction under every footprint, the accurate method, the contact step at each
period's end) at several control periods h, and measures its error against a closed
form: the impact velocities of momentum and restitution and the slides to rest after
them, v² / (2 μ g); the stopper's force Σ μ m_i g under a queue held at rest; a
parcel's speed along a fence, v (cos θ - μ sin θ); the rails' force on a wedged
parcel, μ m g along the belt. Every case also checks that the run stays finite,
its overlap within one period's sweep, its speeds below the belt's (no blow-up)
and, where it comes to rest, the velocity noise left after settling.

The belt law is const1 (μ independent of the slip), so each closed form holds
exactly; the scenes are those of ``test/test_contact*.py`` at the extremes of the
issue's matrix: a mass ratio of 1:100, contact friction 0.05 and 1.5, ten parcels
pressed against a stopper, a parcel wedged between two rails.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from sorter_sim.runtime.cell import Cell
from sorter_sim.runtime.cell_contacts import place_parcel
from sorter_sim.runtime.params import CellParams

G = 9.81
MU = 0.6  # the belt's friction (const1)
V = 1.5  # the belt's speed [m/s]
RAIL_T = 0.02  # the rails' thickness [m]
FENCE_DEG = 30.0  # the fences' angle to the belt
PERIODS = (4e-3, 2e-3, 1e-3, 5e-4, 2.5e-4)  # the control periods swept [s]
QUICK_PERIODS = (2e-3, 1e-3)
FLOOR = 1e-16  # an error shown as 0 is below this


@dataclass
class ContactRow:
    """One case at one control period: its error against the closed form, and its cost."""

    case: str
    h: float
    error: float  # in the case's unit
    wall_s: float  # the timed run [s]
    sim_s: float  # simulated time of the timed run [s]
    finite: bool
    overlap: float  # the largest overlap of two parcels at a period's end [m]
    speed: float  # the largest parcel speed seen [m/s]
    noise: float  # the largest speed after settling (a case at rest) [m/s], else nan

    @property
    def ok(self) -> bool:
        """Finite, no blow-up: no speed above twice the fastest the scene starts or drives."""
        return self.finite and self.speed <= 2.0 * V


@dataclass(frozen=True)
class ContactCase:
    """A scene, its closed form and its error's unit; ``run(h)`` returns a ContactRow."""

    key: str
    title: str
    closed_form: str
    unit: str
    run: object


def _cell(h: float, **changes) -> Cell:
    values = {
        'arrival': 'none',
        'contact': 'rigid',
        'jam_time': 60.0,
        'mu_belt': MU,
        'friction_model': 'const1',
        'belt_speed': V,
        'control_period': h,
        **changes,
    }
    return Cell(CellParams.defaults().with_changes(values, runtime=False))


def _stopper(cell, x):
    """Put a stopper across the belt, its upstream face at x [m]; return its obstacle index."""
    hw = 0.5 * cell.params.belt_width
    cell.add_rail(x + 0.5 * RAIL_T, -hw, x + 0.5 * RAIL_T, hw, RAIL_T)
    return cell.contacts.obstacles.shape[0] - 1


def _overlap(cell) -> float:
    """Return the deepest overlap of the contacts found at the period's end [m] (0: none)."""
    n = cell.contacts.counts[0]
    if n == 0:
        return 0.0
    return max(0.0, -float(cell.contacts.ct_f[:n, 4].min()))


class _Watch:
    """
    Advance a cell period by period keeping the checks' extremes, or (``timed``) time it.

    The checks read the cell after every period, one call a period; the timing run
    makes the same periods in as few calls as the case allows.
    """

    def __init__(self, cell, n: int, timed: bool = False):
        self.cell, self.n, self.timed = cell, n, timed
        self.wall = 0.0
        self.finite = True
        self.overlap = 0.0
        self.speed = 0.0
        self.noise = math.nan

    def advance(self, periods: int, settled: bool = False) -> None:
        cell, n = self.cell, self.n
        if self.timed:
            # the timing run: the periods in one call, as a running cell makes them
            t0 = time.perf_counter()
            cell.advance(periods)
            self.wall += time.perf_counter() - t0
            return
        for _ in range(periods):
            t0 = time.perf_counter()
            cell.advance(1)
            self.wall += time.perf_counter() - t0
            s = cell.state[:n]
            self.finite = self.finite and bool(np.isfinite(s).all())
            self.overlap = max(self.overlap, _overlap(cell))
            self.speed = max(self.speed, float(np.abs(s[:, 3:5]).max()))
            if settled:
                self.noise = np.nanmax([self.noise, float(np.abs(s[:, 3:6]).max())])

    def row(self, case: str, error: float) -> ContactRow:
        cell = self.cell
        return ContactRow(
            case,
            cell.dt,
            error,
            self.wall,
            cell.t,
            self.finite,
            self.overlap,
            self.speed,
            self.noise,
        )


def _periods(h: float, seconds: float) -> int:
    return max(1, round(seconds / h))


# ---------------------------------------------------------------- the cases
def impact(h: float, m1: float, m2: float, restitution: float = 0.5, timed=False) -> ContactRow:
    """
    Slide parcel 1 (m1) at u0 on a stopped belt into parcel 2 (m2) at rest, d ahead.

    It arrives at u = sqrt(u0² - 2 μ g d); momentum and restitution give
    v1 = (m1 - e m2) u / (m1 + m2), v2 = (1 + e) m1 u / (m1 + m2); each then slides
    to rest after v² / (2 μ g). Error: the rest positions [m].
    """
    cell = _cell(h, restitution=restitution)
    cell.run_belt(False)
    a, b, u0, d = 0.3, 0.2, 1.0, 0.05
    x1, x2 = -2.0, -2.0 + a + d
    place_parcel(cell, 0, (x1, 0.0, 0.0), (a, b, m1), (u0, 0.0, 0.0))
    place_parcel(cell, 1, (x2, 0.0, 0.0), (a, b, m2))
    w = _Watch(cell, 2, timed)
    w.advance(_periods(h, 1.0))
    u = math.sqrt(u0**2 - 2 * MU * G * d)
    v1 = (m1 - restitution * m2) * u / (m1 + m2)
    v2 = (1 + restitution) * m1 * u / (m1 + m2)
    rest1 = x1 + d + math.copysign(v1**2, v1) / (2 * MU * G)
    rest2 = x2 + v2**2 / (2 * MU * G)
    err = max(abs(cell.state[0, 0] - rest1), abs(cell.state[1, 0] - rest2))
    return w.row(f'impact {m1:g} kg into {m2:g} kg', err)


def pressed_queue(
    h: float, masses, a: float = 0.3, mu_parcel: float = 0.4, timed=False
) -> ContactRow:
    """
    Queue parcels end to end against a stopper on the running belt, held at rest.

    The stopper carries Σ μ m_i g (each parcel's floor friction, the belt sliding under
    it). Error: the stopper's force, relative, over the last 0.05 s; ``noise`` the
    largest speed over that time.
    """
    cell = _cell(h, mu_parcel=mu_parcel)
    ob = _stopper(cell, -0.6)
    n = len(masses)
    for i, m in enumerate(masses):
        place_parcel(cell, i, (-0.6 - 0.5 * a - i * a, 0.0, 0.0), (a, 0.2, m))
    w = _Watch(cell, n, timed)
    w.advance(_periods(h, 0.3))
    expected = MU * G * float(np.sum(masses))
    err = 0.0
    for _ in range(_periods(h, 0.05)):
        w.advance(1, settled=True)
        err = max(err, abs(cell.contacts.ob_force[ob, 0] - expected) / expected)
    return w.row(f'{n} pressed' if n > 2 else f'pressed {masses[0]:g} / {masses[1]:g} kg', err)


def fence(h: float, mu: float, of_parcel: bool, timed=False) -> ContactRow:
    """
    Run a parcel carried by the belt flat along a fence at θ = 30° to it.

    Along the fence it slides at u = v (cos θ - μ sin θ) (the floor's μ drops out;
    u = 0 where that is <= 0), μ the fence's friction: ``mu_wall`` for a rail, or
    ``mu_parcel`` for a long parcel jammed in its place (a jammed parcel is an
    obstacle that touches with the parcels' friction). Started at that speed; error:
    its speed along the fence after 0.3 s, relative to v.
    """
    cell = _cell(h, mu_wall=mu if not of_parcel else 0.3, mu_parcel=mu if of_parcel else 0.4)
    hw = 0.5 * cell.params.belt_width
    th = math.radians(FENCE_DEG)
    t = np.array([math.cos(th), math.sin(th)])
    nrm = np.array([-math.sin(th), math.cos(th)])
    x0 = -3.0
    length = 2 * hw / math.sin(th)
    if of_parcel:
        # the fence: a parcel as long as the rail would be, jammed where it lies
        wide = 0.1
        mid = np.array([x0, -hw]) + 0.5 * length * t - 0.5 * wide * nrm
        place_parcel(cell, 1, (mid[0], mid[1], th), (length, wide, 50.0))
        cell.jam_parcel(str(cell.ids[1]))
        half_t = 0.5 * wide
    else:
        cell.add_rail(x0, -hw, x0 + length * t[0], hw, RAIL_T)
        half_t = 0.5 * RAIL_T
    a, b, m = 0.3, 0.12, 4.0
    centre = np.array([x0, -hw]) + 0.3 * t + (0.5 * b + half_t) * nrm
    u_closed = max(0.0, V * (math.cos(th) - mu * math.sin(th)))
    place_parcel(cell, 0, (centre[0], centre[1], th), (a, b, m), (*(u_closed * t), 0.0))
    w = _Watch(cell, 1, timed)
    w.advance(_periods(h, 0.3))
    u = float(cell.state[0, 3:5] @ t)
    what = 'a jammed parcel, mu_parcel' if of_parcel else 'a rail, mu_wall'
    return w.row(f'along {what} {mu:g}', abs(u - u_closed) / V)


def wedged(h: float, mu_wall: float = 0.3, timed=False) -> ContactRow:
    """
    Run a parcel into a funnel of two rails narrower than it, until it wedges.

    Wedged, at rest, the rails together carry its floor friction μ m g along the belt.
    Error: their force along the belt, relative, over the last 0.05 s.
    """
    cell = _cell(h, mu_wall=mu_wall)
    hw = 0.5 * cell.params.belt_width
    x_tip, half_gap = -1.0, 0.08
    for side in (1.0, -1.0):
        cell.add_rail(x_tip - 1.0, side * (hw - 0.01), x_tip, side * (half_gap + 0.5 * RAIL_T))
    n_ob = cell.contacts.obstacles.shape[0]
    m = 5.0
    place_parcel(cell, 0, (-2.4, 0.0, 0.0), (0.3, 0.25, m), (V, 0.0, 0.0))
    w = _Watch(cell, 1, timed)
    w.advance(_periods(h, 1.5))
    expected = MU * m * G
    err = 0.0
    for _ in range(_periods(h, 0.05)):
        w.advance(1, settled=True)
        f = cell.contacts.ob_force[n_ob - 2 : n_ob, 0].sum()
        err = max(err, abs(f - expected) / expected)
    return w.row('wedged between two rails', err)


STACK_MASSES = tuple(1.5 + 0.5 * k for k in range(10))

CASES = (
    ContactCase(
        'impact_1_100',
        'A 0.5 kg parcel strikes a 50 kg one (e = 0.5)',
        'rest positions after momentum, restitution and v²/(2 μ g)',
        'm',
        lambda h, timed=False: impact(h, 0.5, 50.0, timed=timed),
    ),
    ContactCase(
        'impact_100_1',
        'A 50 kg parcel strikes a 0.5 kg one (e = 0.5)',
        'rest positions after momentum, restitution and v²/(2 μ g)',
        'm',
        lambda h, timed=False: impact(h, 50.0, 0.5, timed=timed),
    ),
    ContactCase(
        'pressed_1_100',
        'A 0.5 kg parcel pressed against a stopper by a 50 kg one',
        'stopper force Σ μ m_i g (relative)',
        '–',
        lambda h, timed=False: pressed_queue(h, (0.5, 50.0), timed=timed),
    ),
    ContactCase(
        'stack_10',
        'Ten parcels (1.5 ... 6 kg) pressed by the belt against a stopper',
        'stopper force Σ μ m_i g (relative)',
        '–',
        lambda h, timed=False: pressed_queue(h, STACK_MASSES, timed=timed),
    ),
    ContactCase(
        'stack_10_long',
        'Ten long parcels (0.7 x 0.2 m, 5 kg) pressed by the belt against a stopper',
        'stopper force Σ μ m_i g (relative)',
        '–',
        lambda h, timed=False: pressed_queue(h, (5.0,) * 10, a=0.7, timed=timed),
    ),
    ContactCase(
        'wall_mu_0.05',
        'Along a rail at 30°, mu_wall 0.05',
        'speed along it v (cos θ - μ sin θ) (relative to v)',
        '–',
        lambda h, timed=False: fence(h, 0.05, of_parcel=False, timed=timed),
    ),
    ContactCase(
        'wall_mu_1.5',
        'Along a rail at 30°, mu_wall 1.5',
        'speed along it v (cos θ - μ sin θ) (relative to v)',
        '–',
        lambda h, timed=False: fence(h, 1.5, of_parcel=False, timed=timed),
    ),
    ContactCase(
        'parcel_mu_0.05',
        'Along a jammed parcel at 30°, mu_parcel 0.05',
        'speed along it v (cos θ - μ sin θ) (relative to v)',
        '–',
        lambda h, timed=False: fence(h, 0.05, of_parcel=True, timed=timed),
    ),
    ContactCase(
        'parcel_mu_1.5',
        'Along a jammed parcel at 30°, mu_parcel 1.5',
        'speed along it v (cos θ - μ sin θ) (relative to v)',
        '–',
        lambda h, timed=False: fence(h, 1.5, of_parcel=True, timed=timed),
    ),
    ContactCase(
        'wedged',
        'Wedged between two converging rails (mu_wall 0.3)',
        "the rails' force along the belt μ m g (relative)",
        '–',
        lambda h, timed=False: wedged(h, timed=timed),
    ),
)


def contact_rows(quick: bool = False, log=None) -> list[tuple[ContactCase, list[ContactRow]]]:
    """
    Run every case at every control period (``QUICK_PERIODS`` when ``quick``).

    Each case and period runs twice: checked period by period, then timed (the same
    periods in as few calls as the case allows, after the checked run compiled what it
    needs); the row is the checked run's with the timed run's wall time.
    """
    periods = QUICK_PERIODS if quick else PERIODS
    out = []
    for case in CASES:
        t0 = time.perf_counter()
        rows = []
        for h in periods:
            row = case.run(h)
            row.wall_s = case.run(h, timed=True).wall_s
            rows.append(row)
        out.append((case, rows))
        if log is not None:
            log(
                f'  {case.key:<16} {time.perf_counter() - t0:6.1f} s  '
                + ' '.join(f'{r.h:g}:{r.error:.1e}' for r in rows)
            )
    return out


def contact_markdown(results) -> str:
    """Return the report's section: one row per case and period."""
    L = ['## Parcels that touch: stiff and extreme cases', '']
    L.append(
        'The cell itself (`contact: rigid`, the accurate method, the belt law const1) at '
        'each control period h; each case against a closed form, named in its row (every '
        'case has one: no converged reference is needed). Time: the wall time of a second, '
        'timing run of the same periods in as few calls to the cell as the case allows '
        '(a case at rest reads its force every period while it is measured), compiled, '
        'on one core; RTF: simulated over wall time. Overlap: the deepest interpenetration '
        'of two bodies found at a period\'s end, before the contact step takes it out '
        '(contacts are found at the period\'s end, so a body sweeps into one it is about to '
        'meet by up to one period\'s travel: 6 mm at 1.5 m/s and h = 4 ms); noise: the '
        'largest speed of a parcel held '
        'at rest after settling. A case at rest, or sliding steadily along a fence, has an '
        'error of rounding size at every h: its closed form is a balance of forces the step '
        'meets exactly. An impact\'s rest positions are off by O(μ g h²) (docs/model.md, '
        '"Parcels that touch") down to the accurate method\'s tolerance on the slides '
        'before and after it (the cell\'s rtol 1e-6, atol 1e-8: 4e-8 m).'
    )
    L.append('')
    L.append(
        '| case | against | h [s] | error | time [ms] | RTF | overlap [m] | noise [m/s] | checks |'
    )
    L.append('|---|---|---|---|---|---|---|---|---|')
    for case, rows in results:
        unit = '' if case.unit == '–' else f' {case.unit}'
        for r in rows:
            noise = '–' if math.isnan(r.noise) else f'{r.noise:.1e}'
            err = '0' if r.error < FLOOR else f'{r.error:.1e}'
            checks = 'pass' if r.ok else f'FAIL (finite {r.finite}, speed {r.speed:.2g} m/s)'
            L.append(
                f'| {case.title} | {case.closed_form} | {r.h:g} | {err}{unit} | '
                f'{1e3 * r.wall_s:.1f} | {r.sim_s / max(r.wall_s, 1e-12):.0f} | '
                f'{r.overlap:.1e} | {noise} | {checks} |'
            )
    L.append('')
    return '\n'.join(L)


def contact_findings(results) -> list[str]:
    """Return the findings' lines: every case that failed its checks."""
    return [
        f'- contact {case.key}, h = {r.h:g} s: not finite or a speed of {r.speed:.2g} m/s'
        for case, rows in results
        for r in rows
        if not r.ok
    ]


__all__ = ['CASES', 'ContactCase', 'ContactRow', 'contact_markdown', 'contact_rows']
