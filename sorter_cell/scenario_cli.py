"""
``sorter scenario run FILE`` and ``sorter scenario campaign DIR``.

``run`` runs one scenario file (``sorter_cell.testing.scenario``) in this process:
exit 0 when every expectation holds, 1 when one fails (``--junit`` says which and
where the cell was; the MCAP recording is the evidence: ``--record OUT.mcap``, or by
default one in a temporary folder kept only when the run fails, its path printed;
``--no-record``: none), 2 for a bad file (one line naming the key).

``campaign`` runs every ``*.yaml`` of a folder, each ``--seeds`` times with seeds
1, 2, ..., on Dask: a local cluster by default (``--workers`` at once), or the
cluster of ``--scheduler ADDRESS``. Each run is its own process (``sorter scenario
run ... --json``) on a ROS domain of its own, so no two runs share a graph or an
rclpy context: drawn from ``--domains A-B`` (or ``SORTER_CAMPAIGN_DOMAINS``, default
200-231) and claimed on the host while the run lasts (``testing.domains``), so that
two campaigns at once never share one. A progress bar counts the runs; at the end a
table gives each scenario's passes, failures and times, and ``--junit`` writes them
all (each run's domain and wall times as properties).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path


def add_arguments(parser) -> None:
    """
    Add the verb's arguments to its parser.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The verb's parser.

    """
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    one = sub.add_parser("run", help="run one scenario file")
    one.add_argument(
        "file",
        metavar="FILE",
        help="the scenario (YAML), or the name of a shipped one (e.g. stuck_divert_eye)",
    )
    one.add_argument("--junit", metavar="OUT.xml", help="write the result as JUnit XML")
    one.add_argument("--record", metavar="OUT.mcap", help="record the run (evidence), kept")
    one.add_argument(
        "--no-record",
        action="store_true",
        help="no recording (default: one in a temporary folder, kept when the run fails)",
    )
    one.add_argument("--seed", type=int, help="the generated stream's seed instead of the file's")
    one.add_argument("--json", action="store_true", help="print the result as one JSON object")
    many = sub.add_parser("campaign", help="run every scenario of a folder, in parallel on Dask")
    many.add_argument("folder", metavar="DIR", help="a folder of scenario files (*.yaml)")
    many.add_argument("--workers", type=int, default=2, help="runs at once (default 2)")
    many.add_argument("--scheduler", metavar="ADDRESS", help="an existing Dask scheduler")
    many.add_argument("--seeds", type=int, default=1, help="runs per scenario, seeds 1..N")
    many.add_argument("--junit", metavar="OUT.xml", help="write every result as JUnit XML")
    many.add_argument(
        "--domains",
        metavar="A-B",
        help="the ROS domains runs draw from (default: $SORTER_CAMPAIGN_DOMAINS, else 200-231)",
    )
    many.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args) -> int | str:
    """
    Run the verb.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed arguments.

    Returns
    -------
    int or str
        The exit code, or a message for a refused input.

    """
    if args.action == "run":
        return _run_one(args)
    return _campaign(args)


MCAP_MAGIC = b"\x89MCAP0\r\n"  # what a recording of this project starts with
# what each kind of file this command writes starts with: one already there is replaced
# only if it is one of these (a report or a recording from an earlier run)
OWN_FILES = {"recording": (MCAP_MAGIC,), "junit": (b"<?xml", b"<testsuite")}


def output_problem(path: str, flag: str, kind: str, *, base: Path | None = None) -> str | None:
    """
    Say why this command must not write ``path`` (None when it may).

    Parameters
    ----------
    path : str
        The file, as given.
    flag : str
        Where it was given (an option, or the scenario's key), for the message.
    kind : str
        What is written: ``recording`` or ``junit`` (``OWN_FILES``).
    base : Path, optional
        A scenario file's folder: a path the file names is relative to it and may not
        leave it (a path given on the command line may go anywhere).

    Returns
    -------
    str or None
        One line: what is wrong and what is allowed.

    """
    p = Path(path)
    if base is not None:
        p = base / p
        inside = base.resolve()
        if p.resolve() != inside and inside not in p.resolve().parents:
            return (
                f"{flag} {path!r}: a scenario writes only inside its own folder "
                f"({str(base)!r}); give another place on the command line"
            )
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        return f"{flag} {str(p)!r}: folder {str(parent)!r} does not exist (it is not created)"
    if p.is_symlink() or (p.exists() and not p.is_file()):
        return f"{flag} {str(p)!r} exists and is not a plain file: not written"
    if p.exists():
        try:
            with open(p, "rb") as f:
                head = f.read(16)
        except OSError as exc:
            return f"{flag} {str(p)!r}: cannot read it ({exc.strerror or exc})"
        if head and not head.startswith(OWN_FILES[kind]):
            return (
                f"{flag} {str(p)!r} exists and is not a {kind} this command wrote: not overwritten"
            )
    return None


def write_output(path: str, text: str, flag: str) -> str | None:
    """Write ``text`` to ``path``; return one line on failure (a full disk, no rights)."""
    try:
        Path(path).write_text(text, encoding="utf-8")
    except OSError as exc:
        return f"{flag} {path!r}: cannot write ({exc.strerror or exc})"
    return None


def _result_dict(r) -> dict:
    return {
        "name": r.name,
        "passed": r.passed,
        "error": r.error,
        "sim_s": r.sim_s,
        "wall_s": r.wall_s,
        "record": r.record,
        "state": r.state if not r.passed else "",
        "checks": [{"text": c.text, "passed": c.passed, "detail": c.detail} for c in r.checks],
        "outcomes": len(r.outcomes),
        # where each parcel went and when: two runs of one file compare on this
        "notes": r.notes,
        "exits": [[o.label, o.exit, round(o.t, 6)] for o in r.outcomes]
        + [[d.label, f"{d.code} {d.station} {d.chute}", round(d.t, 6)] for d in r.dispositions],
    }


def scenario_path(given: str) -> str:
    """
    Return the scenario file ``given`` names: a path, or the name of a shipped scenario.

    ``sorter scenario run stuck_divert_eye`` runs ``config/scenarios/stuck_divert_eye.yaml``
    of the installed package from any directory; a file of that name in the current
    directory wins, as a path always does.
    """
    from sorter_ros.env import shipped_file

    if Path(given).exists():
        return given
    shipped = shipped_file("scenarios", given)
    return str(shipped) if shipped is not None else given


def _run_one(args) -> int | str:
    from sorter_cell.testing.scenario import ScenarioError, junit_xml, load_scenario, report
    from sorter_cell.testing.scenario import run_scenario

    path = scenario_path(args.file)
    if not Path(path).exists():
        from sorter_ros.env import shipped_names

        return (
            f"no scenario file {args.file!r}, and no shipped scenario of that name "
            f"(shipped: {', '.join(shipped_names('scenarios'))})"
        )
    try:
        sc = load_scenario(path)
    except ScenarioError as exc:
        return str(exc)
    for flag, path, kind in (
        ("--junit", args.junit, "junit"),
        ("--record", args.record, "recording"),
    ):
        if path:
            problem = output_problem(path, flag, kind)
            if problem:
                return problem
    record = args.record
    in_file = sc.cell.get("record_path")
    if in_file and not record:
        # the scenario's own recording: in its folder, named in the result
        if not isinstance(in_file, str):
            return f"cell.record_path must be a file name, got {in_file!r}"
        base = Path(sc.path or args.file).parent
        problem = output_problem(in_file, "cell.record_path", "recording", base=base)
        if problem:
            return problem
        record = str(base / in_file)
    if args.seed is not None and not 0 <= args.seed < 2**31:
        return f"--seed must be in [0, 2^31), got {args.seed}"
    if args.record and args.no_record:
        return "--record and --no-record: give one of them"
    scratch = None
    if not record and not args.no_record:
        import tempfile

        scratch = Path(tempfile.mkdtemp(prefix="sorter-scenario-"))
        record = str(scratch / f"{Path(args.file).stem}.mcap")
    result = run_scenario(sc, record=record, seed=args.seed)
    if result.refused:  # the user's callable made no node: a bad file, as at load
        if scratch is not None:
            import shutil

            shutil.rmtree(scratch, ignore_errors=True)
        return f"{sc.path}: {result.error}"
    if scratch is not None and result.passed:
        import shutil

        shutil.rmtree(scratch, ignore_errors=True)  # evidence is kept for a failure only
        result.record = ""
    if args.junit:
        problem = write_output(args.junit, junit_xml([result]), "--junit")
        if problem:
            return problem
    if args.json:
        print(json.dumps(_result_dict(result)))
    else:
        print(report(result))
    return 0 if result.passed else 1


def _run_in_process(file: str, seed: int, domains: range, cwd: str | None = None) -> dict:
    """
    Run one scenario as its own process on a domain it holds alone; return its JSON result.

    ``cwd``: the directory the campaign was started in, where the run looks for the
    user's modules after the scenario's folder (as ``scenario run`` does).
    """
    from sorter_cell.testing.domains import DomainClaim

    with DomainClaim(domains) as domain:
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
        start = time.time()
        wall0 = time.perf_counter()
        done = subprocess.run(
            [
                sys.executable,
                "-m",
                "sorter_cell",
                "scenario",
                "run",
                file,
                "--seed",
                str(seed),
                "--json",
            ],
            capture_output=True,
            text=True,
            env=env,
            cwd=cwd,
        )
        wall = time.perf_counter() - wall0
        end = time.time()
    lines = [x for x in done.stdout.splitlines() if x.startswith("{")]
    if done.returncode in (0, 1) and lines:
        out = json.loads(lines[-1])
    else:
        tail = (done.stderr.strip().splitlines() or ["no output"])[-1]
        out = {
            "name": Path(file).stem,
            "passed": False,
            "error": tail,
            "sim_s": 0.0,
            "wall_s": 0.0,
            "record": "",
            "state": "",
            "checks": [],
            "outcomes": 0,
        }
    out.update(file=file, seed=seed, process_s=wall, domain=domain, start=start, end=end)
    return out


def _campaign_inputs(args) -> tuple[list[str], object] | str:
    """Check a campaign's folder, files and options; return its files and domains, or why not."""
    from sorter_cell.testing.domains import campaign_domains
    from sorter_cell.testing.scenario import ScenarioError, load_scenario

    folder = Path(args.folder)
    if not folder.is_dir():
        return f"{folder} is not a folder"
    files = sorted(str(p) for p in folder.glob("*.yaml"))
    if not files:
        return f"{folder} holds no scenario (*.yaml)"
    for f in files:  # every file checked before anything runs; no module of the user's
        try:  # is imported here: each run's process does, and refuses it in one line
            load_scenario(f, imports=False)
        except ScenarioError as exc:
            return str(exc)
    if not 1 <= args.seeds <= 1000:
        return f"--seeds must be in [1, 1000], got {args.seeds}"
    if not 1 <= args.workers <= 64:
        return f"--workers must be in [1, 64], got {args.workers}"
    if args.junit:
        problem = output_problem(args.junit, "--junit", "junit")
        if problem:
            return problem
    try:
        return files, campaign_domains(args.domains)
    except ValueError as exc:
        return str(exc)


def local_cluster(threads: int):
    """
    Start the campaign's own Dask cluster: one worker of ``threads`` threads, in-process.

    Threads are enough, as each run is a process of its own. The scheduler's and the
    worker's HTTP servers start whatever the dashboard setting: with None they listened on
    every interface, the scheduler's at port 8787, which a second campaign on the host
    found taken (a warning). Free ports on loopback keep campaigns apart and open nothing
    off the host.
    """
    from distributed import LocalCluster

    return LocalCluster(
        n_workers=1,
        threads_per_worker=threads,
        processes=False,
        dashboard_address="127.0.0.1:0",
        worker_dashboard_address="127.0.0.1:0",
    )


def campaign_table(rows: list[dict]) -> str:
    """
    Return the campaign's table: a line per scenario, its runs and mean times, aligned.

    The name column is as wide as the longest name (at least 32): a long name moves
    the columns, every line alike, rather than pushing its own line out of them.
    """
    by_name: dict[str, list] = {}
    for r in rows:
        by_name.setdefault(r["name"], []).append(r)
    width = max([32] + [len(n) for n in by_name])
    lines = [
        f"{'scenario':<{width}} {'runs':>5} {'passed':>7} {'failed':>7} {'sim s':>7} "
        f"{'run s':>7} {'process s':>10}"
    ]
    for name, rs in by_name.items():
        n_ok = sum(r["passed"] for r in rs)
        sim = sum(r["sim_s"] for r in rs) / len(rs)
        run_s = sum(r["wall_s"] for r in rs) / len(rs)
        proc = sum(r["process_s"] for r in rs) / len(rs)
        lines.append(
            f"{name:<{width}} {len(rs):>5} {n_ok:>7} {len(rs) - n_ok:>7} {sim:>7.1f} "
            f"{run_s:>7.1f} {proc:>10.1f}"
        )
    return "\n".join(lines)


def _campaign(args) -> int | str:
    from sorter_cell.testing.scenario import Check, ScenarioResult, junit_xml
    from sorter_sim.studies.progress import progress_bar

    checked = _campaign_inputs(args)
    if isinstance(checked, str):
        return checked
    files, domains = checked
    folder = Path(args.folder)
    from distributed import Client, as_completed

    wall0 = time.perf_counter()
    cluster = None
    try:
        if args.scheduler:
            from sorter_sim.studies.scheduler import connect_scheduler

            try:
                client = connect_scheduler(args.scheduler, 10.0)
            except Exception as exc:  # noqa: BLE001 - OSError, TimeoutError by address kind
                return f"--scheduler: cannot reach a Dask scheduler at {args.scheduler}: {exc}"
        else:
            cluster = local_cluster(args.workers)
            client = Client(cluster)
        jobs = [(f, s) for f in files for s in range(1, args.seeds + 1)]
        here = os.getcwd()
        futures = [
            client.submit(_run_in_process, f, s, domains, here, pure=False) for f, s in jobs
        ]
        bar = progress_bar(len(futures), "sorter scenario", "run", quiet=args.quiet)
        rows = []
        for fut in as_completed(futures):
            rows.append(fut.result())
            bar.update(1)
        bar.close()
        client.close()
    finally:
        if cluster is not None:
            cluster.close()
    wall = time.perf_counter() - wall0
    rows.sort(key=lambda r: (r["file"], r["seed"]))
    print(campaign_table(rows))
    failed = [r for r in rows if not r["passed"]]
    print(
        f"{len(rows)} runs in {wall:.1f} s wall with {args.workers} at once: "
        f"{len(rows) - len(failed)} passed, {len(failed)} failed"
    )
    for r in failed:
        why = r["error"] or "; ".join(
            f"{c['text']}: {c['detail']}" for c in r["checks"] if not c["passed"]
        )
        print(f"  FAILED {r['name']} (seed {r['seed']}): {why.splitlines()[0] if why else ''}")
        if r.get("state"):
            print("\n".join("    " + x for x in r["state"].splitlines()))
    if args.junit:
        results = []
        for r in rows:
            res = ScenarioResult(
                f"{r['name']} [seed {r['seed']}]",
                sim_s=r["sim_s"],
                wall_s=r["wall_s"],
                record=r["record"],
                error=r["error"],
                state=r.get("state", ""),
                properties={
                    "exits": "; ".join(f"{a} {b} {c:.6f}" for a, b, c in r.get("exits", [])),
                    "ros_domain": r["domain"],
                    "wall_start": f"{r['start']:.6f}",
                    "wall_end": f"{r['end']:.6f}",
                },
            )
            res.checks = [Check(c["text"], c["passed"], c["detail"]) for c in r["checks"]]
            results.append(res)
        problem = write_output(
            args.junit, junit_xml(results, f"sorter campaign {folder.name}"), "--junit"
        )
        if problem:
            return problem
    return 1 if failed else 0
