"""
The documentation's generated parts: regenerate them, or check them.

Four tables are data, declared once in code: the cell description
(``sorter_sim.model.description``, in docs/model.md), the simulation node's parameters
(``sorter_sim.runtime.params``, docs/simulation-node.md), the controller's
(``sorter_control.node``, docs/controller.md) and the fieldbus I/O map
(``sorter_sim.model.io_map``, docs/fieldbus.md). Each sits between a
``<!-- generated: NAME -->`` line and a ``<!-- end: NAME -->`` line; every page of
docs/ also opens with its contents list, generated from its headings the same way.
``python -m sorter_cell.docs`` rewrites them in place; the test suite fails when a
page differs from what this module renders.
"""

from __future__ import annotations

import functools
from pathlib import Path
import re
import sys

from sorter_sim.studies.markdown import with_contents

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / 'README.md'
DOCS = ROOT / 'docs'


def _value(v) -> str:
    if isinstance(v, (list, tuple)):
        return '[' + ', '.join(_value(x) for x in v) + ']'
    if isinstance(v, bool):
        return str(v).lower()
    if isinstance(v, float):
        return f'{v:g}'
    return str(v)


def sim_node_table() -> str:
    """Return the simulation node's parameter table."""
    from sorter_sim.runtime.params import SCHEMA

    rows = [
        '| name | type | default | allowed | units | set at run time | meaning |',
        '|---|---|---|---|---|---|---|',
    ]
    for s in SCHEMA:
        rows.append(
            f'| `{s.name}` | {s.type} | `{_value(s.default)}` | {s.allowed} | {s.units or "–"} | '
            f'{"no (read-only)" if s.read_only else "yes"} | {s.description} |'
        )
    return '\n'.join(rows)


def controller_table() -> str:
    """Return the controller's parameter table."""
    from sorter_control.parameters import SCHEMA

    rows = ['| name | type | default | range | run time | meaning |', '|---|---|---|---|---|---|']
    for s in SCHEMA:
        rng = s.entry_allowed.removeprefix('a finite number in ') if s.lo is not None else ''
        rows.append(
            f'| `{s.name}` | {s.type} | `{_value(s.default)}` | {rng} | '
            f'{"no" if s.read_only else "yes"} | {s.description} |'
        )
    return '\n'.join(rows)


def io_map_table() -> str:
    """Return the fieldbus I/O map of the default cell (config/cell.yaml's sensors)."""
    from sorter_sim.runtime.cell import CHUTE_SENSORS
    from sorter_sim.model.io_map import io_map
    from sorter_sim.runtime.params import CellParams

    p = CellParams.defaults()
    signals = io_map(list(p.photo_eyes_names) + list(CHUTE_SENSORS))
    rows = [
        '| signal | direction | Modbus | S7 | type | unit | scaling | accepts | meaning |',
        '|---|---|---|---|---|---|---|---|---|',
    ]
    short = {
        'discrete_input': 'DI',
        'coil': 'coil',
        'input_register': 'IR',
        'holding_register': 'HR',
    }
    for s in signals:
        where = f'{short[s.table]} {s.address}'
        if s.words > 1:
            where += f'-{s.address + s.words - 1}'
        scaling = f'{s.scale:g} {s.unit or ""}/count'.replace(' /', '/') if s.scale != 1 else ''
        accepts = f'[{s.lo:g}, {s.hi:g}]' if s.lo is not None else ''
        rows.append(
            f'| `{s.name}` | {s.direction} | {where} | {s.s7_address} {s.s7[3]} | {s.type} | '
            f'{s.unit or "–"} | {scaling} | '
            f'{accepts} | {s.meaning} |'
        )
    return '\n'.join(rows)


@functools.cache
def tables() -> dict[str, str]:
    """Return every generated table by name."""
    from sorter_sim.model.description import markdown_table

    return {
        'cell-description': markdown_table(),
        'sim-node-parameters': sim_node_table(),
        'controller-parameters': controller_table(),
        'io-map': io_map_table(),
    }


def pages() -> list[Path]:
    """Return the README and every page of docs/, in order."""
    return [README, *sorted(DOCS.glob('*.md'))]


def render(text: str) -> str:
    """
    Return a page with its generated tables and contents list rendered anew.

    Parameters
    ----------
    text : str
        A page of the documentation; the tables it has markers for are rendered, and its
        contents list if it has one.

    Returns
    -------
    str
        The page as it should be.

    """
    for name, table in tables().items():
        tag = re.escape(name)
        pattern = re.compile(
            rf'(<!-- generated: {tag} -->\n)(?:.*?\n)?(<!-- end: {tag} -->)', re.S
        )
        text = pattern.sub(lambda m: m.group(1) + table + '\n' + m.group(2), text)
    return with_contents(text)


def placement() -> dict[str, list[str]]:
    """Return, for each generated table, the pages that hold it (each must hold one)."""
    found: dict[str, list[str]] = {name: [] for name in tables()}
    for page in pages():
        text = page.read_text()
        for name in found:
            if f'<!-- generated: {name} -->' in text:
                found[name].append(page.name)
    return found


def main() -> int:
    """Rewrite the generated parts of README.md and docs/*.md."""
    for name, where in placement().items():
        if len(where) != 1:
            print(f'the table {name!r} must be on exactly one page, found on {where}')
            return 1
    for page in pages():
        text = page.read_text()
        new = render(text)
        if new != text:
            page.write_text(new)
            print(f'updated {page}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
