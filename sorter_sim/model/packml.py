"""
The machine state of a cell: the PackML state model (ISA-TR88.00.02, OPC 30050).

Plain Python, no ROS and no protocol: the states with the numbers PackTags give them
(``StateCurrent``), the commands with theirs (``CntrlCmd``), which command each state
accepts and where it leads, and ``PackMLMachine``, which holds the current state and
moves it by commands and by the cell's conditions. The simulator owns one per cell
(``sorter_sim.runtime.cell``); the controller reads its state (it sorts only in
Execute); the node serves it on ROS and OPC UA, the fieldbus as a register.

The model has wait states (Stopped, Idle, Execute, Held, Suspended, Complete,
Aborted) and acting states (Resetting, Starting, Holding, Unholding, Suspending,
Unsuspending, Completing, Stopping, Aborting, Clearing); an acting state ends by
itself when its work is done ("state complete") and leads to its wait state.
Commands come from outside (an operator, a line controller, a PLC) or from the
machine itself: in automatic mode the cell issues its own reset and start at
power-up and after a clear, unholds a hold it took when its cause clears, and
unsuspends a suspension it took when parcels come again (or the chute empties).

How the cell's conditions map onto it (docs/simulation-node.md has the table):
an e-stop aborts (Aborting until the disks are down, then Aborted); a jam or a
watchdog trip holds (Holding, Held); starved (no parcel on the cell and none
inducted for ``packml_starved_s``) or blocked (a chute's eye blocked for
``packml_blocked_s``: the chute is full) suspends; a batch whose last parcel has
left completes (Completing, Complete); stop lets the parcels on the cell run out
(Stopping until the cell is empty).

ISA-TR88.00.02 holds from Execute; this cell also holds from the Suspended group
(Suspending, Suspended, Unsuspending) and from Unholding, so that a jam or a trip
while starved is not lost.
"""

from __future__ import annotations

from dataclasses import dataclass

# PackTags StateCurrent numbers (ISA-TR88.00.02 table 8; OPC 30050 uses the same names)
STATE_NUMBERS = {
    'Clearing': 1,
    'Stopped': 2,
    'Starting': 3,
    'Idle': 4,
    'Suspended': 5,
    'Execute': 6,
    'Stopping': 7,
    'Aborting': 8,
    'Aborted': 9,
    'Holding': 10,
    'Held': 11,
    'Unholding': 12,
    'Suspending': 13,
    'Unsuspending': 14,
    'Resetting': 15,
    'Completing': 16,
    'Complete': 17,
}
STATES = tuple(STATE_NUMBERS)
STATE_BY_NUMBER = {n: s for s, n in STATE_NUMBERS.items()}

# PackTags CntrlCmd numbers
COMMAND_NUMBERS = {
    'reset': 1,
    'start': 2,
    'stop': 3,
    'hold': 4,
    'unhold': 5,
    'suspend': 6,
    'unsuspend': 7,
    'abort': 8,
    'clear': 9,
}
COMMANDS = tuple(COMMAND_NUMBERS)
COMMAND_BY_NUMBER = {n: c for c, n in COMMAND_NUMBERS.items()}

# acting state -> the wait state it leads to when its work is done
ACTING = {
    'Resetting': 'Idle',
    'Starting': 'Execute',
    'Holding': 'Held',
    'Unholding': 'Execute',
    'Suspending': 'Suspended',
    'Unsuspending': 'Execute',
    'Completing': 'Complete',
    'Stopping': 'Stopped',
    'Aborting': 'Aborted',
    'Clearing': 'Stopped',
}

_SUSPEND_GROUP = ('Suspending', 'Suspended', 'Unsuspending')

# command -> {state that accepts it: the state it leads to}
TRANSITIONS = {
    'reset': {'Stopped': 'Resetting', 'Complete': 'Resetting'},
    'start': {'Idle': 'Starting'},
    'stop': {
        s: 'Stopping'
        for s in STATES
        if s not in ('Stopping', 'Stopped', 'Aborting', 'Aborted', 'Clearing')
    },
    'hold': {s: 'Holding' for s in ('Execute', 'Unholding', *_SUSPEND_GROUP)},
    'unhold': {'Held': 'Unholding'},
    'suspend': {'Execute': 'Suspending'},
    'unsuspend': {'Suspended': 'Unsuspending'},
    'abort': {s: 'Aborting' for s in STATES if s not in ('Aborting', 'Aborted')},
    'clear': {'Aborted': 'Clearing'},
}

# the states in which the cell takes parcels in from its infeed: producing, waiting for
# material (a starved cell must see the next parcel to leave Suspended), or held. A hold
# leaves the infeed as a fault leaves it (the jam stays where it is, the watchdog's disks
# drop, parcels keep coming and go straight): the infeed is upstream equipment, and
# interlocking it with the cell's hold is the plant's choice (packml/stop closes it)
INFEED_OPEN = (
    'Starting',
    'Execute',
    'Completing',
    'Holding',
    'Held',
    'Unholding',
    *_SUSPEND_GROUP,
)


def accepting(command: str) -> tuple[str, ...]:
    """Return the states that accept ``command``, in STATES order."""
    return tuple(s for s in STATES if s in TRANSITIONS[command])


def refusal(state: str, command: str) -> str:
    """Return why ``state`` does not take ``command`` (and which states would)."""
    return (
        f'{state} does not take {command}: PackML takes it in {", ".join(accepting(command))} only'
    )


@dataclass(frozen=True)
class Conditions:
    """
    What the cell reports to its state machine, evaluated at a period boundary.

    Attributes
    ----------
    estop : bool
        The e-stop is engaged.
    hold_cause : str
        'jam' or 'watchdog' (the cell holds), '' for none.
    suspend_cause : str
        'starved' or 'blocked' (the cell suspends), '' for none.
    batch_done : bool
        The batch's last parcel has been inducted and has left the cell.
    empty : bool
        No parcel on the belt or the disks, none waiting at the infeed.
    disks_down : bool
        The pop-up is fully down.

    """

    estop: bool = False
    hold_cause: str = ''
    suspend_cause: str = ''
    batch_done: bool = False
    empty: bool = True
    disks_down: bool = True


@dataclass(frozen=True)
class Transition:
    """One change of state: when, from, to, and what made it (a command or a condition)."""

    t_ns: int
    previous: str
    state: str
    cause: str


class PackMLMachine:
    """
    The current PackML state and how it moves.

    Parameters
    ----------
    auto : bool
        Automatic mode: the machine issues its own reset and start at power-up and after
        a clear, unholds and unsuspends when the cause it held or suspended for clears.
        Off, only commands from outside move it out of Stopped, Held, Suspended.

    """

    def __init__(self, auto: bool = True):
        self.auto = bool(auto)
        self.state = 'Stopped'
        self.cause = 'power-up'
        self.transitions: list[Transition] = []  # not yet taken by the node
        self.counts = {'commands': 0, 'refused': 0, 'transitions': 0}
        # the hold or suspension the machine took itself ('' for an operator's)
        self._own_hold = ''
        self._own_suspend = ''
        # automatic mode: reset and start when Stopped (at power-up and after a clear,
        # never after an operator's stop)
        self._restart = self.auto

    @property
    def number(self) -> int:
        return STATE_NUMBERS[self.state]

    @property
    def infeed_open(self) -> bool:
        return self.state in INFEED_OPEN

    def accepts(self, command: str) -> bool:
        return self.state in TRANSITIONS.get(command, {})

    def command(self, command: str, t_ns: int, source: str = 'command') -> tuple[bool, str]:
        """
        Take a command; return whether it was taken and the new state or why not.

        Parameters
        ----------
        command : str
            One of COMMANDS.
        t_ns : int
            The time it is taken at [ns].
        source : str
            Who issued it, for the transition's cause.

        Returns
        -------
        (bool, str)
            Taken, and the state it led to; or refused, and why.

        """
        self.counts['commands'] += 1
        if command not in TRANSITIONS:
            self.counts['refused'] += 1
            return False, f'unknown PackML command {command!r}; one of {", ".join(COMMANDS)}'
        target = TRANSITIONS[command].get(self.state)
        if target is None:
            self.counts['refused'] += 1
            return False, refusal(self.state, command)
        if source != 'auto':
            if command == 'hold':
                self._own_hold = ''
            elif command == 'suspend':
                self._own_suspend = ''
            elif command == 'stop':
                self._restart = False
        if command == 'clear' and self.auto:
            self._restart = True
        self._go(target, t_ns, f'{command} ({source})')
        return True, f'{command}: {target}'

    def _go(self, state: str, t_ns: int, cause: str) -> None:
        self.transitions.append(Transition(t_ns, self.state, state, cause))
        self.counts['transitions'] += 1
        self.state, self.cause = state, cause

    def update(self, c: Conditions, t_ns: int) -> None:
        """
        Move by the cell's conditions until nothing more follows from them.

        Parameters
        ----------
        c : Conditions
            What the cell reports now.
        t_ns : int
            The time [ns].

        """
        for _ in range(2 * len(STATES)):  # a bound on a chain of transitions
            if not self._step(c, t_ns):
                return

    def _step(self, c: Conditions, t_ns: int) -> bool:
        """Make the one transition the conditions call for; False if none."""
        s = self.state
        if c.estop and s not in ('Aborting', 'Aborted', 'Clearing'):
            self._go('Aborting', t_ns, 'e-stop')
            return True
        # acting states: done when their work is
        if s == 'Aborting':
            return c.disks_down and self._done(t_ns)
        if s == 'Clearing':
            return not c.estop and self._done(t_ns)
        if s == 'Stopping':
            return c.empty and self._done(t_ns)
        if s == 'Resetting':
            return not c.hold_cause and self._done(t_ns)
        if s == 'Unholding':
            if c.hold_cause:
                self._own_hold = c.hold_cause
                self._go('Holding', t_ns, c.hold_cause)
                return True
            return self._done(t_ns)
        if s in ACTING:
            return self._done(t_ns)
        # wait states: the cell's conditions and the machine's own commands
        if s in ('Execute', *_SUSPEND_GROUP) and c.hold_cause:
            self._own_hold = c.hold_cause
            self._go('Holding', t_ns, c.hold_cause)
            return True
        if s == 'Execute':
            if c.batch_done and c.empty:
                self._go('Completing', t_ns, 'batch done')
                return True
            if c.suspend_cause:
                self._own_suspend = c.suspend_cause
                self._go('Suspending', t_ns, c.suspend_cause)
                return True
            return False
        if not self.auto:
            return False
        if s == 'Held' and self._own_hold and not c.hold_cause:
            self._own_hold = ''
            return self.command('unhold', t_ns, 'auto')[0]
        if s == 'Suspended' and self._own_suspend and not c.suspend_cause:
            self._own_suspend = ''
            return self.command('unsuspend', t_ns, 'auto')[0]
        if s == 'Aborted' and not c.estop:
            # the e-stop was released (the cell's reset): clear, then reset and start
            return self.command('clear', t_ns, 'auto')[0]
        if s == 'Stopped' and self._restart:
            return self.command('reset', t_ns, 'auto')[0]
        if s == 'Idle' and self._restart:
            self._restart = False
            return self.command('start', t_ns, 'auto')[0]
        return False

    def _done(self, t_ns: int) -> bool:
        self._go(ACTING[self.state], t_ns, 'state complete')
        return True

    def take_transitions(self) -> list[Transition]:
        """Return the transitions since the last call, oldest first."""
        out, self.transitions = self.transitions, []
        return out
