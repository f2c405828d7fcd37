"""Scenes and the `sorter run` command line: validation, output and exit codes."""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from sorter_sim.runtime.scene import DEFAULTS, SceneError, apply_overrides, load_scene, validate

ROOT = Path(__file__).resolve().parents[1]
SCENES = sorted((ROOT / "config" / "scenes").glob("*.yaml"))


def sorter(*args, timeout=300):
    env = dict(os.environ)
    return subprocess.run(
        [sys.executable, "-m", "sorter_sim", *args],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


@pytest.mark.parametrize("path", SCENES, ids=[p.stem for p in SCENES])
def test_every_shipped_scene_is_valid(path):
    scene = load_scene(path)
    assert set(scene) == set(DEFAULTS)


def test_run_json_has_the_documented_keys():
    r = sorter("run", "config/scenes/fig9a.yaml", "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    for key in (
        "t_scrap",
        "x_scrap",
        "phi_scrap_deg",
        "capacity_pcs_h",
        "stages",
        "final_state",
        "method",
        "n_steps",
        "n_rhs",
        "n_events",
        "reductions",
        "wall_s",
    ):
        assert key in out
    assert set(out["stages"]) == {"E1", "E2", "E3"}
    assert out["capacity_pcs_h"] == pytest.approx(3600.0 / out["t_scrap"])
    assert out["method"] == "accurate" and out["n_steps"] > 0


def test_run_with_overrides_and_other_methods():
    r = sorter(
        "run",
        "config/scenes/fig7.yaml",
        "--set",
        "solver.method=implicit",
        "--set",
        "solver.dt=1e-3",
        "--set",
        "model.rotation=false",
        "--json",
    )
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["method"] == "implicit" and "no_rotation" in out["reductions"]
    assert out["phi_scrap_deg"] == 0.0


def test_negative_alpha_diverts_to_the_other_side():
    plus = json.loads(sorter("run", "config/scenes/fig7.yaml", "--json").stdout)
    minus = json.loads(
        sorter(
            "run", "config/scenes/fig7.yaml", "--set", "diverter.alpha_deg=-90", "--json"
        ).stdout
    )
    assert minus["t_scrap"] == pytest.approx(plus["t_scrap"], rel=1e-9)
    assert minus["final_state"]["y"] == pytest.approx(-plus["final_state"]["y"], rel=1e-9)
    assert minus["phi_scrap_deg"] == pytest.approx(-plus["phi_scrap_deg"], rel=1e-7)


BAD_SETS = [
    ("parcel.A=-0.4", "parcel.A"),
    ("parcel.m=0", "parcel.m"),
    ("parcel.B=.nan", "parcel.B"),
    ("belt.v=.inf", "belt.v"),
    ("diverter.alpha_deg=91", "diverter.alpha_deg"),
    ("zones.mu_b=-0.1", "zones.mu_b"),
    ("model.v_min=0", "model.v_min"),
    ("model.v_min=-1e-6", "model.v_min"),
    ("solver.method=euler", "solver.method"),
    ("model.rotation=maybe", "model.rotation"),
    ("zones.nonsense=1", "zones.nonsense"),
    ("friction.model=coulomb", "friction.model"),
    ("friction.const2=[0.5]", "friction.const2"),
    ("parcel.A", "key=value"),
]


@pytest.mark.parametrize("override,named", BAD_SETS, ids=[b[0] for b in BAD_SETS])
def test_bad_overrides_exit_2_with_one_line_naming_the_key(override, named):
    r = sorter("run", "config/scenes/fig9a.yaml", "--set", override)
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and named in lines[0]
    assert r.stdout == ""


@pytest.mark.parametrize(
    "content,named",
    [
        ("", "empty"),
        ("parcel: [1, 2\n", "not valid YAML"),
        ("- just\n- a list\n", "mapping"),
        ("parcel: {A: 0.4}\nwheels: {n: 3}\n", "wheels"),
        ("parcel: 3\n", "parcel"),
    ],
)
def test_bad_scene_files_exit_2(tmp_path, content, named):
    f = tmp_path / "scene.yaml"
    f.write_text(content)
    r = sorter("run", str(f))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert named in r.stderr
    assert len([ln for ln in r.stderr.splitlines() if ln.strip()]) == 1


def test_missing_file_and_usage_errors_exit_2():
    r = sorter("run", "no/such/scene.yaml")
    assert r.returncode == 2 and "cannot read scene file" in r.stderr
    r = sorter("run")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    r = sorter("nonsense-verb")
    assert r.returncode == 2 and "Traceback" not in r.stderr


def test_help_names_every_verb_and_loads_no_model():
    """``sorter --help`` lists each verb with its line; neither numba nor rclpy loads for it."""
    from sorter_cell.cli import CELL_VERBS
    from sorter_sim.cli import VERBS

    probe = (
        "import sys\nfrom sorter_cell.cli import main\n"
        "try:\n    rc = main(['--help'])\nexcept SystemExit as e:\n    rc = e.code\n"
        "print(rc, *sorted(m for m in ('numba', 'rclpy', 'scipy') if m in sys.modules))"
    )
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    *help_lines, last = r.stdout.strip().splitlines()
    assert last == "0", last  # exit 0, and none of the heavy modules loaded
    text = "\n".join(help_lines)
    for verb, (_, line) in {**VERBS, **CELL_VERBS}.items():
        assert verb in text and line[:40] in " ".join(text.split()), verb


def test_a_verb_whose_module_is_missing_is_refused_in_one_line_and_the_others_run(capsys):
    """An installation without a verb's module: that verb says so; the others still run."""
    from sorter_sim.cli import VERBS, main

    verbs = dict(VERBS, gone=("sorter_sim.no_such_module", "a verb not installed"))
    assert main(["gone"], verbs) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "sorter gone: error: not installed here" in err[0], err
    assert main(["run", str(ROOT / "config" / "scenes" / "fig9a.yaml"), "--json"], verbs) == 0


def test_validation_changes_nothing_on_error():
    scene = load_scene(ROOT / "config" / "scenes" / "fig9a.yaml")
    before = json.dumps(scene, sort_keys=True, default=str)
    with pytest.raises(SceneError):
        apply_overrides(scene, ["parcel.A=0.3", "parcel.B=-1"])
    assert json.dumps(scene, sort_keys=True, default=str) == before


def test_numbers_written_without_a_dot_are_numbers():
    # YAML 1.1 reads 1e-6 as a string; a user writing it means the number
    scene = validate({"model": {"v_min": "1e-6"}, "solver": {"rtol": "1e-9"}})
    assert scene["model"]["v_min"] == 1e-6 and scene["solver"]["rtol"] == 1e-9
    assert math.isinf(validate({"zones": {"b": float("inf")}})["zones"]["b"])


def test_numba_kernels_are_cached_on_disk():
    # a second process must load compiled kernels instead of compiling again
    r = sorter("run", "config/scenes/fig7.yaml", "--json")
    assert r.returncode == 0
    cache = list((ROOT / "sorter_sim" / "model" / "core" / "__pycache__").glob("*.nbi"))
    assert any("accurate" in p.name for p in cache)
    assert any("wrench" in p.name for p in cache)


@pytest.mark.parametrize(
    "overrides, words",
    [
        # negative μ: the selected law, and one not selected (it could be selected next)
        (["friction.model=stribeck", "friction.stribeck=[0.65,0.3,10,5,-100,0.1]"], "μ(0.102"),
        (["friction.stribeck=[0.65,0.3,10,5,-100,0.1]"], "friction.stribeck: μ("),
        (["friction.const2=[-0.65,0.4]"], "friction.const2"),
        # a law negative only at slip speeds a fast belt reaches
        (["belt.v=3.0", "friction.stribeck=[0.65,0.3,10,-1,1,0.1]"], "from 0 to 6 m/s"),
        (["friction.bspline=[0,0.1,0.2,0.3,0.4,0.4,0.6,0.5,0.4,0.4,0.4,0.4]"], "increase"),
        # every value is checked as it is given, even if a later one replaces it
        (["belt.v=nan", "belt.v=1.0"], "belt.v"),
    ],
)
def test_laws_and_values_are_checked_whether_used_or_not(overrides, words):
    with pytest.raises(SceneError) as err:
        apply_overrides(validate({}), overrides)
    assert words in str(err.value), str(err.value)


def test_every_accepted_law_is_non_negative_over_the_slip_speeds():
    from sorter_sim.model.core.friction import mu_kinetic
    from sorter_sim.model.core.simulate import FrictionLaw

    scene = validate({"belt": {"v": 2.0}})
    for name in ("const2", "const1", "linear", "polynomial", "stribeck", "bspline"):
        law = FrictionLaw(name, tuple(scene["friction"][name]))
        mu = [mu_kinetic(law.law_id, law.row(), 4.0 * k / 400) for k in range(401)]
        assert min(mu) >= 0.0, name


@pytest.mark.parametrize(
    "argv",
    [
        ["paper", "9", "--out", "{file}"],
        ["paper", "9", "--out", "{file}/sub"],
        ["sweep", "{spec}", "--out", "{file}/r.csv"],
        ["sweep", "{spec}", "--out", "{folder}/d.csv"],
        ["bench", "precision", "--out", "{file}"],
    ],
)
def test_outputs_are_checked_before_any_work(tmp_path, argv):
    # a path through a regular file cannot be created, whoever runs the test
    (tmp_path / "file").write_text("x")
    (tmp_path / "d.csv").mkdir()
    spec = tmp_path / "study.yaml"
    spec.write_text("parameters:\n  parcel.A: [0.4]\n")
    argv = [a.format(file=tmp_path / "file", spec=spec, folder=tmp_path) for a in argv]
    r = subprocess.run(
        [sys.executable, "-m", "sorter_sim", *argv], capture_output=True, text=True, timeout=60
    )
    assert r.returncode == 2 and "--out" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    assert not [p for p in tmp_path.glob("*.csv") if p.is_file()]


def test_a_fixed_step_scene_has_room_for_every_step_and_names_its_own_keys_when_not(
    monkeypatch,
):
    from sorter_sim.runtime import scene as sc

    base = sc.load_scene(Path(__file__).resolve().parents[1] / 'config/scenes/fig9a.yaml')
    # 300 000 steps: past the 200 000 records a run once had room for
    s = sc.apply_overrides(base, ['solver.method=implicit', 'solver.dt=1e-5', 'solver.t_max=3'])
    res, summary = sc.run_scene(s)
    assert res.success and summary['t_scrap'] is not None, res.message
    monkeypatch.setattr(sc, 'MAX_RECORDS', 1000)
    res, _ = sc.run_scene(s)
    assert not res.success
    assert 'solver.t_max' in res.message and 'solver.dt' in res.message
    assert 'max_points' not in res.message


def test_a_quick_precision_report_does_not_overwrite_the_committed_one(monkeypatch, tmp_path):
    import argparse

    from sorter_sim.studies import bench

    written = []
    monkeypatch.setattr(
        bench, 'write_precision_report', lambda out, **kw: written.append(Path(out)) or out
    )
    monkeypatch.chdir(tmp_path)
    parser = argparse.ArgumentParser()
    bench.add_arguments(parser)
    for argv, where in (
        (['precision', '--quick'], Path('out/precision_quick')),
        (['precision'], Path('docs')),
        (['precision', '--quick', '--out', 'docs'], Path('docs')),
    ):
        assert bench.run(parser.parse_args(argv)) == 0
        assert written[-1] == where, argv
