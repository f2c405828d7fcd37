"""
The PLC program's parts, each on its own: tracking, faults and supervision, sequencing.

Each part is driven through a recorder in place of the scan (``ScanIO``), so a
test sees exactly what the part logs, faults, commands and finishes. The
routing table and the edge detector have their own tests in test_logic.py.
"""

import dataclasses
import math

import pytest

from sorter_control.logic import ControllerConfig, Edge, RoutingTable, ScanOutput
from sorter_control.logic.faults import Faults, Supervisor
from sorter_control.logic.program import COUNTS
from sorter_control.logic.sequencing import DiverterSequencer
from sorter_control.logic.tracking import R_ABORTED, Tracker
from sorter_control.timing import CellModel, DivertPredictor, GapModel

CFG = ControllerConfig(routing_rules=("L*=left", "R*=right"))
V = CFG.belt_speed
X_SCAN = CFG.eyes["pe_scan"]  # -2.0 m
X_DIVERT = CFG.eyes["pe_divert"]  # -0.3 m


class Recorder:
    """A ScanIO that records what the part under test does."""

    def __init__(self, t=0.0, faults=None):
        self.t = t
        self.logs, self.faults, self.commands, self.finished = [], [], [], []
        self._faults = faults

    def log(self, level, text):
        self.logs.append((level, text))

    def fault(self, kind, message, sensor=None):
        self.faults.append((kind, sensor, message))
        if self._faults is not None:
            self._faults.enter(self, kind, message, sensor)

    def command(self, kind, value):
        self.commands.append((kind, value))

    def finish(self, p, reached, result=None):
        p.done, p.reached = True, reached
        self.finished.append((p.seq, reached, result))


def tracker_at(t=0.0):
    tr = Tracker(CFG, {k: 0 for k in COUNTS})
    tr.advance(t)
    tr.first_seen({s: False for s in tr.sensors})
    return tr


def induct(tr, io, t_rise, length, label=None):
    """Pass a parcel through the scanner eye: rising at t_rise, falling length/V later."""
    tr.advance(t_rise)
    io.t = t_rise
    tr.on_edge(io, Edge("pe_scan", t_rise, True))
    if label is not None:
        tr.apply_labels(io, [(t_rise, label)], running=True)
    t_fall = t_rise + length / V
    tr.advance(t_fall)
    io.t = t_fall
    tr.on_edge(io, Edge("pe_scan", t_fall, False))
    return tr.parcels[-1]


# --------------------------------------------------------------------------- tracking


def test_tracker_measures_length_and_follows_by_encoder():
    tr, io = tracker_at(), Recorder()
    p = induct(tr, io, 0.1, 0.4, "L1")
    assert p.length == pytest.approx(0.4) and p.label == "L1"
    assert tr.counts["inducted"] == 1
    # the leading edge moves at the belt speed from the scanner line
    tr.advance(0.1 + 1.0)
    assert tr.lead_x(p) == pytest.approx(X_SCAN + V * 1.0)
    assert tr.t_enter(p) == pytest.approx(0.1 + -X_SCAN / V)
    # a stopped belt stops the encoder
    tr.belt_running = False
    tr.advance(5.0)
    assert tr.lead_x(p) == pytest.approx(X_SCAN + V * 1.0)
    assert io.faults == []


def test_tracker_resynchronises_at_a_checkpoint_inside_its_window():
    tr, io = tracker_at(), Recorder()
    p = induct(tr, io, 0.0, 0.4)
    # the eye blocks 20 mm later than the encoder says (a slipping parcel): within tolerance
    t_due = (X_DIVERT - X_SCAN) / V
    t_seen = t_due + 0.02 / V
    tr.advance(t_seen)
    tr.on_edge(io, Edge("pe_divert", t_seen, True))
    assert p.confirmed["pe_divert"] == t_seen
    assert tr.lead_x(p) == pytest.approx(X_DIVERT)  # re-synchronised to the eye
    # an eye blocked far from any window is unexplained (flushing at start-up: counted only)
    tr.advance(t_seen + 0.5)
    tr.on_edge(io, Edge("pe_exit", t_seen + 0.5, True))
    assert tr.eyes["pe_exit"].unexpected and tr.counts["untracked"] == 1


def test_label_without_the_scanner_eye_blocking_is_stuck_off():
    tr, io = tracker_at(), Recorder()
    tr.advance(1.0)
    io.t = 1.0
    tr.apply_labels(io, [(1.0, "L9")], running=True)
    assert io.faults == []  # still within the label window
    tr.advance(1.0 + CFG.label_window + 0.01)
    tr.apply_labels(io, [], running=True)
    assert [f[0] for f in io.faults] == ["stuck_off"]
    assert tr.counts["labels_without_parcel"] == 1
    # malformed labels are skipped, not raised
    tr.apply_labels(io, [("x", "L1"), (math.inf, "L1"), (2.0, 7), None], running=True)


def test_chute_sensor_finishes_the_parcel_planned_for_that_side():
    tr, io = tracker_at(), Recorder()
    p = induct(tr, io, 0.0, 0.4, "L1")
    p.committed, p.plan = True, "left"
    t = tr.t_enter(p) + 0.5
    tr.advance(t)
    tr.on_edge(io, Edge("chute_left", t, True))
    assert io.finished == [(p.seq, "left", None)]
    # a chute blocked with no parcel anywhere near: counted and logged
    tr.on_edge(io, Edge("chute_right", t + 5, True))
    assert tr.counts["unexpected_chute"] == 1


def test_clearing_the_tracking_aborts_every_open_parcel_and_flushes():
    tr, io = tracker_at(), Recorder()
    a = induct(tr, io, 0.0, 0.4)
    b = induct(tr, io, 1.0, 0.4)
    tr.clear(io, "e-stop")
    assert io.finished == [(a.seq, "unknown", R_ABORTED), (b.seq, "unknown", R_ABORTED)]
    assert tr.parcels == [] and tr.flush_until > tr.encoder


# --------------------------------------------------------------------------- faults


def test_the_first_fault_defines_the_state_and_a_jam_stops_the_belt():
    f, io = Faults(estop_on_jam=True), Recorder(t=3.0)
    f.enter(io, "jam", "pe_exit blocked", "pe_exit")
    assert f.state == "jam" and f.fault["sensor"] == "pe_exit" and f.fault["t"] == 3.0
    assert io.commands == [("estop", True)]
    f.enter(io, "stuck_off", "later")  # logged, does not replace the jam
    assert f.state == "jam" and f.counts["stuck_off"] == 0
    assert "(while in jam)" in io.logs[-1][1]
    assert f.enter_estop(io, "operator") and f.state == "estop"
    assert not f.enter_estop(io, "again")
    f.state = "resetting"
    f.restore(io, "reset refused")
    assert f.state == "estop"
    assert f.clear(7.0) == "estop" and f.running and f.reset_t == 7.0


def test_supervision_stuck_on_stuck_off_and_inferred_outcomes():
    tr, io = tracker_at(), Recorder()
    faults = Faults()
    io._faults = faults
    sup = Supervisor(CFG, tr.counts)
    # an eye blocked with no parcel due, longer than the longest parcel takes: stuck on
    tr.on_edge(io, Edge("pe_exit", 0.0, True))
    tr.advance(CFG.max_parcel_length / V + CFG.jam_margin + 0.01)
    io.t = tr.t
    sup.check(io, tr, faults)
    assert faults.state == "stuck_on"
    # a parcel whose transit window at pe_divert passed with the eye clear: stuck off
    tr2, io2, f2 = tracker_at(), Recorder(), Faults()
    io2._faults = f2
    p = induct(tr2, io2, 0.0, 0.4)
    tr2.advance((X_DIVERT - X_SCAN) / V + 0.2)
    sup.check(io2, tr2, f2)
    assert f2.state == "stuck_off" and "pe_divert" in f2.fault["message"]
    # a parcel sent straight is done once past the field, by time alone
    p.committed, p.plan = True, "straight"
    tr2.advance(tr2.t + 10.0)
    sup.check(io2, tr2, f2)
    assert (p.seq, "straight", None) in io2.finished


# --------------------------------------------------------------------------- sequencing

PREDICTOR = DivertPredictor(CellModel())


def sequencer(cfg=CFG):
    tr = tracker_at()
    gaps = GapModel(
        PREDICTOR, cfg.actuators(), divert_alpha_deg=cfg.divert_alpha_deg, clearance=0.02
    )
    seq = DiverterSequencer(cfg, gaps, RoutingTable(cfg.routing_rules), tr, tr.counts)
    return tr, seq


def test_sequencer_raises_the_disks_one_stroke_ahead_and_lowers_after_commit():
    tr, seq = sequencer()
    io = Recorder()
    p = induct(tr, io, 0.0, 0.4, "L1")
    te = tr.t_enter(p)
    # with nothing committed, the disk angle is set ahead for the next parcel in line
    out = ScanOutput()
    seq.write_outputs(out, "running")
    assert [(c.kind, c.value) for c in out.commands] == [
        ("alpha", seq.gaps.alpha_for("left")),
        ("popup", False),
    ]
    # decided no later than a stroke and a scan before the entry, and planned left
    tr.advance(te - seq.gaps.act.stroke_total - CFG.scan_period - 1e-3)
    io.t = tr.t
    seq.decide(io)
    assert not p.committed  # not before its last moment: routing may still change
    tr.advance(te - seq.gaps.act.stroke_total - CFG.scan_period + 1e-9)
    io.t = tr.t
    seq.decide(io)
    assert p.committed and p.plan == "left" and p.prediction.feasible
    up, alpha = seq.desired_outputs()
    assert (up, alpha) == (False, seq.gaps.alpha_for("left"))  # angle first, disks still down
    tr.advance(te - seq.gaps.act.stroke_total)
    assert seq.desired_outputs() == (True, seq.gaps.alpha_for("left"))
    tr.advance(te + p.prediction.t_commit + 1e-6)
    assert seq.desired_outputs()[0] is False


def test_sequencer_never_has_two_calls_of_a_kind_in_flight_and_lowers_in_a_fault():
    tr, seq = sequencer()
    out = ScanOutput()
    seq.write_outputs(out, "jam")
    assert [(c.kind, c.value) for c in out.commands] == [("popup", False)]
    seq.commanded_up = None  # as if unknown again: still busy, so no second call
    seq.write_outputs(out, "jam")
    assert len(out.commands) == 1
    seq.in_flight.clear()
    seq.diverter_silent = True  # a call timed out: leave the diverter alone until reset
    seq.write_outputs(out, "jam")
    assert len(out.commands) == 1


@pytest.mark.parametrize("gap_rules", [True, False])
def test_sequencer_refuses_a_divert_too_close_behind_a_divert_to_the_other_side(gap_rules):
    """The gap rules send the second parcel straight; switched off, both are diverted."""
    tr, seq = sequencer(dataclasses.replace(CFG, gap_rules=gap_rules))
    io = Recorder()
    gaps = seq.gaps.min_gap(0.4, V)
    # close enough that the disks cannot swing from left to right in between, far enough
    # that it could pass the raised disks straight
    assert gaps["left->straight"] < gaps["left->right"]
    gap = 0.5 * (gaps["left->straight"] + gaps["left->right"])
    a = induct(tr, io, 0.0, 0.4, "L1")
    seq.write_outputs(ScanOutput(), "running")  # the disk angle set ahead for L1
    b = induct(tr, io, (0.4 + gap) / V, 0.4, "R1")
    for p in (a, b):
        tr.advance(tr.t_enter(p) - seq.gaps.act.stroke_total - CFG.scan_period + 1e-9)
        io.t = tr.t
        seq.decide(io)
    assert a.plan == "left" and a.result is None
    if not gap_rules:
        # not refused for its spacing: diverted as asked unless the disks cannot swing
        # in time (late, an actuator limit the rules do not set)
        assert b.result != "gap_too_short" and seq.counts["gap_too_short"] == 0, b.result
        assert (b.plan, b.result) in (("right", None), ("straight", "late")), (b.plan, b.result)
        return
    assert b.plan == "straight" and b.result == "gap_too_short"
    assert seq.counts["gap_too_short"] == 1
    assert any("gap too short" in text for _, text in io.logs)


# --------------------------------------------------------------------------- the clock


def test_time_going_back_is_one_clock_fault_and_a_reset_rebases():
    from sorter_control.logic import InputImage, SorterLogic

    logic = SorterLogic(CFG, PREDICTOR)
    for k in range(100):
        logic.scan(InputImage(t=100.0 + 0.01 * k))
    # as if a divert had the disks up (its calls answered)
    logic.sequencer.in_flight.clear()
    logic.sequencer.commanded_up = True
    lines = []
    # a second clock, or a restarted simulation: time goes back, and stays on its own base
    commands = []
    for k in range(300):
        out = logic.scan(InputImage(t=5.0 + 0.01 * k))
        lines += out.log
        commands += [(c.kind, c.value) for c in out.commands]
    assert logic.state == "clock" and logic.fault_counts["clock"] == 1
    assert commands == [("popup", False)]  # the disks down, once, whatever time it is
    errors = [t for level, t in lines if level == "error"]
    assert len(errors) == 1 and "went back from 100.990 to 5.000 s" in errors[0]
    assert logic.counts["clock_jumps"] == 300
    logic.request_reset()
    out = logic.scan(InputImage(t=8.0))
    assert logic.state == "running" and logic.t == 8.0
    assert any("time base is now 8.000" in t for _, t in out.log)
    out = logic.scan(InputImage(t=8.01))
    assert logic.state == "running" and out.log == []


def test_a_leap_ahead_and_a_second_clock_source_are_clock_faults():
    from sorter_control.logic import InputImage, SorterLogic

    logic = SorterLogic(CFG, PREDICTOR)
    logic.scan(InputImage(t=1.0))
    logic.scan(InputImage(t=1.0 + 1.7e9))  # use_sim_time switched to the wall clock
    assert logic.state == "clock" and "jumped ahead" in logic.fault["message"]
    # two publishers of /clock: a fault, and a reset does not clear it while they remain
    logic = SorterLogic(CFG, PREDICTOR)
    logic.scan(InputImage(t=1.0, clock_sources=1))
    logic.scan(InputImage(t=1.01, clock_sources=2))
    assert logic.state == "clock" and "2 nodes publish /clock" in logic.fault["message"]
    logic.request_reset()
    logic.scan(InputImage(t=1.02, clock_sources=2))
    assert logic.state == "clock"
    logic.request_reset()
    logic.scan(InputImage(t=1.03, clock_sources=1))
    assert logic.state == "running"


def test_a_clock_lagging_the_cells_stamps_does_not_move_parcels_ahead():
    # This node's clock (from /clock) runs 0.1 s behind the cell under load: the scanner
    # eye's latched edge says 0.20 s while the scan's clock reads 0.10 s. The parcel must
    # be where the cell has it, not 0.1 s x v ahead (which made a false stuck_off).
    from sorter_control.logic import InputImage, SorterLogic

    logic = SorterLogic(CFG, PREDICTOR)
    for k in range(10):
        logic.scan(InputImage(t=0.01 * k, bits={"pe_scan": False}))
    logic.scan(InputImage(t=0.10, bits={"pe_scan": True}, edges=[Edge("pe_scan", 0.20, True)]))
    (p,) = logic.parcels
    assert p.t_scan == 0.20 and logic.t == 0.20
    for k in range(11, 31):  # the clock catches up; time never runs backwards meanwhile
        logic.scan(InputImage(t=0.01 * k, bits={"pe_scan": True}))
        assert logic.state == "running"
    assert logic.tracker.lead_x(p) == pytest.approx(X_SCAN + V * (0.30 - 0.20), abs=1e-12)
    assert logic.status()["clock_lag_max_ms"] == pytest.approx(100.0)
