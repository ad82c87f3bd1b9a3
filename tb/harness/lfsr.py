"""Random stimulus in hardware: LFSR-made input bubbles and result back-pressure.

Self-stimulating testbenches (``tb.units.rtc.RTCSelfTest`` in Amaranth's simulator, ``tb.harness.frame.RTCFrame``
in Verilator) run with no Python in the per-cycle loop, so their randomness is hardware: two
16-bit Fibonacci LFSRs (taps 16, 14, 13, 11), one for input bubbles and one for back-pressure.
A stream is held (bubble / not ready) in the cycles where the LFSR's low 4 bits are below the
rate in sixteenths. The same ``seed`` gives the same LFSR seeds (:func:`lfsr_seeds`), hence the
same bubbles and the same cycle counts, in both simulators.
"""
from __future__ import annotations

from amaranth.hdl import Cat, Module, Signal, Value
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

__all__ = ["LFSR", "lfsr_next", "lfsr_seeds", "sixteenths", "passes", "feed_from_memory",
           "sink_to", "add_stall_args"]


def lfsr_seeds(seed: int, n: int = 2) -> tuple[int, ...]:
    """``n`` LFSR seeds (never 0) for ``seed``: bubbles, back-pressure, then memory holds."""
    return tuple((seed * 40503 + j * 21011) % 65535 + 1 for j in range(n))


def lfsr_next(value: int) -> int:
    """The value after ``value`` of :class:`LFSR` (one enabled cycle), for benches outside
    Amaranth that must follow the hardware's LFSR."""
    return (value >> 1) | (((value ^ value >> 2 ^ value >> 3 ^ value >> 5) & 1) << 15)


def sixteenths(rate: float, what: str = "rate") -> int:
    """``rate`` (a fraction of cycles, 0 .. 15/16) in sixteenths, as the LFSR compares it."""
    q = round(rate * 16)
    if not 0 <= q <= 15:
        raise ValueError(f"{what}={rate}: must be in [0, 15/16] (the LFSR compares 4 bits)")
    return q


class LFSR(wiring.Component):
    """16-bit Fibonacci LFSR, taps 16, 14, 13, 11: ``value`` shifts right by one each cycle
    with ``en``, taking ``value[0] ^ value[2] ^ value[3] ^ value[5]`` as its new top bit.

    Parameters: ``init`` (the value after reset; never 0 unless ``loadable``); ``loadable``: add
    a ``seed`` input, and hold ``value`` at ``seed`` in every cycle without ``en`` (the register
    is then not reset: it is loaded). Latency: the new value one cycle after ``en``.
    """

    def __init__(self, init: int = 0, *, loadable: bool = False):
        if not (0 <= init < 1 << 16 and (init or loadable)):
            raise ValueError(f"LFSR init={init}: must be in 1 .. 65535 (0 locks up) unless "
                             "the LFSR is loadable")
        self.init, self.loadable = init, loadable
        ports = {"en": In(1, init=1), "value": Out(16)}
        if loadable:
            ports["seed"] = In(16)
        super().__init__(ports)

    def elaborate(self, platform):
        m = Module()
        r = Signal(16, init=self.init, reset_less=self.loadable, name="lfsr")
        with m.If(self.en):
            m.d.sync += r.eq(Cat(r[1:], r[0] ^ r[2] ^ r[3] ^ r[5]))
        if self.loadable:
            with m.Else():
                m.d.sync += r.eq(self.seed)
        m.d.comb += self.value.eq(r)
        return m


def passes(lfsr: Value, q) -> Value:
    """True in the cycles the stream may move: the LFSR's low 4 bits are at least ``q``/16."""
    return lfsr[:4] >= q


def feed_from_memory(m: Module, stream, rd, n, go: Value) -> Value:
    """Feed ``n`` words of memory read port ``rd`` (``domain="comb"``), from address 0 on, to
    ``stream`` (we are the source): ``valid`` rises in cycles with ``go`` and then stays up until
    the transfer (stream rules). Returns the transfer count (a register)."""
    i = Signal(32) if isinstance(n, Value) else Signal(range(n + 1))
    hold = Signal()
    size = len(Value.cast(stream.payload))
    m.d.comb += [rd.addr.eq(i), stream.payload.eq(rd.data[:size]),
                 stream.valid.eq((i < n) & (hold | go))]
    m.d.sync += hold.eq(stream.valid & ~stream.ready)        # once valid, stay valid
    with m.If(stream.valid & stream.ready):
        m.d.sync += i.eq(i + 1)
    return i


def sink_to(m: Module, stream, ready: Value) -> Value:
    """Take ``stream`` (we are the sink) in the cycles with ``ready``; returns the transfer
    condition ``valid & ready``."""
    m.d.comb += stream.ready.eq(ready)
    return stream.valid & stream.ready


def add_stall_args(ap, memory: str) -> None:
    """``--stall``, ``--mem-stall`` and ``--seed`` of a frame's command line (``memory``: what
    holds its responses under ``--mem-stall``, for the help)."""
    ap.add_argument("--stall", type=float, default=0.0,
                    help="fraction of cycles the results are back-pressured (0 .. 15/16; "
                         "default 0)")
    ap.add_argument("--mem-stall", type=float, default=0.0,
                    help=f"fraction of cycles {memory} holds its responses, making the memory "
                         "latency random (0 .. 15/16; default 0)")
    ap.add_argument("--seed", type=int, default=1,
                    help="seed of the LFSRs of the random stimulus (default 1)")
