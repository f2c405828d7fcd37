"""
The seed's numerical experiments as commands: ``sorter paper FIG [--out DIR]``.

One function per figure of Piątkowski (2009), sections 3, 5 and 6. Each computes
its data from the model core (``sorter_sim.model.core``) through the same scene code
the simulation node uses (``sorter_sim.runtime.scene``), writes a CSV and a PNG
(matplotlib, Agg) into ``out`` when given, and returns a ``FigureResult``: the
headline figures next to the seed's statements, and the seed's qualitative
claims as measured on this run. ``quick=True`` runs coarse grids (for tests);
the full grids are the command's default.

Symbols keep the seed's letters: A x B parcel length x width [m] (A along the
belt at φ = 0), v belt speed [m/s], α disk angle, b disk-field width (zone b),
s = 0.7 m the lateral distance the centre of gravity must cover to be scrapped,
x_o the distance it travels along the belt meanwhile, W_t = 3600/t_c capacity
[pcs/h], μ_a, μ_b the coefficients of the belt and the disks, v_min the
threshold speed of eq. (3.1).

Figures: 4, 5 (stick-slip body), 7, 8 (a-d), 9, 10, 11, 13, 14 (covers 15 and
16) and ``two-stage`` (the seed's conclusion, ``two_stage.py``).
"""

from sorter_sim.studies.paper_friction import FIG3_LAWS, fig3, fig4, fig5
from sorter_sim.studies.paper_models import (
    FIG13_LAWS,
    FIG14_MODELS,
    FINAL_PART,
    fig13,
    fig14,
    final_rise,
)
from sorter_sim.studies.paper_sorting import fig7, fig8, fig9
from sorter_sim.studies.paper_stages import ACC_WINDOW, fig10, fig11
from sorter_sim.model.core.simulate import FrictionLaw
from sorter_sim.studies.paper_support import FigureResult, minimal_disk_width, step_root

__all__ = [
    "ACC_WINDOW",
    "FIG13_LAWS",
    "FIG14_MODELS",
    "FIG3_LAWS",
    "FINAL_PART",
    "FigureResult",
    "FrictionLaw",
    "fig3",
    "fig4",
    "fig5",
    "fig7",
    "fig8",
    "fig9",
    "fig10",
    "fig11",
    "fig13",
    "fig14",
    "final_rise",
    "minimal_disk_width",
    "step_root",
]
