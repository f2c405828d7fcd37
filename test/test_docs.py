"""
Check the documentation as a newcomer meets it.

A short README, pages that open with their contents, and links that lead somewhere.
"""

import re
from pathlib import Path

import pytest

from sorter_cell import docs
from sorter_sim.studies.markdown import CONTENTS_END, CONTENTS_START, anchor, headings

ROOT = Path(__file__).resolve().parents[1]
LINK = re.compile(r'(?<!!)\[[^\]]*\]\(([^)\s]+)\)|!\[[^\]]*\]\(([^)\s]+)\)')
PAGES = docs.pages()


def _links(text):
    fenced = False
    for line in text.splitlines():
        if line.startswith('```'):
            fenced = not fenced
            continue
        if fenced:
            continue
        for m in LINK.finditer(line):
            yield m.group(1) or m.group(2)


def test_the_readme_is_a_door():
    lines = (ROOT / 'README.md').read_text().splitlines()
    assert len(lines) <= 300, len(lines)
    linked = {t for t in _links('\n'.join(lines)) if t.startswith('docs/')}
    # every page of docs/ is reachable from the README
    for page in sorted((ROOT / 'docs').glob('*.md')):
        assert f'docs/{page.name}' in linked, page.name


@pytest.mark.parametrize(
    'page', [p for p in PAGES if p.parent.name == 'docs'], ids=lambda p: p.name
)
def test_every_page_opens_with_its_contents(page):
    text = page.read_text()
    lines = text.splitlines()
    assert lines[0].startswith('# '), lines[0]
    start = lines.index(CONTENTS_START)
    assert not any(ln.startswith('## ') for ln in lines[:start]), 'contents after a section'
    listed = lines[start + 1 : lines.index(CONTENTS_END)]
    sections = [h for h in headings(text) if h[0] in (2, 3)]
    assert len(listed) == len(sections) >= 1


@pytest.mark.parametrize('page', PAGES, ids=lambda p: p.name)
def test_every_relative_link_resolves(page):
    text = page.read_text()
    for target in _links(text):
        if re.match(r'^[a-z][a-z0-9+.-]*:', target):  # http:, https:, ws:, mailto:
            continue
        path, _, fragment = target.partition('#')
        dest = (page.parent / path).resolve() if path else page
        assert dest.exists(), f'{page.name}: {target} leads nowhere'
        if fragment and dest.suffix == '.md':
            anchors = {h[2] for h in headings(dest.read_text())}
            assert fragment in anchors, f'{page.name}: #{fragment} is no heading of {dest.name}'


def test_the_link_check_can_fail(tmp_path):
    page = tmp_path / 'page.md'
    page.write_text('# T\n\n## A section\n\n[x](#a-section) [y](#no-such) [z](missing.md)\n')
    targets = list(_links(page.read_text()))
    assert targets == ['#a-section', '#no-such', 'missing.md']
    anchors = {h[2] for h in headings(page.read_text())}
    assert 'a-section' in anchors and 'no-such' not in anchors
    assert not (tmp_path / 'missing.md').exists()


def test_anchors_follow_the_viewers_rule():
    assert anchor('The model and `sorter run`') == 'the-model-and-sorter-run'
    assert anchor('Fig. 9: capacity W_t') == 'fig-9-capacity-w_t'
    assert anchor('Fieldbus: a real PLC drives the cell') == 'fieldbus-a-real-plc-drives-the-cell'
    text = '# P\n\n## Benchmark\n\n## Benchmark\n'
    assert [h[2] for h in headings(text)] == ['p', 'benchmark', 'benchmark-1']
