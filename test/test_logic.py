"""
The sorter PLC logic without ROS: routing, timing from the model core, tracking, decisions, faults.

The plant is ``sorter_control.plant_stub.PlantStub`` (kinematic belt and disks);
the divert timing comes from the real model core, checked here against the
seed's Fig. 9 capacity and against closed forms of the spacing rules.
"""

import math

import numpy as np
import pytest

from sorter_control.logic import (
    ControllerConfig,
    Edge,
    EdgeDetector,
    InputImage,
    Reply,
    RoutingError,
    RoutingTable,
    SorterLogic,
)
from sorter_control.plant_stub import PlantStub, run_cell
from sorter_control.timing import (
    Actuators,
    CellModel,
    DivertPredictor,
    GapModel,
    boxes_overlap,
    seed_capacity,
)
from sorter_sim.model.core.geometry import box_corners

RULES = ("L*=left", "R*=right", "S*=straight", "VIP-1=right")
# one predictor for the module: its cache is what a running controller keeps too
PREDICTOR = DivertPredictor(CellModel())


def make(**kw):
    kw.setdefault("routing_rules", RULES)
    cfg = ControllerConfig(**kw)
    pred = PREDICTOR if cfg.cell == PREDICTOR.cell else None
    return cfg, SorterLogic(cfg, pred), PlantStub(cfg)


def safe_gap(logic, A=0.4):
    return logic.min_gap(A)["worst"] + 0.05


# --------------------------------------------------------------------------- routing


def test_routing_exact_beats_prefix_and_longest_prefix_wins():
    rt = RoutingTable(["A*=left", "AB*=right", "ABC7=straight"], default="", reject="right")
    assert rt.lookup("ABC7") == ("straight", "exact")
    assert rt.lookup("ABX") == ("right", "prefix")
    assert rt.lookup("AX") == ("left", "prefix")
    assert rt.lookup("Q1") == ("right", "unknown")  # to the reject destination
    assert rt.lookup(None) == ("right", "no_read")
    assert rt.lookup("") == ("right", "no_read")


def test_routing_default_and_runtime_updates():
    rt = RoutingTable(["A*=left"], default="straight", reject="right")
    assert rt.lookup("Z9") == ("straight", "default")
    rt.set("Z9", "right")
    assert rt.lookup("Z9") == ("right", "exact")
    rt.set("Z9", "")  # removed again
    assert rt.lookup("Z9") == ("straight", "default")
    rt.set("*", "")  # no default: unknown labels are rejected
    assert rt.lookup("Z9") == ("right", "unknown")
    rt.set("Z*", "left")
    assert rt.lookup("Z9") == ("left", "prefix")
    assert sorted(rt.rules()) == ["A*=left", "Z*=left"]


@pytest.mark.parametrize(
    "rule, words",
    [
        ("A=up", "one of left, right, straight"),
        ("no_equals", "label=destination"),
        ("=left", "1 to 64"),
        ("A*B=left", "not allowed"),
        (42, "label=destination"),
        # the grammar: a destination cannot be a number, a label holds no '=' or ';'
        ("D=1", "one of left, right, straight"),
        ("D;1=left", "not allowed"),
        ("D=1=left", "one of left, right, straight"),
        ("x" * 65 + "=left", "1 to 64"),
        ("A B=left", "not allowed"),
        ("A=", "the destination is empty"),
        ("A= ", "the destination is empty"),
    ],
)
def test_routing_rejects_bad_rules_with_a_reason(rule, words):
    with pytest.raises(RoutingError, match=words) as refused:
        RoutingTable([rule])
    # a rule of the table cannot be empty: the refusal does not offer it
    assert "or empty" not in str(refused.value)


def test_routing_refuses_a_pattern_given_twice_and_a_removal_of_nothing():
    with pytest.raises(RoutingError, match="given twice"):
        RoutingTable(["A*=left", "A*=right"])
    with pytest.raises(RoutingError, match="given twice"):
        RoutingTable(["*=left"], default="right")  # two defaults
    rt = RoutingTable(["A*=left"])
    with pytest.raises(RoutingError, match="no rule for 'B7' to remove"):
        rt.set("B7", "")
    with pytest.raises(RoutingError, match="no default to remove"):
        rt.set("*", "")
    assert rt.rules() == ["A*=left"]


def test_routing_error_messages_never_echo_a_long_input():
    with pytest.raises(RoutingError) as err:
        RoutingTable(["A" * 100_000 + "=left"])
    assert len(str(err.value)) < 500


def test_routing_update_that_is_bad_changes_nothing():
    cfg, logic, _ = make()
    before = logic.routing.rules()
    out = logic.scan(InputImage(t=0.0, routing_updates=[("L1", "sideways"), ("", "left")]))
    assert logic.routing.rules() == before
    assert logic.counts["routing_rejected"] == 2
    assert any("sideways" in text for _, text in out.log)


@pytest.mark.parametrize(
    "kw, words",
    [
        ({"scan_period": 0.0}, "scan_period"),
        ({"belt_speed": math.nan}, "belt_speed"),
        ({"divert_alpha_deg": 120.0}, "divert_alpha_deg"),
        ({"photo_eyes": (("pe_scan", -0.1), ("pe_divert", -0.3))}, "scanner < divert eye"),
        ({"scan_eye": "nope"}, "not among photo_eyes"),
        ({"routing_rules": ("A=up",)}, "one of left"),
        ({"reject_destination": "bin"}, "reject destination"),
    ],
)
def test_config_rejects_bad_values_naming_them(kw, words):
    with pytest.raises(ValueError, match=words):
        ControllerConfig(**kw)


# ------------------------------------------------------------------ timing from the model core


def test_seed_capacity_fig9a():
    # seed section 5: v = 1.5 m/s, A = 0.7 m, alpha = 90 deg, B = 0.2 m, b -> inf: about 3600 pcs/h
    cap = seed_capacity(CellModel(disk_field_length=math.inf, parcel_width=0.2), 0.7, 1.5, 90.0)
    assert cap == pytest.approx(3600, rel=0.05)


def test_prediction_order_and_the_seed_trends():
    p = PREDICTOR
    pr = p.predict(0.4, 1.5, 90.0)
    assert pr.feasible
    assert 0 < pr.t_chute < pr.t_commit
    # Fig. 8a/b: x_o grows with the length A and with the speed v
    assert p.predict(0.7, 1.5, 90).x_o > pr.x_o > p.predict(0.2, 1.5, 90).x_o
    assert pr.x_o > p.predict(0.4, 1.0, 90).x_o
    # the centre of gravity is on the commit line at t_commit
    y_commit = np.interp(pr.t_commit, pr.trajectory[:, 0], pr.trajectory[:, 2])
    assert y_commit == pytest.approx(CellModel().commit_distance, abs=1e-9)


def test_prediction_mirrors_for_the_other_chute_and_rounds_length_up():
    left = PREDICTOR.predict(0.4, 1.5, 90.0)
    right = PREDICTOR.predict(0.4, 1.5, -90.0)
    assert right.t_commit == left.t_commit
    np.testing.assert_allclose(right.trajectory[:, 2], -left.trajectory[:, 2])
    runs = PREDICTOR.n_runs
    assert PREDICTOR.predict(0.3951, 1.5, 90.0) is left  # cached: 0.3951 m rounds up to 0.40
    assert PREDICTOR.n_runs == runs
    assert PREDICTOR.key_length(0.4001) == pytest.approx(0.41)


def test_predictors_with_the_same_settings_share_their_results_and_no_others_do():
    cell = CellModel(disk_field_length=1.1)  # settings no other test uses: nothing shared yet
    one, two = DivertPredictor(cell), DivertPredictor(cell)
    first = one.predict(0.4, 1.5, 90.0)
    assert two.predict(0.4, 1.5, 90.0) is first and (one.n_runs, two.n_runs) == (1, 0)
    # another method, tolerance or cell runs the model again, to its own result
    other = DivertPredictor(cell, rtol=1e-7).predict(0.4, 1.5, 90.0)
    assert other is not first and other.t_commit == pytest.approx(first.t_commit, abs=1e-4)
    assert DivertPredictor(CellModel(disk_field_length=1.0)).predict(0.4, 1.5, 90.0) is not first
    # a gap model shares its headways only with one of the same disk angle and clearance
    act = Actuators()
    a = GapModel(one, act, divert_alpha_deg=90.0, clearance=0.02)
    h = a.geometric_headway(0.4, 'left', 0.4, 'left', 1.5)
    b = GapModel(two, act, divert_alpha_deg=90.0, clearance=0.02)
    assert b._geo_cache is a._geo_cache and b.geometric_headway(0.4, 'left', 0.4, 'left', 1.5) == h
    wider = GapModel(two, act, divert_alpha_deg=90.0, clearance=0.05)
    assert wider.geometric_headway(0.4, 'left', 0.4, 'left', 1.5) > h


def test_prediction_infeasible_when_the_field_is_too_short():
    pr = DivertPredictor(CellModel(disk_field_length=0.3)).predict(0.4, 1.5, 90.0)
    assert not pr.feasible and "never reaches" in pr.why


def test_boxes_overlap_separating_axes():
    p = np.array([[0.0, 0.0, 0.0]])
    assert boxes_overlap(p, np.array([[0.39, 0.0, 0.0]]), 0.4, 0.3, 0.4, 0.3)[0]
    assert not boxes_overlap(p, np.array([[0.41, 0.0, 0.0]]), 0.4, 0.3, 0.4, 0.3)[0]
    assert boxes_overlap(p, np.array([[0.41, 0.0, 0.0]]), 0.4, 0.3, 0.4, 0.3, clearance=0.02)[0]
    # a square turned 45 deg reaches half its diagonal: 0.2 * sqrt(2) = 0.283 m
    q45 = np.array([[0.2 + 0.27, 0.0, math.pi / 4]])
    assert boxes_overlap(p, q45, 0.4, 0.4, 0.4, 0.4)[0]
    q45[0, 0] = 0.2 + 0.29
    assert not boxes_overlap(p, q45, 0.4, 0.4, 0.4, 0.4)[0]


def _corners(x, y, phi, A, B):
    """Return the corners of an A x B box, counter-clockwise, from the model's geometry."""
    out = np.empty((4, 2))
    box_corners(x, y, phi, 0.5 * A, 0.5 * B, out)
    return [tuple(c) for c in out]


def _clipped_area(subject, clip):
    """Area of convex ``subject`` clipped by convex ``clip`` (both counter-clockwise)."""
    out = subject
    for (ax, ay), (bx, by) in zip(clip, clip[1:] + clip[:1]):
        pts, out = out, []
        inside = [(bx - ax) * (py - ay) - (by - ay) * (px - ax) >= 0.0 for px, py in pts]
        for i, (cur, prev) in enumerate(zip(pts, pts[-1:] + pts[:-1])):
            if inside[i] != inside[i - 1]:  # the edge crosses the clip line
                (px, py), (qx, qy) = prev, cur
                d1 = (bx - ax) * (py - ay) - (by - ay) * (px - ax)
                d2 = (bx - ax) * (qy - ay) - (by - ay) * (qx - ax)
                f = d1 / (d1 - d2)
                out.append((px + f * (qx - px), py + f * (qy - py)))
            if inside[i]:
                out.append(cur)
        if not out:
            return 0.0
    return 0.5 * abs(sum(x1 * y2 - x2 * y1 for (x1, y1), (x2, y2) in zip(out, out[1:] + out[:1])))


def test_boxes_overlap_is_where_the_footprints_share_area():
    """Rectangles of unequal sizes at any angles: overlap exactly where clipping leaves area."""
    rng = np.random.default_rng(7)
    n = 4000
    p = np.column_stack([np.zeros(n), np.zeros(n), rng.uniform(-math.pi, math.pi, n)])
    q = np.column_stack(
        [rng.uniform(-0.8, 0.8, n), rng.uniform(-0.6, 0.6, n), rng.uniform(-math.pi, math.pi, n)]
    )
    A1, B1, A2, B2, gap = 0.7, 0.25, 0.45, 0.4, 0.03
    got = boxes_overlap(p, q, A1, B1, A2, B2, clearance=gap)
    seen = set()
    for i in range(n):
        # the clearance inflates each box by half of it on every side
        one = _corners(*p[i], A1 + gap, B1 + gap)
        two = _corners(*q[i], A2 + gap, B2 + gap)
        area = _clipped_area(two, one)
        if 1e-9 < area or area == 0.0:  # leave out the grazing contacts
            assert got[i] == (area > 0.0), (p[i], q[i], area)
            seen.add(bool(got[i]))
    assert seen == {True, False}


def test_spacing_rules_closed_forms():
    act = Actuators(
        popup_stroke_time=0.1,
        alpha_slew_rate_deg_s=360.0,
        scan_period=0.01,
        latency=0.005,
        margin=0.02,
    )
    gm = GapModel(PREDICTOR, act, divert_alpha_deg=90.0, clearance=0.02)
    A, v, b = 0.4, 1.5, CellModel().disk_field_length
    pr = PREDICTOR.predict(A, v, 90.0)
    gaps = gm.min_gap(A, v)
    # straight, then divert: the leader must clear the field before the stroke
    assert gaps["straight->left"] == pytest.approx(b + v * (0.1 + 0.01 + 0.005 + 0.02), abs=1e-9)
    # divert, then straight: down only after the commit, then the stroke
    assert gaps["left->straight"] >= v * (pr.t_commit + 0.135) - A - 1e-9
    # the other side: swing 180 deg at 360 deg/s after the commit
    assert gaps["left->right"] >= v * (pr.t_commit + 0.5 + 0.035) - A - 1e-9
    # the same side: only the footprints matter, and a parcel pushed across lingers
    assert 0.02 < gaps["left->left"] < gaps["left->straight"]
    assert gaps["straight->straight"] == pytest.approx(0.02)
    assert gaps["worst"] == max(v for k, v in gaps.items() if "->" in k)


# --------------------------------------------------------------------------- edge detection


def test_edges_use_latched_stamps_and_catch_short_pulses():
    det = EdgeDetector(["pe_divert", "pe_exit"])
    # a sensor's first bit is its starting state, not an edge
    assert det.detect(InputImage(t=0.0, bits={"pe_divert": False}), 0.0) == (
        [],
        {"pe_divert": False},
    )
    # a bit change with its latched stamp: the stamp is the edge time
    edges, _ = det.detect(
        InputImage(t=0.01, bits={"pe_divert": True}, edges=[Edge("pe_divert", 0.0042, True)]),
        0.01,
    )
    assert edges == [Edge("pe_divert", 0.0042, True)]
    # no stamp (the latched edge has not arrived): the scan time
    assert det.detect(InputImage(t=0.02, bits={"pe_divert": False}), 0.02)[0] == [
        Edge("pe_divert", 0.02, False)
    ]
    # blocked and cleared inside one scan: the bits agree, the latched pair tells
    pulse, _ = det.detect(
        InputImage(
            t=0.03,
            bits={"pe_divert": False},
            edges=[Edge("pe_divert", 0.022, True), Edge("pe_divert", 0.027, False)],
        ),
        0.03,
    )
    assert [(e.t, e.rising) for e in pulse] == [(0.022, True), (0.027, False)]
    # a latched edge the bit does not show (a forced input) is not an edge
    assert (
        det.detect(
            InputImage(t=0.04, bits={"pe_divert": False}, edges=[Edge("pe_divert", 0.035, True)]),
            0.04,
        )[0]
        == []
    )
    # a stamp later than the scan that reads it is clipped to the scan; unknown sensors and
    # non-finite stamps are ignored
    late, _ = det.detect(
        InputImage(
            t=0.05,
            bits={"pe_divert": True},
            edges=[
                Edge("pe_divert", 0.07, True),
                Edge("nowhere", 0.045, True),
                Edge("pe_divert", math.nan, True),
            ],
        ),
        0.05,
    )
    assert late == [Edge("pe_divert", 0.05, True)]


# --------------------------------------------------------------------------- sorting a stream


def test_mixed_stream_sorts_with_zero_mis_sorts():
    cfg, logic, plant = make()
    g = safe_gap(logic)
    items = [
        ("L1", 0.4, 0.0),
        ("R1", 0.5, g),
        ("S1", 0.3, g),
        ("X9", 0.4, g),
        ("L2", 0.6, g),
        ("VIP-1", 0.4, g),
        (None, 0.4, g),
        ("R7", 0.35, g),
    ]
    parcels = plant.add_stream(items)
    run = run_cell(plant, logic, 14.0)
    want = {
        "L1": "left",
        "R1": "right",
        "S1": "straight",
        "X9": "straight",
        "L2": "left",
        "VIP-1": "right",
        None: "straight",
        "R7": "right",
    }
    assert plant.collisions == 0
    for p in parcels:
        assert p.exit == want[p.label], p
    assert len(run.confirmations) == len(items)
    for c in run.confirmations:
        assert c.destination_reached == want[c.label or None]
        assert c.result in ("sorted", "rejected")
    assert logic.counts["mis_sorted"] == 0
    assert logic.counts["rejected"] == 2 and logic.counts["no_read"] == 1
    assert logic.state == "running"


def test_disks_fully_up_at_entry_for_diverts_and_down_for_straight():
    cfg, logic, plant = make()
    g = safe_gap(logic)
    parcels = plant.add_stream([("L1", 0.4, 0.0), ("S1", 0.4, g), ("R1", 0.4, g), ("L2", 0.4, g)])
    run_cell(plant, logic, 9.0)
    at_entry = plant.stroke_at_entry
    assert (
        at_entry[parcels[0].id] == 1.0
        and at_entry[parcels[2].id] == 1.0
        and at_entry[parcels[3].id] == 1.0
    )
    assert at_entry[parcels[1].id] == 0.0


def test_measured_length_and_resync_at_the_divert_eye():
    cfg, logic, plant = make()
    plant.add_stream([("S1", 0.437, 0.0)])
    seen = {}

    def watch(plant_, logic_):
        for p in logic_.parcels:
            if p.length is not None:
                seen["length"] = p.length
            if "pe_divert" in p.confirmed and "lead" not in seen:
                seen["lead"] = logic_.tracker.lead_x(p)
                seen["true_lead"] = plant_.parcels[0].x + 0.5 * 0.437

    run_cell(plant, logic, 2.0, on_scan=watch)
    assert seen["length"] == pytest.approx(0.437, abs=plant.v * plant.dt)
    assert seen["lead"] == pytest.approx(seen["true_lead"], abs=plant.v * plant.dt)


def test_raise_and_lower_times_compensate_stroke_and_scan():
    cfg, logic, plant = make()
    plant.add_stream([("L1", 0.4, 0.0)])
    run = run_cell(plant, logic, 3.0)
    t_raise = next(t for t, k, v in run.commands if k == "popup" and v is True)
    t_lower = next(t for t, k, v in run.commands if k == "popup" and v is False and t > t_raise)
    p = plant.parcels[0]
    t_enter = next(t for t, x, _ in p.path if x + 0.2 >= 0.0)
    pr = PREDICTOR.predict(0.4, 1.5, 90.0)
    # written at the first scan after the stroke, a scan period, the latency and the margin
    # ahead of the entry: even from the last possible scan the stroke ends before it
    lead = cfg.popup_stroke_time + cfg.scan_period + cfg.service_latency + cfg.timing_margin
    assert t_enter - lead - 1e-9 <= t_raise <= t_enter - lead + cfg.scan_period + 1e-9
    assert (
        t_raise + cfg.popup_stroke_time + cfg.service_latency <= t_enter - cfg.timing_margin + 1e-9
    )
    assert (
        t_enter + pr.t_commit - 1e-9
        <= t_lower
        <= t_enter + pr.t_commit + cfg.scan_period + 2 * plant.dt
    )


def test_routing_update_after_the_scan_changes_the_destination():
    cfg, logic, plant = make()
    plant.add_stream([("L5", 0.4, 0.0)])
    run = run_cell(plant, logic, 0.5)  # scanned, tracked, not yet decided
    assert logic.parcels and logic.parcels[0].label == "L5" and not logic.parcels[0].committed
    logic.update_route("L5", "right")
    run = run_cell(plant, logic, 3.0, run)
    assert plant.parcels[0].exit == "right"
    (c,) = run.confirmations
    assert (c.destination_asked, c.destination_reached, c.result) == ("right", "right", "sorted")


def test_too_short_gap_goes_straight_flagged():
    cfg, logic, plant = make()
    short = logic.min_gap(0.4)["left->right"] - 0.3
    parcels = plant.add_stream([("L1", 0.4, 0.0), ("R1", 0.4, short)])
    run = run_cell(plant, logic, 5.0)
    assert [p.exit for p in parcels] == ["left", "straight"]
    res = {c.label: c for c in run.confirmations}
    assert res["R1"].result == "gap_too_short" and res["R1"].destination_asked == "right"
    assert res["R1"].destination_reached == "straight"
    assert logic.counts["gap_too_short"] == 1 and logic.counts["mis_sorted"] == 0
    assert plant.collisions == 0


def test_close_same_side_followers_ride_the_raised_disks():
    # a scanner far enough upstream to see who follows the pair
    cfg, logic, plant = make(photo_eyes=(("pe_scan", -3.0), ("pe_divert", -0.3), ("pe_exit", 2.0)))
    g_same = logic.min_gap(0.4)["left->left"] + 0.05
    assert g_same < logic.min_gap(0.4)["left->straight"]
    parcels = plant.add_stream([("L1", 0.4, 0.0), ("L2", 0.4, g_same)])
    run = run_cell(plant, logic, 4.0)
    assert [p.exit for p in parcels] == ["left", "left"]
    assert [c.result for c in run.confirmations] == ["sorted", "sorted"]
    # one raise for both: the disks stayed up between them
    assert [v for _, k, v in run.commands if k == "popup"].count(True) == 1


def test_same_side_pair_refused_when_the_scanner_cannot_see_behind_it():
    cfg, logic, plant = make()  # scanner 2 m upstream of the field
    g = logic.min_gap(0.4)["left->left"] + 0.05
    parcels = plant.add_stream([("L1", 0.4, 0.0), ("L2", 0.4, g)])
    run = run_cell(plant, logic, 4.0)
    assert [p.exit for p in parcels] == ["straight", "straight"]
    assert "cannot see far enough" in " ".join(text for _, _, text in run.log)


def test_follower_that_could_neither_pass_nor_follow_refuses_the_leader():
    cfg, logic, plant = make(photo_eyes=(("pe_scan", -3.0), ("pe_divert", -0.3), ("pe_exit", 2.0)))
    g = logic.min_gap(0.4)["left->left"] + 0.05
    parcels = plant.add_stream([("L1", 0.4, 0.0), ("R1", 0.4, g)])
    run = run_cell(plant, logic, 5.0)
    assert [p.exit for p in parcels] == ["straight", "straight"]
    assert [c.result for c in run.confirmations] == ["gap_too_short", "gap_too_short"]
    assert plant.collisions == 0 and logic.counts["mis_sorted"] == 0


def test_mis_sort_is_detected_at_the_chute():
    cfg, logic, plant = make()
    plant.add_stream([("S1", 0.4, 0.0)])

    def raise_disks(plant_, logic_):
        plant_.stroke_target, plant_.alpha_target = 1.0, 90.0  # someone else raised them

    run = run_cell(plant, logic, 3.0, on_scan=raise_disks)
    (c,) = run.confirmations
    assert (c.destination_asked, c.destination_reached, c.result) == (
        "straight",
        "left",
        "mis-sorted",
    )
    assert logic.counts["mis_sorted"] == 1


# --------------------------------------------------------------------------- faults


def _no_raise_after(run, t0):
    return not any(k == "popup" and v is True and t > t0 for t, k, v in run.commands)


def _fault_time(run, state):
    return next(t for t, s in run.states if s == state)


def test_jam_photo_eye_blocked_too_long():
    cfg, logic, plant = make()
    g = safe_gap(logic)
    parcels = plant.add_stream([("S1", 0.4, 0.0), ("L1", 0.4, g)])

    def hold(plant_, logic_):
        p = parcels[0]
        if p.x >= cfg.eyes["pe_divert"]:
            p.held = True  # stuck under the divert eye

    run = run_cell(plant, logic, 6.0, on_scan=hold)
    assert logic.state == "jam" and logic.fault["sensor"] == "pe_divert"
    assert "blocked for" in logic.fault["message"]
    assert "estop" in [k for _, k, _ in run.commands]  # the belt is stopped
    assert _no_raise_after(run, _fault_time(run, "jam"))
    assert logic.status()["faults"]["jam"] == 1


def test_stuck_on_photo_eye_with_no_parcel_due():
    cfg, logic, plant = make()
    run = run_cell(plant, logic, 0.2)
    plant.force("pe_divert", True)
    run = run_cell(plant, logic, 2.0, run)
    assert logic.state == "stuck_on" and logic.fault["sensor"] == "pe_divert"
    assert "no parcel due" in logic.fault["message"]


def test_stuck_off_photo_eye_misses_a_tracked_parcel():
    cfg, logic, plant = make()
    plant.force("pe_divert", False)
    plant.add_stream([("L1", 0.4, 0.0)])
    run = run_cell(plant, logic, 4.0)
    assert logic.state == "stuck_off" and logic.fault["sensor"] == "pe_divert"
    assert "should have blocked" in logic.fault["message"]
    assert _no_raise_after(run, 0.0)  # decided after the fault: no divert
    assert plant.parcels[0].exit == "straight"
    assert run.confirmations[0].result == "fault"


def test_stuck_off_exit_eye_misses_a_straight_parcel():
    cfg, logic, plant = make()
    plant.force("pe_exit", False)
    plant.add_stream([("S1", 0.4, 0.0)])
    run = run_cell(plant, logic, 4.0)
    assert logic.state == "stuck_off" and logic.fault["sensor"] == "pe_exit"
    # the parcel itself had already been confirmed straight
    assert [(c.destination_reached, c.result) for c in run.confirmations] == [
        ("straight", "sorted")
    ]


def test_stuck_off_scanner_eye_label_without_blocking():
    cfg, logic, plant = make()
    plant.force("pe_scan", False)
    plant.add_stream([("L1", 0.4, 0.0)])
    run_cell(plant, logic, 1.0)
    assert logic.state == "stuck_off" and logic.fault["sensor"] == "pe_scan"


def test_missed_divert_when_no_chute_sensor_in_time():
    cfg, logic, plant = make()
    plant.force("chute_left", False)
    g = safe_gap(logic)
    plant.add_stream([("L1", 0.4, 0.0), ("L2", 0.4, g)])
    run = run_cell(plant, logic, 6.0)
    assert logic.state == "missed_divert" and logic.fault["sensor"] == "chute_left"
    res = [c.result for c in run.confirmations]
    assert res[0] == "missed" and logic.counts["missed"] == 1
    assert _no_raise_after(run, _fault_time(run, "missed_divert"))


def test_a_missed_divert_while_the_cells_watchdog_holds_is_its_consequence_not_a_fault():
    cfg, logic, plant = make()
    plant.force("chute_left", False)  # the disks the watchdog dropped divert nothing
    plant.watchdog = True
    g = safe_gap(logic)
    plant.add_stream([("L1", 0.4, 0.0), ("L2", 0.4, g)])
    run = run_cell(plant, logic, 6.0)
    assert logic.state == "running", logic.fault
    assert logic.status()["faults"]["after_cell_watchdog"] >= 1
    assert [c.result for c in run.confirmations][:1] == ["fault"]


def test_after_the_watchdog_clears_and_its_grace_passes_a_missed_divert_latches_again():
    cfg, logic, plant = make()
    plant.watchdog = True
    run = run_cell(plant, logic, 0.5)
    plant.watchdog = False  # heartbeats back: the grace time starts
    run = run_cell(plant, logic, 4.0, run)
    plant.force("chute_left", False)
    g = safe_gap(logic)
    plant.add_stream([("L1", 0.4, 0.0), ("L2", 0.4, g)])
    run = run_cell(plant, logic, plant.t + 6.0, run)
    assert logic.state == "missed_divert" and logic.fault["sensor"] == "chute_left"


def test_diverter_timeout_is_not_retried():
    cfg, logic, plant = make()
    plant.withheld.add("popup")
    g = safe_gap(logic)
    plant.add_stream([("L1", 0.4, 0.0), ("L2", 0.4, g), ("R1", 0.4, g)])
    run = run_cell(plant, logic, 8.0)
    assert logic.state == "diverter_timeout"
    popups = [v for _, k, v in run.commands if k == "popup"]
    assert len(popups) == 1  # the first call only; nothing after it
    assert "not retried" in logic.fault["message"]


def test_diverter_timeout_during_another_fault_stops_all_diverter_calls():
    cfg, logic, plant = make()
    run = run_cell(plant, logic, 0.2)
    plant.force("pe_divert", True)
    run = run_cell(plant, logic, 2.0, run)
    assert logic.state == "stuck_on"
    plant.withheld.add("popup")
    logic.commanded_up = True  # as if a raise had been the last word
    run = run_cell(plant, logic, 4.0, run)
    # the lowering timed out: one call, then silence, though the state still wants the disks down
    assert [v for t, k, v in run.commands if k == "popup" and t > 2.0] == [False]
    assert logic.state == "stuck_on" and logic.counts["timeouts"] == 1
    plant.withheld.clear()
    plant.force("pe_divert", None)
    logic.request_reset()
    run = run_cell(plant, logic, 4.2, run)
    assert logic.state == "running"
    assert [v for t, k, v in run.commands if k == "popup" and t > 4.0] == [False]  # written afresh


def test_diverter_refused():
    cfg, logic, plant = make()
    plant.refused["alpha"] = "alpha_deg must be in [-45, 45]"
    plant.add_stream([("L1", 0.4, 0.0)])
    run_cell(plant, logic, 3.0)
    assert logic.state == "diverter_refused" and "[-45, 45]" in logic.fault["message"]


def test_estop_from_operator_drops_tracking_and_reset_resumes():
    cfg, logic, plant = make()
    g = safe_gap(logic)
    parcels = plant.add_stream([("L1", 0.4, 0.0), ("R1", 0.4, g), ("L2", 0.4, 2 * g)])
    run = run_cell(plant, logic, 0.8)
    logic.request_estop()
    run = run_cell(plant, logic, 1.5, run)
    assert logic.state == "estop" and plant.estop
    assert logic.parcels == []
    assert any(c.result == "aborted" for c in run.confirmations)
    logic.request_reset()
    run = run_cell(plant, logic, 12.0, run)
    assert ("reset" in [k for _, k, _ in run.commands]) and not plant.estop
    assert logic.state == "running"
    # parcels that were on the belt during the e-stop went through untracked and straight
    # (flush); L2, scanned after the reset, is sorted again
    assert parcels[2].exit == "left"
    assert [c.result for c in run.confirmations if c.label == "L2"] == ["sorted"]


def test_estop_reported_by_the_cell_and_refusal_reasons():
    cfg, logic, plant = make()
    run = run_cell(plant, logic, 0.1)
    plant.estop = True
    run_cell(plant, logic, 0.2, run)
    assert logic.state == "estop"
    cfg2, logic2, _ = make()
    out = logic2.scan(InputImage(t=0.0))  # the first scan writes the disks down
    (cmd,) = [c for c in out.commands if c.kind == "popup"]
    assert cmd.value is False
    # the cell's own words (sim_node's popup service), said once in the PLC's log
    cell_says = "refused: e-stop engaged (call reset first)"
    logic2.scan(InputImage(t=0.01, replies=[Reply(cmd.id, False, cell_says)]))
    assert logic2.state == "estop"
    assert logic2.fault["message"] == "popup False refused: e-stop engaged (call reset first)"


def test_cell_status_older_than_the_last_reset_is_ignored():
    cfg, logic, _ = make()
    logic.scan(InputImage(t=1.0, cell_estop=True, cell_status_t=0.99))
    assert logic.state == "estop"
    logic.request_reset()
    out = logic.scan(InputImage(t=1.01))
    (cmd,) = [c for c in out.commands if c.kind == "reset"]
    logic.scan(InputImage(t=1.02, replies=[Reply(cmd.id, True, "cleared estop")]))
    assert logic.state == "running"
    logic.scan(InputImage(t=1.03, cell_estop=True, cell_status_t=1.0))  # sent before the reset
    assert logic.state == "running"
    logic.scan(InputImage(t=1.04, cell_estop=True, cell_status_t=1.035))  # a new e-stop
    assert logic.state == "estop"


def test_reset_clears_a_local_fault_without_the_cell():
    cfg, logic, plant = make()
    run = run_cell(plant, logic, 0.2)
    plant.force("pe_divert", True)
    run = run_cell(plant, logic, 2.0, run)
    assert logic.state == "stuck_on"
    plant.force("pe_divert", None)
    logic.request_reset()
    run = run_cell(plant, logic, 2.1, run)
    assert logic.state == "running" and logic.fault is None
    assert "reset" not in [k for _, k, _ in run.commands]


def test_no_diverts_while_faulted_parcels_go_straight():
    cfg, logic, plant = make()
    g = safe_gap(logic)
    parcels = plant.add_stream([("L1", 0.4, 0.0), ("R1", 0.4, g)])
    run = run_cell(plant, logic, 0.1)
    plant.force("pe_exit", True)  # stuck on: a fault unrelated to these parcels
    run = run_cell(plant, logic, 6.0, run)
    assert logic.state == "stuck_on"
    assert [p.exit for p in parcels] == ["straight", "straight"]
    assert {c.result for c in run.confirmations} == {"fault"}


def test_scan_statistics_and_overruns():
    cfg, logic, _ = make()
    logic.scan(InputImage(t=0.0))
    logic.scan(InputImage(t=0.01))
    logic.scan(InputImage(t=0.03))  # late, within the margin
    logic.scan(InputImage(t=0.07))  # later than the margin allows
    logic.record_scan_wall(0.002)
    logic.record_scan_wall(0.015)  # longer than a scan period
    st = logic.status()
    assert st["counts"]["late_scans"] == 1 and st["counts"]["overruns"] == 1
    assert st["counts"]["scans"] == 4
    assert st["scan_wall_max_ms"] == pytest.approx(15.0)


def test_bad_scan_time_changes_nothing():
    cfg, logic, _ = make()
    logic.scan(InputImage(t=1.0))
    out = logic.scan(InputImage(t=math.nan))
    assert logic.t == 1.0 and out.log and "not finite" in out.log[0][1]
    # a step back within MAX_CLOCK_LAG is this node's clock lagging: no time passes
    out = logic.scan(InputImage(t=0.7))
    assert logic.t == 1.0 and out.log == [] and logic.state == "running"
    out = logic.scan(InputImage(t=0.2))  # beyond it: the clock went back
    assert logic.t == 1.0 and "went back" in out.log[0][1] and logic.state == "clock"


def test_a_jam_stays_a_jam_whatever_order_its_estop_and_disks_are_answered_in():
    # L1 held under the divert eye while the disks are up for it: the jam's scan calls
    # estop (estop_on_jam) and popup False; the plant answers in call order, so the
    # disks' command meets the e-stop just engaged and is refused for it. The fault is
    # still the jam (an executor serving services in another order answers popup first)
    cfg, logic, plant = make()
    parcels = plant.add_stream([("L1", 0.4, 0.0), ("L2", 0.4, safe_gap(logic))])

    def hold(plant_, logic_):
        if parcels[0].x >= cfg.eyes["pe_divert"]:
            parcels[0].held = True

    run = run_cell(plant, logic, 6.0, on_scan=hold)
    t_jam = _fault_time(run, "jam")
    same_scan = [(k, v) for t, k, v in run.commands if abs(t - t_jam) < 0.006]
    assert same_scan[:2] == [("estop", True), ("popup", False)]
    assert logic.state == "jam" and logic.fault["sensor"] == "pe_divert"
    assert logic.sequencer.commanded_up is False
    assert logic.status()["faults"]["estop"] == 0
