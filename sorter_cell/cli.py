"""
The ``sorter`` command and its verbs.

``sorter run | paper | sweep | bench | demo | replay | scenario | recover | warmup |
line-key``.

The model's verbs come from ``sorter_sim.cli``; ``demo`` starts the simulation
node and the controller together, so it sits here, above both packages.

This module imports nothing heavy at its top: the console script loads it first, and
a Ctrl-C while numpy, numba and rclpy still load is a clean stop (exit 130, no
traceback), as it is once the command runs.
"""

from __future__ import annotations

import sys

# verb -> (module, help), besides the model's (sorter_sim.cli.VERBS)
CELL_VERBS = dict(
    demo=("sorter_cell.demo", "run the sorter cell: simulation + controller nodes"),
    replay=("sorter_cell.replay", "summarise a recorded run (MCAP) and draw its parcel paths"),
    scenario=("sorter_cell.scenario_cli", "run scenario files (one, or a campaign on Dask)"),
    recover=("sorter_cell.recover", "write a complete MCAP file from a recording cut short"),
    warmup=("sorter_cell.warmup_cli", "compile the model's kernels into numba's cache, once"),
    **{"line-key": ("sorter_cell.line_key_cli", "write a new random key for a line's segments")},
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
        The exit code (130 after Ctrl-C).

    """
    try:
        from sorter_sim import cli as model_cli

        return model_cli.main(argv, dict(model_cli.VERBS, **CELL_VERBS))
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
