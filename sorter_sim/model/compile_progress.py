"""
Say on standard error what numba compiles while it compiles: which kernel, how far, how long.

A kernel is compiled at its first call and cached on disk (``core/cache.py``); on a
machine that has never run the model, a cell's first parcel waits a minute or more for
it. Silent, that looks like a hang. numba announces every compile it starts and ends
(``numba:compile`` events, fired only when a kernel is really compiled, never when it
is loaded from the cache); this module listens and, while a kernel compiles, prints
one line every few seconds::

    sorter_cell: compiling the model's kernels, once (cached for later runs): advance_cell,
    23 of ~61 functions, 41 s

and when it is done, what it compiled and how long it took. On a terminal the line is
rewritten in place. ``set_quiet(True)`` (the commands' ``--quiet`` and ``--json``) or
``SORTER_QUIET_COMPILE=1`` keeps it silent. The count of functions is an estimate: the
jitted functions a kernel's code names, followed transitively.
"""

from __future__ import annotations

import os
import sys
import threading
import time

_lock = threading.Lock()
_installed = False
_compiles = 0
_quiet = bool(os.environ.get('SORTER_QUIET_COMPILE', '').strip() not in ('', '0'))

PREFIX = 'sorter_cell'
FIRST_S = 2.0  # a compile shorter than this goes unannounced
EVERY_TTY_S = 2.0  # then a line this often on a terminal
EVERY_LOG_S = 15.0  # and this often into a log


def set_quiet(quiet: bool) -> None:
    """Silence (or restore) the progress lines of this process."""
    global _quiet
    _quiet = quiet


def _is_dispatcher(obj) -> bool:
    return hasattr(obj, 'py_func') and hasattr(obj, 'targetoptions')


def reachable(dispatcher) -> set[str]:
    """
    Return the qualified names of the jitted functions ``dispatcher``'s code can call.

    Follows the global names of each function's code (and of the code nested in it)
    to the dispatchers they name, transitively: an upper bound of what compiling the
    kernel compiles.
    """
    seen: dict[str, object] = {}
    todo = [dispatcher]
    while todo:
        d = todo.pop()
        fn = d.py_func
        key = f'{fn.__module__}.{fn.__qualname__}'
        if key in seen:
            continue
        seen[key] = d
        codes = [fn.__code__]
        while codes:
            code = codes.pop()
            for name in code.co_names:
                target = fn.__globals__.get(name)
                if _is_dispatcher(target):
                    todo.append(target)
            codes.extend(c for c in code.co_consts if hasattr(c, 'co_names'))
    return set(seen)


class _Progress:
    """The compile of one top-level kernel and the functions it pulls in."""

    def __init__(self, dispatcher, out):
        self.name = dispatcher.py_func.__name__
        self.total = len(reachable(dispatcher))
        self.done: set[str] = set()
        self.t0 = time.perf_counter()
        self.out = out
        self.tty = hasattr(out, 'isatty') and out.isatty()
        self.finished = threading.Event()
        self.printed = False
        self.thread = threading.Thread(target=self._tick, name='compile-progress', daemon=True)
        self.thread.start()

    def line(self) -> str:
        return (
            f"{PREFIX}: compiling the model's kernels, once (cached for later runs): "
            f'{self.name}, {len(self.done)} of ~{max(self.total, len(self.done))} functions, '
            f'{time.perf_counter() - self.t0:.0f} s'
        )

    def _say(self, text: str, final: bool = False) -> None:
        if _quiet:
            return
        try:
            if self.tty:
                self.out.write('\r\x1b[K' + text + ('\n' if final else ''))
            else:
                self.out.write(text + '\n')
            self.out.flush()
        except (OSError, ValueError):  # a closed or full stream: progress is not worth a crash
            pass
        self.printed = True

    def _tick(self) -> None:
        # the first line after 2 s (a small kernel compiles unannounced), then every
        # 2 s on a terminal and every 15 s in a log
        if self.finished.wait(FIRST_S):
            return
        while True:
            self._say(self.line())
            if self.finished.wait(EVERY_TTY_S if self.tty else EVERY_LOG_S):
                return

    def finish(self) -> None:
        self.finished.set()
        self.thread.join(timeout=1.0)
        if self.printed:
            self._say(
                f'{PREFIX}: compiled {self.name} ({len(self.done)} functions) in '
                f'{time.perf_counter() - self.t0:.1f} s',
                final=True,
            )


def compiles() -> int:
    """Return how many functions numba compiled in this process since ``install()``."""
    return _compiles


def install(out=None) -> None:
    """
    Listen to numba's compile events in this process (once; cheap when nothing compiles).

    Parameters
    ----------
    out : file, optional
        Where the lines go (default: standard error at the time of printing).

    """
    global _installed
    with _lock:
        if _installed:
            return
        _installed = True
    from numba.core import event

    class Listener(event.Listener):
        depth = 0
        current: _Progress | None = None

        def on_start(self, ev):
            global _compiles
            d = ev.data.get('dispatcher')
            if d is None:
                return
            _compiles += 1  # numba's compile event fires on a cache miss only
            Listener.depth += 1
            if Listener.depth == 1:
                Listener.current = _Progress(d, out or sys.stderr)
            fn = d.py_func
            if Listener.current is not None:
                Listener.current.done.add(f'{fn.__module__}.{fn.__qualname__}')

        def on_end(self, ev):
            if ev.data.get('dispatcher') is None:
                return
            Listener.depth -= 1
            if Listener.depth == 0 and Listener.current is not None:
                Listener.current.finish()
                Listener.current = None

    event.register('numba:compile', Listener())
