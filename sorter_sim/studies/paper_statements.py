"""
The seed's statements, one by one, and the checks and tests that decide them.

Every qualitative statement the seed makes about its figures 3-16 and in its
conclusions is listed here with its words (quoted, shortened where marked …),
the keys of the figure checks (``FigureResult.checks``) that measure it, and the
test in ``test/test_paper.py`` that asserts those checks. ``docs/paper.md`` draws
its statement table from this list, both stick laws side by side.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Statement:
    """
    One statement of the seed.

    where: the figure or section it is about; words: the seed's words; checks: the
    figure-check keys that decide it (all must hold); test: the test asserting them
    (None for a statement about run time, reported but not asserted); note: what
    the verdict depends on beyond the seed (an assumed parameter, a reading).
    """

    where: str
    words: str
    checks: tuple
    test: str | None
    note: str = ""


STATEMENTS = (
    Statement(
        "Fig. 3",
        "(a)-(c) "
        "“present a logical and real range of variability”; (d), (e): “for the speed "
        "approaching v_o = 1 m/s, the friction coefficient would reach an unbelievably high "
        "value”",
        ("3-range",),
        "test_fig3_laws_as_used",
        "the parameters of (c)-(e) are assumed (the seed names their sources, not their "
        "values): the verdict shows the assumed shapes agree with the seed's words",
    ),
    Statement(
        "Fig. 4",
        "rows F(1), F(2), F(3) of eq. (3.1) take turns (“Activity of respective rows … is "
        "illustrated in Fig. 4b,c,d”)",
        ("4-rows",),
        "test_fig4_rows_of_eq_3_1_and_first_break_away",
    ),
    Statement(
        "Fig. 4",
        "row F(3) is “for the initiation of the body transition … when the external force "
        "P_ext becomes larger than the static friction force F_stat”",
        ("4-break",),
        "test_fig4_rows_of_eq_3_1_and_first_break_away",
    ),
    Statement(
        "Fig. 5",
        "“A strict relationship between the speed threshold value v_min and duration of "
        "stage F(3) occurs during the first body transition” (t_I)",
        ("5-tI",),
        "test_fig5_first_static_stage_follows_v_min_later_ones_do_not",
    ),
    Statement(
        "Fig. 5",
        "“The next cycles of the stick-slip friction (curves t_II and t_III) do not show such "
        "a dependence”",
        ("5-tII",),
        "test_fig5_first_static_stage_follows_v_min_later_ones_do_not",
    ),
    Statement(
        "Fig. 7",
        "the moment of friction forces “causes that the load is rotated by the angle φ_k”",
        ("7-rot",),
        "test_fig7_moment_of_friction_rotates_and_shortens_x_o",
    ),
    Statement(
        "Fig. 7",
        "“and the distance at which the load forces its way into the manipulator working "
        "space is shortened”",
        ("7-short",),
        "test_fig7_moment_of_friction_rotates_and_shortens_x_o",
    ),
    Statement(
        "Section 5",
        "“Neglecting the moment of friction forces … significantly speeds up numerical "
        "experiments”",
        ("7-speed",),
        None,
        "a run time on this machine: reported, not asserted (a timed test would flake)",
    ),
    Statement(
        "Fig. 8a",
        "“the distance x_o depends on the length of the manipulated object … The longer the "
        "load, the greater the required width of the zone b”",
        ("8a-A",),
        "test_fig8_trends_of_x_o",
    ),
    Statement(
        "Fig. 8a",
        "x_o “is not sensitive to its width B”",
        ("8a-B",),
        "test_fig8_trends_of_x_o",
    ),
    Statement(
        "Fig. 8b",
        "“The greater the speed value v, the greater the distance x_o”",
        ("8b",),
        "test_fig8_trends_of_x_o",
    ),
    Statement(
        "Fig. 8c",
        "“The lower the disk setting angle α, the greater the required width of the zone b”",
        ("8c",),
        "test_fig8_trends_of_x_o",
    ),
    Statement(
        "Fig. 8d",
        "“The greater the value of friction coefficient μ_b, the shorter the distance x_o”",
        ("8d-b",),
        "test_fig8_trends_of_x_o",
    ),
    Statement(
        "Fig. 8d",
        "μ_a: “the lower the value of this coefficient, the more effective translocation of "
        "the load onto the chute”",
        ("8d-a",),
        "test_fig8_trends_of_x_o",
    ),
    Statement(
        "Fig. 8d",
        "“μ_b (in the zone b) has greater influence on the course of the sorting process "
        "than … μ_a”",
        ("8d-more",),
        "test_fig8_trends_of_x_o",
    ),
    Statement(
        "Fig. 9a",
        "“for the transportation speed v = 1.5 m/s and load length equal to A = 0.7 m, one "
        "can achieve technical capacity … of approximately W_t = 3600 pcs/h”",
        ("9a",),
        "test_fig9_capacity_falls_with_alpha_and_length",
        "the seed does not say when t_c starts; here at the leading edge on the border "
        "(the CoG on the border gives the larger figure in brackets)",
    ),
    Statement(
        "Fig. 9",
        "capacity against load length (drawn in Fig. 9, not put in words)",
        ("9-A",),
        "test_fig9_capacity_falls_with_alpha_and_length",
    ),
    Statement(
        "Fig. 9b",
        "“When … α = 45° …, the sorting capacity slightly deteriorates (in comparison to … "
        "Fig. 9a – especially in the case of longer objects)”",
        ("9b",),
        "test_fig9_the_45_degree_loss_is_slight_and_least_for_long_loads",
        "read as: the loss is slight, slightest for longer loads; the next sentence (30°: "
        "“similar … more significant in the case of short loads”) and conclusion 2b say "
        "the same. The other reading, a loss larger for longer loads, is the opposite of "
        "this check",
    ),
    Statement(
        "Fig. 9c",
        "“When … α = 30° …, the drop of sorting capacity looks similar: it is more "
        "significant in the case of short loads, and less significant for longer loads”",
        ("9c",),
        "test_fig9_capacity_falls_with_alpha_and_length",
    ),
    Statement(
        "Section 5",
        "“The change of the working angle α does not have any radical effect on the time of "
        "scrapping … (especially in the case of long loads), despite the fact that the load "
        "… must travel much longer way”",
        ("9-tc",),
        "test_fig9_scrapping_time_grows_far_less_than_the_path",
        "“radical” taken as: t_c grows by less than half as much as the path 1/sin α",
    ),
    Statement(
        "Fig. 10",
        "“a substantial part of time of load translocation onto the chute is the time of "
        "transient motion (stage E2)”",
        ("10-share",),
        "test_fig10_e2_is_a_substantial_part_and_the_early_push_is_stronger_at_low_alpha",
        "“substantial” taken as: at least a fifth of t_c",
    ),
    Statement(
        "Fig. 10",
        "at α = 45° (and 30°) the load “remains for a much shorter period in the state of "
        "transient motion (stage E2)” than at α = 90°",
        ("10-E2",),
        "test_fig10_rubbing_components_and_stages",
    ),
    Statement(
        "Fig. 10",
        "at α = 45°, 30° “the component of rubbing speed in the direction of the axis y_o "
        "(η_b) … is much greater than the component in the direction of the axis x_o (ξ_b)”",
        ("10-eta",),
        "test_fig10_rubbing_components_and_stages",
    ),
    Statement(
        "Fig. 10",
        "“If … α = 90°, the components of the load rubbing speed in the directions of the "
        "axes x_o and y_o are the same (ξ_b = η_b)”",
        ("10-eta90",),
        "test_fig10_rubbing_components_and_stages",
    ),
    Statement(
        "Section 5",
        "F_ηb “is much greater than … F_ξb, which results in a greater acceleration of the "
        "load motion towards the chute” (at α = 45°, 30°)",
        ("10-acc",),
        "test_fig10_e2_is_a_substantial_part_and_the_early_push_is_stronger_at_low_alpha",
        "measured over the first 50 ms of E2; the averages over the whole of E2 follow in "
        "brackets",
    ),
    Statement(
        "Fig. 11",
        "“α = 90° … leads to the expected shortening of the required width of the "
        "manipulator working space b – as compared to … α = 45° … and α = 30°”",
        ("11-a",),
        "test_fig11_minimal_width_falls_as_alpha_rises_and_is_a_sharp_threshold",
    ),
    Statement(
        "Fig. 11",
        "“A particularly high difference in the selected zone width … appears in the case of "
        "low transportation velocity of the conveyor v and loads of small length A”",
        ("11-lowv",),
        "test_fig11_the_excess_of_30_degrees_is_largest_at_low_speed_and_short_loads",
        "decided on the full grid (the quick grid has one v and one A)",
    ),
    Statement(
        "Fig. 13a",
        "by model 1 “the object was set in damped oscillatory motion”",
        ("13-damped",),
        "test_fig13_bspline_damps_constant_laws_do_not",
        "depends on the assumed b-spline points and the assumed 0.05 m release offset",
    ),
    Statement(
        "Fig. 13b",
        "“The simulation of this process with the use of classical friction coefficient "
        "models always leads to … non-damped oscillatory motion”",
        ("13-undamped",),
        "test_fig13_bspline_damps_constant_laws_do_not",
    ),
    Statement(
        "Fig. 14",
        "“In the case of model 1 …, in the final interval of stage E2 … one observes a rapid "
        "increase of this force” (F_b)",
        ("14-rise",),
        "test_fig14_to_16_models_2_3_within_1_percent_and_model_1_force_rise",
        "how large the rise is depends on the assumed b-spline points; the level at the end "
        "of E2, against models 2 and 3, follows it",
    ),
    Statement(
        "Figs. 15, 16",
        "“The relative discrepancy between the results based on classic models 2 and 3 and "
        "those obtained with model 1 does not exceed 1%”",
        ("16-1pct",),
        "test_fig14_to_16_models_2_3_within_1_percent_and_model_1_force_rise",
        "model 3 taken as μ = μ_G = 0.46 and model 1 as the assumed b-spline",
    ),
    Statement(
        "Section 6",
        "sorting “usually involves high rubbing speeds of loads and the number of "
        "transitions between the states of static and kinematic friction is minimal”",
        ("6-trans",),
        "test_fig14_to_16_models_2_3_within_1_percent_and_model_1_force_rise",
    ),
    Statement(
        "Conclusion 1",
        "“The classic one-parameter function describing the friction coefficient … "
        "realistically represents the nature of the load sorting process”",
        ("16-1pct", "6-trans"),
        "test_fig14_to_16_models_2_3_within_1_percent_and_model_1_force_rise",
    ),
    Statement(
        "Conclusion 2a",
        "an increase of α in ⟨30°, 90°⟩ causes that “the required width b of the manipulator "
        "working zone becomes shorter”",
        ("11-a",),
        "test_fig11_minimal_width_falls_as_alpha_rises_and_is_a_sharp_threshold",
    ),
    Statement(
        "Conclusion 2b",
        "“capacity of the sorting process increases; this increase is more pronounced in the "
        "case of short loads and less significant for longer loads”",
        ("C2b",),
        "test_fig9_capacity_falls_with_alpha_and_length",
    ),
    Statement(
        "Conclusion 2c",
        "“acceleration of motion of the manipulated object towards the chute decreases, and "
        "the period of transient motion of the object in this direction becomes longer”",
        ("C2c",),
        "test_fig10_e2_is_a_substantial_part_and_the_early_push_is_stronger_at_low_alpha",
        "the acceleration over the first 50 ms of E2, as in the section 5 row above",
    ),
    Statement(
        "Conclusion 3",
        "“For the sake of capacity …, one should assume possibly high values of the friction "
        "coefficient for the disk system, and possibly low values for the carrying surface "
        "of the main conveyor; the course of the sorting process is definitely more "
        "sensitive to changes of frictional properties of the disk system”",
        ("C3",),
        "test_capacity_rises_with_the_disks_mu_and_falls_with_the_belts",
    ),
    Statement(
        "Conclusion 4",
        "“A decrease in length of the manipulator working space (friction zone b) can be "
        "obtained by dividing the sorting process into two stages”",
        ("C4-same", "C4"),
        "test_two_stage_shortens_the_final_field_at_30_degrees",
    ),
)
