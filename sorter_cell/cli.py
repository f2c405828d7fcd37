"""
The ``sorter`` command: ``run | paper | sweep | bench | demo | replay | scenario | recover``.

The model's verbs come from ``sorter_sim.cli``; ``demo`` starts the simulation
node and the controller together, so it sits here, above both packages.
"""

from __future__ import annotations

import sys

from sorter_sim import cli as model_cli

VERBS = dict(
    model_cli.VERBS,
    demo=("sorter_cell.demo", "run the sorter cell: simulation + controller nodes"),
    replay=("sorter_cell.replay", "summarise a recorded run (MCAP) and draw its parcel paths"),
    scenario=("sorter_cell.scenario_cli", "run scenario files (one, or a campaign on Dask)"),
    recover=("sorter_cell.recover", "write a complete MCAP file from a recording cut short"),
)


def main(argv: list[str] | None = None) -> int:
    """
    Entry point of ``sorter``.

    Parameters
    ----------
    argv : list of str, optional
        The arguments (default: the process's).

    Returns
    -------
    int
        The exit code.

    """
    return model_cli.main(argv, VERBS)


if __name__ == "__main__":
    sys.exit(main())
