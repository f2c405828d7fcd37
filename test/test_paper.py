"""
The seed's figures on coarse grids.

The seed's figures on coarse grids: its qualitative statements (sections 3, 5, 6, 7)
and the closed forms some of them reduce to. Every number asserted here comes
from the seed's text or from a closed form, never from an earlier run's output.
"""

import math
from pathlib import Path

import numpy as np
import pytest

from sorter_sim.cli import main
from sorter_sim.studies import paper, paper_support, two_stage
from sorter_sim.studies.markdown import headings
from sorter_sim.studies.paper_cli import FIGURES
from sorter_sim.studies.paper_statements import STATEMENTS

G = 9.81
LAWS = pytest.mark.parametrize("stick", ["seed", "exact"])


# ---------------------------------------------------------------- Fig. 3 (section 3)
def test_fig3_laws_as_used():
    r = paper.fig3(None, quick=True)
    mu = {
        label.split(":")[0]: float(np.interp(1.0, r.data["speeds"], c[0]))
        for label, c in r.data["curves"].items()
    }
    # closed forms of each law at v_o = 1 m/s, from the parameters FIG3_LAWS declares
    assert mu["(c) linear"] == pytest.approx(0.65 - 0.15)
    assert mu["(d) polynomial"] == pytest.approx(0.65 - 1.0 + 0.0 + 2.0)
    mu0, mumin, b1, b2, b3, vk = 0.65, 0.3, 10.0, 5.0, 1.5, 0.1
    stribeck = mumin + (mu0 - mumin) * math.exp(-b1) + b2 * b3 * (1 - vk) / (1 + b2 * (1 - vk))
    assert mu["(e) Stribeck"] == pytest.approx(stribeck)
    # the seed: (d), (e) unbelievably high near 1 m/s; (a)-(c) in a real range
    assert mu["(d) polynomial"] > 1.0 and mu["(e) Stribeck"] > 1.0
    assert r.checks["3-range"].holds
    # every law is drawn from rest with its static value μ_s = μ(0+) for the continuous ones
    for label, (curve, mu_s, source) in r.data["curves"].items():
        assert source.startswith(("the seed", "assumption")), label
        if "const2" not in label:
            assert curve[0] == pytest.approx(mu_s, abs=1e-6), label


# ---------------------------------------------------------------- Figs. 4 and 5 (section 3)
def test_fig4_rows_of_eq_3_1_and_first_break_away():
    r = paper.fig4(None, quick=True)
    # the row recorded at t_i is the one the step into t_i started with (at t_{i-1})
    row, F, P, v = r.data["row"][1:], r.data["F"][:-1], r.data["P"][:-1], r.data["v"][:-1]
    assert set(np.unique(row)) == {1, 2, 3}
    # row 1: kinetic, |F| = F_kin = 1 N; row 2: holding, F = P; row 3: F = F_stat sgn(P) = 1.5 N
    assert np.allclose(np.abs(F[row == 1]), 1.0)
    assert np.allclose(F[row == 2], P[row == 2])
    assert np.allclose(F[row == 3], 1.5 * np.sign(P[row == 3]))
    assert np.all(np.abs(v[row == 1]) > 0.0)
    # P = k v_s t reaches F_stat = 1.5 N at 7.5 s; then F(3) lasts until v = k v_s τ²/(2m) = v_min
    assert r.headline["first break-away (row 3 starts) [s]"] == pytest.approx(7.5, abs=2e-4)
    assert r.data["durations"][0] == pytest.approx(
        math.sqrt(2 * 1.0 * 1e-3 / (2.0 * 0.1)), rel=0.01
    )


def test_fig5_first_static_stage_follows_v_min_later_ones_do_not():
    r = paper.fig5(None, quick=True)
    vm, d = r.data["v_min"], r.data["durations"]
    # t_I = sqrt(2 m v_min / (k v_s)) while the body has not yet moved (closed form)
    assert d[:, 0] == pytest.approx(np.sqrt(10.0 * vm), rel=0.01)
    # the seed: t_II, t_III show no such dependence; over two decades of v_min t_I
    # grows tenfold while neither later stage shows a trend
    for j in (1, 2):
        slope = np.polyfit(np.log(vm), np.log(d[:, j]), 1)[0]
        assert abs(slope) < 0.2, (j, d[:, j])
    assert np.all(d[:, 1:] < 0.5 * d[-1, 0])


# ---------------------------------------------------------------- section 5: Figs. 7-11
@LAWS
def test_fig7_moment_of_friction_rotates_and_shortens_x_o(stick):
    r = paper.fig7(None, quick=True, stick=stick)
    with_m, without = r.data["with"], r.data["without"]
    phi_k = math.degrees(with_m.y[-1, 2])
    assert abs(phi_k) > 1.0
    assert np.all(without.y[:, 2] == 0.0)
    assert with_m.y[-1, 0] - with_m.y[0, 0] < without.y[-1, 0] - without.y[0, 0]


@LAWS
def test_fig8_trends_of_x_o(stick):
    r = paper.fig8(None, quick=True, stick=stick)
    a, b, c, d = (r.data[k] for k in "abcd")
    # (a) rows A, columns B: grows with A, hardly depends on B
    assert np.all(np.diff(a, axis=0) > 0)
    assert np.max(np.ptp(a, axis=1)) < 0.1 * np.min(np.ptp(a, axis=0))
    # (b) rows v, columns A: grows with v
    assert np.all(np.diff(b, axis=0) > 0)
    # (c) rows α (rising), columns A: falls as α rises
    assert np.all(np.diff(c, axis=0) < 0)
    # (d) rows μ_a, columns μ_b: falls with μ_b, rises with μ_a, μ_b matters more
    assert np.all(np.diff(d, axis=1) < 0)
    assert np.all(np.diff(d, axis=0) > 0)
    assert np.all(np.abs(np.diff(d, axis=1)).min() > np.abs(np.diff(d, axis=0)).max())


@LAWS
def test_fig9_capacity_falls_with_alpha_and_length(stick):
    r = paper.fig9(None, quick=True, stick=stick)
    W = r.data["W"]  # [α = 90, 45, 30][v][A]
    assert np.all(W[0] > W[1]) and np.all(W[1] > W[2])
    assert np.all(np.diff(W, axis=2) < 0)
    assert np.all(np.diff(W, axis=1) > 0)  # a faster belt scraps more per hour
    # the seed reads about 3600 pcs/h at v = 1.5 m/s, A = 0.7 m, α = 90° off its plot
    assert r.data["ref_full"] == pytest.approx(3600, rel=0.05)
    assert r.data["ref_simple"] == pytest.approx(3600, rel=0.05)
    # at α = 30° the drop against 90° is larger for short loads
    loss = 1 - W[2, -1] / W[0, -1]
    assert loss[0] > loss[-1]


@LAWS
def test_fig9_the_45_degree_loss_is_slight_and_least_for_long_loads(stick):
    r = paper.fig9(None, quick=True, stick=stick)
    W, l45, l30 = r.data["W"], r.data["loss_45"], r.data["loss_30"]
    iv = r.data["v"].index(1.5)
    assert l45 == pytest.approx(100 * (1 - W[1, iv] / W[0, iv]))
    # slight (below the 30° loss at every A) and slightest for the longest loads
    assert np.all(l45 < l30)
    assert np.all(np.diff(l45) < 0)


@LAWS
def test_fig9_scrapping_time_grows_far_less_than_the_path(stick):
    r = paper.fig9(None, quick=True, stick=stick)
    ratio = r.data["tc_30_over_90"]
    # W_t = 3600/t_c, so t_c(30°)/t_c(90°) = W_t(90°)/W_t(30°)
    iv = r.data["v"].index(1.5)
    assert ratio == pytest.approx(r.data["W"][0, iv] / r.data["W"][2, iv])
    # the path across at 30° is 1/sin 30° = 2 times the one at 90°; t_c grows by less
    # than half of that for the longest load, and by less for long loads than short ones
    assert ratio[-1] < 1.5
    assert np.all(np.diff(ratio) < 0)


@LAWS
def test_capacity_rises_with_the_disks_mu_and_falls_with_the_belts(stick):
    r = paper.fig8(None, quick=True, stick=stick)
    W = r.data["W_d"]  # rows μ_a, columns μ_b
    assert np.all(np.diff(W, axis=1) > 0)
    assert np.all(np.diff(W, axis=0) < 0)
    assert np.abs(np.diff(W, axis=1)).min() > np.abs(np.diff(W, axis=0)).max()
    # the same runs: W_t = 3600 / t_c and x_o over that time
    s = paper_support.sort_once(mu_a=r.data["mu"][0], mu_b=r.data["mu"][1], stick=stick)
    assert W[0, 1] == pytest.approx(3600.0 / s["t_scrap"])


@LAWS
def test_fig10_e2_is_a_substantial_part_and_the_early_push_is_stronger_at_low_alpha(stick):
    r = paper.fig10(None, quick=True, stick=stick)
    acc, share, e2 = r.data["acc_early"], r.data["E2_share"], r.data["E2_duration"]
    assert min(share.values()) >= 0.2
    # the seed's conclusion 2c: a larger α, less lateral acceleration and a longer E2
    assert 0.0 < acc[90.0] < acc[45.0] < acc[30.0]
    assert e2[90.0] > e2[45.0] > e2[30.0]
    for al, (res, summ, _) in r.data["runs"].items():
        st = summ["stages"]
        # E2 starts at the break off the belt: the parcel still moves at (v, 0) there
        k = np.searchsorted(res.t, st["E2"])
        assert res.y[k, 3] == pytest.approx(1.5, abs=1e-6)
        assert res.y[k, 4] == pytest.approx(0.0, abs=1e-6)
        assert any(e["kind"] == "break" and e["t"] == st["E2"] for e in summ["events"])
        # a parcel pulled by friction alone: |ÿ| <= μ g
        assert abs(acc[al]) <= 0.6 * G


@LAWS
def test_fig11_the_excess_of_30_degrees_is_largest_at_low_speed_and_short_loads(stick):
    r = paper.fig11(None, quick=False, stick=stick)
    gap = r.data["excess_30_over_90"]  # [v, A], v and A rising
    assert np.unravel_index(np.nanargmax(gap), gap.shape) == (0, 0)
    assert r.checks["11-lowv"].holds


@LAWS
def test_fig10_rubbing_components_and_stages(stick):
    r = paper.fig10(None, quick=True, stick=stick)
    e2 = r.data["E2_duration"]
    assert e2[45.0] < e2[90.0] and e2[30.0] < e2[90.0]
    for al, (res, summ, rub) in r.data["runs"].items():
        xi_b, eta_b = rub["b"]
        st = summ["stages"]
        e1 = (res.t > 0.01) & (res.t < st["E2"])
        # E1: the parcel rides the belt at (v, 0), so ξ_b = v cos α - v, η_b = -v sin α
        a = math.radians(al)
        assert np.allclose(xi_b[e1], 1.5 * (math.cos(a) - 1.0))
        assert np.allclose(eta_b[e1], -1.5 * math.sin(a))
        # E3: stuck on the disks, no rubbing on them
        e3 = res.t > st["E3"] + 1e-9
        assert np.allclose(xi_b[e3], 0.0, atol=1e-9) and np.allclose(eta_b[e3], 0.0, atol=1e-9)
        # zone a rubs only once E1 is over
        xi_a, eta_a = rub["a"]
        assert np.allclose(np.nan_to_num(xi_a[e1]), 0.0, atol=1e-12)
    # |η_b| = |ξ_b| at 90°, much greater at 45° and 30° (cot(α/2) while on the belt)
    ratio = r.data["eta_over_xi_b"]
    assert ratio[90.0, "E1"] == pytest.approx(1.0)
    assert ratio[45.0, "E1"] == pytest.approx(1 / math.tan(math.radians(22.5)))
    assert ratio[30.0, "E2"] > 2.0 and ratio[45.0, "E2"] > 1.5


@LAWS
def test_fig11_minimal_width_falls_as_alpha_rises_and_is_a_sharp_threshold(stick):
    r = paper.fig11(None, quick=True, stick=stick)
    b = r.data["b_min"][:, 0, 0]  # α = 90, 45, 30 at v = 1.5, A = 0.4
    assert b[0] < b[1] < b[2]
    # the root is where the criterion switches: just below it the field no longer scrapes
    for al, bm in zip(paper_support.ALPHAS, b):
        for width, expect in ((bm + 0.01, True), (bm - 0.02, False)):
            from sorter_sim.runtime.scene import run_scene

            res, _ = run_scene(
                paper_support.sorting_scene(
                    A=0.4, v=1.5, alpha_deg=al, b=width, t_max=5.0, stick=stick
                )
            )
            assert paper_support.scrapes_without_sliding(res, 1.5, al) is expect, (al, width)


def test_fig11_needs_more_width_than_the_distance_to_the_stick():
    # a field narrower than half the parcel can never hold it against the belt
    # (equal μ: the disks' static limit is below the belt's kinetic pull)
    mw = paper_support.minimal_disk_width(A=0.8, v=1.0, alpha_deg=90.0, xtol=5e-3)
    assert mw.converged and mw.b_min > 0.4


# ---------------------------------------------------------------- section 6: Figs. 13-16
@LAWS
def test_fig13_bspline_damps_constant_laws_do_not(stick):
    r = paper.fig13(None, quick=True, stick=stick)
    names = list(r.data["runs"])
    assert r.data["decay"][names[0]] < 0.5
    for n in names[1:]:
        assert r.data["decay"][n] == pytest.approx(1.0, abs=0.01)


def test_two_belts_with_constant_mu_oscillate_harmonically():
    # both belts slide under the parcel while |ẋ| < v: F = -μ m g (2x/A), a harmonic
    # oscillator with ω² = 2 μ g / A and the amplitude kept
    mu, A = 0.46, 0.4
    res = paper_support.two_belt_positioning(
        paper.FrictionLaw("const1", (mu,)), A=A, x0=0.03, t_end=4.0
    )
    x, vx, t = res.y[:, 0], res.y[:, 3], res.t
    omega = math.sqrt(2 * mu * G / A)
    # zero crossings, interpolated where x'' = -ω² x vanishes: half a period apart
    k = np.nonzero(np.sign(x[1:]) != np.sign(x[:-1]))[0]
    t0 = t[k] - x[k] * (t[k + 1] - t[k]) / (x[k + 1] - x[k])
    assert np.diff(t0) == pytest.approx(math.pi / omega, rel=1e-5)
    # the invariant of the harmonic motion keeps the release offset
    assert np.hypot(x, vx / omega) == pytest.approx(0.03, rel=1e-6)


@LAWS
def test_fig14_to_16_models_2_3_within_1_percent_and_model_1_force_rise(stick):
    r = paper.fig14(None, quick=True, stick=stick)
    for j in ("2", "3"):
        assert r.data["rel_t"][j] == pytest.approx(1.0, abs=0.01)
        assert r.data["rel_L"][j] == pytest.approx(1.0, abs=0.01)
    res1, s1, f1 = r.data["runs"]["1"]

    def last_quarter(res, st):
        return (res.t >= st["E3"] - 0.25 * (st["E3"] - st["E2"])) & (res.t < st["E3"])

    for j, (res, s, f) in r.data["runs"].items():
        fb = np.hypot(f[:, 1, 0], f[:, 1, 1])[last_quarter(res, s["stages"])]
        rises = np.any(np.diff(fb) > 1e-9 * fb[1:])
        # a constant μ only falls in the last quarter of E2 (the rubbing turns into
        # rotation); the b-spline's μ rises towards μ_0 = 0.65 as the rubbing slows
        assert rises if j == "1" else not rises, j
    assert r.data["rise"]["1"] > 1.01
    # models 2 and 3 slide on the disks alone by then: |F_b| <= μ_G m g = 0.46 * 5 * 9.81
    for j in ("2", "3"):
        assert r.data["F_b_end"][j] < 0.46 * 5.0 * G
    assert r.data["F_b_end"]["1"] > 1.2 * r.data["F_b_end"]["2"]
    # sorting needs few stick/slip transitions: a break off the belt, a stick on the disks
    assert all(n <= 3 for n in r.data["transitions"].values())
    # stuck surfaces hold the parcel: forces sum to zero while stuck (no acceleration)
    stuck = res1.mode >= 0
    assert np.allclose(f1[stuck].sum(axis=1), 0.0, atol=1e-9)


# ---------------------------------------------------------------- section 7: two-stage sorting
@LAWS
def test_two_stage_shortens_the_final_field_at_30_degrees(stick):
    r = two_stage.two_stage_figure(None, quick=True, stick=stick)
    rows = {x["d_over_s"]: x for x in r.data["rows"]}
    assert rows[0.0]["b2_min_m"] == pytest.approx(rows[0.0]["b_single_m"], abs=0.011)
    assert rows[0.4]["d_m"] == pytest.approx(0.4 * paper_support.SEED_S, abs=1e-3)
    assert rows[0.4]["b2_min_m"] < 0.85 * rows[0.4]["b_single_m"]


def test_disk_fields_in_series_build_strips():
    law = paper.FrictionLaw("const1", (0.6,))
    strips = two_stage.disk_field_strips(
        1.5,
        [two_stage.DiskField(1.0, 0.5, 30.0, "final"), two_stage.DiskField(0.0, 0.3, 90.0, "pre")],
        law,
    )
    assert [s.name for s in strips] == ["a", "pre", "belt", "final", "c"]
    assert [(s.x_lo, s.x_hi) for s in strips] == [
        (-math.inf, 0.0),
        (0.0, 0.3),
        (0.3, 1.0),
        (1.0, 1.5),
        (1.5, math.inf),
    ]
    assert strips[1].vy == pytest.approx(1.5) and strips[3].vx == pytest.approx(
        1.5 * math.cos(math.pi / 6)
    )
    with pytest.raises(ValueError, match="overlap"):
        two_stage.disk_field_strips(
            1.5, [two_stage.DiskField(0.0, 1.0, 90.0), two_stage.DiskField(0.5, 1.0, 30.0)], law
        )


# ---------------------------------------------------------------- the command
def test_paper_command_writes_csv_and_png(tmp_path, capsys):
    assert main(["paper", "7", "--quick", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "Fig. 7" in out and "φ_k" in out
    png = (tmp_path / "fig7.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    lines = (tmp_path / "fig7.csv").read_text().splitlines()
    assert lines[0] == "line,t_s,x_o_m,y_o_m,phi_deg" and len(lines) > 20


def test_paper_command_runs_either_stick_law(tmp_path, capsys):
    assert main(["paper", "7", "--quick", "--stick", "exact", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "[stick: exact]" in out and "[stick: seed]" not in out
    assert (tmp_path / "exact" / "fig7.png").exists() and not (tmp_path / "fig7.png").exists()
    assert main(["paper", "4", "--quick", "--stick", "both", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert out.count("Fig. 4:") == 1  # no stick law: run once
    assert main(["paper", "10", "--quick", "--stick", "both", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "[stick: seed]" in out and "[stick: exact]" in out


def test_paper_command_bad_input(tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["paper", "12"])
    assert exc.value.code == 2
    assert "invalid choice" in capsys.readouterr().err
    f = tmp_path / "file"
    f.write_text("x")
    assert main(["paper", "7", "--quick", "--out", str(f)]) == 2
    err = capsys.readouterr().err
    assert "not a folder" in err and "Traceback" not in err
    assert main(["paper", "7", "--doc", str(tmp_path)]) == 2
    assert "sorter paper all --doc" in capsys.readouterr().err
    assert main(["paper", "all", "--doc", str(tmp_path), "--stick", "exact"]) == 2
    assert "leave out --stick" in capsys.readouterr().err
    assert main(["paper", "all", "--doc", str(f)]) == 2
    assert "--doc" in capsys.readouterr().err and not (tmp_path / "paper.md").exists()
    with pytest.raises(SystemExit) as exc:
        main(["paper", "7", "--stick", "sometimes"])
    assert exc.value.code == 2


# ---------------------------------------------------------------- the statement table and the page
def test_every_statement_is_checked_by_a_figure_and_names_a_test_that_exists():
    keys = set()
    for name, fn in FIGURES.items():
        keys |= set(fn(None, quick=True).checks)
    keys.add("11-lowv")  # the full grid only (its own test above)
    here = {n for n in globals() if n.startswith("test_")}
    for st in STATEMENTS:
        assert set(st.checks) <= keys, st.where
        assert st.test is None or st.test in here, st.test
    # every check a figure makes is some statement's
    assert keys <= {k for st in STATEMENTS for k in st.checks}


def _table(page: str) -> list:
    start = page.index("| # | where |")
    rows = page[start:].split("\n\n", 1)[0].splitlines()[2:]
    return [[c.strip() for c in row.strip("|").split(" | ")] for row in rows]


def test_docs_paper_md_is_what_the_command_writes(tmp_path):
    page = (Path(__file__).parent.parent / "docs" / "paper.md").read_text()
    assert (
        main(["paper", "all", "--quick", "--doc", str(tmp_path), "--out", str(tmp_path / "f")])
        == 0
    )
    quick = (tmp_path / "paper.md").read_text()
    # the same sections, the same statements with the same tests
    assert [h[1] for h in headings(quick)] == [h[1] for h in headings(page)]
    ours, theirs = _table(quick), _table(page)
    assert len(ours) == len(theirs) == len(STATEMENTS)
    for a, b in zip(ours, theirs):
        assert (a[:3], a[-1]) == (b[:3], b[-1])
    # numbers that do not depend on the grids come out the same as on the page
    where = {st.checks: k for k, st in enumerate(STATEMENTS)}
    for key in (
        ("7-rot",),
        ("7-short",),
        ("9a",),
        ("10-E2",),
        ("10-acc",),
        ("16-1pct",),
        ("6-trans",),
        ("14-rise",),
    ):
        k = where[key]
        assert ours[k][3:5] == theirs[k][3:5], key
    for png in ("fig3.png", "fig9.png", "fig9_exact.png", "fig14_16_exact.png"):
        assert f"(img/{png})" in page
        assert (tmp_path / "img" / png).read_bytes()[:4] == b"\x89PNG"
    assert "sorter paper all --doc docs" in page and "--quick" not in page.split("\n", 3)[2]
