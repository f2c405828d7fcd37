"""
One declared parameter of a node: name, type, default, allowed range and meaning.

Both nodes declare their parameters as a tuple of ``ParamSpec``; each turns an entry
into a ``ParameterDescriptor`` and checks values against it, and the documentation's
parameter tables are generated from the same tuples. A parameter that is one of the
cell's quantities takes its unit, range and meaning from the cell description
(``quantity_spec``), so the scene keys, the simulation node and the controller accept
the same values and refuse the same ones. Nothing here imports ROS.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

DOUBLE = 'double'
INTEGER = 'integer'
STRING = 'string'
BOOL = 'bool'
DOUBLE_ARRAY = 'double_array'
STRING_ARRAY = 'string_array'


@dataclass(frozen=True)
class ParamSpec:
    """One declared parameter: name, type, default, allowed range and meaning."""

    name: str
    type: str
    default: Any
    description: str
    units: str = ''
    lo: float | None = None  # inclusive bounds for numbers and array entries
    hi: float | None = None
    choices: tuple = ()
    read_only: bool = True
    length: tuple[int, int] | None = None  # allowed array length (min, max)
    lo_open: bool = False  # lo itself excluded

    @property
    def _bracket(self) -> str:
        return '(' if self.lo_open else '['

    def in_range(self, v: float) -> bool:
        """
        Return True if the finite number ``v`` lies in the declared range.

        Parameters
        ----------
        v : float
            A finite number.

        Returns
        -------
        bool
            True if it lies in the range.

        """
        return (self.lo < v if self.lo_open else self.lo <= v) and v <= self.hi

    @property
    def entry_allowed(self) -> str:
        """Return the range of a number, or of each entry of an array, in words."""
        unit = f' {self.units}' if self.units else ''
        return f'a finite number in {self._bracket}{self.lo:g}, {self.hi:g}]{unit}'

    @property
    def allowed(self) -> str:
        """Return what is allowed, in words, for error messages and the documentation."""
        unit = f' {self.units}' if self.units else ''
        if self.choices:
            return 'one of ' + ', '.join(self.choices)
        if self.type == BOOL:
            return 'true or false'
        if self.type in (DOUBLE, INTEGER):
            kind = 'an integer' if self.type == INTEGER else 'a finite number'
            return f'{kind} in {self._bracket}{self.lo:g}, {self.hi:g}]{unit}'
        if self.type == DOUBLE_ARRAY:
            n = self.length
            if n is None:
                return 'a list of numbers, each ' + self.entry_allowed
            count = f'{n[0]}' if n[0] == n[1] else f'{n[0]} to {n[1]}'
            return f'{count} finite numbers in {self._bracket}{self.lo:g}, {self.hi:g}]{unit}'
        if self.type == STRING_ARRAY:
            if self.length is None:
                return 'a list of strings'
            return f'a list of {self.length[0]} to {self.length[1]} strings'
        return 'a string'


def quantity_spec(
    name: str,
    quantity,
    type_: str = DOUBLE,
    default: Any = None,
    extra: str = '',
    read_only: bool = True,
    length: tuple[int, int] | None = None,
    unit_in_description: bool = False,
) -> ParamSpec:
    """
    Return the spec of a parameter that is one of the cell's quantities.

    Parameters
    ----------
    name : str
        The parameter's name on the node.
    quantity
        The quantity of the cell description (``sorter_sim.model.description.Q[key]``):
        its unit, range, default and meaning become the parameter's.
    type_ : str
        The parameter's type (``DOUBLE`` or ``DOUBLE_ARRAY``).
    default : optional
        The node's default, where it differs from the quantity's.
    extra : str
        What is particular to this node, appended to the meaning in parentheses.
    read_only : bool
        Whether the parameter is fixed once the node runs.
    length : (int, int), optional
        For an array, its allowed length (min, max).
    unit_in_description : bool
        Put the unit in the meaning, in brackets, rather than in the spec's ``units``
        (the controller's table has no units column).

    Returns
    -------
    ParamSpec
        The declared parameter.

    """
    q = quantity
    meaning = q.meaning + (f' ({extra})' if extra else '')
    units = q.unit
    if unit_in_description:
        meaning += f' [{q.unit}]' if q.unit else ''
        units = ''
    return ParamSpec(
        name,
        type_,
        q.default if default is None else default,
        meaning,
        units,
        q.lo,
        q.hi,
        (),
        read_only,
        length,
        q.lo_open,
    )
