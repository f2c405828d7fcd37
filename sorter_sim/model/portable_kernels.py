"""
Build the core's kernels for any x86-64 CPU, into the folder a wheel ships them in.

numba caches a compiled kernel under the CPU it was compiled for (its name and
features), so the cache of a build machine is refused on every other machine.
Compiled with ``NUMBA_CPU_NAME=generic`` the code uses only what every x86-64 CPU has,
and ``KernelCache`` (``sorter_sim.model.core.cache``) loads it under that key on any of
them. On this model's scalar loops the generic code runs as fast as the host's (Fig. 9a
core runs, best of 20 on one core: 0.635 against 0.640 ms accurate, 2.49 against
2.56 ms implicit).

``python -m sorter_sim.model.portable_kernels DEST [--from SOURCE_ROOT]`` runs
``sorter warmup --all``'s workload in a child process under ``NUMBA_CPU_NAME=generic``
on the sources in ``SOURCE_ROOT`` (its own numba cache: warm if that tree compiled
them portably before, as ``scripts/test.sh`` does), then copies the portable entries
of every kernel's cache into ``DEST`` with a manifest: the sources' digest, numba's
version, the interpreter and the target triple, which ``KernelCache`` checks before it
reads any of them.
The wheel build calls it (``setup.py``).
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import shutil
import subprocess
import sys
from pathlib import Path

from sorter_sim.model.core.cache import (
    PORTABLE_CPU,
    python_tag,
    read_index,
    sources_digest,
    target_triple,
)

_WARM_UP = (
    'from sorter_sim.runtime.warmup import warm_up\n'
    'from sorter_sim.model.core.cache import kernel_cache_dir\n'
    'warm_up()\n'
    'print(kernel_cache_dir(), flush=True)\n'
)


def compile_portable(source_root: Path) -> Path:
    """
    Compile every kernel of the core in ``source_root`` for the generic x86-64 CPU.

    Returns
    -------
    Path
        The numba cache folder the child process compiled (or found) them in.

    """
    # the tree ahead of what is there: an isolated build finds its build environment
    # through PYTHONPATH
    path = os.pathsep.join(filter(None, [str(source_root), os.environ.get('PYTHONPATH')]))
    # none of the build machine's numba settings (optimisation, bounds checks, debug
    # information) reaches the shipped code, and no call into Intel's SVML library,
    # which numba uses where it is installed and a user's machine may not have
    env = {k: v for k, v in os.environ.items() if not k.startswith('NUMBA_')}
    if 'NUMBA_CACHE_DIR' in os.environ:
        env['NUMBA_CACHE_DIR'] = os.environ['NUMBA_CACHE_DIR']
    env.update(NUMBA_CPU_NAME='generic', NUMBA_DISABLE_INTEL_SVML='1', PYTHONPATH=path)
    done = subprocess.run(
        [sys.executable, '-c', _WARM_UP],
        cwd=source_root,
        env=env,
        stdout=subprocess.PIPE,
        text=True,
        check=False,
    )
    if done.returncode:
        raise RuntimeError(
            f'compiling the portable kernels in {source_root} failed (exit {done.returncode})'
        )
    return Path(done.stdout.strip().splitlines()[-1])


def copy_portable(cache: Path, dest: Path) -> int:
    """
    Copy the portable entries of every kernel cached in ``cache`` into ``dest``.

    An index (``*.nbi``) maps each compiled signature, keyed with the CPU it was
    compiled for, to a data file (``*.nbc``). Only the generic CPU's entries are kept:
    the index is written again with those alone, and only their data files are
    copied. An entry whose data file is not there (numba writes the index first: a
    compile beside the copy) is left out. Returns how many compiled signatures were
    copied.
    """
    from numba.core.serialize import dumps

    dest.mkdir(parents=True, exist_ok=True)
    copied = 0
    for index in sorted(cache.glob('*.nbi')):
        version, stamp, overloads = read_index(index)
        portable = {
            k: v
            for k, v in overloads.items()
            if tuple(k[1][1:]) == PORTABLE_CPU and (cache / v).is_file()
        }
        if not portable:
            continue
        with open(dest / index.name, 'wb') as f:
            pickle.dump(version, f, protocol=-1)
            f.write(dumps((stamp, portable)))
        for data in portable.values():
            shutil.copyfile(cache / data, dest / data)
        copied += len(portable)
    return copied


def build(dest: Path, source_root: Path, sources: Path | None = None) -> dict:
    """
    Compile the core in ``source_root`` portably and ship its kernels into ``dest``.

    ``sources``, the core folder the kernels are shipped with, must hold the very
    sources compiled (the digest is compared): by default the compiled tree's own.

    Returns
    -------
    dict
        The manifest written next to them.

    """
    import numba

    core = source_root / 'sorter_sim' / 'model' / 'core'
    cache = compile_portable(source_root)
    stamp = cache / 'numba-sources.sha256'
    digest = sources_digest(core)
    if sources is not None and sources_digest(sources) != digest:
        raise RuntimeError(f'{sources} and {core} hold different sources')
    if not stamp.is_file() or stamp.read_text() != digest:
        raise RuntimeError(f'{cache} does not hold the kernels of {core}')
    if dest.exists():
        shutil.rmtree(dest)
    signatures = copy_portable(cache, dest)
    if not signatures:
        raise RuntimeError(f'no kernel compiled for the generic CPU in {cache}')
    manifest = {
        'sources': digest,
        'numba': numba.__version__,
        'python': python_tag(),
        'triple': target_triple(),
        'cpu': 'generic',
        'signatures': signatures,
    }
    (dest / 'manifest.json').write_text(json.dumps(manifest, indent=1) + '\n')
    return manifest


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m sorter_sim.model.portable_kernels``."""
    parser = argparse.ArgumentParser(
        prog='python -m sorter_sim.model.portable_kernels',
        description="compile the core's kernels for any x86-64 CPU into DEST",
    )
    parser.add_argument('dest', type=Path, help='the folder to ship them in')
    parser.add_argument(
        '--from',
        dest='source_root',
        type=Path,
        default=Path(__file__).resolve().parents[2],
        help='the source tree to compile (default: the one this module is in)',
    )
    parser.add_argument(
        '--sources',
        type=Path,
        help='the core folder they ship with, which must hold the same sources',
    )
    args = parser.parse_args(argv)
    try:
        manifest = build(args.dest.resolve(), args.source_root.resolve(), args.sources)
    except (OSError, RuntimeError) as exc:
        print(f'portable kernels: {exc}', file=sys.stderr)
        return 1
    print(f'portable kernels: {manifest["signatures"]} signatures in {args.dest}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
