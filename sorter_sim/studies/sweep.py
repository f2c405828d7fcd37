"""
Design studies: ``sorter sweep SPEC.yaml`` runs one scene over many values of its keys.

A study spec (YAML) names a base scene, the scene keys to vary and how to sample
them; every point is one ``run_scene`` of the model core, exactly what ``sorter
run`` does, and one row of the result table (CSV or Parquet, by the extension
of the output path).

Spec keys (everything but ``parameters`` optional)::

    scene: ../scenes/fig9a.yaml     # base scene: a path (relative to this spec) or a mapping
    set: {zones.mu_b: 0.7}          # fixed overrides of the base scene
    parameters:                     # scene keys "section.key" -> values
      belt.v: [0.5, 1.0, 1.5]                   # a list: these values
      parcel.A: {min: 0.2, max: 1.2, num: 6}    # grid: linspace; random: uniform in [min, max]
      zones.mu_b: {min: 0.3, max: 0.9, log: true}  # random: log-uniform
      friction.model: {values: [const1, const2]}
    sampling: grid                  # grid (every combination) or random
    samples: 100                    # random: how many points
    seed: 1                         # random: the generator's seed (same seed, same points)
    outputs: [t_scrap, x_scrap]     # columns to keep (default: all of OUTPUTS)
    out: results.parquet            # default <spec name>.csv in the current folder

``sweep_spec`` reads and checks the spec into its design points (``load_study``);
here the points run and their rows are stored.

Resuming: a point is keyed by its parameter values (as written in the table).
Rows are appended as each point finishes, each with a single write to a file
opened for appending, so an interrupted study loses no finished point; run the
same command again and only the missing points are computed. Parquet files
cannot be appended to, so a Parquet study journals its rows to
``OUT.journal.jsonl`` the same way and rewrites the Parquet file (atomically:
temporary file + rename) at the end or on interruption. A finished study is
rewritten in design order.

Parallelism: local worker processes by default (``concurrent.futures``); with
``--scheduler ADDRESS`` the points go to that Dask cluster (``dask.distributed``;
the workers need sorter_cell installed). Bad input: one line naming the key,
exit code 2.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import math
import os
import time
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures import as_completed as futures_as_completed
from dataclasses import dataclass, field
from pathlib import Path

from sorter_sim.model.description import shown
from sorter_sim.runtime.scene import SceneError, run_scene
from sorter_sim.studies.outpaths import file_problem
from sorter_sim.studies.progress import progress_bar
from sorter_sim.studies.sweep_spec import (
    OUTPUTS,
    SpecError,
    Study,
    load_study,
    param_text,
    point_key,
)


def _one_line(exc) -> str:
    """Return a (YAML) error message, whose text spans several lines, as one line."""
    return " ".join(str(exc).split())


# ---------------------------------------------------------------------------- one point
def run_point(scene: dict) -> dict:
    """
    One design point: run the scene; every output of OUTPUTS (a failed run is a row too).

    Parameters
    ----------
    scene : dict
        A validated scene.

    Returns
    -------
    dict
        The result row.

    """
    try:
        _, s = run_scene(scene)
    except Exception as exc:  # noqa: BLE001 - a point that cannot run is a result, not a crash
        row = {k: None for k in OUTPUTS}
        row.update(success=False, status=-99, message=f"{type(exc).__name__}: {exc}")
        return row
    row = {k: s.get(k) for k in OUTPUTS if k in s}
    for stage in ("E1", "E2", "E3"):
        row[stage] = s["stages"][stage]
    return row


def _out_text(v) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "" if math.isnan(v) else repr(v)
    return str(v)


# ---------------------------------------------------------------------------- result stores
class CsvStore:
    """The CSV table is its own journal: a header, then one appended line per point."""

    def __init__(self, path: Path, columns: list):
        self.path = path
        self.columns = columns
        self.fd = None

    def load(self) -> list[dict]:
        if not self.path.exists():
            return []
        data = self.path.read_bytes()
        if data and not data.endswith(b"\n"):
            # a line cut short by a crash is not a finished point: drop it
            data = data[: data.rfind(b"\n") + 1]
            with open(self.path, "r+b") as fh:
                fh.truncate(len(data))
        if not data:
            return []
        rows = list(csv.reader(io.StringIO(data.decode())))
        if rows[0] != self.columns:
            raise SpecError(
                f"--out {shown(str(self.path))} holds a table with other columns "
                f"({', '.join(rows[0])}); this study writes {', '.join(self.columns)}: "
                "choose another --out or remove the file"
            )
        return [dict(zip(self.columns, r)) for r in rows[1:] if len(r) == len(self.columns)]

    def open(self) -> None:
        if not self.path.exists() or self.path.stat().st_size == 0:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            tmp = self.path.with_name(self.path.name + ".tmp")
            tmp.write_text(self._line(self.columns))
            os.replace(tmp, self.path)
        self.fd = os.open(self.path, os.O_WRONLY | os.O_APPEND)

    @staticmethod
    def _line(cells) -> str:
        buf = io.StringIO()
        csv.writer(buf, lineterminator="\n").writerow(cells)
        return buf.getvalue()

    def append(self, row: dict) -> None:
        """
        Append one result row to the file.

        Parameters
        ----------
        row : dict
            A result row.

        """
        # one write() on an O_APPEND descriptor: the line lands whole or not at all
        os.write(self.fd, self._line([row[c] for c in self.columns]).encode())

    def close(self, rows_in_order: list[dict] | None = None) -> None:
        """
        Finish the file; with ``rows_in_order``, rewrite it in the study's order.

        Parameters
        ----------
        rows_in_order : list of dict
            Every row, in the study's order.

        """
        if self.fd is not None:
            os.fsync(self.fd)
            os.close(self.fd)
            self.fd = None
        if rows_in_order is not None:
            tmp = self.path.with_name(self.path.name + ".tmp")
            with open(tmp, "w") as fh:
                fh.write(self._line(self.columns))
                for r in rows_in_order:
                    fh.write(self._line([r[c] for c in self.columns]))
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, self.path)


class ParquetStore:
    """Rows journalled as JSON lines next to the Parquet file, which is rewritten whole."""

    def __init__(self, path: Path, columns: list, keys: list):
        self.path = path
        self.columns = columns
        self.keys = keys
        self.journal = path.with_name(path.name + ".journal.jsonl")
        self.fd = None
        self.rows: dict = {}

    def load(self) -> list[dict]:
        import pyarrow.parquet as pq

        rows = []
        if self.path.exists():
            try:
                table = pq.read_table(self.path)
            except Exception as exc:  # noqa: BLE001 - any unreadable file is the same user error
                raise SpecError(
                    f"--out {shown(str(self.path))} is not a readable Parquet file: {exc}"
                ) from None
            if table.column_names != self.columns:
                raise SpecError(
                    f"--out {shown(str(self.path))} holds a table with other columns "
                    f"({', '.join(table.column_names)}); this study writes "
                    f"{', '.join(self.columns)}: choose another --out or remove the file"
                )
            rows += [
                {c: _from_parquet(c, r[c], self.keys) for c in self.columns}
                for r in table.to_pylist()
            ]
        if self.journal.exists():
            data = self.journal.read_bytes()
            if data and not data.endswith(b"\n"):
                data = data[: data.rfind(b"\n") + 1]
                with open(self.journal, "r+b") as fh:
                    fh.truncate(len(data))
            rows += [json.loads(line) for line in data.decode().splitlines() if line.strip()]
        for r in rows:
            self.rows[tuple(r[k] for k in self.keys)] = r
        return list(self.rows.values())

    def open(self) -> None:
        self.journal.parent.mkdir(parents=True, exist_ok=True)
        self.fd = os.open(self.journal, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)

    def append(self, row: dict) -> None:
        """
        Append one result row to the file.

        Parameters
        ----------
        row : dict
            A result row.

        """
        os.write(self.fd, (json.dumps(row) + "\n").encode())
        self.rows[tuple(row[k] for k in self.keys)] = row

    def close(self, rows_in_order: list[dict] | None = None) -> None:
        """
        Finish the file; with ``rows_in_order``, rewrite it in the study's order.

        Parameters
        ----------
        rows_in_order : list of dict
            Every row, in the study's order.

        """
        import pyarrow as pa
        import pyarrow.parquet as pq

        if self.fd is not None:
            os.fsync(self.fd)
            os.close(self.fd)
            self.fd = None
        rows = (
            rows_in_order
            if rows_in_order is not None
            else sorted(self.rows.values(), key=lambda r: int(r["point"]))
        )
        arrays = {c: _parquet_column(c, [r[c] for r in rows], self.keys) for c in self.columns}
        tmp = self.path.with_name(self.path.name + ".tmp")
        pq.write_table(pa.table(arrays), tmp)
        os.replace(tmp, self.path)
        # the Parquet file now holds every journalled row
        self.journal.unlink(missing_ok=True)


def _parquet_column(name, texts, keys):
    """Typed Parquet column from the table's text cells (numbers, booleans, else text)."""
    import pyarrow as pa

    if name == "point":
        return pa.array([int(t) for t in texts], pa.int64())
    vals = [None if t in ("", "null") else t for t in texts]
    present = [v for v in vals if v is not None]
    if present and all(v in ("true", "false") for v in present):
        return pa.array([None if v is None else v == "true" for v in vals], pa.bool_())
    if present and all(v.lstrip("-").isdigit() for v in present):
        return pa.array([None if v is None else int(v) for v in vals], pa.int64())
    try:
        return pa.array([None if v is None else float(v) for v in vals], pa.float64())
    except ValueError:
        return pa.array(vals, pa.string())


def _from_parquet(name, v, keys):
    if name == "point":
        return str(int(v))
    if name in keys:
        return param_text(v)
    return _out_text(v)


# ---------------------------------------------------------------------------- running
@dataclass
class SweepResult:
    """What ``run_study`` did: points in the design, already done, run now, left."""

    n_points: int
    n_resumed: int
    n_run: int
    n_left: int
    out: Path
    wall_s: float
    interrupted: bool = False
    computed: list = field(default_factory=list)  # keys run in this call


def _executor(workers: int, scheduler: str | None, timeout_s: float = 10.0):
    """
    Return the engine's submit, as_completed and close.

    (submit, as_completed, close) for the engine: a Dask cluster or local processes;
    (None, None, close) to run in this process.
    """
    if scheduler:
        try:
            from distributed import as_completed
        except ImportError:  # pragma: no cover - a declared dependency
            raise SpecError("--scheduler needs dask[distributed] installed") from None
        from sorter_sim.studies.scheduler import connect_scheduler

        try:
            client = connect_scheduler(scheduler, timeout_s)
        except Exception as exc:  # noqa: BLE001 - OSError, TimeoutError, ValueError by address kind
            raise SpecError(
                f"--scheduler: cannot reach a Dask scheduler at {shown(scheduler)}: {exc}"
            ) from None
        return (
            (lambda scene: client.submit(run_point, scene, pure=False)),
            as_completed,
            client.close,
        )
    if workers > 1:
        pool = ProcessPoolExecutor(max_workers=workers)
        return (
            (lambda scene: pool.submit(run_point, scene)),
            futures_as_completed,
            lambda: pool.shutdown(wait=True, cancel_futures=True),
        )
    return None, None, (lambda: None)


def run_study(
    study: Study,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    max_points: int | None = None,
    progress: bool = True,
    scheduler_timeout: float = 10.0,
) -> SweepResult:
    """
    Run the study's unfinished points, appending each row as it finishes.

    Parameters
    ----------
    study : Study
        The study.
    workers : int
        Local worker processes.
    scheduler : str, optional
        A Dask scheduler's address.
    max_points : int
        Room for records.
    progress : bool
        Show a progress bar.
    scheduler_timeout : float
        How long to wait for the scheduler [s].

    Returns
    -------
    SweepResult
        The result.

    """
    t0 = time.perf_counter()
    out = study.out
    store = (
        ParquetStore(out, study.columns, study.keys)
        if out.suffix.lower() == ".parquet"
        else CsvStore(out, study.columns)
    )
    done_rows = store.load()
    design = {point_key(values): (i, values) for i, values in enumerate(study.points)}
    finished = {}
    for r in done_rows:
        k = tuple(r[c] for c in study.keys)
        if k in design:
            finished[k] = r
    pending = [(k, design[k]) for k in design if k not in finished]
    if max_points is not None:
        pending = pending[:max_points]
    n_resumed = len(finished)
    # more workers than points would only start idle processes
    workers = max(1, min(workers or os.cpu_count() or 1, len(pending)))
    # the engine first: a scheduler that cannot be reached leaves no file behind
    submit, completed, close = (
        _executor(workers, scheduler, scheduler_timeout) if pending else (None, None, lambda: None)
    )
    bar = progress_bar(
        len(design), f"sweep {out.name}", "pt", quiet=not progress, initial=n_resumed
    )
    store.open()
    computed = []

    def record(key, index, values, row):
        cells = {"point": str(index)}
        cells.update({c: param_text(v) for c, v in zip(study.keys, values)})
        cells.update({c: _out_text(row.get(c)) for c in study.outputs})
        store.append(cells)
        finished[key] = cells
        computed.append(key)
        bar.update(1)

    interrupted = False
    try:
        if submit is None:
            for key, (i, values) in pending:
                record(key, i, values, run_point(study.scene(values)))
        else:
            futures = {
                submit(study.scene(values)): (key, i, values) for key, (i, values) in pending
            }
            for fut in completed(list(futures)):
                key, i, values = futures[fut]
                record(key, i, values, fut.result())
    except KeyboardInterrupt:
        interrupted = True
        raise
    finally:
        close()
        bar.close()
        complete = len(finished) == len(design)
        ordered = None
        if complete:
            ordered = [finished[k] for k in design]
        store.close(ordered)
    return SweepResult(
        len(design),
        n_resumed,
        len(computed),
        len(design) - len(finished),
        out,
        time.perf_counter() - t0,
        interrupted,
        computed,
    )


# ---------------------------------------------------------------------------- command
def add_arguments(parser: argparse.ArgumentParser) -> None:
    """
    Add the verb's arguments to its parser.

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The verb's parser.

    """
    parser.add_argument(
        "spec", metavar="SPEC.yaml", help="study spec (see config/sweeps/example.yaml)"
    )
    parser.add_argument(
        "--out",
        metavar="PATH",
        help="result table, .csv or .parquet (default: the spec's out, else <spec name>.csv)",
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="local worker processes (default: one per core; 1 runs in this process)",
    )
    parser.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on the Dask cluster at ADDRESS (e.g. tcp://10.0.0.5:8786)",
    )
    parser.add_argument(
        "--scheduler-timeout",
        type=float,
        default=10.0,
        metavar="SECONDS",
        help="how long to try reaching the scheduler (default 10 s)",
    )
    parser.add_argument(
        "--max-points",
        type=int,
        default=None,
        metavar="N",
        help="stop after N newly finished points (the rest on the next run)",
    )
    parser.add_argument(
        "--quiet",
        "--no-progress",
        dest="no_progress",
        action="store_true",
        help="no progress bar (there is none either when stderr is not a terminal)",
    )


def run(args) -> int | str:
    """
    ``sorter sweep``.

    Parameters
    ----------
    args : argparse.Namespace
        The verb's parsed arguments.

    Returns
    -------
    int or str
        The exit code, or a message for a refused input.

    """
    if args.workers is not None and args.workers < 1:
        return f"--workers must be >= 1, got {args.workers}"
    if not args.scheduler_timeout > 0:
        return f"--scheduler-timeout must be > 0 s, got {args.scheduler_timeout}"
    if args.max_points is not None and args.max_points < 0:
        return f"--max-points must be >= 0, got {args.max_points}"
    try:
        study = load_study(args.spec, args.out)
        problem = file_problem(study.out)
        if problem:
            return problem
        res = run_study(
            study,
            workers=args.workers,
            scheduler=args.scheduler,
            max_points=args.max_points,
            progress=not args.no_progress,
            scheduler_timeout=args.scheduler_timeout,
        )
    except (SpecError, SceneError) as exc:
        return _one_line(exc)
    state = "complete" if res.n_left == 0 else f"{res.n_left} left (run again to resume)"
    print(
        f"sweep: {res.n_points} points, {res.n_resumed} already done, {res.n_run} run now; "
        f"{state}; {res.out} ({res.wall_s:.1f} s)"
    )
    return 0
