"""
ROS domains for runs that share a host: a range to draw from, each claimed while in use.

A campaign runs every scenario in a ROS domain of its own. Two campaigns on one host
(two CI jobs, two users) must not draw the same domain at the same time, or their
graphs would mix. Each run therefore claims its domain with an exclusive ``flock`` on
``<lock dir>/domain-<id>.lock`` (``SORTER_DOMAIN_LOCKS``, default the temporary
folder's ``sorter-domains``) and holds it until its process ends; the kernel lets the
lock go when the holder dies, so a killed campaign leaves nothing to clean. The range
is ``--domains A-B`` or ``SORTER_CAMPAIGN_DOMAINS``, default 200-231 (Fast DDS takes
ids up to 232; the test suite keeps to 100-199).

The pytest plugin's fixtures claim theirs the same way, one for each test while it
runs: ``--sorter-domains A-B`` or ``SORTER_TEST_DOMAINS``, default 100-139 (this
project's own suite gives its workers 150-197 and a test of its own graph 141), so
that two xdist workers, or two test runs, on one host never share a graph, whatever
``ROS_DOMAIN_ID`` the shell exports.
"""

from __future__ import annotations

import fcntl
import os
import tempfile
import time
from pathlib import Path

DOMAINS_ENV = 'SORTER_CAMPAIGN_DOMAINS'
LOCKS_ENV = 'SORTER_DOMAIN_LOCKS'
DEFAULT_DOMAINS = '200-231'
TEST_DOMAINS_ENV = 'SORTER_TEST_DOMAINS'
DEFAULT_TEST_DOMAINS = '100-139'
MAX_DOMAIN = 232
POLL_S = 0.05


def parse_domains(text: str, what: str = '--domains') -> range:
    """
    Return the domains ``A-B`` (or ``A``) names.

    Parameters
    ----------
    text : str
        ``A-B`` with 0 <= A <= B <= 232, or one id.
    what : str
        Where it came from, for the message.

    Returns
    -------
    range
        The domains.

    Raises
    ------
    ValueError
        Anything else, in one line naming ``what`` and what it allows.

    """
    parts = str(text).strip().split('-')
    if len(parts) in (1, 2) and all(p.strip().isdigit() for p in parts):
        lo, hi = int(parts[0]), int(parts[-1])
        if 0 <= lo <= hi <= MAX_DOMAIN:
            return range(lo, hi + 1)
    raise ValueError(
        f'{what} must be a ROS domain range A-B with 0 <= A <= B <= {MAX_DOMAIN} '
        f'(e.g. 140-171), got {text!r}'
    )


def campaign_domains(option: str | None = None) -> range:
    """Return the range ``option`` names, else ``SORTER_CAMPAIGN_DOMAINS``, else 200-231."""
    return _domains(option, '--domains', DOMAINS_ENV, DEFAULT_DOMAINS)


def fixture_domains(option: str | None = None) -> range:
    """Return the range ``option`` names, else ``SORTER_TEST_DOMAINS``, else 100-139."""
    return _domains(option, '--sorter-domains', TEST_DOMAINS_ENV, DEFAULT_TEST_DOMAINS)


def _domains(option: str | None, flag: str, env_name: str, default: str) -> range:
    if option:
        return parse_domains(option, flag)
    env = os.environ.get(env_name, '').strip()
    if env:
        return parse_domains(env, env_name)
    return parse_domains(default)


def lock_dir() -> Path:
    """Return the folder of the domains' lock files (made if missing)."""
    folder = Path(os.environ.get(LOCKS_ENV) or Path(tempfile.gettempdir()) / 'sorter-domains')
    folder.mkdir(parents=True, exist_ok=True)
    return folder


class DomainClaim:
    """
    One domain of a range, held exclusively on this host until ``release`` (a context manager).

    Parameters
    ----------
    domains : range
        The domains to draw from, in order.
    timeout_s : float
        The longest wall time to wait for a free one.

    """

    def __init__(self, domains: range, timeout_s: float = 600.0):
        self.domains = domains
        self.timeout_s = timeout_s
        self.domain: int | None = None
        self._fd: int | None = None

    def acquire(self) -> int:
        """Return a domain no other claim on this host holds; wait while all are held."""
        folder = lock_dir()
        deadline = time.monotonic() + self.timeout_s
        while True:
            for d in self.domains:
                fd = os.open(folder / f'domain-{d}.lock', os.O_RDWR | os.O_CREAT, 0o666)
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except BlockingIOError:
                    os.close(fd)
                    continue
                os.ftruncate(fd, 0)
                os.write(fd, f'{os.getpid()}\n'.encode())
                self._fd, self.domain = fd, d
                return d
            if time.monotonic() > deadline:
                raise TimeoutError(
                    f'every ROS domain of {self.domains.start}-{self.domains.stop - 1} was '
                    f'held by other runs for {self.timeout_s:g} s'
                )
            time.sleep(POLL_S)

    def release(self) -> None:
        """Let the domain go."""
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> int:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()
