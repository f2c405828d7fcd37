"""
The faults injected into a cell's sensors: what a faulted sensor shows instead.

The physics is untouched: parcels move as before, only the signal is wrong, as with
a misaligned reflector (held blocked), a dirty or dead eye (held clear) or a loose
connector (chatter: toggling every half period). ``cell.Cell`` owns one
``SensorFaults`` and asks it what each sensor shows and which edges a period's
events become.
"""

from __future__ import annotations

import math

from sorter_sim.model.description import shown
from sorter_sim.runtime.cell_records import (
    CHATTER_PERIOD_RANGE,
    SENSOR_FAULTS,
    SensorEdge,
    SensorFault,
)
from sorter_sim.runtime.params import ParamError


class SensorFaults:
    """The faults injected into the sensors of one cell, by sensor name."""

    def __init__(self, sensor_names: list[str]):
        self.sensor_names = sensor_names
        self.active: dict[str, SensorFault] = {}

    def shows_blocked(self, name: str, k: int, sees_blocked: bool) -> bool:
        """
        Return what sensor ``name`` shows at period ``k``: the fault's state, or what it sees.

        Parameters
        ----------
        name : str
            The sensor.
        k : int
            The period index.
        sees_blocked : bool
            Whether a parcel blocks it (what it would show without a fault).

        Returns
        -------
        bool
            True: it shows blocked.

        """
        fault = self.active.get(name)
        return fault.blocked_at(k) if fault is not None else sees_blocked

    def check(self, sensor: str, fault: str, period: float, dt: float) -> int:
        """
        Check a fault to inject; return the chatter's half period in control periods.

        Parameters
        ----------
        sensor : str
            The sensor's name.
        fault : str
            One of SENSOR_FAULTS, or 'ok' to clear the fault.
        period : float
            The chatter's full period [s], in CHATTER_PERIOD_RANGE.
        dt : float
            The control period [s].

        Returns
        -------
        int
            The chatter's half period in control periods (0 for the other faults).

        Raises
        ------
        ParamError
            An unknown sensor or fault, or a period out of range.

        """
        if sensor not in self.sensor_names:
            raise ParamError(
                f'unknown sensor {shown(sensor)}; the cell has {", ".join(self.sensor_names)}'
            )
        if fault not in (*SENSOR_FAULTS, 'ok'):
            raise ParamError(
                f'sensor fault must be one of {", ".join((*SENSOR_FAULTS, "ok"))}, '
                f'got {shown(fault)}'
            )
        lo, hi = CHATTER_PERIOD_RANGE
        half_k = 0
        if fault == 'chatter':
            if not (isinstance(period, (int, float)) and math.isfinite(period)):
                raise ParamError(f'chatter period must be a finite number, got {shown(period)}')
            if not lo <= period <= hi:
                raise ParamError(f'chatter period must be in [{lo:g}, {hi:g}] s, got {period:g} s')
            half_k = max(1, round(0.5 * period / dt))
        return half_k

    def set(self, sensor: str, fault: str, half_k: int, k: int) -> None:
        """
        Inject ``fault`` (checked by ``check``) into ``sensor`` from period ``k``; 'ok' ends it.

        Parameters
        ----------
        sensor : str
            The sensor's name.
        fault : str
            One of SENSOR_FAULTS, or 'ok'.
        half_k : int
            The chatter's half period in control periods (``check``'s).
        k : int
            The period the fault starts at.

        """
        if fault == 'ok':
            self.active.pop(sensor, None)
        else:
            self.active[sensor] = SensorFault(fault, half_k, k)

    def edges(self, events: list, k_from: int, k_to: int, dt_ns: int) -> list:
        """
        Replace the faulted sensors' true edges by what they show over (k_from, k_to].

        Parameters
        ----------
        events : list
            A span's events, sensor edges among them.
        k_from, k_to : int
            The span's periods.
        dt_ns : int
            The control period [ns].

        Returns
        -------
        list
            The events, with the faulted sensors' edges as they show them.

        """
        if not self.active:
            return events
        out = [e for e in events if not (isinstance(e, SensorEdge) and e.sensor in self.active)]
        for name, f in self.active.items():
            if f.fault != 'chatter':
                continue
            # the first toggle after k_from, then every half_k periods up to k_to
            j = (k_from - f.k0) // f.half_k + 1
            k = f.k0 + j * f.half_k
            while k <= k_to:
                out.append(SensorEdge(k * dt_ns, name, f.blocked_at(k)))
                k += f.half_k
        return out


__all__ = ['SensorFaults']
