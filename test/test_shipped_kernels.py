"""
The kernels a wheel ships: which are used, which are refused, what is copied.

The whole path (a wheel built with them, installed, its commands run without compiling
anything) is tested in test_installed_package.py; these are its pieces.
"""

from __future__ import annotations

import json
import pickle

import numba
import pytest
from numba.core.serialize import dumps

from sorter_sim.model.core.cache import (
    CORE_DIR,
    PORTABLE_CPU,
    python_tag,
    read_index,
    shipped_kernels_fit,
    sources_digest,
    target_triple,
)
from sorter_sim.model.portable_kernels import copy_portable


def _manifest(folder, **changes):
    folder.mkdir(exist_ok=True)
    fits = {
        'sources': sources_digest(),
        'numba': numba.__version__,
        'python': python_tag(),
        'triple': target_triple(),
    }
    (folder / 'manifest.json').write_text(json.dumps(dict(fits, **changes)))
    return folder


def test_shipped_kernels_of_these_sources_numba_and_python_fit(tmp_path):
    assert shipped_kernels_fit(_manifest(tmp_path)) is None


@pytest.mark.parametrize(
    ('key', 'value'),
    [
        ('sources', '0' * 64),
        ('numba', '0.0.1'),
        ('python', 'py27'),
        ('triple', 'aarch64-unknown-linux-gnu'),
    ],
)
def test_shipped_kernels_of_other_sources_numba_or_python_are_refused_saying_which(
    tmp_path, key, value
):
    said = shipped_kernels_fit(_manifest(tmp_path, **{key: value}))
    assert said is not None and said.startswith(f'the shipped kernels are for {key} {value!r}')


@pytest.mark.parametrize('manifest', [None, '', '{not json', '[1, 2]'])
def test_a_missing_or_torn_manifest_means_no_shipped_kernel(tmp_path, manifest):
    if manifest is not None:
        (tmp_path / 'manifest.json').write_text(manifest)
    assert shipped_kernels_fit(tmp_path) == f'no shipped kernels in {tmp_path}'


def test_the_digest_covers_every_core_source(tmp_path):
    for src in CORE_DIR.glob('*.py'):
        (tmp_path / src.name).write_bytes(src.read_bytes())
    assert sources_digest(tmp_path) == sources_digest()
    some = sorted(tmp_path.glob('*.py'))[3]
    some.write_text(some.read_text() + '\n')
    assert sources_digest(tmp_path) != sources_digest()


def _index(path, stamp, overloads):
    with open(path, 'wb') as f:
        pickle.dump(numba.__version__, f, protocol=-1)
        f.write(dumps((stamp, overloads)))


def test_only_the_portable_entries_of_a_cache_are_copied(tmp_path):
    cache, dest = tmp_path / 'cache', tmp_path / 'dest'
    cache.mkdir()
    triple = 'x86_64-unknown-linux-gnu'
    here = (triple, 'znver3', '+avx2,+fma')
    portable = (triple, *PORTABLE_CPU)
    code = ('a' * 64, 'b' * 64)
    _index(
        cache / 'm.f-10.py311.nbi',
        b'stamp',
        {
            ('sig1', here, code): 'm.f-10.py311.1.nbc',
            ('sig1', portable, code): 'm.f-10.py311.2.nbc',
        },
    )
    _index(cache / 'm.g-20.py311.nbi', b'stamp', {('sig', here, code): 'm.g-20.py311.1.nbc'})
    for name in ('m.f-10.py311.1.nbc', 'm.f-10.py311.2.nbc', 'm.g-20.py311.1.nbc'):
        (cache / name).write_bytes(name.encode())
    assert copy_portable(cache, dest) == 1
    assert sorted(p.name for p in dest.iterdir()) == ['m.f-10.py311.2.nbc', 'm.f-10.py311.nbi']
    version, stamp, overloads = read_index(dest / 'm.f-10.py311.nbi')
    assert version == numba.__version__
    assert stamp == b'stamp' and overloads == {('sig1', portable, code): 'm.f-10.py311.2.nbc'}


KERNEL_MODULE = '''
from sorter_sim.model.core.jit import kernel


@kernel
def sliding_power(mu, normal_force, speed):
    return mu * normal_force * speed
'''


def _kernel_module(folder):
    import importlib.util

    folder.mkdir(exist_ok=True)
    (folder / 'shipped_probe.py').write_text(KERNEL_MODULE)
    spec = importlib.util.spec_from_file_location(
        f'shipped_probe_{abs(hash(folder))}', folder / 'shipped_probe.py'
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize('damage', ['torn index', 'torn data'])
def test_a_damaged_shipped_kernel_is_compiled_instead_and_said(
    tmp_path, monkeypatch, capfd, damage
):
    from sorter_sim.model.core import cache

    shipped = tmp_path / 'shipped'
    shipped.mkdir()
    module = _kernel_module(tmp_path / 'src')
    base = module.sliding_power._cache._impl.filename_base
    if damage == 'torn index':
        (shipped / f'{base}.nbi').write_bytes(b'\x80\x04\x95')
    else:  # an index that names a data file cut short
        from numba.core.serialize import dumps

        stamp = module.sliding_power._cache._impl.locator.get_source_stamp()
        codegen = module.sliding_power.targetctx.codegen()
        sig = (numba.float64, numba.float64, numba.float64)
        key = module.sliding_power._cache._index_key(sig, codegen)
        portable = (key[0], (key[1][0], *PORTABLE_CPU), key[2])
        _index(shipped / f'{base}.nbi', stamp, {portable: f'{base}.1.nbc'})
        (shipped / f'{base}.1.nbc').write_bytes(dumps({'cut': 'short'})[:5])
    monkeypatch.setattr(cache, 'shipped_kernels', lambda: shipped)
    assert module.sliding_power(0.3, 10.0, 2.0) == pytest.approx(6.0)
    said = capfd.readouterr().err
    assert f'the shipped kernel {base} in {shipped} cannot be read' in said, said
    assert 'compiling it instead' in said


LOAD_PROBE = '''
import sys
from pathlib import Path
sys.path.insert(0, sys.argv[1])
from sorter_sim.model import compile_progress
from sorter_sim.model.core import cache
compile_progress.install()
if len(sys.argv) > 2:
    cache.shipped_kernels = lambda: Path(sys.argv[2])
import shipped_probe
print(shipped_probe.sliding_power(0.3, 10.0, 2.0), compile_progress.compiles())
'''


def test_a_kernel_compiled_for_the_generic_cpu_is_loaded_on_this_one_without_compiling(
    tmp_path,
):
    import os
    import subprocess
    import sys

    src = tmp_path / 'src'
    _kernel_module(src)
    env = {k: v for k, v in os.environ.items() if not k.startswith('NUMBA_')}

    def probe(cache_dir, *argv, **numba_env):
        done = subprocess.run(
            [sys.executable, '-c', LOAD_PROBE, str(src), *map(str, argv)],
            env=dict(env, NUMBA_CACHE_DIR=str(cache_dir), **numba_env),
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert done.returncode == 0, done.stderr
        value, compiles = done.stdout.split()
        return float(value), int(compiles)

    built = tmp_path / 'built'
    assert probe(built, NUMBA_CPU_NAME='generic') == (6.0, 1)  # compiled for any x86-64
    (compiled,) = [d for d in built.iterdir() if d.is_dir()]
    shipped = tmp_path / 'shipped'
    assert copy_portable(compiled, shipped) == 1
    # the index's stamp of the source file is not what decides (the manifest's digest of
    # the sources does): before numba 0.68 it was the file's time, which an install resets
    (index,) = shipped.glob('*.nbi')
    version, _stamp, overloads = read_index(index)
    assert version == numba.__version__
    _index(index, (0.0, 0), overloads)
    # this CPU's own key: nothing in an empty cache, the generic entry is found behind it
    assert probe(tmp_path / 'empty', shipped) == (6.0, 0)
    # without the shipped folder the same empty cache compiles
    assert probe(tmp_path / 'empty2') == (6.0, 1)
