"""Stream agents of the cocotb testbenches: they run inside the simulator, on exported Verilog.

The pytest side (:mod:`tb.harness.cocotb.runner`) exports a top with ``tb.harness.tops``, writes the golden
model's streams as NumPy arrays into a run directory and starts Icarus or Verilator; a bench
module (``tb/harness/cocotb/<unit>.py``) reads them with :func:`load`, drives the Verilog with the agents
below and writes what it saw back with :func:`save`.

Ports of the exported Verilog (``docs/fpga.md``): a stream ``x`` is ``x__valid``, ``x__ready``
and ``x__payload``; a struct payload is one flat vector (field order of the ``lib.data`` layout,
first field in the low bits), so here a payload is one Python ``int``, and a list of payloads
travels as an ``(n, words)`` uint64 array (:func:`to_ints` / :func:`from_ints`); ``clk`` is the
clock, ``rst`` a synchronous active-high reset.

One clock loop, :func:`run`, steps every agent in lock step, once per cycle: ``drive(cycle)``
just after the rising edge (the agent's new ``valid`` / ``ready`` / payload), ``sample(cycle)``
at the falling edge, when everything has settled; a transfer happens at the next rising edge,
where ``valid & ready`` are still what ``sample`` read. Agents:

* :class:`Source`: sends a list of payloads (we are the source), bubbles from a :class:`Pattern`;
* :class:`Sink`: takes payloads (we are the sink), back-pressure from a :class:`Pattern`,
  and checks each against an expected list, bit for bit and in order;
* :class:`Memory`: serves a memory read port (``rtl/memport.py``) from an image, responses after
  random delays, in random order;
* :class:`Watch`: reads a few output ports every cycle (a monitor);
* :class:`LFSRPattern`: the cycles a frame top's hardware LFSR holds a stream (a
  :class:`Pattern` for the benches that must see that top's cycles);
* :class:`FixedLatency`: drives a fixed-latency datapath (``i_valid``/``en``/``o_valid``: the FP
  units) and checks every output at the exact cycle it must appear.

A mismatch raises :class:`Mismatch` (an ``AssertionError``) naming the cycle and the fields.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

import cocotb
from cocotb.clock import Clock
from cocotb.triggers import FallingEdge, RisingEdge

__all__ = ["RUN_DIR_ENV", "Mismatch", "StreamTimeout", "Fields", "Pattern", "LFSRPattern",
           "to_ints", "from_ints", "load", "save", "start", "run", "read", "read_ports", "Source",
           "Sink", "Memory", "Watch", "FixedLatency"]

RUN_DIR_ENV = "SAARCOR_COCOTB_DIR"      # the run directory, set by tb.harness.cocotb.runner


class Mismatch(AssertionError):
    """The Verilog produced something other than the golden model's stream."""


class StreamTimeout(AssertionError):
    """No stream moved for longer than the bench allows."""


# ---- data in and out ---------------------------------------------------------------------------

def to_ints(words: np.ndarray) -> list[int]:
    """``(n, k)`` uint64 words (little-endian: word 0 = bits 0..63) -> ``n`` Python ints."""
    words = np.ascontiguousarray(np.asarray(words, np.uint64).reshape(len(words), -1))
    return [int.from_bytes(row.tobytes(), "little") for row in words]


def from_ints(values: Sequence[int], bits: int) -> np.ndarray:
    """``n`` ints of at most ``bits`` bits -> ``(n, ceil(bits / 64))`` uint64 words."""
    k = max(1, -(-bits // 64))
    raw = b"".join(int(v).to_bytes(8 * k, "little") for v in values)
    return np.frombuffer(raw, np.uint64).reshape(len(values), k).copy()


def load() -> tuple[dict, dict[str, np.ndarray]]:
    """The run's parameters (``params.json``) and arrays (``in.npz``)."""
    d = Path(os.environ[RUN_DIR_ENV])
    params = json.loads((d / "params.json").read_text())
    with np.load(d / "in.npz") as z:
        arrays = {k: z[k] for k in z.files}
    return params, arrays


def save(arrays: dict[str, np.ndarray] | None = None, **values) -> None:
    """Write what the bench saw: ``arrays`` to ``out.npz``, ``values`` (JSON) to ``out.json``."""
    d = Path(os.environ[RUN_DIR_ENV])
    np.savez(d / "out.npz", **(arrays or {}))
    (d / "out.json").write_text(json.dumps(values, indent=1))


class Fields:
    """The fields of a flat payload: ``[(name, offset, width), ...]`` as the pytest side
    computes them from the ``lib.data`` layout (``tb.harness.cocotb.runner.fields``)."""

    def __init__(self, fields: Sequence[Sequence]):
        self.fields = [(str(n), int(o), int(w)) for n, o, w in fields]

    def split(self, value: int) -> dict[str, int]:
        return {n: (value >> o) & ((1 << w) - 1) for n, o, w in self.fields}

    def pack(self, **values: int) -> int:
        """A payload from field values (fields not given are 0)."""
        out = 0
        for n, o, w in self.fields:
            if n in values:
                out |= (int(values[n]) & ((1 << w) - 1)) << o
        return out

    def diff(self, got: int, want: int) -> str:
        """The fields that differ, in words."""
        g, w = self.split(got), self.split(want)
        return ", ".join(f"{n} {g[n]:#x} (model {w[n]:#x})" for n in g if g[n] != w[n])


# ---- random bubbles and back-pressure ----------------------------------------------------------

class Pattern:
    """The cycles in which a stream is held (a source's bubble, a sink's back-pressure).

    A fraction ``p`` of cycles, in runs of mean length ``burst`` cycles (1: each cycle
    independently), from a NumPy generator seeded with ``seed``: the same seed gives the same
    cycles in every simulator. ``Pattern(0)`` never holds. Call it with the cycle number."""

    def __init__(self, p: float = 0.0, seed: int = 0, burst: float = 1.0, chunk: int = 4096):
        if not 0.0 <= p < 1.0:
            raise ValueError(f"Pattern: p={p} must be in [0, 1)")
        if burst < 1.0:
            raise ValueError(f"Pattern: burst={burst} must be >= 1 cycle")
        self.p, self.burst, self.chunk = p, burst, chunk
        self.rng = np.random.default_rng(seed)
        self.held = np.zeros(0, bool)

    def _extend(self) -> None:
        n = self.chunk
        if self.burst == 1.0:
            more = self.rng.random(n) < self.p
        else:
            # alternate free and held runs with geometric lengths: held runs of mean `burst`,
            # free runs of mean burst * (1 - p) / p, so a fraction p of cycles is held
            k = n // 2 + 2
            held = self.rng.geometric(1.0 / self.burst, k)
            free = self.rng.geometric(min(1.0, self.p / (self.burst * (1.0 - self.p))), k)
            runs = np.empty(2 * k, np.int64)
            runs[0::2], runs[1::2] = free, held
            more = np.repeat(np.arange(2 * k) % 2 == 1, runs)[:n]
        self.held = np.concatenate([self.held, more])

    def __call__(self, cycle: int) -> bool:
        if self.p == 0.0:
            return False
        while cycle >= len(self.held):
            self._extend()
        return bool(self.held[cycle])


NEVER = Pattern(0.0)


class LFSRPattern:
    """The cycles ``tb/harness/lfsr.py``'s hardware LFSR holds a stream: held in cycle k when the low 4
    bits of the LFSR's k-th value are below ``q`` (sixteenths: ``tb.harness.lfsr.passes``), value 0 =
    ``seed``, one step a cycle (16 bits, taps 16, 14, 13, 11). A bench that holds a stream with
    the LFSR of a frame top (``tb.harness.chip_frame.ChipFrame``'s result back-pressure and memory
    holds) from that top's first run cycle on sees that run's cycles."""

    def __init__(self, q: int, seed: int):
        if not 0 <= q <= 15 or not 0 < seed < 1 << 16:
            raise ValueError(f"LFSRPattern: q={q} in 0..15, seed={seed} in 1..65535")
        from tb.harness.lfsr import lfsr_next
        self.q, self.value, self.held, self._next = q, seed, [], lfsr_next

    def __call__(self, cycle: int) -> bool:
        while cycle >= len(self.held):
            self.held.append((self.value & 15) < self.q)
            self.value = self._next(self.value)
        return self.held[cycle]


# ---- the clock loop ----------------------------------------------------------------------------

def read(handle, what: str = "") -> int:
    """A signal's value as an unsigned int; X or Z raise :class:`Mismatch`."""
    v = handle.value
    try:
        return int(v) if len(handle) == 1 else v.to_unsigned()
    except ValueError:
        raise Mismatch(f"{what or handle._name} is {v} (X or Z): undriven or uninitialised")


async def start(dut, consts: dict[str, int] | None = None, reset_cycles: int = 2) -> None:
    """Set the constant inputs ``consts`` (port name -> value), start a 100 MHz clock on
    ``clk`` (first rising edge after half a period, when the inputs are set) and hold ``rst``
    for ``reset_cycles`` rising edges. Create the agents first: they set their inputs idle."""
    for name, value in (consts or {}).items():
        getattr(dut, name).value = int(value)
    dut.rst.value = 1
    Clock(dut.clk, 10, unit="ns").start(start_high=False)
    for _ in range(reset_cycles):
        await RisingEdge(dut.clk)
    dut.rst.value = 0


async def run(dut, agents: Sequence, done: Callable[[], bool], *, max_cycles: int = 1_000_000,
              quiet: int = 20_000) -> int:
    """Step ``agents`` every cycle until ``done()``; returns the cycles run (cycle 0 is the
    first after reset). Raises :class:`StreamTimeout` after ``max_cycles`` cycles, or when no
    agent moved data for ``quiet`` cycles."""
    rise, fall = RisingEdge(dut.clk), FallingEdge(dut.clk)
    cycle = last = 0
    while not done():
        if cycle - last > quiet or cycle >= max_cycles:
            state = "; ".join(str(a) for a in agents)
            raise StreamTimeout(f"cycle {cycle}: no stream moved for {cycle - last} cycles "
                                f"(limit {quiet}; {max_cycles} cycles at most): {state}")
        for a in agents:
            a.drive(cycle)
        await fall
        for a in agents:
            if a.sample(cycle):
                last = cycle
        await rise
        cycle += 1
    return cycle


async def read_ports(dut, names: Sequence[str], settle: int = 2) -> dict[str, int]:
    """After ``settle`` more clock cycles, the values of output ports ``names`` (counters)."""
    for _ in range(settle):
        await RisingEdge(dut.clk)
    await FallingEdge(dut.clk)
    return {n: read(getattr(dut, n), n) for n in names}


class _Port:
    """Only writes a signal when its value changes (a write costs a simulator call)."""

    def __init__(self, handle, value: int | None = 0):
        self.handle, self.value = handle, None
        if value is not None:
            self.set(value)

    def set(self, value: int) -> None:
        if value != self.value:
            self.handle.value = value
            self.value = value


# ---- agents ------------------------------------------------------------------------------------

class Source:
    """Send ``payloads`` on stream ``name`` of ``dut`` (we are the source), in order.

    Payload ``i`` is offered no earlier than cycle ``due[i]`` (default 0), only once
    ``may_send(i)`` is true (a requester waiting for a free tag), and not in the cycles ``hold``
    holds (bubbles); once raised, ``valid`` and the payload stay until the transfer (stream
    rules). :meth:`push` appends a payload while the bench runs (a response to an output).
    ``on_transfer(cycle, i)`` is called at each transfer; ``cycles``: the cycle of each."""

    def __init__(self, dut, name: str, payloads: Sequence[int] = (), *, hold: Callable = NEVER,
                 due: Sequence[int] | None = None,
                 may_send: Callable[[int], bool] | None = None,
                 on_transfer: Callable[[int, int], None] | None = None):
        self.name = name
        self.valid = _Port(getattr(dut, f"{name}__valid"))
        self.ready = getattr(dut, f"{name}__ready")
        self.payload = getattr(dut, f"{name}__payload")
        self.payload.value = 0          # defined from the start, as Amaranth's simulator has it
        self.payloads = list(payloads)
        self.due = list(due) if due is not None else [0] * len(self.payloads)
        self.hold, self.may_send, self.on_transfer = hold, may_send, on_transfer
        self.i, self.offered, self.cycles = 0, False, []

    def push(self, payload: int, due: int = 0) -> None:
        self.payloads.append(payload)
        self.due.append(due)

    @property
    def done(self) -> bool:
        return self.i == len(self.payloads)

    def drive(self, cycle: int) -> None:
        if not self.offered and not self.done and self.due[self.i] <= cycle \
                and not self.hold(cycle) and (self.may_send is None or self.may_send(self.i)):
            self.payload.value = self.payloads[self.i]
            self.offered = True
        self.valid.set(int(self.offered))

    def sample(self, cycle: int) -> bool:
        if self.offered and read(self.ready, f"{self.name}__ready"):
            self.cycles.append(cycle)
            if self.on_transfer is not None:
                self.on_transfer(cycle, self.i)
            self.i += 1
            self.offered = False
            return True
        return False

    def __str__(self):
        return f"source {self.name}: {self.i} of {len(self.payloads)} sent"


class Sink:
    """Take payloads from stream ``name`` (we are the sink): ``ready`` low in the cycles
    ``hold`` holds. With ``expect`` (a list of ints) every payload must equal the next expected
    one, bit for bit (``fields`` names the fields that differ); a payload beyond the list is a
    mismatch too. ``got`` / ``cycles``: payloads and transfer cycles. ``count``: how many make
    the sink done (default ``len(expect)``)."""

    def __init__(self, dut, name: str, *, hold: Callable = NEVER,
                 expect: Sequence[int] | None = None, fields: Fields | None = None,
                 count: int | None = None, on_transfer: Callable[[int, int], None] | None = None):
        self.name = name
        self.ready = _Port(getattr(dut, f"{name}__ready"))
        self.valid = getattr(dut, f"{name}__valid")
        self.payload = getattr(dut, f"{name}__payload")
        self.hold, self.expect, self.fields = hold, expect, fields
        self.count = count if count is not None else (len(expect) if expect is not None else None)
        self.on_transfer = on_transfer
        self.got, self.cycles = [], []
        self.taking = False

    @property
    def done(self) -> bool:
        return self.count is not None and len(self.got) >= self.count

    def drive(self, cycle: int) -> None:
        self.taking = not self.hold(cycle)
        self.ready.set(int(self.taking))

    def sample(self, cycle: int) -> bool:
        if not (self.taking and read(self.valid, f"{self.name}__valid")):
            return False
        p = read(self.payload, f"{self.name}__payload")
        i = len(self.got)
        self.got.append(p)
        self.cycles.append(cycle)
        if self.expect is not None:
            if i >= len(self.expect):
                raise Mismatch(f"{self.name} #{i} at cycle {cycle}: {p:#x}, but the model's "
                               f"stream has only {len(self.expect)} payloads")
            if p != self.expect[i]:
                detail = self.fields.diff(p, self.expect[i]) if self.fields else \
                    f"model {self.expect[i]:#x}"
                raise Mismatch(f"{self.name} #{i} at cycle {cycle}: {p:#x}: {detail}")
        if self.on_transfer is not None:
            self.on_transfer(cycle, p)
        return True

    def __str__(self):
        n = "?" if self.count is None else self.count
        return f"sink {self.name}: {len(self.got)} of {n} received"


class Memory:
    """Serve the read port ``name`` of ``dut`` (we are the server: ``name__req`` in,
    ``name__resp`` out, ``rtl/memport.py``) from ``read(addr) -> int`` (``data_bits`` wide).

    Request payload ``{addr: addr_bits, tag}``, response ``{data: data_bits, tag}``. Each
    accepted request is answered ``min_delay``..``max_delay`` cycles later (uniform, from
    ``rng``, a ``numpy.random.Generator``); of the due responses a random one goes next
    (``in_order``: the oldest) and stays offered until taken (stream rules); requests are
    back-pressured in the cycles ``hold`` holds. ``addrs``: every address read, in order."""

    def __init__(self, dut, name: str, read_item: Callable[[int], int], *, addr_bits: int,
                 data_bits: int, rng: np.random.Generator, min_delay: int = 1,
                 max_delay: int = 20, hold: Callable = NEVER, in_order: bool = False):
        self.name = name
        self.req_ready = _Port(getattr(dut, f"{name}__req__ready"))
        self.req_valid = getattr(dut, f"{name}__req__valid")
        self.req_payload = getattr(dut, f"{name}__req__payload")
        self.resp_valid = _Port(getattr(dut, f"{name}__resp__valid"))
        self.resp_ready = getattr(dut, f"{name}__resp__ready")
        self.resp_payload = getattr(dut, f"{name}__resp__payload")
        self.resp_payload.value = 0
        self.read_item, self.addr_bits, self.data_bits = read_item, addr_bits, data_bits
        self.rng, self.min_delay, self.max_delay = rng, min_delay, max_delay
        self.hold, self.in_order = hold, in_order
        self.pending: list = []        # (due cycle, sequence, tag, addr)
        self.current = None
        self.taking = False
        self.addrs: list[int] = []

    def drive(self, cycle: int) -> None:
        self.taking = not self.hold(cycle)
        self.req_ready.set(int(self.taking))
        if self.current is None:
            due = [p for p in self.pending if p[0] <= cycle]
            if due:
                self.current = min(due, key=lambda p: p[1]) if self.in_order else \
                    due[int(self.rng.integers(len(due)))]
                self.pending.remove(self.current)
                _, _, tag, addr = self.current
                self.resp_payload.value = self.read_item(addr) | tag << self.data_bits
        self.resp_valid.set(int(self.current is not None))

    def sample(self, cycle: int) -> bool:
        moved = False
        if self.taking and read(self.req_valid, f"{self.name}__req__valid"):
            p = read(self.req_payload, f"{self.name}__req__payload")
            addr, tag = p & ((1 << self.addr_bits) - 1), p >> self.addr_bits
            delay = int(self.rng.integers(self.min_delay, self.max_delay + 1))
            self.pending.append((cycle + delay, len(self.addrs), tag, addr))
            self.addrs.append(addr)
            moved = True
        if self.current is not None and read(self.resp_ready, f"{self.name}__resp__ready"):
            self.current = None
            moved = True
        return moved

    def __str__(self):
        return (f"memory {self.name}: {len(self.addrs)} requests, "
                f"{len(self.pending) + (self.current is not None)} unanswered")


class Watch:
    """Read ``signals`` (port names) at every falling edge and call ``on_cycle(cycle, values)``
    with their values (ints); with ``cond`` (a port name) only in cycles where it is high."""

    def __init__(self, dut, signals: Sequence[str], on_cycle: Callable[[int, list], None], *,
                 cond: str | None = None):
        self.names = list(signals)
        self.handles = [getattr(dut, n) for n in self.names]
        self.cond = getattr(dut, cond) if cond else None
        self.cond_name, self.on_cycle = cond, on_cycle

    def drive(self, cycle: int) -> None:
        pass

    def sample(self, cycle: int) -> bool:
        if self.cond is not None and not read(self.cond, self.cond_name):
            return False
        self.on_cycle(cycle, [read(h, n) for h, n in zip(self.handles, self.names)])
        return False

    def __str__(self):
        return f"watch {', '.join(self.names)}"


class FixedLatency:
    """A fixed-latency datapath: ``i_valid``, ``en`` (stall) and operand ports in, ``o_valid``
    and result ports out (every FP unit, ``rtl/fp/pipe.py``).

    Operation ``i`` has operands ``inputs[port][i]`` and result ``expect[port][i]``. It is
    presented in a cycle that ``bubble`` does not hold (in the others ``i_valid`` is low and
    the operand ports carry random bits); ``en`` is low in the cycles ``stall`` holds. A shift
    register of ``latency`` stages that moves only when ``en`` is high says which operation
    must be at the output in each cycle: ``o_valid`` is checked in every cycle and the results
    in every cycle it is high, so each result appears at exactly its cycle or the bench fails.
    ``cycles``: the cycle each result was seen (first time) at the output."""

    def __init__(self, dut, inputs: dict[str, Sequence[int]], expect: dict[str, Sequence[int]],
                 latency: int, *, bubble: Callable = NEVER, stall: Callable = NEVER,
                 rng: np.random.Generator | None = None, name: str = ""):
        if latency < 1:
            raise ValueError("FixedLatency: latency >= 1 (a clocked datapath)")
        self.name = name or dut._name
        self.ins = [(getattr(dut, k), [int(x) for x in v]) for k, v in inputs.items()]
        self.outs = [(k, getattr(dut, k), [int(x) for x in v]) for k, v in expect.items()]
        self.n = len(self.ins[0][1])
        self.i_valid, self.en = _Port(dut.i_valid), _Port(dut.en, 1)
        self.o_valid = dut.o_valid
        self.bubble, self.stall = bubble, stall
        self.rng = rng or np.random.default_rng(0)
        self.pipe = [None] * latency          # pipe[-1]: the operation at the output
        self.i, self.valid_now, self.en_now = 0, False, True
        self.checked, self.cycles = 0, []
        self.last_head = None

    @property
    def done(self) -> bool:
        return self.i == self.n and all(x is None for x in self.pipe)

    def drive(self, cycle: int) -> None:
        self.en_now = not self.stall(cycle)
        self.valid_now = self.i < self.n and not self.bubble(cycle)
        for handle, values in self.ins:
            handle.value = values[self.i] if self.valid_now else \
                int.from_bytes(self.rng.bytes((len(handle) + 7) // 8), "little") \
                & ((1 << len(handle)) - 1)
        self.i_valid.set(int(self.valid_now))
        self.en.set(int(self.en_now))

    def sample(self, cycle: int) -> bool:
        head = self.pipe[-1]
        o_valid = read(self.o_valid, "o_valid")
        if o_valid != (head is not None):
            raise Mismatch(f"{self.name}: cycle {cycle}: o_valid={o_valid}, expected "
                           f"{int(head is not None)}"
                           + (f" (operation #{head})" if head is not None else ""))
        if head is not None:
            for port, handle, values in self.outs:
                got = read(handle, port)
                if got != values[head]:
                    ops = ", ".join(f"{h._name}={v[head]:#x}" for h, v in self.ins)
                    raise Mismatch(f"{self.name}: cycle {cycle}, operation #{head} ({ops}): "
                                   f"{port}={got:#x}, model {values[head]:#x}")
            if head != self.last_head:
                self.checked += 1
                self.cycles.append(cycle)
                self.last_head = head
        if self.en_now:
            self.pipe = [self.i if self.valid_now else None] + self.pipe[:-1]
            if self.valid_now:
                self.i += 1
            return True
        return False

    def __str__(self):
        return f"{self.name}: {self.i} of {self.n} operations in, {self.checked} checked"
