"""
The routing table: where each label goes.

Grammar (the same for the ``routing.rules`` parameter and for updates on
``routing/updates``):

- a *rule* is ``pattern=destination``;
- a *pattern* is a label (1 to 64 characters among letters, digits and
  ``- _ . : / #``), a prefix (such a label followed by ``*``) or ``*`` alone,
  the default;
- a *destination* is ``left``, ``right`` or ``straight``; in an update, an empty
  destination removes the rule (which must exist).

A pattern may appear once in a table. Lookup: the exact label wins, then the
longest matching prefix, then the default; labels that match nothing (with no
default) and missing reads go to the reject destination.
"""

from __future__ import annotations

from sorter_sim.model.description import LABEL_CHARS, LABEL_MAX
from sorter_sim.model.description import LABEL_RE as _LABEL

from sorter_control.timing import DESTINATIONS

GRAMMAR = (
    "a rule is 'pattern=destination'; a pattern is a label of 1 to "
    f"{LABEL_MAX} {LABEL_CHARS}, such a label followed by '*' (a prefix) or '*' alone "
    f"(the default); a destination is one of {', '.join(DESTINATIONS)}"
)


class RoutingError(ValueError):
    """A routing rule or destination that is not allowed."""


def _show(value) -> str:
    """Quote a value for an error message, cut short: a message never echoes a long input."""
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def check_pattern(pattern) -> str:
    """
    Return the pattern stripped, or raise RoutingError naming the grammar.

    Parameters
    ----------
    pattern : str
        A label pattern of the routing grammar.

    Returns
    -------
    str
        The pattern, stripped.

    """
    if not isinstance(pattern, str):
        raise RoutingError(f"routing pattern must be a string; got {_show(pattern)}")
    pattern = pattern.strip()
    if pattern == "*":
        return pattern
    body = pattern[:-1] if pattern.endswith("*") else pattern
    if not _LABEL.fullmatch(body):
        raise RoutingError(f"routing pattern {_show(pattern)} is not allowed: {GRAMMAR}")
    return pattern


def check_destination(dest, what: str, allow_empty: bool = False) -> str:
    """
    Return the destination stripped, or raise RoutingError naming what is allowed.

    Parameters
    ----------
    dest : str
        A destination.
    what : str
        What it is, for the message.
    allow_empty : bool
        An empty destination is allowed (it removes a rule).

    Returns
    -------
    str
        The destination, stripped.

    """
    if not isinstance(dest, str):
        raise RoutingError(
            f"{what} must be a string, one of {', '.join(DESTINATIONS)}; got {_show(dest)}"
        )
    dest = dest.strip()
    if dest == "" and allow_empty:
        return ""
    if dest not in DESTINATIONS:
        allowed = ", ".join(DESTINATIONS) + (" or empty" if allow_empty else "")
        raise RoutingError(f"{what} must be one of {allowed}; got {_show(dest)}")
    return dest


class RoutingTable:
    """
    Destination per label: exact labels, prefixes (``ABC*``, longest wins), a default.

    ``rules`` are ``pattern=destination`` strings (see the module's grammar);
    ``default`` is the destination of labels no rule matches (empty: the reject
    destination), and may also be given as the rule ``*=destination``, not both.
    """

    def __init__(self, rules=(), default: str = "", reject: str = "straight"):
        self.exact: dict[str, str] = {}
        self.prefixes: dict[str, str] = {}
        self.default = check_destination(default, "routing default", allow_empty=True) or None
        self.reject = check_destination(reject, "reject destination")
        if isinstance(rules, str):
            raise RoutingError(f"routing rules must be a list of strings; got {_show(rules)}")
        seen: set[str] = set()
        for rule in rules:
            pattern, dest = self.parse_rule(rule)
            if pattern in seen or (pattern == "*" and self.default is not None):
                raise RoutingError(
                    f"routing rule {_show(rule)}: pattern {pattern!r} is given twice; "
                    "each pattern may appear once"
                )
            seen.add(pattern)
            self.set(pattern, dest)

    @staticmethod
    def parse_rule(rule) -> tuple[str, str]:
        """
        Split 'pattern=destination' and check both halves.

        Parameters
        ----------
        rule : str
            ``pattern=destination``.

        Returns
        -------
        (str, str)
            The pattern and the destination.

        """
        if not isinstance(rule, str) or "=" not in rule:
            raise RoutingError(
                f"routing rule {_show(rule)}: expected 'label=destination' or "
                f"'prefix*=destination' ({GRAMMAR})"
            )
        pattern, _, dest = rule.partition("=")
        pattern = check_pattern(pattern)
        # a rule routes somewhere: an empty destination only removes one (routing/updates)
        if isinstance(dest, str) and not dest.strip():
            raise RoutingError(f"routing rule {_show(rule)}: the destination is empty")
        return pattern, check_destination(dest, f"destination for {pattern!r}")

    def set(self, pattern: str, destination: str) -> str:
        """
        Add, change or (destination '') remove a rule; returns what was done.

        Parameters
        ----------
        pattern : str
            A label pattern of the routing grammar.
        destination : str
            A destination (left, right, straight, or a chute name).

        Returns
        -------
        str
            What was done.

        """
        pattern = check_pattern(pattern)
        dest = check_destination(destination, f"destination for {pattern!r}", allow_empty=True)
        if pattern == "*":
            if dest == "" and self.default is None:
                raise RoutingError("no default to remove: the table has none")
            self.default = dest or None
            return f"default -> {dest or '(none: reject)'}"
        table, key = (
            (self.prefixes, pattern[:-1]) if pattern.endswith("*") else (self.exact, pattern)
        )
        if dest == "":
            if key not in table:
                raise RoutingError(f"no rule for {pattern!r} to remove")
            del table[key]
            return f"{pattern} removed"
        table[key] = dest
        return f"{pattern} -> {dest}"

    def lookup(self, label: str | None) -> tuple[str, str]:
        """
        (destination, how) with how in exact | prefix | default | unknown | no_read.

        Parameters
        ----------
        label : str
            A parcel label (empty: no read).

        Returns
        -------
        (str, str)
            The destination, and how it was found (exact, prefix, default, unknown, no_read).

        """
        if label is None or label == "":
            return self.reject, "no_read"
        if label in self.exact:
            return self.exact[label], "exact"
        best = None
        for prefix, dest in self.prefixes.items():
            if label.startswith(prefix) and (best is None or len(prefix) > len(best[0])):
                best = (prefix, dest)
        if best is not None:
            return best[1], "prefix"
        if self.default is not None:
            return self.default, "default"
        return self.reject, "unknown"

    def rules(self, with_default: bool = True) -> list[str]:
        """
        Return the table as rules, the default last as ``*=destination``.

        ``with_default=False`` leaves the default out: the form of the
        ``routing.rules`` parameter, which holds the default on its own.

        Parameters
        ----------
        with_default : bool
            Include the default as ``*=destination``.

        Returns
        -------
        list of str
            The rules.

        """
        out = [f"{k}={v}" for k, v in sorted(self.exact.items())]
        out += [f"{k}*={v}" for k, v in sorted(self.prefixes.items())]
        if self.default and with_default:
            out.append(f"*={self.default}")
        return out
