"""
The seed's general claims over their ranges (``sorter paper statements``).

The grid behind the statement table is saved (docs/data/statement_grid.json, written
by ``sorter paper statements --doc docs``); each run recomputes a few random points
of it and compares, then asserts the verdicts that grid gives. The verdict rules are
checked on made-up curves whose verdict is known in advance.
"""

import json
import math
import random
import subprocess
import sys
from pathlib import Path

import pytest

from sorter_sim.cli import main
from sorter_sim.studies import claims, claims_cli
from sorter_sim.studies.claims_grid import (
    BMIN_XTOL,
    BMIN_XTOL_FINE,
    FULL,
    MODELS,
    GridStore,
    Model,
    load_table,
    recompute,
)

DOCS = Path(__file__).parent.parent / "docs"
GRID = DOCS / "data" / "statement_grid.json"


@pytest.fixture(scope="module")
def saved():
    return load_table(GRID)


@pytest.fixture(scope="module")
def verdicts(saved):
    result = claims.table(GridStore(saved, compute=False))
    return {
        row["id"]: {k: v["verdict"] for k, v in row["models"].items()} for row in result["rows"]
    }


def test_saved_grid_matches_fresh_runs(saved):
    # a few random points each run (one of each kind), printed so a failure can be redone
    rng = random.Random()
    for kind in ("sort", "law", "bmin", "two", "f14", "detail", "pos", "bminfine"):
        keys = sorted(k for k in saved if k.startswith(kind + "|"))
        key = rng.choice(keys)
        print("recomputed:", key)
        fresh = recompute(key)
        for name, value in saved[key].items():
            # NaN where a point has no value (no width sorts it, say): NaN again, any kind
            if math.isnan(value):
                assert math.isnan(fresh[name]), (key, name)
            elif kind in ("bmin", "two"):
                assert fresh[name] == pytest.approx(value, abs=2 * BMIN_XTOL), key
            elif kind == "bminfine":
                assert fresh[name] == pytest.approx(value, abs=2 * BMIN_XTOL_FINE), key
            elif kind == "f14":
                assert fresh[name] == pytest.approx(value, rel=1e-4), (key, name)
            else:
                assert fresh[name] == pytest.approx(value, rel=1e-5, abs=1e-6), (key, name)


# the verdicts the saved grid gives, per claim and model; a change in the model or in a
# claim's test that moves one must show here
H, P, F, D = claims.HOLDS, claims.PAPER_ONLY, claims.FAILS, claims.DEPENDS
KEYS = ("seed/full", "seed/simplified", "exact/full", "exact/simplified")
EXPECTED = {
    "C2a": dict(zip(KEYS, (P, P, P, P))),
    "C2b": dict(zip(KEYS, (P, P, P, P))),
    "C2c": dict(zip(KEYS, (D, D, D, D))),
    "C2c-E2": dict(zip(KEYS, (F, F, F, F))),
    "C2c-peak": dict(zip(KEYS, (F, F, F, F))),
    "C2c-E2len": dict(zip(KEYS, (H, H, H, H))),
    "7-short": dict(zip(KEYS, (F, F, F, F))),
    "5-excess": dict(zip(KEYS, (F, F, F, F))),
    "8a-A": dict(zip(KEYS, (H, H, H, H))),
    "8a-B": dict(zip(KEYS, (H, H, H, H))),
    "8b": dict(zip(KEYS, (H, H, H, H))),
    "8c": dict(zip(KEYS, (H, H, H, H))),
    "8d-b": dict(zip(KEYS, (H, H, H, H))),
    "8d-a": dict(zip(KEYS, (H, H, H, H))),
    "8d-more": dict(zip(KEYS, (H, H, H, H))),
    "9a": dict(zip(KEYS, (H, H, H, H))),
    "9-A": dict(zip(KEYS, (H, H, H, H))),
    "9b": dict(zip(KEYS, (H, H, H, H))),
    "9b-longer": dict(zip(KEYS, (F, F, F, F))),
    "9c": dict(zip(KEYS, (H, H, H, H))),
    "9-tc": dict(zip(KEYS, (H, H, H, H))),
    "10-share": dict(zip(KEYS, (F, F, F, F))),
    "10-equal": dict(zip(KEYS, (F, H, F, H))),
    "11-lowv": dict(zip(KEYS, (H, H, H, H))),
    "6-trans": dict(zip(KEYS, (H, H, H, H))),
    "16-1pct": dict(zip(KEYS, (P, P, P, P))),
    "16-1pct-mu0.6": dict(zip(KEYS, (F, F, F, F))),
    "14-rise": dict(zip(KEYS, (F, H, F, H))),
    "C4": dict(zip(KEYS, (H, F, F, F))),
    "C3": dict(zip(KEYS, (H, H, H, H))),
    "13-offsets": dict(zip(KEYS, (P, P, P, P))),
    "7-rot": dict(zip(KEYS, (H, H, H, H))),
    "10-eta": dict(zip(KEYS, (H, H, H, H))),
    "5-speed": dict(zip(KEYS, (F, F, P, P))),
    "16-1pct-flat": dict(zip(KEYS, (F, F, F, F))),
}


def test_the_table_covers_every_claim_and_model(verdicts):
    assert set(verdicts) == {c.id for c in claims.CLAIMS} == set(EXPECTED)
    assert KEYS == tuple(m.key for m in MODELS)
    for row in verdicts.values():
        assert set(row) == {m.key for m in MODELS}
        assert set(row.values()) <= set(claims.VERDICTS)


@pytest.mark.parametrize("claim_id", sorted(EXPECTED))
def test_verdicts_the_grid_gives(verdicts, claim_id):
    assert verdicts[claim_id] == EXPECTED[claim_id]


def test_no_field_holds_a_fast_parcel_at_90_degrees(saved):
    # closed form, moment neglected: at α = 90° the disks' slip starts at (v, -v) and a
    # constant μ keeps its direction, so the lateral push is at most μ g / √2 and the
    # parcel reaches the disks' speed only after v² / (√2 μ g) across the belt. Beyond
    # s = 0.7 m (v > 2.41 m/s at μ = 0.6) it is scrapped still sliding: no width serves
    limit = math.sqrt(math.sqrt(2) * 0.6 * 9.81 * 0.7)
    assert 2.0 < limit < 2.5
    for stick in ("seed", "exact"):
        for A in FULL.As:
            b = f"bmin|{stick}/simplified|A={A:g}|alpha=90|v="
            assert math.isnan(saved[b + "2.5"]["b"]) and saved[b + "2"]["b"] > 0, (stick, A)
            r = saved[f"sort|{stick}/simplified|A={A:g}|B=0.2|alpha=90|mu_a=0.6|mu_b=0.6|v=2.5"]
            assert r["e2_end"] == r["t"]  # no stick on the disks before the line


# ---------------------------------------------------------------- the verdict rules
class Curves:
    """A stand-in store: W_t(α, A) from a formula, every other record quantity fixed."""

    def __init__(self, capacity):
        self.capacity = capacity
        self.touched = set()

    def sort(self, model, *, A, v, alpha, B=0.2, mu_a=0.6, mu_b=0.6):
        self.touched.add((A, v, alpha, B, mu_a, mu_b))
        return {"t": 3600.0 / self.capacity(alpha, A)}


C2B = next(c for c in claims.CLAIMS if c.id == "C2b")
SEED_FULL = Model("seed", True)


def test_a_capacity_rising_to_90_degrees_holds():
    store = Curves(lambda al, A: 3000 + 10 * al / A)
    v = claims.verdict(store, C2B, SEED_FULL)
    assert v["verdict"] == H
    # every (v, A) curve over α, plus the gain over A at each v
    assert v["points"] == len(FULL.alphas) * len(FULL.vs) * len(FULL.As)


def test_a_capacity_peaking_between_the_seeds_angles_holds_there_only():
    # a peak at 75°, 1 % over 90°: the seed's 30°, 45°, 90° still rise
    store = Curves(
        lambda al, A: 3000 - (al - 75) ** 2 + 600 * math.sin(math.radians(al)) + 2000 * A
    )
    v = claims.verdict(store, C2B, SEED_FULL)
    assert v["verdict"] == P
    assert "peak" in v["where"] and "75°" in v["where"]


def test_a_capacity_falling_at_the_seeds_angles_fails():
    store = Curves(lambda al, A: (4000 - 10 * abs(al - 45)) / A)
    assert claims.verdict(store, C2B, SEED_FULL)["verdict"] == F


def test_the_gain_over_length_is_part_of_the_claim():
    # rising with α at every A, but the gain 30° -> 90° larger for long loads
    store = Curves(lambda al, A: 3000 + 10 * al * A)
    v = claims.verdict(store, C2B, SEED_FULL)
    assert v["verdict"] == F and "gain over A" in v["where"]


class Accelerations:
    """A stand-in store: ÿ early in E2 from a formula per break-away detection."""

    def __init__(self, early, by_threshold):
        self.early, self.by_threshold = early, by_threshold
        self.touched = set()

    def sort(self, model, *, A, v, alpha, B=0.2, mu_a=0.6, mu_b=0.6):
        self.touched.add(("s", A, v, alpha))
        return {"ay_early": self.early(alpha)}

    def detail(self, model, *, A, v, alpha):
        self.touched.add(("d", A, v, alpha))
        return {f"ay_thr{i}": self.by_threshold(i, alpha) for i in range(3)}


C2C = next(c for c in claims.CLAIMS if c.id == "C2c")


def test_a_verdict_that_flips_within_its_judging_range_depends():
    # falling with α from the break-away event and at two thresholds, but at 1e-3 m/s
    # a rise 45° -> 90° at every (v, A) (the 0.50 / 0.49 / 0.56 shape)
    def by_threshold(i, al):
        return 0.56 - 0.002 * al + (0.003 * (al - 45) if i == 1 and al > 45 else 0.0)

    store = Accelerations(lambda al: 0.6 - 0.002 * al, by_threshold)
    v = claims.verdict(store, C2C, SEED_FULL)
    assert v["verdict"] == claims.DEPENDS, v
    assert "event: holds" in v["where"] and "0.001 m/s: fails" in v["where"]
    # every threshold agreeing: one verdict, the range named
    store = Accelerations(lambda al: 0.6 - 0.002 * al, lambda i, al: 0.5 - 0.001 * al)
    v = claims.verdict(store, C2C, SEED_FULL)
    assert v["verdict"] == H and "the same at every" in v["where"], v


class Widths:
    """A stand-in store: b_min located to 1 mm (``coarse``) or to 0.1 mm (``fine``)."""

    def __init__(self, coarse, fine):
        self.coarse, self.fine = coarse, fine
        self.touched = set()
        self.fine_calls = 0

    def b_min(self, model, *, A, v, alpha, fine=False):
        self.touched.add((A, v, alpha, fine))
        self.fine_calls += fine
        return self.fine(alpha) if fine else self.coarse(alpha)


C2A = next(c for c in claims.CLAIMS if c.id == "C2a")


def _steps(al):
    """1 mm bracket ends: the true width falls 0.3 mm per 5°, the bracket rounds it up."""
    return math.ceil((1.0 - 0.00006 * al) / BMIN_XTOL) * BMIN_XTOL


def test_a_rise_of_b_min_within_its_resolution_is_no_failure():
    # a true width falling slowly, located to 1 mm: steps of 0 and +1 mm noise at the
    # coarse resolution; located again to 0.1 mm it falls
    store = Widths(lambda al: _steps(al) + (BMIN_XTOL if al == 60.0 else 0.0),
                   lambda al: 1.0 - 0.00006 * al)  # fmt: skip
    v = claims.verdict(store, C2A, SEED_FULL)
    assert v["verdict"] == H, v
    assert store.fine_calls > 0


def test_a_rise_of_b_min_beyond_its_fine_resolution_fails():
    # the exact/full, v 1.5, A 1.2 shape: 0.875 -> 0.881 -> 0.886 m at 80/85/90°
    def width(al):
        return 1.0 - 0.0025 * (al - 30) if al <= 80 else 0.875 + 0.0011 * (al - 80)

    store = Widths(width, width)
    v = claims.verdict(store, C2A, SEED_FULL)
    assert v["verdict"] == P and "80°->85°: 0.8750 -> 0.8805 m" in v["where"], v


def test_speeds_beyond_the_stated_range_are_reported_apart():
    # W_t rises with α at every A up to 1.5 m/s; beyond it, a dip at 2.5 m/s
    class Beyond(Curves):
        def sort(self, model, *, A, v, alpha, B=0.2, mu_a=0.6, mu_b=0.6):
            self.touched.add((A, v, alpha, B, mu_a, mu_b))
            dip = 400 * (alpha == 60.0) if v > 2.0 else 0.0
            return {"t": 3600.0 / (3000 + 10 * alpha / A + dip)}

    v = claims.verdict(Beyond(None), C2B, SEED_FULL)
    assert v["verdict"] == H, v
    assert v["beyond"]["verdict"] == F and "v 2.5" in v["beyond"]["where"], v


# ---------------------------------------------------------------- the command and the page
def test_statements_command_json_shape(tmp_path, capsys, saved):
    grid = tmp_path / "grid.json"
    grid.write_text(GRID.read_text())
    assert main(["paper", "statements", "--json", "--grid", str(grid), "--quiet"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert list(out) == ["rows"]
    for row in out["rows"]:
        assert {"id", "claim", "models"} <= set(row)
        for key, v in row["models"].items():
            assert key in {m.key for m in MODELS}
            assert v["verdict"] in claims.VERDICTS
            assert v.get("beyond", {"verdict": H})["verdict"] in (H, F)
            assert isinstance(v["where"], str) and v["points"] >= 1


def test_statements_command_bad_input(tmp_path, capsys):
    assert main(["paper", "statements", "--grid", str(tmp_path / "none.json")]) == 2
    err = capsys.readouterr().err
    assert "--grid" in err and "not a file" in err and "Traceback" not in err
    assert main(["paper", "7", "--json"]) == 2
    assert "sorter paper statements" in capsys.readouterr().err
    page = tmp_path / "paper.md"
    page.write_text("# no block\n")
    assert main(["paper", "statements", "--doc", str(tmp_path)]) == 2
    assert "block" in capsys.readouterr().err


def _grid_with(tmp_path, text: str) -> str:
    path = tmp_path / "grid.json"
    path.write_text(text)
    return str(path)


def test_statements_command_refuses_a_grid_file_no_run_makes(tmp_path, capsys):
    """A grid file is checked as a scenario file is: one line, exit 2, nothing written."""
    first = json.loads(GRID.read_text())
    key = next(k for k in sorted(first) if k.startswith("sort|"))
    f14 = next(k for k in sorted(first) if k.startswith("f14|"))
    # every sorting run alike (the rest as run): a claim divides by a difference of them
    every = json.dumps(
        {
            k: {f: 1.0 for f in r} if k.startswith(("sort|", "law|")) else r
            for k, r in first.items()
        }
    )
    cases = {
        "[1, 2]": "must be a JSON object",
        json.dumps({key: 3.0}): "its record must hold t, x, e2",
        "[" * 100_000: "nested too deep",
        json.dumps({key: {**first[key], "t": 1e300}}): "t = 1e+300 is not a time [s]",
        json.dumps({key: {**first[key], "t": -1}}): "t = -1 is not a time [s] above 0",
        json.dumps({key: {**first[key], "t": 0}}): "t = 0 is not a time [s] above 0",
        '{"%s": {"end": Infinity, "low": 1, "high": 1}}' % f14: "end = inf is not a force",
        json.dumps({key: {**first[key], "t": "1"}}): "t = 1 is not a time",
        json.dumps({key: {**first[key], "transitions": True}}): "transitions = True",
        json.dumps({"sort|seed/full|v=nan": first[key]}): "v='nan' is not a finite number",
        json.dumps({"cap|seed/full|v=1": first[key]}): "its kind 'cap' is none of",
        '{"a": ': "not JSON",
        every: "undecidable",
    }
    for text, why in cases.items():
        grid = _grid_with(tmp_path, text)
        assert main(["paper", "statements", "--grid", grid]) == 2, why
        captured = capsys.readouterr()
        err = captured.err.strip()
        one_line = len(err.splitlines()) == 1
        assert one_line and err.startswith("sorter paper: error: --grid:"), err[:300]
        assert why in err and "Traceback" not in err and len(err) < 600, (why, err[:300])
        assert captured.out == ""
    # as a command: numpy's warnings over a table of alike values are no second line
    out = subprocess.run(
        [sys.executable, "-m", "sorter_sim.cli", "paper", "statements", "--grid", str(grid)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1, out.stderr[-600:]
    assert "undecidable" in out.stderr


def test_docs_paper_md_shows_the_table_first(saved):
    page = (DOCS / "paper.md").read_text()
    block = claims_cli.markdown_block(
        claims.table(GridStore(saved, compute=False)), claims_cli.SOURCE
    )
    start, end = claims_cli.BLOCK
    assert page.split(start, 1)[1].split(end, 1)[0].strip() == block.strip()
    # the first section after the contents
    first = page.split("<!-- end: contents -->", 1)[1].lstrip().splitlines()[0]
    assert first == "## The seed's claims over their ranges"
