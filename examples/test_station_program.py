"""The third-party station program on a line: pytest with sorter_cell installed runs it as is."""

import pytest
from station_program import StationProgram

from sorter_cell.testing.contract import check_station_program


@pytest.mark.sorter_line(stations=3, programs={2: StationProgram})
def test_my_program_sorts_its_parcels_and_passes_the_others_on(sorter_line):
    for label, destination in (('M-1', 'D03'), ('M-2', 'D04'), ('M-3', 'D05'), ('M-4', 'D02')):
        sorter_line.induct(label, destination)
        sorter_line.run(2.5)
    assert sorter_line.run_until(lambda: len(sorter_line.dispositions) == 4, 30.0)
    got = {d.label: (d.code, d.station, d.chute) for d in sorter_line.dispositions}
    assert got == {
        'M-1': ('sorted', 'S02', 'S02L'),
        'M-2': ('sorted', 'S02', 'S02R'),
        'M-3': ('sorted', 'S03', 'S03L'),
        'M-4': ('sorted', 'S01', 'S01R'),
    }


def test_my_program_keeps_the_station_contract():
    report = check_station_program(StationProgram)
    assert report, report
