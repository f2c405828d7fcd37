"""
The package as a user installs it: built into a wheel, installed into a fresh virtualenv.

``installed_venv(where)`` builds the wheel and the sdist with ``python -m build`` (as a
release would), makes a new virtualenv outside the repository and installs the wheel
into it with pip, from the wheel alone (``--no-deps --no-index``: nothing of the
checkout can leak in). Its dependencies are the project's ``.venv``'s, linked in (each
installed distribution, library and share folder), so the test runs offline and in
seconds: numpy, rclpy and the ROS libraries under the new prefix's ``lib/`` and
``share/`` are the same files, the project's own files are the wheel's. The editable
install of the checkout (its finder, its dist-info, its ament index entry) is left out.

The wheel ships the model's kernels compiled for any x86-64 CPU, as a release's does
(setup.py). The build compiles them in the checkout (``SORTER_KERNELS_FROM``), where
``scripts/test.sh`` compiled them that way before the suite: the build takes seconds,
not the minutes of a cold compile. The installed commands then run with a user's numba
set-up (no ``NUMBA_*`` variable, an empty cache) and load those shipped kernels; the
tests check that nothing compiles. The cold compile where no shipped kernel fits is
measured by ``benchmarks/bench_first_run.py``, not by the suite.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SITE = Path(sysconfig.get_paths()['purelib'])
CORE = Path('sorter_sim') / 'model' / 'core'


def _run(cmd: list, **kw) -> subprocess.CompletedProcess:
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=240, **kw)
    if done.returncode:
        raise RuntimeError(f'{" ".join(map(str, cmd))} failed:\n{done.stdout}\n{done.stderr}')
    return done


def _source_tree(where: Path) -> Path:
    """
    Return a copy of the checkout's tracked files under ``where``.

    The checkout itself is returned when it is not a git checkout. The build reads
    every file of the tree; other tests running beside this one write and remove files
    of their own in it (outputs, caches), and a file gone between the listing and the
    copy failed the sdist ("No such file or directory"). What is released is what git
    tracks.
    """
    listed = subprocess.run(
        ['git', '-C', str(REPO), 'ls-files', '-z'], capture_output=True, timeout=60
    )
    if listed.returncode:
        return REPO
    tree = where / 'source'
    for name in listed.stdout.decode().split('\0'):
        src = REPO / name
        if name and src.is_file():
            (tree / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, tree / name)
    return tree


def build_dists(out: Path) -> tuple[Path, Path]:
    """Build the sdist and, from it, the wheel (``python -m build``); return both paths."""
    tree = _source_tree(out.parent)
    # --no-isolation: the build backend from this environment (setuptools, no network);
    # the kernels compiled in the checkout, whose cache scripts/test.sh made portable
    env = dict(os.environ, SORTER_KERNELS_FROM=str(REPO), SORTER_KERNELS='required')
    _run(
        [sys.executable, '-m', 'build', '--no-isolation', '--outdir', str(out), str(tree)],
        env=env,
    )
    (wheel,) = out.glob('sorter_cell-*.whl')
    (sdist,) = out.glob('sorter_cell-*.tar.gz')
    return wheel, sdist


def _is_ours(name: str) -> bool:
    return 'sorter_cell' in name or name.startswith('__editable__')


def _link_dependencies(venv: Path) -> None:
    """Link the project's .venv's installed files into ``venv``, the project's own left out."""
    prefix = Path(sys.prefix)
    site = venv / SITE.relative_to(prefix)
    for entry in SITE.iterdir():
        if not _is_ours(entry.name) and not (site / entry.name).exists():
            (site / entry.name).symlink_to(entry)
    for top in ('lib', 'share'):
        (venv / top).mkdir(exist_ok=True)
        for entry in (prefix / top).iterdir():
            if entry.name in ('python3.11', 'sorter_cell') or (venv / top / entry.name).exists():
                continue
            if entry.name == 'ament_index':
                # the wheel adds its own entry here: real folders, the others' files linked
                _run(['cp', '-as', str(entry), str(venv / top / entry.name)])
            else:
                (venv / top / entry.name).symlink_to(entry)
    marker = venv / 'share/ament_index/resource_index/packages/sorter_cell'
    if marker.is_symlink():
        marker.unlink()


def installed_venv(where: Path) -> Path:
    """
    Build the dists and install the wheel into a fresh virtualenv under ``where``.

    Returns
    -------
    Path
        The virtualenv (its ``bin/`` holds ``sorter``, ``sim_node`` and the others).

    """
    dist = where / 'dist'
    wheel, _ = build_dists(dist)
    venv = where / 'venv'
    _run([sys.executable, '-m', 'venv', '--without-pip', str(venv)])
    _link_dependencies(venv)
    _run(
        [
            str(venv / 'bin' / 'python'),
            '-m',
            'pip',
            'install',
            '--no-deps',
            '--no-index',
            '--no-compile',
            '-q',
            str(wheel),
        ],
        env=user_env(venv),
    )
    return venv


def user_env(venv: Path, domain: int | None = None) -> dict:
    """
    Return the environment a user of ``venv`` has: its bin first, nothing of the checkout.

    No ``PYTHONPATH``, no ``AMENT_PREFIX_PATH``, no library path of the project's .venv
    (the ROS wheels' bootstrap sets it for the new prefix), no numba setting (the suite
    compiles for the generic CPU, a user's numba for theirs).
    """
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ('PYTHONPATH', 'AMENT_PREFIX_PATH', 'LD_LIBRARY_PATH', 'VIRTUAL_ENV')
        and not k.startswith(('_ROS_WHEELS', 'NUMBA_'))
        and not k.startswith('PYTEST')
    }
    env['PATH'] = f'{venv / "bin"}{os.pathsep}{env.get("PATH", "")}'
    env['VIRTUAL_ENV'] = str(venv)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    if domain is not None:
        env['ROS_DOMAIN_ID'] = str(domain)
    return env
