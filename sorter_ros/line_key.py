"""
The line key: an HMAC-SHA-256 seal on every message a line's segments exchange, without ROS.

The Fast DDS the ROS wheels ship has no security plugins, so nothing below the line
tells a segment's message from a forger's in its name. A line started with a key
(``SORTER_LINE_KEY``: the path of a file holding it, made by ``sorter line-key``) seals
every message it sends and refuses every one without a good seal. The seal rides
inside the message's payload, so the messages stay the standard types they are: a
last field ``seal`` (a ``KeyValue`` of the ``DiagnosticStatus``) with the value
``<sender> <counter> <tag>``:

- ``sender``: 16 hexadecimal digits drawn at random when the sealer is made (one per
  line node: a restarted segment is a new sender);
- ``counter``: a decimal integer the sender raises with every message (its wall clock
  in ns, at least one more than the last), so that a receiver refuses a message whose
  counter is not above the last one it took from that sender on that topic: a replay;
- ``tag``: 64 hexadecimal digits, HMAC-SHA-256 under the key of the topic, the
  message's name, level, message and hardware id, its fields before the seal, the
  sender and the counter (``_signed_bytes``); compared in constant time
  (``hmac.compare_digest``).

A receiver first hearing a sender takes a counter no older than ``FRESH_S``: a
message recorded from a sender that has gone is not taken by a segment started later.

The key protects the line's messages from anyone who can reach its DDS domain but
does not hold the key: no forged, altered, re-routed (another topic) or replayed
message is taken. It does not protect against a process that holds the key (it is
the line's), does not hide the messages (they are signed, not encrypted: anyone on
the domain reads them, their timing and sizes), and does not stop a flood: each
forged message still costs its receiver a check and a counted refusal.
"""

from __future__ import annotations

import hashlib
import hmac
import json
import os
import secrets
import stat
import threading
import time
from collections import OrderedDict

KEY_ENV = 'SORTER_LINE_KEY'  # names the key's file, never the key
KEY_BYTES = 32
SEAL_FIELD = 'seal'
FRESH_S = 120.0  # s: the oldest counter taken from a sender heard for the first time
MAX_SENDERS = 4096  # (topic, sender) counters kept; the oldest heard is forgotten past it


class LineKeyError(ValueError):
    """A line key that cannot be used: the message names the file and what is wrong."""


class SealError(ValueError):
    """A message refused for its seal: none, a bad one, or a replay (the message says)."""


def new_key_file(path: str) -> None:
    """
    Write a new random line key to ``path`` (mode 0600); LineKeyError if it cannot.

    Never overwrites: a file there already is refused (another line's key, or a file
    that is no key at all).
    """
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o600)
    except FileExistsError:
        raise LineKeyError(f'{path}: exists already; a new key goes to a new file') from None
    except OSError as exc:
        raise LineKeyError(f'{path}: cannot create ({exc.strerror or exc})') from None
    with os.fdopen(fd, 'w', encoding='ascii') as f:
        f.write(secrets.token_hex(KEY_BYTES) + '\n')


def read_key_file(path: str) -> bytes:
    """
    Return the key a line key file holds; LineKeyError naming what is wrong.

    The file holds 64 hexadecimal digits (``sorter line-key``'s); it must be a regular
    file readable by its owner only (mode 0600 or 0400): a key others can read is no
    key.
    """
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW)
    except OSError as exc:
        raise LineKeyError(f'line key {path}: cannot open ({exc.strerror or exc})') from None
    with os.fdopen(fd, 'rb') as f:
        st = os.fstat(f.fileno())
        if not stat.S_ISREG(st.st_mode):
            raise LineKeyError(f'line key {path}: not a regular file')
        if st.st_mode & 0o077:
            raise LineKeyError(
                f'line key {path}: readable by others (mode {stat.S_IMODE(st.st_mode):04o}); '
                'chmod 600 it'
            )
        text = f.read(4 * KEY_BYTES + 1).strip()
    try:
        key = bytes.fromhex(text.decode('ascii'))
    except (UnicodeDecodeError, ValueError):
        key = b''
    if len(key) != KEY_BYTES:
        raise LineKeyError(
            f'line key {path}: must hold {2 * KEY_BYTES} hexadecimal digits (sorter line-key '
            'writes one)'
        )
    return key


def key_from_env(environ=None) -> bytes | None:
    """Return the key of the file ``SORTER_LINE_KEY`` names, None when unset; LineKeyError."""
    path = (os.environ if environ is None else environ).get(KEY_ENV, '')
    return read_key_file(path) if path else None


def _signed_bytes(topic: str, head: tuple, pairs: list, sender: str, counter: int) -> bytes:
    # JSON of strings only: no two different messages give the same bytes
    return json.dumps([topic, *head, pairs, sender, counter], ensure_ascii=True).encode()


class Sealer:
    """Seals the messages one line node sends (see the module)."""

    def __init__(self, key: bytes):
        self._key = key
        self.sender = secrets.token_hex(8)
        self._counter = 0
        self._lock = threading.Lock()

    def seal(self, topic: str, head: tuple, pairs: list) -> str:
        """
        Return the ``seal`` value of a message.

        Parameters
        ----------
        topic : str
            The topic's full name (``/line/owners``).
        head : tuple of str
            The message's name, level, message and hardware id, as strings.
        pairs : list of (str, str)
            Its fields, without the seal.

        """
        with self._lock:
            self._counter = max(self._counter + 1, time.time_ns())
            counter = self._counter
        data = _signed_bytes(topic, head, pairs, self.sender, counter)
        tag = hmac.new(self._key, data, hashlib.sha256).hexdigest()
        return f'{self.sender} {counter} {tag}'


class SealCheck:
    """
    Checks the seals of the messages a line node takes (see the module).

    ``check`` returns the fields without the seal, or raises ``SealError`` naming why
    the message is refused. ``counts`` says how many were refused for want of a seal,
    a bad one, or a replay.
    """

    def __init__(self, key: bytes):
        self._key = key
        self._last: OrderedDict[tuple[str, str], int] = OrderedDict()
        self._lock = threading.Lock()
        self.counts = {'unsealed': 0, 'bad_seal': 0, 'replayed': 0}

    def check(self, topic: str, head: tuple, pairs: list) -> list:
        """Return ``pairs`` without the seal when it is good; SealError otherwise."""
        if not pairs or pairs[-1][0] != SEAL_FIELD:
            self.counts['unsealed'] += 1
            raise SealError('not sealed with the line key (this line is keyed)')
        parts = pairs[-1][1].split(' ')
        body = pairs[:-1]
        ok = (
            len(parts) == 3
            and len(parts[0]) == 16
            and parts[1].isascii()
            and parts[1].isdigit()
            and len(parts[1]) <= 20
            and len(parts[2]) == 64
        )
        if ok:
            sender, counter = parts[0], int(parts[1])
            data = _signed_bytes(topic, head, body, sender, counter)
            good = hmac.new(self._key, data, hashlib.sha256).hexdigest()
            ok = hmac.compare_digest(good.encode(), parts[2].encode('ascii', 'replace'))
        if not ok:
            self.counts['bad_seal'] += 1
            raise SealError('its seal is not the line key\'s')
        with self._lock:
            last = self._last.get((topic, sender))
            if last is None and counter < time.time_ns() - FRESH_S * 1e9:
                self.counts['replayed'] += 1
                raise SealError(
                    f'a replay: sender {sender} first heard with a counter over {FRESH_S:g} s old'
                )
            if last is not None and counter <= last:
                self.counts['replayed'] += 1
                raise SealError(
                    f'a replay: counter {counter} of sender {sender}, which was at {last} already'
                )
            self._last[(topic, sender)] = counter
            self._last.move_to_end((topic, sender))
            if len(self._last) > MAX_SENDERS:
                self._last.popitem(last=False)
        return body


__all__ = [
    'KEY_ENV',
    'LineKeyError',
    'SEAL_FIELD',
    'SealError',
    'SealCheck',
    'Sealer',
    'key_from_env',
    'new_key_file',
    'read_key_file',
]
