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
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

CORE_DIR = Path(__file__).resolve().parent
_checked = False


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


def drop_stale_kernels(here: Path = CORE_DIR) -> list[Path]:
    """
    Drop the numba cache of the package in ``here`` if its sources changed.

    Parameters
    ----------
    here : Path
        The package folder whose ``*.py`` sources stamp the cache in ``here/__pycache__``.

    Returns
    -------
    list of Path
        The cached kernel files removed (empty when the stamp matched, or nothing was cached).
        A missing stamp counts as a change: nothing cached without one can be trusted.

    """
    cache = kernel_cache_dir(here)
    digest = hashlib.sha256()
    for src in sorted(here.glob('*.py')):
        digest.update(src.name.encode())
        digest.update(src.read_bytes())
    stamp = cache / 'numba-sources.sha256'
    try:
        if stamp.read_text() == digest.hexdigest():
            return []
    except OSError:
        pass
    dropped: list[Path] = []
    try:
        cache.mkdir(exist_ok=True)
        for old in list(cache.glob('*.nbi')) + list(cache.glob('*.nbc')):
            old.unlink(missing_ok=True)
            dropped.append(old)
        stamp.write_text(digest.hexdigest())
    except OSError:  # a read-only install: numba then compiles in memory anyway
        pass
    return dropped


def check_kernel_cache() -> int:
    """
    Drop the core's stale kernels once per process, before the first kernel call.

    Returns
    -------
    int
        How many cached kernel files this call removed (0 after the first call).

    """
    global _checked
    if _checked:
        return 0
    _checked = True
    # a cold cache compiles for a minute or more: say so while it happens
    from sorter_sim.model.compile_progress import install

    install()
    dropped = drop_stale_kernels()
    if dropped:
        kernels = len({p.name.split('-')[0] for p in dropped})
        print(
            f'sorter_sim: the model core changed since its kernels were cached; dropped '
            f'{len(dropped)} cache files ({kernels} kernels) in {kernel_cache_dir()}, '
            'they compile again on first use',
            file=sys.stderr,
            flush=True,
        )
    return len(dropped)
