"""
The ROS-free model core: friction laws, footprint geometry, wrenches, integrators.

Nothing under this package imports rclpy or any message module (a test enforces it).

numba checks a cached kernel against its own source file only: a kernel of
``cell_kernels.py`` that calls ``integrators.py`` would keep the old callee after an
edit there. So the core's cache is stamped with a hash of all its sources, and
dropped whole when they change (after an update or an edit; a fresh clone has none).
"""

from __future__ import annotations

import hashlib
from pathlib import Path


def _drop_stale_kernels(here: Path = Path(__file__).resolve().parent) -> bool:
    """Drop the numba cache of the package in ``here`` if its sources changed; True if it did."""
    cache = here / '__pycache__'
    digest = hashlib.sha256()
    for src in sorted(here.glob('*.py')):
        digest.update(src.name.encode())
        digest.update(src.read_bytes())
    stamp = cache / 'numba-sources.sha256'
    try:
        if stamp.read_text() == digest.hexdigest():
            return False
    except OSError:
        pass
    try:
        cache.mkdir(exist_ok=True)
        for old in list(cache.glob('*.nbi')) + list(cache.glob('*.nbc')):
            old.unlink(missing_ok=True)
        stamp.write_text(digest.hexdigest())
    except OSError:  # a read-only install: numba then compiles in memory anyway
        pass
    return True


_drop_stale_kernels()
