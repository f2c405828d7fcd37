"""The minimal controller against the cell: pytest with sorter_cell installed runs it as is."""

import pytest
from minimal_controller import MinimalController


@pytest.mark.sorter_cell(params={'alpha_deg': 90.0})
def test_l_parcels_go_left_and_the_others_straight(sorter_cell):
    sorter_cell.add_node(MinimalController(context=sorter_cell.context))
    for label in ('L-1', 'S-1', 'L-2', 'S-2'):
        sorter_cell.induct(label, length=0.4, width=0.3)
    assert sorter_cell.run_until(lambda: len(sorter_cell.outcomes) == 4, timeout_s=30.0)
    exits = {o.label: o.exit for o in sorter_cell.outcomes}
    assert exits == {'L-1': 'left', 'S-1': 'straight', 'L-2': 'left', 'S-2': 'straight'}


def test_the_cell_catches_a_controller_that_stops(sorter_cell):
    node = sorter_cell.add_node(MinimalController(context=sorter_cell.context))
    sorter_cell.run(1.0)
    node.heartbeat_timer.cancel()  # the PLC hangs: no more heartbeats
    sorter_cell.run(2.0)
    assert 'watchdog' in sorter_cell.sim.cell.faults
