"""
Markdown the generated reports and the documentation share: anchors and contents lists.

A page's contents list sits between ``<!-- generated: contents -->`` and
``<!-- end: contents -->`` and lists its ``##`` and ``###`` headings, linked by the
anchors GitHub and most Markdown viewers give them.
"""

from __future__ import annotations

import re

CONTENTS_START = '<!-- generated: contents -->'
CONTENTS_END = '<!-- end: contents -->'
_FENCE = re.compile(r'^(```|~~~)')


def headings(text: str) -> list[tuple[int, str, str]]:
    """
    Return the headings of a Markdown page outside code fences.

    Parameters
    ----------
    text : str
        The page.

    Returns
    -------
    list of (int, str, str)
        Each heading's level (1 for ``#``), its text, and its anchor (unique in the page,
        as ``-1``, ``-2`` ... suffixes make repeated ones).

    """
    out = []
    seen: dict[str, int] = {}
    fenced = False
    for line in text.splitlines():
        if _FENCE.match(line):
            fenced = not fenced
            continue
        m = None if fenced else re.match(r'^(#{1,6}) +(.*?) *#*$', line)
        if not m:
            continue
        title = m.group(2)
        base = anchor(title)
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.append((len(m.group(1)), title, base if n == 0 else f'{base}-{n}'))
    return out


def anchor(title: str) -> str:
    """
    Return the anchor of a heading: lower case, punctuation dropped, spaces as hyphens.

    Parameters
    ----------
    title : str
        The heading's text, Markdown included (links keep their text, code its content).

    Returns
    -------
    str
        The fragment a link to the heading uses (without ``#``).

    """
    text = re.sub(r'\[([^\]]*)\]\([^)]*\)', r'\1', title)  # a link: its text
    text = text.replace('`', '').strip().lower()
    text = ''.join(c for c in text if c.isalnum() or c in ' -_')
    return text.replace(' ', '-')


def contents(text: str) -> str:
    """
    Return the contents list of a page: its level-2 and level-3 headings, linked.

    Parameters
    ----------
    text : str
        The page.

    Returns
    -------
    str
        A Markdown list, one line per heading, level-3 ones indented under their section.

    """
    lines = []
    for level, title, ref in headings(text):
        if level in (2, 3):
            lines.append(f'{"  " * (level - 2)}- [{title}](#{ref})')
    return '\n'.join(lines)


def with_contents(text: str) -> str:
    """
    Return ``text`` with its contents list, between the contents markers, made anew.

    Parameters
    ----------
    text : str
        The page; one without the markers is returned unchanged.

    Returns
    -------
    str
        The page with the list rendered from its headings.

    """
    pattern = re.compile(
        rf'({re.escape(CONTENTS_START)}\n)(?:.*?\n)?({re.escape(CONTENTS_END)})', re.S
    )
    return pattern.sub(lambda m: m.group(1) + contents(text) + '\n' + m.group(2), text, count=1)


def replace_block(text: str, block: str, markers: tuple) -> str:
    """
    Return ``text`` with the part between the two marker lines replaced by ``block``.

    Parameters
    ----------
    text : str
        The page.
    block : str
        The new part.
    markers : tuple of str
        The opening and closing marker lines.

    Returns
    -------
    str
        The page.

    Raises
    ------
    ValueError
        When the page lacks the markers.

    """
    start, end = markers
    if start not in text or end not in text:
        raise ValueError(f"the page has no {start} ... {end} block to write into")
    head, rest = text.split(start, 1)
    _, tail = rest.split(end, 1)
    return f"{head}{start}\n{block}{end}{tail}"
