"""
Divert timing from the model core.

When a parcel is committed to its chute, and how close parcels may follow.

The controller cannot see a parcel's motion over the disk field; it predicts it.
``DivertPredictor`` runs the model core (``sorter_sim.model.core.simulate``, the seed's
eq. 4.1 with the moment of friction) for a parcel of the measured length A at the
current belt speed v and disk angle α, starting as the seed's runs do (leading
edge on the zone a/b border, moving with the belt, φ = 0), and keeps from the
trajectory what a PLC needs:

* ``t_chute``: when the first corner of the footprint reaches the chute entry
  line y = w/2 (the chute sensor should switch then),
* ``t_commit``: when the centre of gravity has crossed the chute entry line
  y = w/2 by ``commit_margin`` (the cell hands a parcel to the chute once its
  centre of gravity is past the line; the margin covers the lateral offset a
  parcel may arrive with); the disks may drop only after it,
* ``x_o``: how far the centre of gravity moved along the belt meanwhile (Fig. 8),
* ``t_off``: when the whole footprint has left the belt (y_min > w/2),
* whether the footprint stays inside the chute opening (x from -chute_margin to
  b + chute_margin) wherever it reaches past the side wall before the commit:
  a corner over the wall elsewhere jams the parcel, so such a divert is not
  ``feasible``, nor one that never reaches the line (zone c stops it, Fig. 11).

``seed_capacity`` is the seed's technical capacity W_t = 3600 / t_scrap of
Fig. 9, with the seed's criterion (the centre of gravity covers the belt width s).

All times are relative to the moment the leading edge reaches the upstream edge
of the disk field (x = 0). Predictions are cached per (A, v, α) with A rounded
*up* to ``length_step`` (a longer parcel needs longer: Fig. 9), so a running scan
only pays for a new length once.

``GapModel`` turns predictions into the spacing rules of a stream: for two
consecutive parcels and their destinations, the least time between their leading
edges reaching the disk field such that (1) their footprints never touch (a
parcel pushed across at α = 90° nearly stops along the belt, Fig. 7, so the
next one catches up with it) and (2) the actuators can do what the pair needs:
lower the disks (pop-up stroke time), swing them to the other side (slew rate)
or raise them only after a straight parcel has cleared the field, each plus one
scan period (an output is written at the next scan at the latest) and a
service latency allowance. ``min_gap`` reports the result as a gap in metres.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from sorter_sim.model.core.simulate import Parcel, simulate
from sorter_sim.model.build import cell_strips, entry_state

DESTINATIONS = ("left", "right", "straight")

# A prediction depends only on the cell's mechanics and the method's settings, so every
# predictor of a process with the same ones shares its results: a line's station
# programs, or the controllers a test worker makes one after another, each run the
# model once per length rather than once per program. The last SHARED_SETTINGS
# settings are kept; a predictor keeps its own results whatever is dropped.
SHARED_SETTINGS = 8
_shared: OrderedDict[tuple, dict] = OrderedDict()


def _shared_cache(key: tuple) -> dict:
    """Return the results store every predictor (or gap model) with settings ``key`` uses."""
    store = _shared.get(key)
    if store is None:
        store = _shared[key] = {}
        while len(_shared) > SHARED_SETTINGS:
            _shared.popitem(last=False)
    else:
        _shared.move_to_end(key)
    return store


def side_of(destination: str) -> int:
    """
    +1 for the +y chute (α > 0), -1 for the -y chute, 0 for straight on.

    Parameters
    ----------
    destination : str
        A destination (left, right, straight, or a chute name).

    Returns
    -------
    int
        +1, -1 or 0.

    """
    return {"left": 1, "right": -1, "straight": 0}[destination]


@dataclass(frozen=True)
class CellModel:
    """
    What the controller knows of the cell's mechanics (SI units, angles in degrees).

    belt_width is the seed's s at the same time as w; disk_field_length is the
    seed's zone b; mu_belt/mu_disks are μ_a(=μ_c)/μ_b at the scene's reference
    speed; parcel_width and parcel_mass are nominal values for the prediction (a
    photo-eye measures only the length, and x_o does not depend on B: Fig. 8a).
    """

    belt_width: float = 0.7
    disk_field_length: float = 1.2
    chute_margin: float = 0.1
    mu_belt: float = 0.6
    mu_disks: float = 0.6
    friction_model: str = "const1"
    parcel_width: float = 0.4
    parcel_mass: float = 5.0
    commit_margin: float = 0.05
    length_step: float = 0.01

    def __post_init__(self):
        for name in (
            "belt_width",
            "disk_field_length",
            "parcel_width",
            "parcel_mass",
            "length_step",
        ):
            v = getattr(self, name)
            finite = math.isfinite(v) or (name == "disk_field_length" and v == math.inf)
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and finite and v > 0):
                raise ValueError(
                    f"{name} must be a finite number > "
                    f"0{' (or inf)' if name == 'disk_field_length' else ''}, "
                    f"got {v!r}"
                )
        for name in ("chute_margin", "commit_margin"):
            v = getattr(self, name)
            if isinstance(v, bool) or not (
                isinstance(v, (int, float)) and math.isfinite(v) and v >= 0
            ):
                raise ValueError(f"{name} must be a finite number >= 0, got {v!r}")
        for name in ("mu_belt", "mu_disks"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and 0.0 <= v <= 3.0):
                raise ValueError(f"{name} must be in [0, 3], got {v!r}")

    @property
    def commit_distance(self) -> float:
        """Lateral travel of the centre of gravity after which a parcel is the chute's [m]."""
        return 0.5 * self.belt_width + self.commit_margin

    @property
    def opening(self) -> tuple[float, float]:
        """X range of the chute openings in the side walls [m]."""
        return -self.chute_margin, self.disk_field_length + self.chute_margin


@dataclass(frozen=True)
class Prediction:
    """
    One predicted divert, times relative to the leading edge reaching x = 0 [s].

    trajectory: (n, 4) array of t, x, y, φ of the centre of gravity in the conveyor
    frame, from t = 0 until the parcel is off the belt (or the run ended); x starts
    at -A/2 and y at 0. feasible is False when the parcel never reaches the commit
    line (a disk field too short for it at this speed: zone c stops it, Fig. 11) or
    would catch a side wall outside the chute opening first (``why`` says which).
    """

    A: float
    v: float
    alpha_deg: float
    feasible: bool
    t_chute: float
    t_commit: float
    t_off: float
    x_o: float
    phi_commit_deg: float
    trajectory: np.ndarray = field(repr=False)
    wall_s: float = 0.0
    why: str = ""

    @property
    def capacity_pcs_h(self) -> float:
        """Return the seed's technical capacity W_t = 3600 / t_scrap (Fig. 9) [pcs/h]."""
        return 3600.0 / self.t_commit if self.feasible and self.t_commit > 0 else 0.0

    def t_clear_of(self, x_eye: float, belt_width: float, parcel_width: float) -> float:
        """
        When the parcel stops blocking a photo-eye at x_eye (beam across the belt) [s].

        Either its rear has passed the eye, or its centre of gravity has crossed the
        chute entry line and the parcel has gone onto the chute.

        Parameters
        ----------
        x_eye : float
            The photo-eye's x [m].
        belt_width : float
            The belt's width [m].
        parcel_width : float
            The parcel's width [m].

        Returns
        -------
        float
            The time [s].

        """
        tr = self.trajectory
        xmin, _, _, _ = _corner_extents(tr[:, 1], tr[:, 2], tr[:, 3], self.A, parcel_width)
        idx = np.nonzero((xmin > x_eye) | (np.abs(tr[:, 2]) >= 0.5 * belt_width))[0]
        return float(tr[idx[0], 0]) if idx.size else self.t_off

    def pose(self, t: np.ndarray) -> np.ndarray:
        """
        (len(t), 3) poses x, y, φ at relative times t (belt motion before 0.

        The last pose after the end).

        Parameters
        ----------
        t : ndarray
            Times relative to entry [s].

        Returns
        -------
        ndarray, shape (len(t), 3)
            The poses x, y, φ.

        """
        t = np.asarray(t, dtype=float)
        tr = self.trajectory
        out = np.empty((t.size, 3))
        for k in range(3):
            out[:, k] = np.interp(t, tr[:, 0], tr[:, k + 1])
        before = t < 0.0
        out[before, 0] = tr[0, 1] + self.v * t[before]
        out[before, 1] = 0.0
        out[before, 2] = 0.0
        return out


def _corner_extents(x, y, phi, A, B):
    """Per pose: min x, max x, min y, max y of the footprint corners."""
    c, s = np.cos(phi), np.sin(phi)
    ha, hb = 0.5 * A, 0.5 * B
    ex = np.abs(ha * c) + np.abs(hb * s)
    ey = np.abs(ha * s) + np.abs(hb * c)
    return x - ex, x + ex, y - ey, y + ey


def boxes_overlap(p, q, A1, B1, A2, B2, clearance=0.0) -> np.ndarray:
    """
    Separating-axis test of two rectangles per row of poses p, q (n x 3: x, y, φ).

    Each box is inflated by clearance/2 on every side; True where they overlap.

    Parameters
    ----------
    p : ndarray, shape (n, 3)
        One rectangle's poses (x, y, φ).
    q : ndarray, shape (n, 3)
        The other rectangle's poses.
    A1 : float
        The first rectangle's (or parcel's) length [m].
    B1 : float
        Its width [m].
    A2 : float
        The second's length [m].
    B2 : float
        Its width [m].
    clearance : float
        The clearance they must keep [m].

    Returns
    -------
    ndarray of bool
        Per row, whether they overlap.

    """
    p = np.atleast_2d(p)
    q = np.atleast_2d(q)
    h1x, h1y = 0.5 * A1 + 0.5 * clearance, 0.5 * B1 + 0.5 * clearance
    h2x, h2y = 0.5 * A2 + 0.5 * clearance, 0.5 * B2 + 0.5 * clearance
    dx = q[:, 0] - p[:, 0]
    dy = q[:, 1] - p[:, 1]
    c1, s1 = np.cos(p[:, 2]), np.sin(p[:, 2])
    c2, s2 = np.cos(q[:, 2]), np.sin(q[:, 2])
    # the boxes' axes are u = (cos, sin) and v = (-sin, cos); projected on each other's,
    # |u2.u1| = |v2.v1| = |cos(phi2 - phi1)| and |v2.u1| = |u2.v1| = |sin(phi2 - phi1)|
    # (the last two are exact negatives of each other, so one serves both)
    cc = np.abs(c2 * c1 + s2 * s1)
    sn = np.abs(-s2 * c1 + c2 * s1)
    # on each of box 1's axes, then box 2's: the centres' distance against the half
    # extents of both boxes
    separated = np.abs(dx * c1 + dy * s1) > h1x + (h2x * cc + h2y * sn)
    separated |= np.abs(dx * -s1 + dy * c1) > h1y + (h2x * sn + h2y * cc)
    separated |= np.abs(dx * c2 + dy * s2) > h2x + (h1x * cc + h1y * sn)
    separated |= np.abs(dx * -s2 + dy * c2) > h2y + (h1x * sn + h1y * cc)
    return ~separated


class DivertPredictor:
    """Model-core predictions of a divert, cached per (A rounded up, v, α)."""

    def __init__(
        self,
        cell: CellModel,
        *,
        method: str = "accurate",
        t_max: float = 10.0,
        rtol: float = 1e-6,
        atol: float = 1e-8,
    ):
        self.cell = cell
        self.method = method
        self.t_max = t_max
        self.rtol = rtol
        self.atol = atol
        self.settings = ("predictions", cell, method, t_max, rtol, atol)
        self._cache: dict[tuple, Prediction] = _shared_cache(self.settings)
        self.n_runs = 0
        self.wall_s = 0.0

    def key_length(self, A: float) -> float:
        """
        Return the prediction grid's length for A.

        Parameters
        ----------
        A : float
            A parcel's length [m].

        Returns
        -------
        float
            The grid's length [m] for A.

        """
        step = self.cell.length_step
        return round(math.ceil(A / step - 1e-9) * step, 6)

    def predict(self, A: float, v: float, alpha_deg: float) -> Prediction:
        """
        Return the divert of a parcel of length A [m] at belt speed v [m/s] by disks at α [deg].

        A negative α is the mirror image of the positive one (the model is
        symmetric), so both share one run.

        Parameters
        ----------
        A : float
            A parcel's length [m].
        v : float
            The belt speed [m/s].
        alpha_deg : float
            The disk angle [deg].

        Returns
        -------
        Prediction
            The divert.

        """
        if not (math.isfinite(A) and A > 0):
            raise ValueError(f"parcel length must be a finite number > 0 m, got {A!r}")
        if not (math.isfinite(v) and v > 0):
            raise ValueError(f"belt speed must be a finite number > 0 m/s, got {v!r}")
        if not (math.isfinite(alpha_deg) and 0 < abs(alpha_deg) <= 90):
            raise ValueError(f"disk angle must be in [-90, 0) or (0, 90] deg, got {alpha_deg!r}")
        key = (self.key_length(A), round(v, 6), round(abs(alpha_deg), 6))
        pred = self._cache.get(key)
        if pred is None:
            pred = self._run(*key)
            self._cache[key] = pred
        if alpha_deg < 0:
            tr = pred.trajectory * np.array([1.0, 1.0, -1.0, -1.0])
            return Prediction(
                pred.A,
                pred.v,
                alpha_deg,
                pred.feasible,
                pred.t_chute,
                pred.t_commit,
                pred.t_off,
                pred.x_o,
                -pred.phi_commit_deg,
                tr,
                pred.wall_s,
                pred.why,
            )
        return pred

    def _run(self, A: float, v: float, alpha_deg: float) -> Prediction:
        cell = self.cell
        try:
            parcel = Parcel(A, cell.parcel_width, cell.parcel_mass)
            strips = cell_strips(
                v,
                alpha_deg,
                cell.disk_field_length,
                cell.mu_belt,
                cell.mu_disks,
                cell.mu_belt,
                cell.friction_model,
            )
        except ValueError as exc:
            raise ValueError(f"cannot predict a divert: {exc}") from None
        y0 = entry_state(parcel, v)
        half_diag = 0.5 * math.hypot(A, cell.parcel_width)
        # run until the whole footprint is off the belt, and at least to the commit line
        y_run = max(cell.commit_distance, 0.5 * cell.belt_width + half_diag) + 0.01
        res = simulate(
            parcel,
            strips,
            y0,
            (0.0, self.t_max),
            self.method,
            y_target=y_run,
            h_max=0.01,
            rtol=self.rtol,
            atol=self.atol,
        )
        self.n_runs += 1
        self.wall_s += res.wall_s
        t = res.t
        x, y, phi = res.y[:, 0], res.y[:, 1], res.y[:, 2]
        traj = np.column_stack([t, x, y, phi])
        xmin, xmax, ymin, ymax = _corner_extents(x, y, phi, A, cell.parcel_width)
        edge = 0.5 * cell.belt_width

        def first_cross(values, level):
            idx = np.nonzero(values >= level)[0]
            if idx.size == 0:
                return math.inf
            i = int(idx[0])
            if i == 0:
                return float(t[0])
            f = (level - values[i - 1]) / (values[i] - values[i - 1])
            return float(t[i - 1] + f * (t[i] - t[i - 1]))

        t_chute = first_cross(ymax, edge)
        t_commit = first_cross(y, cell.commit_distance)
        t_off = first_cross(ymin, edge)
        feasible = math.isfinite(t_commit)
        why = (
            ""
            if feasible
            else f"the centre of gravity never reaches y = {cell.commit_distance:.3f} m"
        )
        if feasible:
            x_o = float(np.interp(t_commit, t, x) - x[0])
            phi_c = math.degrees(float(np.interp(t_commit, t, phi)))
            # corners past the side wall (y > w/2) before the centre of gravity is over the
            # line must be inside the opening, else the wall stops the parcel
            lo, hi = cell.opening
            before = t <= t_commit
            c, s_ = np.cos(phi[before]), np.sin(phi[before])
            for sa, sb in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
                cx = x[before] + 0.5 * sa * A * c - 0.5 * sb * cell.parcel_width * s_
                cy = y[before] + 0.5 * sa * A * s_ + 0.5 * sb * cell.parcel_width * c
                bad = (cy > edge) & ((cx < lo) | (cx > hi))
                if np.any(bad):
                    feasible = False
                    k = int(np.argmax(bad))
                    why = (
                        f"a corner passes the side wall at x = {cx[k]:.3f} m, outside the chute "
                        f"opening [{lo:.2f}, {hi:.2f}] m"
                    )
                    break
        else:
            x_o, phi_c = math.nan, math.nan
        return Prediction(
            A,
            v,
            alpha_deg,
            feasible,
            t_chute,
            t_commit,
            t_off if math.isfinite(t_off) else float(t[-1]),
            x_o,
            phi_c,
            traj,
            res.wall_s,
            why,
        )


@dataclass(frozen=True)
class Actuators:
    """
    Actuator and scan timing the spacing rules must leave room for [s].

    A command is written at the scan after it falls due (one scan period), reaches
    the cell after ``latency``, and ``margin`` more covers a scan that comes late.
    """

    popup_stroke_time: float = 0.1
    alpha_slew_rate_deg_s: float = 360.0
    scan_period: float = 0.01
    latency: float = 0.005
    margin: float = 0.02

    def slew_time(self, alpha_from_deg: float, alpha_to_deg: float) -> float:
        """
        Return the time the disks take to turn.

        Parameters
        ----------
        alpha_from_deg : float
            The angle the disks start from [deg].
        alpha_to_deg : float
            The angle they turn to [deg].

        Returns
        -------
        float
            The time [s].

        """
        return abs(alpha_to_deg - alpha_from_deg) / self.alpha_slew_rate_deg_s

    @property
    def stroke_total(self) -> float:
        """From the decision to the stroke's end: one scan, latency, margin, the stroke."""
        return self.popup_stroke_time + self.scan_period + self.latency + self.margin

    def slew_total(self, alpha_from_deg: float, alpha_to_deg: float) -> float:
        """
        Return the time the disks take to turn and settle.

        Parameters
        ----------
        alpha_from_deg : float
            The angle the disks start from [deg].
        alpha_to_deg : float
            The angle they turn to [deg].

        Returns
        -------
        float
            The time [s], settling included.

        """
        if alpha_from_deg == alpha_to_deg:
            return 0.0
        return (
            self.slew_time(alpha_from_deg, alpha_to_deg)
            + self.scan_period
            + self.latency
            + self.margin
        )


class GapModel:
    """Spacing rules for consecutive parcels, from predictions and actuator timing."""

    def __init__(
        self,
        predictor: DivertPredictor,
        actuators: Actuators,
        *,
        divert_alpha_deg: float = 90.0,
        clearance: float = 0.02,
        dt: float = 0.002,
        geometry_step: float = 0.05,
    ):
        self.predictor = predictor
        self.act = actuators
        self.divert_alpha_deg = float(divert_alpha_deg)
        self.clearance = clearance
        self.dt = dt
        self.geometry_step = geometry_step
        self._geo_cache: dict[tuple, float] = _shared_cache(
            ("headways", predictor.settings, self.divert_alpha_deg, clearance, dt, geometry_step)
        )

    @property
    def cell(self) -> CellModel:
        return self.predictor.cell

    def alpha_for(self, destination: str) -> float:
        """
        Return the disk angle for a destination.

        Parameters
        ----------
        destination : str
            A destination (left, right, straight, or a chute name).

        Returns
        -------
        float
            The disk angle [deg] for the destination.

        """
        return side_of(destination) * self.divert_alpha_deg

    def prediction(self, A: float, v: float, destination: str) -> Prediction | None:
        """
        Return the divert for a destination.

        Parameters
        ----------
        A : float
            A parcel's length [m].
        v : float
            The belt speed [m/s].
        destination : str
            A destination (left, right, straight, or a chute name).

        Returns
        -------
        Prediction or None
            The divert, or None for straight on.

        """
        if side_of(destination) == 0:
            return None
        return self.predictor.predict(A, v, self.alpha_for(destination))

    # --- (1) footprints never touch -------------------------------------------------
    def geometric_headway(self, A1: float, dest1: str, A2: float, dest2: str, v: float) -> float:
        """
        Least time between the leading edges reaching x = 0 so the footprints stay apart [s].

        Only a diverted leader can be caught up (it slows down along x); a straight
        leader moves on at belt speed and needs just the clearance. Lengths are
        rounded up to ``geometry_step`` (a longer pair needs more room), so a stream
        of similar parcels costs a handful of these searches.

        Parameters
        ----------
        A1 : float
            The first rectangle's (or parcel's) length [m].
        dest1 : str
            The first parcel's destination.
        A2 : float
            The second's length [m].
        dest2 : str
            The second's.
        v : float
            The belt speed [m/s].

        Returns
        -------
        float
            The time [s].

        """
        step = self.geometry_step
        A1 = round(math.ceil(A1 / step - 1e-9) * step, 6)
        A2 = round(math.ceil(A2 / step - 1e-9) * step, 6)
        key = (A1, dest1, A2, dest2, round(v, 6))
        hit = self._geo_cache.get(key)
        if hit is not None:
            return hit
        base = (A1 + self.clearance) / v  # touching at belt speed
        first = self.prediction(A1, v, dest1)
        if first is None:
            self._geo_cache[key] = base
            return base
        second = self.prediction(A2, v, dest2)
        B = self.cell.parcel_width
        # a parcel handed to the chute no longer meets the parcels on the belt
        ts = np.arange(0.0, first.t_commit + self.dt, self.dt)
        p = first.pose(ts)

        def overlaps(headway: float) -> bool:
            tau = ts - headway
            if second is None:
                q = np.column_stack([-0.5 * A2 + v * tau, np.zeros_like(tau), np.zeros_like(tau)])
            else:
                q = second.pose(tau)
            return bool(np.any(boxes_overlap(p, q, A1, B, A2, B, self.clearance)))

        lo, hi = base, base
        if overlaps(lo):
            # walk up to a separating headway, then bisect down to 1 mm of belt travel
            step = 0.05
            hi = lo + step
            while overlaps(hi):
                lo = hi
                hi += step
                if hi > first.t_commit + 60.0:
                    break
            while (hi - lo) * v > 1e-3:
                mid = 0.5 * (lo + hi)
                if overlaps(mid):
                    lo = mid
                else:
                    hi = mid
        self._geo_cache[key] = hi
        return hi

    # --- (2) the actuators can follow ----------------------------------------------
    def actuator_headway(
        self,
        A1: float,
        dest1: str,
        A2: float,
        dest2: str,
        v: float,
        alpha_before_deg: float | None = None,
    ) -> float:
        """
        Least time between the leading edges reaching x = 0 for the disks to serve both [s].

        alpha_before_deg: the disk angle before the leader (only matters when the
        leader goes straight and the follower is diverted: the disks may swing
        while down).

        Parameters
        ----------
        A1 : float
            The first rectangle's (or parcel's) length [m].
        dest1 : str
            The first parcel's destination.
        A2 : float
            The second's length [m].
        dest2 : str
            The second's.
        v : float
            The belt speed [m/s].
        alpha_before_deg : float
            The disks' angle before the first parcel [deg].

        Returns
        -------
        float
            The time [s].

        """
        s1, s2 = side_of(dest1), side_of(dest2)
        b = self.cell.disk_field_length
        act = self.act
        if s1 == 0 and s2 == 0:
            return 0.0
        if s1 == 0:
            # disks must stay down until the leader's trailing edge has left the field
            t_clear = (A1 + b) / v
            need = t_clear + act.stroke_total
            if alpha_before_deg is not None:
                need = max(need, act.slew_total(alpha_before_deg, self.alpha_for(dest2)))
            return need
        first = self.prediction(A1, v, dest1)
        if s2 == 0:
            return first.t_commit + act.stroke_total
        if s2 == s1:
            return 0.0
        return first.t_commit + act.slew_total(self.alpha_for(dest1), self.alpha_for(dest2))

    def headway(
        self,
        A1: float,
        dest1: str,
        A2: float,
        dest2: str,
        v: float,
        alpha_before_deg: float | None = None,
    ) -> float:
        """
        Return the least headway between two parcels.

        Parameters
        ----------
        A1 : float
            The first rectangle's (or parcel's) length [m].
        dest1 : str
            The first parcel's destination.
        A2 : float
            The second's length [m].
        dest2 : str
            The second's.
        v : float
            The belt speed [m/s].
        alpha_before_deg : float
            The disks' angle before the first parcel [deg].

        Returns
        -------
        float
            The least headway [s], geometric or actuator.

        """
        return max(
            self.geometric_headway(A1, dest1, A2, dest2, v),
            self.actuator_headway(A1, dest1, A2, dest2, v, alpha_before_deg),
        )

    def warm(self, lengths, v: float) -> None:
        """
        Fill the caches for parcels of these lengths [m] so that scans find them ready.

        Parameters
        ----------
        lengths : sequence of float
            Parcel lengths [m].
        v : float
            The belt speed [m/s].

        """
        for A in lengths:
            for d1 in ("left", "right"):
                self.predictor.predict(A, v, self.alpha_for(d1))
            for d1, d2 in (("left", "left"), ("left", "straight"), ("left", "right")):
                self.geometric_headway(A, d1, A, d2, v)

    def min_gap(
        self, A: float, v: float, dest1: str | None = None, dest2: str | None = None
    ) -> dict:
        """
        Return the least gap [m] (trailing edge to leading edge) at which parcels of length A sort.

        With dest1/dest2 given, for that pair; otherwise for every pair of
        destinations, with the worst case (the gap a mixed stream needs) under
        "worst" and the matching capacity in pcs/h.

        Parameters
        ----------
        A : float
            A parcel's length [m].
        v : float
            The belt speed [m/s].
        dest1 : str
            The first parcel's destination.
        dest2 : str
            The second's.

        Returns
        -------
        dict
            The least gap [m] by pair of destinations, and the worst.

        """
        pairs = (
            [(dest1, dest2)]
            if dest1 is not None
            else [(d1, d2) for d1 in DESTINATIONS for d2 in DESTINATIONS]
        )
        out = {}
        for d1, d2 in pairs:
            out[f"{d1}->{d2}"] = max(0.0, self.headway(A, d1, A, d2, v) * v - A)
        worst = max(out.values())
        out["worst"] = worst
        out["capacity_pcs_h"] = 3600.0 * v / (A + worst)
        return out


def seed_capacity(
    cell: CellModel, A: float, v: float, alpha_deg: float = 90.0, B: float | None = None
) -> float:
    """
    Return the seed's technical capacity W_t = 3600 / t_scrap [pcs/h] (Fig. 9).

    t_scrap: from the leading edge on the zone a/b border until the centre of gravity
    has covered the belt width s, on this cell's disk field and friction (the model
    is mirror-symmetric, so ±α give the same), within the scenes' 20 s horizon.

    Parameters
    ----------
    cell : CellModel
        The cell as the controller knows it.
    A : float
        A parcel's length [m].
    v : float
        The belt speed [m/s].
    alpha_deg : float
        The disk angle [deg].
    B : float
        Its width [m].

    Returns
    -------
    float
        W_t [pcs/h].

    """
    strips = cell_strips(
        v,
        abs(alpha_deg),
        cell.disk_field_length,
        cell.mu_belt,
        cell.mu_disks,
        cell.mu_belt,
        cell.friction_model,
    )
    parcel = Parcel(A, B if B is not None else cell.parcel_width, cell.parcel_mass)
    y0 = entry_state(parcel, v)
    res = simulate(parcel, strips, y0, (0.0, 20.0), "accurate", y_target=y0[1] + cell.belt_width)
    return 3600.0 / res.t_target if res.t_target else 0.0
