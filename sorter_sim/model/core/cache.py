"""
The on-disk numba cache of the core: dropped whole when any core source changes.

numba checks a cached kernel against its own source file only: a kernel of
``cell_kernels.py`` that calls ``accurate.py`` would keep the old callee after an
edit there. So the core's cache is stamped with a hash of all its sources, and
dropped whole when they change (after an update or an edit; a fresh clone has none).

The check runs where kernels are first needed, not at import: ``simulate``, the
oscillator, the cell runtime, the warm-up and the command lines call
``check_kernel_cache()`` before their first kernel call; it does its work once per
process and says on standard error what it dropped.

A wheel ships the kernels compiled for any x86-64 CPU (``shipped_kernels/``, built by
``sorter_sim.model.portable_kernels`` when the wheel is made): numba keys a cached kernel
by the CPU it was compiled for, so a kernel compiled on the build machine would be
refused on every other. ``KernelCache`` looks there after the user's own cache and
before compiling, so the first run of an installed package loads what it needs instead
of compiling it for minutes.
"""

from __future__ import annotations

import functools
import hashlib
import json
import pickle
import sys
from pathlib import Path

import numba
from numba.core.caching import FunctionCache


def _answer_numbas_blas_probe() -> None:
    """
    Spare every process the import of all of ``scipy.linalg`` at its first kernel.

    When numba's target context first loads (a process's first kernel, compiled or
    read from the cache), its array maths asks once whether a BLAS exists, by importing
    ``scipy.linalg.cython_blas``, and Python imports the whole ``scipy.linalg`` package
    before it: 0.3 s of a process's start, a sixth of a simulation node's, for kernels
    that call no BLAS. scipy is a dependency of this package, so the answer is known.
    That one question is answered yes without the import, and the probe is numba's own
    again at once: compiling a call to ``np.dot`` still imports scipy's BLAS.
    """
    if 'numba.np.arraymath' in sys.modules:  # asked already
        return
    try:
        from numba.np import linalg

        probe = linalg.ensure_blas
    except (ImportError, AttributeError):  # numba moved it: it asks as before
        return

    def ensure_blas():
        linalg.ensure_blas = probe
        if sys._getframe(1).f_code.co_name != '_check_blas':  # not the one question
            probe()

    linalg.ensure_blas = ensure_blas


_answer_numbas_blas_probe()

CORE_DIR = Path(__file__).resolve().parent
SHIPPED_DIR = CORE_DIR / 'shipped_kernels'
# what numba's codegen reports with NUMBA_CPU_NAME=generic: no CPU name, no extra feature
PORTABLE_CPU = ('generic', '')
_checked: set[Path] = set()  # the package folders checked in this process


def kernel_cache_dir(here: Path = CORE_DIR) -> Path:
    """
    Return the folder numba caches the kernels of the package in ``here`` in.

    ``here/__pycache__`` unless ``NUMBA_CACHE_DIR`` is set (a CI job that keeps its
    cache between runs) or the package folder is read-only (numba then uses a folder in
    the user's cache): numba's own locators say which.
    """
    try:
        from numba.core import caching

        impl = getattr(caching, 'CacheImpl', None) or caching._CacheImpl  # renamed in 0.62
        source = str(here / 'cache.py')
        probe = compile('def probe():\n    pass\n', source, 'exec')
        namespace: dict = {}
        exec(probe, namespace)
        for locator_class in impl._locator_classes:
            locator = locator_class.from_function(namespace['probe'], source)
            if locator is not None:
                return Path(locator.get_cache_path())
    except Exception:  # numba's internals moved: its default place
        pass
    return here / '__pycache__'


def sources_digest(here: Path = CORE_DIR) -> str:
    """Return the hash of the core's sources that stamps its kernels (names and contents)."""
    digest = hashlib.sha256()
    for src in sorted(here.glob('*.py')):
        digest.update(src.name.encode())
        digest.update(src.read_bytes())
    return digest.hexdigest()


def python_tag() -> str:
    """Return the interpreter tag numba names its cache files with (``py311``)."""
    return f'py{sys.version_info[0]}{sys.version_info[1]}{getattr(sys, "abiflags", "")}'


def target_triple() -> str:
    """Return the target numba compiles for here: the triple in its cache keys."""
    from numba.core.registry import cpu_target

    return cpu_target.target_context.codegen().magic_tuple()[0]


def read_index(path: Path) -> tuple[str, object, dict]:
    """
    Return a numba cache index's numba version, source stamp and compiled signatures.

    numba's format: its version pickled, then the stamp and the signatures' data files
    pickled together (``numba.core.caching.IndexDataCacheFile``).
    """
    with open(path, 'rb') as f:
        version = pickle.load(f)
        stamp, overloads = pickle.loads(f.read())
    return version, stamp, overloads


def read_manifest(folder: Path) -> dict | None:
    """Return the manifest of a folder of shipped kernels, or None if it has none."""
    try:
        manifest = json.loads((folder / 'manifest.json').read_text())
    except (OSError, ValueError):
        return None
    return manifest if isinstance(manifest, dict) else None


def shipped_kernels_fit(folder: Path, here: Path = CORE_DIR) -> str | None:
    """
    Say why the shipped kernels in ``folder`` cannot serve the core in ``here``.

    Returns
    -------
    str or None
        None when they were built from these very sources, by this numba, for this
        interpreter and target (``x86_64-unknown-linux-gnu``); otherwise what differs (the
        kernels then compile on first use).

    """
    manifest = read_manifest(folder)
    if manifest is None:
        return f'no shipped kernels in {folder}'
    wanted = {
        'sources': sources_digest(here),
        'numba': numba.__version__,
        'python': python_tag(),
        'triple': target_triple(),
    }
    for key, value in wanted.items():
        if manifest.get(key) != value:
            return f'the shipped kernels are for {key} {manifest.get(key)!r}, this is {value!r}'
    return None


@functools.cache
def shipped_kernels() -> Path | None:
    """Return the folder of kernels shipped with this install, if they fit it."""
    return SHIPPED_DIR if shipped_kernels_fit(SHIPPED_DIR) is None else None


class KernelCache(FunctionCache):
    """
    numba's cache of a kernel, with the kernels shipped for any x86-64 CPU behind it.

    A kernel is looked up in the user's cache under this CPU's key first (it holds what
    was compiled here), then in the shipped folder under the portable CPU's key, and
    compiled only when neither has it. Code for the generic x86-64 CPU runs on every
    x86-64 CPU; on another architecture the key's target triple differs and the
    shipped kernels are never used. What is loaded from the shipped folder is not
    copied into the user's cache: it is read in place, read-only.
    """

    _shipped_index: dict | None = None

    def _shipped_entries(self, shipped: Path) -> dict:
        """
        Return the shipped index of this kernel: its compiled signatures' data files.

        numba's own reader would also compare the index's stamp of the kernel's source
        file with the installed file's; the manifest's digest of every core source has
        proven them the same already, and before numba 0.68 that stamp was the file's
        time, which an install does not keep.
        """
        if self._shipped_index is None:
            index = shipped / f'{self._impl.filename_base}.nbi'
            self._shipped_index = {}
            if index.is_file():
                version, _stamp, overloads = read_index(index)
                if version == numba.__version__:
                    self._shipped_index = overloads
        return self._shipped_index

    def _load_overload(self, sig, target_context):
        data = super()._load_overload(sig, target_context)
        if data is not None or not self._enabled:
            return data
        shipped = shipped_kernels()
        if shipped is None:
            return None
        sig_key, (triple, _cpu, _features), code_key = self._index_key(
            sig, target_context.codegen()
        )
        try:
            name = self._shipped_entries(shipped).get((sig_key, (triple, *PORTABLE_CPU), code_key))
            if name is None:
                return None
            with open(shipped / name, 'rb') as f:
                data = pickle.loads(f.read())
            return self._impl.rebuild(target_context, data)
        except Exception as exc:  # a torn or foreign file: compile, as without it
            print(
                f'sorter_sim: the shipped kernel {self._impl.filename_base} in {shipped} '
                f'cannot be read ({type(exc).__name__}: {exc}); compiling it instead',
                file=sys.stderr,
                flush=True,
            )
            return None


def drop_stale_kernels(here: Path = CORE_DIR, inlined: tuple[Path, ...] = ()) -> list[Path]:
    """
    Drop the numba cache of the package in ``here`` if its sources changed.

    Parameters
    ----------
    here : Path
        The package folder whose ``*.py`` sources stamp the cache in ``here/__pycache__``.
    inlined : tuple of Path
        Package folders whose kernels those of ``here`` compile into themselves: their
        sources stamp the cache too (a study's kernels that call the core's).

    Returns
    -------
    list of Path
        The cached kernel files removed (empty when the stamp matched, or nothing was cached).
        A missing stamp counts as a change: nothing cached without one can be trusted.

    """
    cache = kernel_cache_dir(here)
    digest = ' '.join(sources_digest(d) for d in (here, *inlined))
    stamp = cache / 'numba-sources.sha256'
    try:
        if stamp.read_text() == digest:
            return []
    except OSError:
        pass
    dropped: list[Path] = []
    try:
        cache.mkdir(exist_ok=True)
        for old in list(cache.glob('*.nbi')) + list(cache.glob('*.nbc')):
            old.unlink(missing_ok=True)
            dropped.append(old)
        stamp.write_text(digest)
    except OSError:  # a read-only install: numba then compiles in memory anyway
        pass
    return dropped


def check_kernel_cache(here: Path = CORE_DIR, inlined: tuple[Path, ...] = ()) -> int:
    """
    Drop a package's stale kernels once per process, before its first kernel call.

    Parameters
    ----------
    here : Path
        The package folder whose kernels are checked (the core's by default).
    inlined : tuple of Path
        The folders whose kernels those of ``here`` compile into themselves
        (``drop_stale_kernels``).

    Returns
    -------
    int
        How many cached kernel files this call removed (0 after the first call).

    """
    if here in _checked:
        return 0
    _checked.add(here)
    # a cold cache compiles for a minute or more: say so while it happens
    from sorter_sim.model.compile_progress import install

    install()
    dropped = drop_stale_kernels(here, inlined)
    if dropped:
        kernels = len({p.name.split('-')[0] for p in dropped})
        print(
            f'sorter_sim: the sources of the kernels cached in {kernel_cache_dir(here)} '
            f'changed since; dropped {len(dropped)} cache files ({kernels} kernels), they '
            'compile again on first use',
            file=sys.stderr,
            flush=True,
        )
    return len(dropped)
