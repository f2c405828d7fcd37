"""
The line key on ROS messages: seal what a line node sends, check what it takes (``line_key``).

Every line message is a ``diagnostic_msgs/DiagnosticStatus``; its seal is its last
field, ``seal`` (``line_key`` says what it holds and what it protects). A
``LineSeal`` without a key seals nothing and checks nothing: the line is open, as it
was before keys, and only the checks of what a message says protect it
(``sorter_sim.runtime.handover``, ``sorter_sim.frontends.segments``).
"""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

from sorter_ros.line_key import KEY_ENV, SEAL_FIELD, SealCheck, Sealer, key_from_env


def _head(msg: DiagnosticStatus) -> tuple:
    level = msg.level
    level = int.from_bytes(level, 'little') if isinstance(level, bytes) else int(level)
    return (msg.name, str(level), msg.message, msg.hardware_id)


class LineSeal:
    """
    One line node's sealer and checker.

    Parameters
    ----------
    key : bytes or None
        The line key; None: ``SORTER_LINE_KEY``'s file, or an open line when it is unset.

    Raises
    ------
    LineKeyError
        The key file cannot be used (a ValueError naming it and what is wrong).

    """

    def __init__(self, key: bytes | None = None):
        key = key_from_env() if key is None else key
        self.keyed = key is not None
        self._sealer = Sealer(key) if self.keyed else None
        self._check = SealCheck(key) if self.keyed else None

    @property
    def counts(self) -> dict:
        """Return the messages refused for their seal: unsealed, bad_seal, replayed."""
        return dict(self._check.counts) if self.keyed else {}

    def describe(self) -> str:
        """Return what a node says at its start about the line's messages."""
        if self.keyed:
            return 'a line key: every line message sealed, and checked on arrival'
        return (
            f'the line is open: no line key ({KEY_ENV} unset), its messages are taken on '
            'what they say (sorter line-key FILE makes one; docs/simulation-node.md)'
        )

    def sealed(self, topic: str, msg: DiagnosticStatus) -> DiagnosticStatus:
        """Return ``msg`` with its seal for ``topic`` (the topic's full name), when keyed."""
        if self.keyed:
            pairs = [(kv.key, kv.value) for kv in msg.values]
            msg.values.append(
                KeyValue(key=SEAL_FIELD, value=self._sealer.seal(topic, _head(msg), pairs))
            )
        return msg

    def opened(self, topic: str, msg: DiagnosticStatus) -> DiagnosticStatus:
        """
        Return ``msg`` without its seal once the seal is checked; SealError naming why not.

        On an open line a seal is dropped unchecked (a keyed sender, an open reader).
        """
        pairs = [(kv.key, kv.value) for kv in msg.values]
        if self.keyed:
            self._check.check(topic, _head(msg), pairs)
        if pairs and pairs[-1][0] == SEAL_FIELD:
            msg.values = list(msg.values)[:-1]
        return msg


__all__ = ['LineSeal']
