"""
The README's tables that are generated from declarations: regenerate or check them.

Three tables are data, declared once in code: the cell description
(``sorter_sim.model.description``), the simulation node's parameters
(``sorter_sim.runtime.params``) and the controller's (``sorter_control.node``). In
README.md each sits between a ``<!-- generated: NAME -->`` line and a ``<!-- end: NAME -->`` line.
``python -m sorter_cell.readme`` rewrites them in place; the test suite fails
when README.md differs from what this module renders.
"""

from __future__ import annotations

from pathlib import Path
import re
import sys

README = Path(__file__).resolve().parents[1] / 'README.md'


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
    from sorter_control.node import SCHEMA

    rows = ['| name | type | default | range | run time | meaning |', '|---|---|---|---|---|---|']
    for s in SCHEMA:
        rng = s.allowed.removeprefix('a finite number in ') if s.lo is not None else ''
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
        '| signal | direction | Modbus | type | unit | scaling | accepts | meaning |',
        '|---|---|---|---|---|---|---|---|',
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
            f'| `{s.name}` | {s.direction} | {where} | {s.type} | {s.unit or "–"} | {scaling} | '
            f'{accepts} | {s.meaning} |'
        )
    return '\n'.join(rows)


def tables() -> dict[str, str]:
    """Return every generated table by name."""
    from sorter_sim.model.description import markdown_table

    return {
        'cell-description': markdown_table(),
        'sim-node-parameters': sim_node_table(),
        'controller-parameters': controller_table(),
        'io-map': io_map_table(),
    }


def render(text: str) -> str:
    """Return ``text`` with every generated table replaced by its current rendering."""
    for name, table in tables().items():
        tag = re.escape(name)
        pattern = re.compile(
            rf'(<!-- generated: {tag} -->\n)(?:.*?\n)?(<!-- end: {tag} -->)', re.S
        )
        if not pattern.search(text):
            raise ValueError(f'README.md has no generated section {name!r}')
        text = pattern.sub(lambda m: m.group(1) + table + '\n' + m.group(2), text)
    return text


def main() -> int:
    """Rewrite README.md's generated tables."""
    text = README.read_text()
    new = render(text)
    if new != text:
        README.write_text(new)
        print(f'updated {README}')
    else:
        print(f'{README} is up to date')
    return 0


if __name__ == '__main__':
    sys.exit(main())
