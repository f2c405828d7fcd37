"""``sorter sweep``: design points, resuming after an interruption, formats, engines, bad input."""

import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from sorter_sim.cli import main
from sorter_sim.runtime.scene import run_scene, validate
from sorter_sim.studies import sweep

REPO = Path(__file__).resolve().parents[1]
TIMING = {"wall_s"}  # the only column that may differ between two runs of a point


def write_spec(tmp_path, body: str, name="study.yaml") -> Path:
    p = tmp_path / name
    p.write_text(body)
    return p


GRID = """
scene: {scene}
parameters:
  belt.v: [1.0, 1.5]
  parcel.A: {{min: 0.3, max: 0.9, num: 3}}
  diverter.alpha_deg: [45, 90]
outputs: [success, t_scrap, x_scrap, capacity_pcs_h, E3, wall_s]
"""


def grid_spec(tmp_path):
    return write_spec(tmp_path, GRID.format(scene=REPO / "config/scenes/fig9a.yaml"))


def read_rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def without_timing(rows):
    return [{k: v for k, v in r.items() if k not in TIMING} for r in rows]


def test_grid_points_are_the_scene_runs(tmp_path):
    out = tmp_path / "r.csv"
    assert (
        main(
            [
                "sweep",
                str(grid_spec(tmp_path)),
                "--out",
                str(out),
                "--workers",
                "1",
                "--no-progress",
            ]
        )
        == 0
    )
    rows = read_rows(out)
    assert len(rows) == 2 * 3 * 2
    assert [int(r["point"]) for r in rows] == list(range(12))
    assert {(r["belt.v"], r["parcel.A"], r["diverter.alpha_deg"]) for r in rows} == {
        (repr(v), repr(a), repr(al))
        for v in (1.0, 1.5)
        for a in (0.3, 0.6, 0.9)
        for al in (45.0, 90.0)
    }
    # a row is what `sorter run` gives for that scene
    r = rows[5]
    scene = validate(
        {
            "parcel": {"A": 0.7, "B": 0.2, "m": 5.0},
            "belt": {"v": 1.5, "s": 0.7},
            "zones": {"b": float("inf"), "mu_a": 0.6, "mu_b": 0.6},
        }
    )
    scene["belt"]["v"] = float(r["belt.v"])
    scene["parcel"]["A"] = float(r["parcel.A"])
    scene["diverter"]["alpha_deg"] = float(r["diverter.alpha_deg"])
    _, s = run_scene(validate(scene))
    assert (
        float(r["t_scrap"]) == s["t_scrap"] and float(r["capacity_pcs_h"]) == s["capacity_pcs_h"]
    )
    # capacity = 3600 / t_scrap in every row
    for r in rows:
        assert float(r["capacity_pcs_h"]) == pytest.approx(3600 / float(r["t_scrap"]))


def test_resume_after_max_points_recomputes_nothing_finished(tmp_path, monkeypatch):
    spec = grid_spec(tmp_path)
    ref = tmp_path / "ref.csv"
    assert main(["sweep", str(spec), "--out", str(ref), "--workers", "1", "--no-progress"]) == 0

    computed = []
    real = sweep.run_point

    def counting(scene):
        computed.append((scene["belt"]["v"], scene["parcel"]["A"], scene["diverter"]["alpha_deg"]))
        return real(scene)

    monkeypatch.setattr(sweep, "run_point", counting)
    out = tmp_path / "part.csv"
    assert (
        main(
            [
                "sweep",
                str(spec),
                "--out",
                str(out),
                "--workers",
                "1",
                "--no-progress",
                "--max-points",
                "5",
            ]
        )
        == 0
    )
    first = read_rows(out)
    assert len(first) == 5 and len(computed) == 5
    done = {
        (float(r["belt.v"]), float(r["parcel.A"]), float(r["diverter.alpha_deg"])) for r in first
    }
    computed.clear()
    assert main(["sweep", str(spec), "--out", str(out), "--workers", "1", "--no-progress"]) == 0
    assert len(computed) == 7 and not done & set(computed)
    final = read_rows(out)
    # finished rows kept as they were (their timing too), the whole equals an uninterrupted run
    by_point = {r["point"]: r for r in final}
    for r in first:
        assert by_point[r["point"]] == r
    assert without_timing(final) == without_timing(read_rows(ref))
    # a third run finds nothing to do
    computed.clear()
    assert main(["sweep", str(spec), "--out", str(out), "--workers", "1", "--no-progress"]) == 0
    assert computed == []


def test_resume_after_the_process_is_killed(tmp_path, monkeypatch):
    # slow-ish points (implicit method, 1 ms steps) so the kill lands mid-study
    spec = write_spec(
        tmp_path,
        f"""
scene: {REPO / 'config/scenes/fig9a.yaml'}
set: {{solver.method: implicit, solver.dt: 0.001}}
parameters:
  parcel.A: {{min: 0.3, max: 1.0, num: 8}}
  belt.v: [1.0, 1.5]
  diverter.alpha_deg: [60, 90]
outputs: [success, t_scrap, x_scrap, wall_s]
""",
    )
    out = tmp_path / "killed.csv"
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "sorter_sim.cli",
            "sweep",
            str(spec),
            "--out",
            str(out),
            "--workers",
            "1",
            "--no-progress",
        ],
        env=env,
        cwd=tmp_path,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if out.exists() and out.read_text().count("\n") >= 4:  # header + 3 points
                break
            time.sleep(0.01)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    survived = read_rows(out)
    assert 3 <= len(survived) < 32, "the kill must land inside the study"
    computed = []
    real = sweep.run_point
    monkeypatch.setattr(sweep, "run_point", lambda scene: computed.append(1) or real(scene))
    assert main(["sweep", str(spec), "--out", str(out), "--workers", "1", "--no-progress"]) == 0
    assert len(computed) == 32 - len(survived)
    final = read_rows(out)
    by_point = {r["point"]: r for r in final}
    for r in survived:
        assert by_point[r["point"]] == r
    ref = tmp_path / "ref.csv"
    assert main(["sweep", str(spec), "--out", str(ref), "--workers", "1", "--no-progress"]) == 0
    assert without_timing(final) == without_timing(read_rows(ref))


def test_a_line_cut_short_is_not_a_finished_point(tmp_path):
    spec = grid_spec(tmp_path)
    out = tmp_path / "r.csv"
    assert (
        main(
            [
                "sweep",
                str(spec),
                "--out",
                str(out),
                "--workers",
                "1",
                "--no-progress",
                "--max-points",
                "3",
            ]
        )
        == 0
    )
    with open(out, "a") as fh:
        fh.write("3,1.0,0.6,90.0,tr")  # what a crash mid-line would leave
    assert main(["sweep", str(spec), "--out", str(out), "--workers", "1", "--no-progress"]) == 0
    rows = read_rows(out)
    assert len(rows) == 12 and all(r["success"] == "true" for r in rows)


def test_parquet_output_resumes_and_is_typed(tmp_path):
    pq = pytest.importorskip("pyarrow.parquet")
    spec = grid_spec(tmp_path)
    out = tmp_path / "r.parquet"
    assert (
        main(
            [
                "sweep",
                str(spec),
                "--out",
                str(out),
                "--workers",
                "1",
                "--no-progress",
                "--max-points",
                "4",
            ]
        )
        == 0
    )
    assert pq.read_table(out).num_rows == 4
    assert main(["sweep", str(spec), "--out", str(out), "--workers", "1", "--no-progress"]) == 0
    t = pq.read_table(out)
    assert t.num_rows == 12 and t.column("point").to_pylist() == list(range(12))
    assert str(t.schema.field("t_scrap").type) == "double"
    assert str(t.schema.field("success").type) == "bool"
    assert not Path(str(out) + ".journal.jsonl").exists()
    csv_out = tmp_path / "r.csv"
    assert (
        main(["sweep", str(spec), "--out", str(csv_out), "--workers", "1", "--no-progress"]) == 0
    )
    assert t.column("t_scrap").to_pylist() == [float(r["t_scrap"]) for r in read_rows(csv_out)]


def test_random_sampling_is_seeded_and_keeps_its_prefix(tmp_path):
    body = f"""
scene: {REPO / 'config/scenes/fig9a.yaml'}
parameters:
  parcel.A: {{min: 0.3, max: 1.0}}
  zones.mu_b: {{min: 0.3, max: 0.9, log: true}}
  diverter.alpha_deg: {{values: [45, 90]}}
  solver.n_quad: {{min: 4, max: 6}}
sampling: random
samples: {{n}}
seed: 7
"""
    s5 = sweep.load_study(write_spec(tmp_path, body.replace("{n}", "5"), "a.yaml"))
    s8 = sweep.load_study(write_spec(tmp_path, body.replace("{n}", "8"), "b.yaml"))
    again = sweep.load_study(write_spec(tmp_path, body.replace("{n}", "5"), "c.yaml"))
    v5 = list(s5.points)
    assert v5 == list(again.points) == list(s8.points)[:5]
    for A, mu_b, al, nq in s8.points:
        assert 0.3 <= A <= 1.0 and 0.3 <= mu_b <= 0.9 and al in (45.0, 90.0) and nq in (4, 5, 6)
    assert len({v[0] for v in v5}) == 5


def test_local_processes_and_dask_give_the_serial_result(tmp_path):
    distributed = pytest.importorskip("distributed")
    spec = grid_spec(tmp_path)
    serial, pool, dask_out = tmp_path / "s.csv", tmp_path / "p.csv", tmp_path / "d.csv"
    assert main(["sweep", str(spec), "--out", str(serial), "--workers", "1", "--no-progress"]) == 0
    assert main(["sweep", str(spec), "--out", str(pool), "--workers", "2", "--no-progress"]) == 0
    with distributed.LocalCluster(
        n_workers=1,
        threads_per_worker=1,
        processes=False,
        protocol="tcp://",
        host="127.0.0.1",
        dashboard_address=None,
    ) as cluster:
        assert (
            main(
                [
                    "sweep",
                    str(spec),
                    "--out",
                    str(dask_out),
                    "--no-progress",
                    "--scheduler",
                    cluster.scheduler_address,
                ]
            )
            == 0
        )
    ref = without_timing(read_rows(serial))
    assert without_timing(read_rows(pool)) == ref
    assert without_timing(read_rows(dask_out)) == ref


@pytest.mark.parametrize(
    "body, named",
    [
        ("parameters:\n  belt.speed: [1]\n", "belt.speed"),
        ("parameters:\n  belt.v: [1.0, 20.0]\n", "belt.v"),
        ("parameters:\n  belt.v: {min: 1, max: 2}\n", "num"),
        ("parameters:\n  belt.v: [1]\nsampling: random\n", "samples"),
        ("parameters:\n  belt.v: [1]\nsampling: latin\n", "sampling"),
        ("parameters:\n  belt.v: [1]\nout: r.txt\n", "out"),
        ("parameters:\n  belt.v: [1]\noutputs: [speed]\n", "outputs"),
        ("parameters:\n  belt.v: [1]\nwhatever: 1\n", "whatever"),
        ("parameters: {}\n", "parameters"),
        ("scene: missing.yaml\nparameters:\n  belt.v: [1]\n", "missing.yaml"),
        ("parameters: [\n", "not valid YAML"),
        # sizes are checked before any point is built or validated
        (
            "parameters:\n  parcel.A: {min: 0.3, max: 1.0}\nsampling: random\nsamples: 10000000\n",
            "samples: must be in [1, 100000]",
        ),
        (
            "parameters:\n  parcel.A: {min: 0.3, max: 1.0, num: 1000}\n"
            "  parcel.B: {min: 0.2, max: 0.5, num: 1000}\n",
            "the grid has 1000000 points",
        ),
        ("parameters:\n  belt.v: [1]\n  belt.v: [2]\n", "appears twice"),
    ],
)
def test_bad_spec_is_one_line_exit_2(tmp_path, capsys, body, named):
    spec = write_spec(tmp_path, body)
    assert (
        main(["sweep", str(spec), "--out", str(tmp_path / "r.csv"), "--no-progress"]) == 2
        if "out:" not in body
        else main(["sweep", str(spec), "--no-progress"]) == 2
    )
    err = capsys.readouterr().err
    assert named in err and "Traceback" not in err and err.count("\n") == 1
    assert not (tmp_path / "r.csv").exists()


def test_an_existing_table_of_another_study_is_refused(tmp_path, capsys):
    out = tmp_path / "r.csv"
    out.write_text("a,b\n1,2\n")
    assert main(["sweep", str(grid_spec(tmp_path)), "--out", str(out), "--no-progress"]) == 2
    assert "other columns" in capsys.readouterr().err
    assert out.read_text() == "a,b\n1,2\n"


def test_unreachable_scheduler_is_a_clear_error(tmp_path, capsys):
    import socket

    with socket.socket() as s:  # a loopback port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    assert (
        main(
            [
                "sweep",
                str(grid_spec(tmp_path)),
                "--out",
                str(tmp_path / "r.csv"),
                "--no-progress",
                "--scheduler",
                f"tcp://127.0.0.1:{port}",
                "--scheduler-timeout",
                "1",
            ]
        )
        == 2
    )
    err = capsys.readouterr().err
    assert "cannot reach a Dask scheduler" in err
    assert f"connection refused: nothing listens on 127.0.0.1 port {port}" in err, err
    assert not (tmp_path / "r.csv").exists()  # no header-only table left behind


def test_an_oversized_study_is_refused_at_once(tmp_path, capsys):
    spec = write_spec(
        tmp_path,
        "parameters:\n  parcel.A: {min: 0.3, max: 1.0}\nsampling: random\nsamples: 10000000\n",
    )
    t0 = time.perf_counter()
    assert main(["sweep", str(spec), "--out", str(tmp_path / "r.csv"), "--max-points", "1"]) == 2
    # refused from the spec alone: no point was drawn (drawing ten million takes minutes)
    assert time.perf_counter() - t0 < 5.0
    assert "100000" in capsys.readouterr().err


def test_more_workers_than_points_is_fine(tmp_path):
    spec = write_spec(tmp_path, "parameters:\n  parcel.A: [0.4, 0.5]\n")
    out = tmp_path / "r.csv"
    assert main(["sweep", str(spec), "--out", str(out), "--workers", "64", "--no-progress"]) == 0
    assert len(read_rows(out)) == 2
