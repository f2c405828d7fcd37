"""
Reading YAML strictly: every file and value a user gives the project goes through here.

PyYAML's safe loader builds no objects, but it still keeps the last of two equal
keys without a word, expands aliases without limit (a few lines of "billion
laughs" fill the memory), recurses once per nesting level (a few thousand ``[``
end in RecursionError) and reads whatever a path holds (``/dev/zero`` never
ends). Here a key given twice, an alias, nesting deeper than ``MAX_DEPTH`` and a
text longer than ``MAX_BYTES`` are refused with one line naming the file, the
line and the rule. Nothing the project reads needs aliases or deep nesting.

Plain Python and PyYAML: no ROS, so the model's scene files use it too.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

MAX_BYTES = 1 << 20  # the project's files are a few kB; refuse anything near a megabyte
MAX_DEPTH = 32  # nesting levels of mappings and lists


class StrictYamlError(ValueError):
    """A YAML text the project refuses, with a one-line reason."""


class _StrictLoader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate keys, aliases and deep nesting."""

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise StrictYamlError(
                f'line {event.start_mark.line + 1}: aliases (*{event.anchor}) are not allowed'
            )
        self._depth += 1
        try:
            if self._depth > MAX_DEPTH:
                mark = self.peek_event().start_mark
                raise StrictYamlError(
                    f'line {mark.line + 1}: nested more than {MAX_DEPTH} levels deep'
                )
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_mapping(self, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=deep)
            try:
                twice = key in seen
            except TypeError:  # an unhashable key: the constructor says so below
                continue
            if twice:
                raise StrictYamlError(
                    f'line {key_node.start_mark.line + 1}: key {_show(key)} appears twice'
                )
            seen.add(key)
        return super().construct_mapping(node, deep)


_StrictLoader.add_constructor(
    yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG,
    lambda loader, node: loader.construct_mapping(node),
)


def _show(value: Any, limit: int = 60) -> str:
    """Quote a value for a message, cut short: no message echoes a large input whole."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + '...'


def load_yaml_text(text: str, what: str) -> Any:
    """
    Parse ``text`` (from ``what``, for messages) strictly; raise StrictYamlError.

    Parameters
    ----------
    text : str
        The YAML.
    what : str
        What it is, for messages.

    Returns
    -------
    object
        The parsed document.

    Raises
    ------
    StrictYamlError
        A duplicate key, an alias, a tag or a syntax error, in one line.

    """
    if len(text) > MAX_BYTES:
        raise StrictYamlError(f'{what}: longer than {MAX_BYTES} characters')
    try:
        return yaml.load(text, Loader=_StrictLoader)  # noqa: S506 (a SafeLoader, stricter)
    except StrictYamlError as exc:
        raise StrictYamlError(f'{what}: {exc}') from None
    except RecursionError:
        raise StrictYamlError(f'{what}: nested too deeply') from None
    except yaml.YAMLError as exc:
        # PyYAML's message spans lines; keep the problem and its position on one line
        mark = getattr(exc, 'problem_mark', None)
        where = f' at line {mark.line + 1}, column {mark.column + 1}' if mark else ''
        problem = getattr(exc, 'problem', None) or str(exc).splitlines()[0]
        raise StrictYamlError(f'{what}: not valid YAML{where}: {problem[:200]}') from None


def read_yaml_file(path: str | Path, what: str = 'file') -> Any:
    """
    Read and parse a YAML file strictly (size first, then the text).

    Parameters
    ----------
    path : str or Path
        The file.
    what : str
        What it is, for messages.

    Returns
    -------
    object
        The parsed document.

    Raises
    ------
    StrictYamlError
        The file missing, too large, unreadable, or not strict YAML.

    """
    p = Path(path)
    label = f'{what} {str(p)!r}'
    try:
        with p.open('rb') as f:
            raw = f.read(MAX_BYTES + 1)
    except OSError as exc:
        raise StrictYamlError(f'cannot read {label}: {exc.strerror or exc}') from None
    if len(raw) > MAX_BYTES:
        raise StrictYamlError(f'{label}: more than {MAX_BYTES} bytes')
    try:
        text = raw.decode('utf-8')
    except UnicodeDecodeError as exc:
        raise StrictYamlError(f'{label}: not UTF-8 text (byte {exc.start})') from None
    return load_yaml_text(text, label)
