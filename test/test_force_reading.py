"""
The two readings of the seed's zone force, eqs. (4.2)-(4.3) (``force_reading``).

The centre reading's force is closed form (F_max of eq. 4.3 against the centre's slip),
and it equals the per-element force whenever the parcel does not spin; the statements
that tell the readings apart are asserted against the seed's own numbers.
"""

import math

import numpy as np
import pytest

from sorter_sim.studies.claims_grid import FRICTION_MODELS
from sorter_sim.studies.force_reading import _Wrench, sort_centre_reading
from sorter_sim.studies.paper_support import sort_once, sorting_scene

G = 9.81


def test_the_centre_force_is_eq_4_3_against_the_centres_slip():
    scene = sorting_scene(A=0.7, v=1.5, alpha_deg=90.0, stick="seed")
    w = _Wrench(scene)
    # the parcel astride the border, sliding and spinning
    state = np.array([0.1, 0.02, 0.2, 1.1, 0.4, 1.5])
    force, _ = w.centre(state)
    spun, _ = w(state)
    area = w.area.copy()
    for k, (vx, vy) in enumerate([(1.5, 0.0), (0.0, 1.5)]):
        slip = np.array([state[3] - vx, state[4] - vy])
        f_max = 0.6 * 5.0 * G * area[k] / (0.7 * 0.2)  # eq. (4.3), constant μ
        assert force[k] == pytest.approx(-f_max * slip / np.hypot(*slip), rel=1e-9)
        # the per-element force of a spinning parcel is smaller (its parts pull apart)
        assert np.hypot(*spun[k, :2]) < np.hypot(*force[k])
    # without spin the readings are one
    still = state.copy()
    still[5] = 0.0
    assert w(still)[0][:, :2] == pytest.approx(force, rel=1e-12)


def test_the_seeds_numbers_tell_the_readings_apart():
    kw = dict(A=0.7, v=1.5, alpha_deg=90.0, stick="seed")
    centre = sort_centre_reading(sorting_scene(**kw), dt=2e-4)
    element = sort_once(**kw)
    simplified = sort_once(rotation=False, **kw)
    w_centre = 3600 / centre.t_c
    # Fig. 9a: the seed reads "approximately 3600 pcs/h"
    assert abs(w_centre / 3600 - 1) < 0.01
    assert abs(element["capacity_pcs_h"] / 3600 - 1) > 0.03
    # the moment still turns the parcel and (barely) shortens x_o under the centre reading
    assert centre.phi_deg > 5.0
    assert centre.x_o < simplified["x_scrap"]
    assert simplified["x_scrap"] - centre.x_o < 0.25 * (simplified["x_scrap"] - element["x_scrap"])


def test_fig14_force_rises_under_the_centre_reading_for_model_1_only():
    end, rise = {}, {}
    for j in ("1", "2", "3"):
        law, values = FRICTION_MODELS[j]
        scene = sorting_scene(
            A=0.4, B=0.26, v=1.5, alpha_deg=45.0, mu_a=None, mu_b=None, mu_c=None,
            model=law, law=values, stick="seed",
        )  # fmt: skip
        r = sort_centre_reading(scene, dt=2e-4)
        e3 = r.e3 if math.isfinite(r.e3) else r.t_c
        part = r.F_b[r.t >= e3 - 0.25 * (e3 - r.e2)]
        rise[j] = float(np.max(part / np.minimum.accumulate(part)))
        end[j] = r.F_b[-1]
    # models 2, 3: the full F_max = μ_G m g once on the disks; model 1: μ climbs to μ_0
    for j in ("2", "3"):
        assert end[j] == pytest.approx(0.46 * 5.0 * G, rel=1e-3)
        assert rise[j] < 1.005
    assert end["1"] == pytest.approx(0.65 * 5.0 * G, rel=0.02)
    assert rise["1"] > 1.3
