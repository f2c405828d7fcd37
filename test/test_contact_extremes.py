"""
Contact: rigid at its extremes, the cases of ``sorter bench precision`` against their closed forms.

Every case of ``contact_cases.CASES`` (a mass ratio of 1:100 impacting and pressed,
contact friction 0.05 and 1.5 at a rail and at a parcel, ten parcels and ten long
parcels pressed against a stopper, a parcel wedged between two rails) at the default
control period and at the quick report's coarser one: finite, no speed above the
belt's, no overlap beyond one period's sweep, its error within the closed form's
bound, and a case held at rest still to below 1e-9 m/s.
"""

from __future__ import annotations

import math

import pytest

from sorter_sim.studies import contact_cases as cc

# each case's bound on its error at h [s]: an impact's rest positions are off by
# O(μ g h²) (the touch's place, taken back along the new velocity: docs/model.md);
# every other closed form is a balance the step meets to rounding
BOUNDS = {
    'impact_1_100': lambda h: cc.MU * cc.G * h**2,
    'impact_100_1': lambda h: cc.MU * cc.G * h**2,
}
AT_REST = {'pressed_1_100', 'stack_10', 'stack_10_long', 'wedged'}


@pytest.mark.parametrize('case', cc.CASES, ids=lambda c: c.key)
@pytest.mark.parametrize('h', [1e-3, 2e-3])
def test_contact_extreme_case_meets_its_closed_form(case, h):
    row = case.run(h)
    assert row.finite and row.ok, row
    assert row.sim_s > 0.0 and row.wall_s > 0.0
    # no blow-up: nothing faster than the belt or the case's own start (1 m/s impacts)
    assert row.speed <= cc.V * (1 + 1e-9), row.speed
    # the contacts are found at the period's end: one period's travel at most
    assert row.overlap <= 2 * cc.V * h, row.overlap
    bound = BOUNDS.get(case.key, lambda h: 1e-9)(h)
    assert row.error <= bound, (case.key, h, row.error, bound)
    if case.key in AT_REST:
        assert row.noise < 1e-9, (case.key, row.noise)
    else:
        assert math.isnan(row.noise)


def test_the_contact_report_names_each_case_and_its_closed_form():
    rows = [(c, [c.run(2e-3)]) for c in cc.CASES[:2]]
    text = cc.contact_markdown(rows)
    assert text.startswith('## Parcels that touch: stiff and extreme cases')
    for c in cc.CASES[:2]:
        assert c.title in text and c.closed_form in text
    assert cc.contact_findings(rows) == []
