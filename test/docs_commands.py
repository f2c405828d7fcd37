"""
The shell commands the documentation gives, collected from README.md and docs/*.md.

Every line of a fenced ``bash`` (``sh``, ``shell``) block is a command a reader may
paste; the blocks without a language are output and are left alone. What the suite
cannot run is marked where it stands, in words a reader understands too:

- ``<!-- not run by the suite: REASON -->`` on the line before a block: the whole block;
- a command's trailing comment saying ``not run by the suite: REASON``: that line.

``export`` lines set the reader's environment and are not commands of their own (the
suite gives every command its own ROS domain). A trailing ``&`` (a node left in the
background while the next line runs) is dropped: each command runs on its own.
"""

from __future__ import annotations

import re
import shlex
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SKIP_BLOCK = re.compile(r'<!--\s*not run by the suite:\s*(.+?)\s*-->\s*$')
SKIP_LINE = re.compile(r'#.*?\bnot run by the suite:\s*(.+)$')
FENCE = re.compile(r'^```(\w*)\s*$')
SHELL = {'bash', 'sh', 'shell'}


@dataclass(frozen=True)
class DocCommand:
    """One command of the documentation and where it stands."""

    doc: str  # the file, relative to the repository
    line: int  # its line number there
    text: str  # the command, without its trailing comment
    skip: str  # why the suite does not run it ('' when it does)

    @property
    def argv(self) -> list[str]:
        """Return the command split as the shell would (no shell features are used)."""
        return shlex.split(self.text)


def _strip_comment(line: str) -> str:
    """Return ``line`` without a trailing ``# ...`` outside quotes."""
    lexer = shlex.shlex(line, posix=True, punctuation_chars=False)
    lexer.whitespace_split = True
    lexer.commenters = '#'
    try:
        words = list(lexer)
    except ValueError:  # an unbalanced quote: leave the line to fail loudly
        return line.strip()
    return ' '.join(shlex.quote(w) if w != '&' else w for w in words)


def doc_files() -> list[Path]:
    """README.md and every page of docs/."""
    return [REPO / 'README.md', *sorted((REPO / 'docs').glob('*.md'))]


def collect(files: list[Path] | None = None) -> list[DocCommand]:
    """Return every command of the shell blocks of ``files`` (default: ``doc_files()``)."""
    found: list[DocCommand] = []
    for path in files or doc_files():
        lines = path.read_text().splitlines()
        rel = str(path.relative_to(REPO))
        block = None  # the language of the open block, or None outside one
        block_skip = ''
        for i, raw in enumerate(lines):
            fence = FENCE.match(raw.strip())
            if fence and block is None:
                block = fence.group(1)
                prev = lines[i - 1] if i else ''
                m = SKIP_BLOCK.search(prev)
                block_skip = m.group(1) if m else ''
                continue
            if raw.strip() == '```' and block is not None:
                block = None
                continue
            if block not in SHELL:
                continue
            text = raw.strip()
            if not text or text.startswith('#') or text.startswith('export '):
                continue
            m = SKIP_LINE.search(text)
            command = _strip_comment(text)
            if command.endswith(' &'):
                command = command[:-2].rstrip()
            found.append(DocCommand(rel, i + 1, command, block_skip or (m.group(1) if m else '')))
    return found
