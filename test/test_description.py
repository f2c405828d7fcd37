"""
One description of the cell: every consumer takes its ranges from it, the README too.

For each physical quantity the scene schema (``sorter run --set``), the simulation
node's parameters and the controller's parameters that stand for it must declare
the same range as ``sorter_sim.model.description``, and refuse a value just outside it
with a message naming their own key.
"""

import math

import pytest

from sorter_cell import docs
from sorter_control.parameters import SCHEMA as CTL_SCHEMA
from sorter_control.parameters import config_from_values
from sorter_sim.model.description import QUANTITIES, DescriptionError, Q
from sorter_sim.runtime.params import SPECS, CellParams, ParamError
from sorter_sim.runtime.scene import _RULES, SceneError, validate

CTL_SPECS = {s.name: s for s in CTL_SCHEMA}

# quantity -> (scene key, node parameter, controller parameter); None where it has none
CONSUMERS = {
    'belt.speed': ('belt.v', 'belt_speed', 'belt_speed'),
    'belt.width': ('belt.s', 'belt_width', 'belt_width'),
    'disk_field.length': (None, 'disk_field_length', 'disk_field_length'),
    'disk_field.chute_margin': (None, 'chute_margin', 'chute_margin'),
    'friction.mu': ('zones.mu_b', 'mu_disks', 'mu_disks'),
    'diverter.alpha_deg': ('diverter.alpha_deg', 'alpha_deg', None),
    'diverter.alpha_slew_rate': (None, 'alpha_slew_rate_deg_s', 'alpha_slew_rate_deg_s'),
    'diverter.stroke': ('diverter.stroke', None, None),
    'diverter.stroke_time': (None, 'popup_stroke_time', 'popup_stroke_time'),
    'diverter.watchdog_timeout': (None, 'watchdog_timeout', None),
    'diverter.safe_alpha_deg': (None, 'safe_alpha_deg', None),
    'sensors.x': (None, 'photo_eyes.x', 'photo_eyes.x'),
    'parcel.length': ('parcel.A', 'parcel_A', 'max_parcel_length'),
    'parcel.width': ('parcel.B', 'parcel_B', 'nominal_parcel_width'),
    'parcel.mass': ('parcel.m', 'parcel_m', None),
    'parcel.skew_deg': ('parcel.phi0_deg', 'parcel_phi0_deg', None),
    'stream.gap': (None, 'arrival_gap', None),
    'stream.rate': (None, 'arrival_rate', None),
}


def test_every_quantity_has_its_consumers_listed():
    assert set(CONSUMERS) == {q.key for q in QUANTITIES}


def _outside(q):
    """Values just outside the range (and not a number at all)."""
    below = q.lo if q.lo_open else q.lo - 1e-9 * max(1.0, abs(q.lo))
    return [below, q.hi + 1e-9 * max(1.0, abs(q.hi)), math.nan, math.inf]


def _node_value(name, v):
    spec = SPECS[name]
    if spec.type == 'double_array':
        return [v] * max(2, spec.length[0]) if name != 'photo_eyes.x' else [v, -0.3, 2.0]
    return v


def _controller_values(name, v):
    values = {s.name: s.default for s in CTL_SCHEMA}
    values[name] = [v, -0.3, 2.0] if name == 'photo_eyes.x' else v
    return values


@pytest.mark.parametrize('key', sorted(CONSUMERS))
def test_consumers_declare_the_described_range_and_refuse_outside_it(key):
    q = Q[key]
    scene_key, node_name, ctl_name = CONSUMERS[key]
    if scene_key is not None:
        kind, lo, hi, allowed = _RULES[scene_key]
        assert (lo, hi) == (q.lo, q.hi) and q.allowed in allowed
        section, k = scene_key.split('.')
        for v in _outside(q):
            with pytest.raises(SceneError, match=scene_key.replace('.', r'\.')):
                validate({section: {k: v}})
    if node_name is not None:
        spec = SPECS[node_name]
        assert (spec.lo, spec.hi, spec.lo_open, spec.units) == (q.lo, q.hi, q.lo_open, q.unit)
        assert spec.description.startswith(q.meaning)
        for v in _outside(q):
            with pytest.raises(ParamError, match=node_name):
                CellParams.defaults().with_changes(
                    {node_name: _node_value(node_name, v)}, runtime=False
                )
    if ctl_name is not None:
        spec = CTL_SPECS[ctl_name]
        assert (spec.lo, spec.hi, spec.lo_open) == (q.lo, q.hi, q.lo_open)
        assert spec.description.startswith(q.meaning)
        for v in _outside(q):
            with pytest.raises(ValueError, match=ctl_name):
                config_from_values(_controller_values(ctl_name, v))


def test_a_quantity_refuses_with_its_key_the_value_and_the_range():
    with pytest.raises(DescriptionError) as err:
        Q['belt.speed'].check(12.0)
    assert str(err.value) == 'belt.speed: must be a finite number in [0.05, 10] m/s, got 12.0'
    with pytest.raises(DescriptionError, match="disk_field.length: .*\\(0, 10\\] m, got 0"):
        Q['disk_field.length'].check(0)
    with pytest.raises(DescriptionError, match='True'):
        Q['friction.mu'].check(True)
    assert Q['friction.mu'].check(3) == 3.0


def test_the_documented_tables_are_the_generated_ones():
    for name, where in docs.placement().items():
        assert len(where) == 1, (name, where)
    for page in docs.pages():
        text = page.read_text()
        assert docs.render(text) == text, (
            f'{page.name} differs from the declarations: run python -m sorter_cell.docs'
        )
