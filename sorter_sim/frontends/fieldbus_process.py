"""
The fieldbus servers in a process of their own, sharing the I/O image with the node.

The Modbus TCP, OPC UA and S7 servers are Python (pymodbus, asyncua, python-snap7):
in the node's interpreter every client request they serve holds the physics up
(the interpreter runs one thread at a time). Here they run in a child process; the
image is exchanged through shared memory, once per I/O cycle (docs/fieldbus.md, Timing):

- **inputs** (the cell to the PLC): at each latch the node encodes what changed
  straight into shared memory (``multiprocessing.shared_memory``: the raw discrete
  inputs and input registers, the Modbus image itself), bracketed by a sequence
  counter (a seqlock); the servers read a consistent copy of it, retrying while the
  node is writing. With a cycle of one period the node latches at the end of each run
  of periods and when a read asks: a read while the node runs (``STEPPING``) counts
  itself in ``READ_ASK`` and waits, ASK_WAIT_S at most, until the node has latched for
  it (``READ_SERVED``), which it does between two chunks of periods.
- **outputs** (the PLC to the cell): the servers check and apply each write as they
  do in process (``IOImage``) and put it in shared memory too: per output its raw
  value, a count of its writes and a count of its rising edges, then a sequence
  number. The node, at the start of each period or chunk, compares the sequence
  number with the one it saw (one read when nothing was written) and takes the
  outputs whose counts moved. Nothing else the servers do waits on the node: a cell
  that is not stepped never holds a client up.
- **counters** (writes refused, reads refused, calls refused ...) are kept in shared
  memory by the servers and read by the node's diagnostics.

The child stops when the node asks it to, or when the pipe closes (the node died):
no server outlives its cell. It ignores SIGINT: Ctrl-C reaches the node, which stops it.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Mapping
from multiprocessing.connection import Connection

import numpy as np

from sorter_sim.frontends.fieldbus import FieldbusServers, IOImage, Warehouse
from sorter_sim.model.io_map import DI, INPUT, IR, OUTPUT, decode, table_size

STATS = (
    'writes',
    'refused',
    'reads_refused',
    'illegal_functions',
    'frames_dropped',
    'calls_refused',
)
START_TIMEOUT_S = 60.0


# the header: the inputs' sequence number, the outputs', when the inputs were sampled
# [ns since the epoch]; the reads asked for (servers) and served (node), whether the node
# is running periods now; then the servers' counters
IN_SEQ, OUT_SEQ, IN_WALL, READ_ASK, READ_SERVED, STEPPING, HEAD = range(7)
ASK_WAIT_S = 0.005  # the longest a read waits for a running node to latch the inputs
ASK_POLL_S = 2e-4  # how often it looks meanwhile (each look a wake-up of this process)
# reads this soon after an answered one take its latch: the variables of one OPC UA
# request (a callback each), a PLC scan's few requests, see one period
ASK_FRESH_S = 0.001


def _layout(signals) -> dict:
    """Return the shared block's layout: offsets and sizes of its arrays."""
    n_di, n_ir = table_size(signals, DI), table_size(signals, IR)
    n_out = sum(1 for s in signals if s.direction == OUTPUT)
    outputs = 8 * (HEAD + len(STATS))
    di = outputs + 8 * 3 * n_out  # per output: raw value, writes, rising edges
    ir = di + n_di + (n_di % 2)  # registers at an even offset
    return {
        'n_di': n_di,
        'n_ir': n_ir,
        'n_out': n_out,
        'outputs': outputs,
        'di': di,
        'ir': ir,
        'size': ir + 2 * n_ir,
    }


def _views(buf, layout):
    """Return (header, outputs [3, n_out], discrete inputs, input registers) over ``buf``."""
    head = np.ndarray((HEAD + len(STATS),), dtype=np.int64, buffer=buf, offset=0)
    out = np.ndarray((3, layout['n_out']), dtype=np.int64, buffer=buf, offset=layout['outputs'])
    di = np.ndarray((layout['n_di'],), dtype=np.uint8, buffer=buf, offset=layout['di'])
    ir = np.ndarray((layout['n_ir'],), dtype=np.uint16, buffer=buf, offset=layout['ir'])
    return head, out, di, ir


class NodeImage(IOImage):
    """
    The node's side of a shared image: inputs into shared memory, outputs from a pipe.

    Parameters
    ----------
    signals : list of Signal
        The I/O map.
    initial_outputs : dict
        The outputs' values before any client writes.
    shm : SharedMemory
        The block the inputs live in (made by ``FieldbusProcess``).
    conn : Connection
        The node's end of the pipe the servers send their writes on.

    """

    def __init__(self, signals, initial_outputs: dict, shm):
        super().__init__(signals, initial_outputs)
        self._shm = shm
        layout = _layout(self.signals)
        self._head, self._out, di, ir = _views(shm.buf, layout)
        self.raw[DI], self.raw[IR] = di, ir  # _encode writes into shared memory
        self._local = {'overwritten': 0, 'refreshes': 0}
        self._out_signals = [s for s in self.signals if s.direction == OUTPUT]
        self._out_seen = 0
        self._counts_seen = np.zeros((2, layout['n_out']), dtype=np.int64)
        self._served = 0  # the reads the last latch answered (READ_ASK then)

    @property
    def stats(self) -> dict:
        out = {k: int(v) for k, v in zip(STATS, self._head[HEAD:])}
        out.update(self._local)
        return out

    @stats.setter
    def stats(self, value) -> None:  # IOImage.__init__ sets it; the counters live above
        pass

    def refresh_inputs(self, values: dict) -> None:
        head = self._head
        asked = int(head[READ_ASK])  # the reads asked so far: this latch answers them all
        head[IN_SEQ] += 1  # odd: being written
        super().refresh_inputs(values)  # encodes what changed, into shared memory
        head[IN_WALL] = self.sampled_ns
        head[IN_SEQ] += 1  # even: consistent
        head[READ_SERVED] = asked
        self._served = asked
        self._local['refreshes'] += 1

    # the node's side of latching on demand (``FieldbusBridge``, a cycle of one period)
    on_demand = True

    def read_asked(self) -> bool:
        """Return whether a client asked for the inputs since they were last latched."""
        return int(self._head[READ_ASK]) != self._served

    def running(self, on: bool) -> None:
        """
        Say the node is running periods (a read then asks it for a latch) or stopped.

        Parameters
        ----------
        on : bool
            True before the node runs periods; False once it has latched their end.

        """
        self._head[STEPPING] = 1 if on else 0

    def take_outputs(self) -> tuple[dict, set]:
        seq = int(self._head[OUT_SEQ])
        if seq == self._out_seen:
            return {}, set()  # the common case: one read
        self._out_seen = seq
        counts = self._out[1:].copy()  # writes, rises: read before the values
        values = self._out[0].copy()
        moved = counts != self._counts_seen
        out, rises = {}, set()
        for i in np.flatnonzero(moved[0]):
            s = self._out_signals[i]
            lost = int(counts[0, i] - self._counts_seen[0, i]) - 1
            self._local['overwritten'] += lost  # newer writes before the cell took them
            value = bool(values[i]) if s.type == 'bool' else s.value(int(values[i]))
            out[s.name] = self.outputs[s.name] = value
        for i in np.flatnonzero(moved[1]):
            rises.add(self._out_signals[i].name)
        self._counts_seen = counts
        return out, rises


class _SharedInputs(Mapping):
    """The inputs' engineering values, decoded from shared memory when asked."""

    def __init__(self, image: ServerImage):
        self._image = image
        self._names = [s.name for s in image.signals if s.direction == INPUT]

    def __getitem__(self, name):
        return self._image.decoded()[name]

    def __iter__(self):
        return iter(self._names)

    def __len__(self):
        return len(self._names)


class ServerImage(IOImage):
    """The servers' side: inputs read from shared memory, each write sent to the node."""

    def __init__(self, signals, initial_outputs: dict, buf):
        super().__init__(signals, initial_outputs)
        self._head, self._out, self._di, self._ir = _views(buf, _layout(self.signals))
        self._out_index = {
            s.name: i for i, s in enumerate(s for s in self.signals if s.direction == OUTPUT)
        }
        self._decoded = None  # (sequence number, {input: value}, sampled [ns]) of the last decode
        self._ask_lock = threading.Lock()  # the servers' threads ask one at a time
        self._answered = -ASK_FRESH_S  # when the node last latched for a read [monotonic s]
        self.inputs = _SharedInputs(self)

    def _consistent_inputs(self, tables=(DI, IR)) -> tuple[dict, int]:
        """Return copies of the input tables and their sampling time, of one period (seqlock)."""
        head = self._head
        while True:
            seq = int(head[IN_SEQ])
            if seq % 2:
                continue  # the node is writing: a microsecond
            copy = {t: (self._di if t == DI else self._ir).tolist() for t in tables}
            sampled = int(head[IN_WALL])
            if int(head[IN_SEQ]) == seq:
                return copy, sampled

    def _ask_for_inputs(self) -> None:
        """
        Have a node that is running periods latch its inputs for this read; wait for it.

        A node with a cycle of one period latches the inputs when a read asks (and at the
        end of each run of periods), not every period: the read sees the cell at the end
        of the periods run by then, as it would with a latch every period, and nobody
        reading costs the physics nothing. The node answers within a run of periods (a
        pose period at most, some hundred µs); a node that does not within ASK_WAIT_S
        (stopped, killed) leaves the read with the inputs last latched. A node that is
        not running periods (between steps, between realtime ticks) is not asked, and
        neither is one that latched for a read less than ASK_FRESH_S ago.
        """
        head = self._head
        if not head[STEPPING] or time.monotonic() - self._answered < ASK_FRESH_S:
            return
        with self._ask_lock:
            head[READ_ASK] += 1
            asked = int(head[READ_ASK])
        deadline = time.monotonic() + ASK_WAIT_S
        while head[STEPPING] and head[READ_SERVED] < asked and time.monotonic() < deadline:
            time.sleep(ASK_POLL_S)
        self._answered = time.monotonic()

    def snapshot_tables(self, tables) -> dict:
        out = {}
        wanted = [t for t in tables if t in (DI, IR)]
        if wanted:
            self._ask_for_inputs()
            out.update(self._consistent_inputs(wanted)[0])
        with self._lock:
            for t in tables:
                if t not in (DI, IR):
                    out[t] = list(self.raw[t])
        return out

    def snapshot(self, table: str) -> list[int]:
        return self.snapshot_tables((table,))[table]

    def input_values(self, names) -> tuple:
        values = self.decoded()
        return tuple(values[n] for n in names)

    def input_sample(self, names) -> tuple[tuple, int]:
        self.decoded()
        _, values, sampled = self._decoded
        return tuple(values[n] for n in names), sampled

    def decoded(self) -> dict:
        """
        Return every input's engineering value, of one period.

        Decoded once per period the node wrote: a client reading thirty variables in one
        request (an OPC UA read, a subscription's sampling) decodes the image once.
        """
        self._ask_for_inputs()
        seq = int(self._head[IN_SEQ])
        cached = self._decoded
        if cached is not None and cached[0] == seq and seq % 2 == 0:
            return cached[1]
        tables, sampled = self._consistent_inputs()
        values = {}
        for s in self.signals:
            if s.direction != INPUT:
                continue
            regs = tables[s.table]
            values[s.name] = (
                bool(regs[s.address])
                if s.table == DI
                else decode(s, regs[s.address : s.address + s.words])
            )
        self._decoded = (seq, values, sampled)  # seq read before the copy: at worst decoded again
        return values

    def count(self, key: str = 'refused') -> None:
        with self._lock:
            self.stats[key] += 1
            if key in STATS:
                self._head[HEAD + STATS.index(key)] = self.stats[key]

    def _apply(self, changes: dict) -> None:
        out, head = self._out, self._head
        with self._lock:
            for name, value in changes.items():
                s, i = self.by_name[name], self._out_index[name]
                if value is True and self.outputs[name] is False:
                    out[2, i] += 1  # a rising edge, even if it falls again before the cell looks
                self._store_output(s, value)
                out[0, i] = (1 if value else 0) if s.type == 'bool' else s.raw(value)
                out[1, i] += 1  # after the value: a count the node sees has its value there
            self.stats['writes'] += 1
            head[HEAD + STATS.index('writes')] = self.stats['writes']
            head[OUT_SEQ] += 1


class _MirroredWarehouse(Warehouse):
    """The warehouse link, its refusals counted where the node's diagnostics read them."""

    def __init__(self, head):
        self._head = head
        super().__init__()

    @property
    def refused(self) -> int:
        return int(self._head[HEAD + STATS.index('calls_refused')])

    @refused.setter
    def refused(self, value: int) -> None:
        self._head[HEAD + STATS.index('calls_refused')] = value


def _serve(conn) -> None:
    """Run the servers over the shared image until the node says stop or goes away."""
    from multiprocessing import shared_memory

    shm_name, signals, initial_outputs, addresses, cell_name = conn.recv()
    # the node owns the block: this process only attaches, and its resource tracker must
    # not unlink the block when this process ends (Python < 3.13 registers an attach too)
    shm = shared_memory.SharedMemory(name=shm_name)
    try:
        from multiprocessing import resource_tracker

        resource_tracker.unregister(shm._name, 'shared_memory')
    except Exception:  # a Python without the registration: nothing to undo
        pass
    image = ServerImage(signals, initial_outputs, shm.buf)
    servers = FieldbusServers(image, cell_name=cell_name, **addresses)
    servers.warehouse = _MirroredWarehouse(image._head)
    try:
        servers.start()
    except ValueError as exc:
        conn.send(('error', str(exc)))
        shm.close()
        return
    conn.send(
        (
            'ready',
            servers.modbus_port,
            servers.opcua_endpoint,
            servers.s7_port,
        )
    )
    try:
        while True:
            if conn.recv() == 'stop':
                break
    except (EOFError, OSError):
        pass  # the node died
    servers.stop()
    image.inputs = {}  # drop the views before the block closes
    image._head = image._out = image._di = image._ir = None
    shm.close()
    # the servers are stopped and the block closed: leave without the interpreter's
    # teardown, which reports every asyncio task of a client session still pending
    sys.stderr.flush()
    os._exit(0)


class _WarehouseCounts:
    def __init__(self, head):
        self._head = head

    @property
    def refused(self) -> int:
        return int(self._head[HEAD + STATS.index('calls_refused')])


class FieldbusProcess:
    """
    The cell's fieldbus servers in a child process; the node's handle on them.

    The same face as ``FieldbusServers`` for the node: ``start()`` (ValueError with one
    line when a server cannot listen), ``stop()``, ``modbus_port``, ``opcua_endpoint``,
    ``s7_port``, ``warehouse.refused``; ``image`` is the node's side of
    the shared image, exchanged as ``IOImage`` is.
    """

    def __init__(
        self,
        signals,
        initial_outputs: dict,
        *,
        modbus=None,
        opcua=None,
        s7=None,
        cell_name: str = 'cell',
    ):
        from multiprocessing import shared_memory

        layout = _layout(tuple(signals))
        self._shm = shared_memory.SharedMemory(create=True, size=max(layout['size'], 8))
        np.ndarray((layout['size'],), dtype=np.uint8, buffer=self._shm.buf)[:] = 0
        # a socket pair, the child's end inherited: a plain interpreter runs the servers
        # (multiprocessing's spawn would import the caller's main module again, and fork
        # would copy a process with DDS threads)
        mine, theirs = socket.socketpair()
        self._conn = Connection(mine.detach())
        self._child_fd = theirs.detach()
        self.image = NodeImage(signals, initial_outputs, self._shm)
        self._config = (
            self._shm.name,
            tuple(signals),
            dict(initial_outputs),
            {'modbus': modbus, 'opcua': opcua, 's7': s7},
            cell_name,
        )
        self._proc = None
        self.modbus_port = self.opcua_endpoint = self.s7_port = None
        self.warehouse = _WarehouseCounts(self.image._head)

    def start(self) -> None:
        self._proc = subprocess.Popen(
            [sys.executable, '-m', 'sorter_sim.frontends.fieldbus_process', str(self._child_fd)],
            pass_fds=(self._child_fd,),
            stdin=subprocess.DEVNULL,
        )
        os.close(self._child_fd)  # the child's end lives in the child now
        self._conn.send(self._config)
        if not self._conn.poll(START_TIMEOUT_S):
            self.stop()
            raise ValueError(f'the fieldbus servers did not start within {START_TIMEOUT_S:g} s')
        try:
            answer = self._conn.recv()
        except EOFError:
            self.stop()
            raise ValueError('the fieldbus process ended before it served') from None
        if answer[0] == 'error':
            self.stop()
            raise ValueError(answer[1])
        _, self.modbus_port, self.opcua_endpoint, self.s7_port = answer

    @property
    def alive(self) -> bool:
        """Return whether the servers' process runs (a killed one leaves the cell running)."""
        return self._proc is not None and self._proc.poll() is None

    @property
    def pid(self) -> int | None:
        return None if self._proc is None else self._proc.pid

    def stop(self, wait_s: float = 1.0) -> None:
        """Stop the servers and the process (idempotent), in at most about ``wait_s``."""
        if self._proc is not None and self._proc.poll() is None:
            try:
                self._conn.send('stop')
            except (BrokenPipeError, OSError):
                pass
            try:
                self._proc.wait(wait_s)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait(1.0)
        if self._shm is not None:
            # the node's views go before the block does; what it writes after is dropped
            image = self.image
            image.raw[DI] = np.array(image.raw[DI])
            image.raw[IR] = np.array(image.raw[IR])
            image._head = image._head.copy()
            image._out = image._out.copy()
            self.warehouse = _WarehouseCounts(self.image._head)
            try:
                self._shm.close()
                self._shm.unlink()
            except (FileNotFoundError, BufferError):
                pass
            self._shm = None
        try:
            self._conn.close()
        except OSError:
            pass


if __name__ == '__main__':
    # Ctrl-C on a terminal reaches the whole process group: the node stops this process
    # through the pipe (or by closing it), so the interrupt is not this process's to take
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _serve(Connection(int(sys.argv[1])))
