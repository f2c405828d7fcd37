"""
Every friction law x method x shipped scene x stick law, within Coulomb's bounds.

A surface can push a parcel no harder than μ_max m g (μ_max: the law's largest
coefficient, static or kinetic, at any speed the cell can reach), and turn it no harder
than μ_max m g r_max about its centre of gravity (r_max: half the footprint's diagonal).
So between any two recorded instants the velocity changes by at most μ_max g Δt and the
rate of turn by at most μ_max g r_max Δt / k² (k² = (A² + B²)/12); and a parcel that
starts with no lateral velocity needs t >= sqrt(2 s / (μ_max g)) to travel s across the
belt. A law that crashed, stalled or put out energy from nowhere fails here.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from sorter_sim.model.core.friction import mu_kinetic_array, mu_static
from sorter_sim.runtime.scene import apply_overrides, load_scene, run_scene, scene_strips

SCENES = sorted(Path(__file__).resolve().parent.parent.glob('config/scenes/*.yaml'))
LAWS = ('const2', 'const1', 'linear', 'polynomial', 'stribeck', 'bspline')
METHODS = ('accurate', 'implicit', 'threshold')
STICKS = ('exact', 'seed')


def _mu_max(strips, v_top: float) -> float:
    """Return the largest μ any strip's law gives at any speed up to ``v_top``, static included."""
    speeds = np.linspace(0.0, v_top, 20001)[1:]
    top = 0.0
    for st in strips:
        row = st.law.row()
        mus = mu_kinetic_array(st.law.law_id, row, speeds)
        top = max(top, float(mus.max()), float(mu_static(st.law.law_id, row))) * max(
            1.0, st.weight
        )
    return top


def test_the_matrix_covers_every_shipped_scene():
    assert {p.stem for p in SCENES} >= {'fig7', 'fig9a', 'fig14', 'three_zones'}


@pytest.mark.parametrize('stick', STICKS)
@pytest.mark.parametrize('method', METHODS)
@pytest.mark.parametrize('law', LAWS)
@pytest.mark.parametrize('scene_path', SCENES, ids=lambda p: p.stem)
def test_every_law_method_and_scene_runs_within_coulombs_bounds(scene_path, law, method, stick):
    scene = apply_overrides(
        load_scene(scene_path),
        [f'friction.model={law}', f'solver.method={method}', f'model.stick={stick}'],
    )
    res, summary = run_scene(scene)
    assert res.success, f'{scene_path.stem} {law} {method} {stick}: {res.message}'
    assert np.all(np.isfinite(res.y)) and np.all(np.isfinite(res.t))
    strips = scene_strips(scene)
    v_belt = scene['belt']['v']
    mu_max = _mu_max(strips, 4.0 * v_belt + 1.0)
    g = scene['model']['g']
    A, B = scene['parcel']['A'], scene['parcel']['B']
    r_max = 0.5 * math.hypot(A, B)
    k2 = (A * A + B * B) / 12.0
    dt = np.diff(res.t)
    assert np.all(dt >= 0.0)
    dv = np.hypot(np.diff(res.y[:, 3]), np.diff(res.y[:, 4]))
    dw = np.abs(np.diff(res.y[:, 5]))
    # the seed's threshold law snaps a slip below v_min to the surface's velocity
    snap = 2.0 * scene['model']['v_min'] if stick == 'seed' or method == 'threshold' else 0.0
    slack = 1e-9 + snap
    worst_v = float(np.max(dv - mu_max * g * dt * (1 + 1e-6)))
    assert worst_v <= slack, f'velocity changed faster than μ_max g allows by {worst_v:.3g} m/s'
    worst_w = float(np.max(dw - mu_max * g * r_max / k2 * dt * (1 + 1e-6)))
    assert worst_w <= slack / r_max + 1e-9, f'turn rate changed too fast by {worst_w:.3g} rad/s'
    if summary['t_scrap'] is not None:
        s = scene['belt']['s']
        t_min = math.sqrt(2.0 * s / (mu_max * g))
        assert summary['t_scrap'] >= t_min * (1 - 1e-9), (summary['t_scrap'], t_min)
        assert math.isfinite(summary['t_scrap'])
