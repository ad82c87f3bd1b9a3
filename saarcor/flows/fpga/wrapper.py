"""Pin wrapper for FPGA timing runs: every input and output of a unit behind registers, 6 pins.

A unit's ports are far wider than an FPGA's pins (the RTC has ~1600 port bits; the ECP5-85k
in CABGA381 has 205 user IOs), and a port driven straight from a pin leaves its logic out of
register-to-register timing. :class:`PinWrapper` feeds all inputs from a shift chain and
captures all outputs into another, so every path of the unit starts and ends at a flip-flop
and no input is a constant that synthesis could propagate.

Pins: ``clk``; ``rst`` (registered once, then resets the unit's ``sync`` domain); ``sin``,
``load`` (``sin`` shifts into an ``n_in``-bit chain every cycle; ``load`` copies the chain into
the hold register that drives the unit's inputs); ``capture``, ``sout`` (``capture`` loads the
unit's outputs into an ``n_out``-bit chain, which otherwise shifts one bit per cycle to
``sout``). All pins are registered. Cost: ``2 * n_in + n_out + 6`` flip-flops and ``n_out``
2:1 muxes (reported separately by :func:`overhead`). It is a measurement harness, not a way
to talk to the unit at speed.
"""
from __future__ import annotations

from amaranth.hdl import Cat, ClockDomain, ClockSignal, Module, Mux, ResetInserter, Signal, Value
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

__all__ = ["PinWrapper", "port_bits", "overhead"]


def port_bits(component: wiring.Component) -> tuple[list[Value], list[Value]]:
    """(inputs, outputs) of ``component`` as flat Amaranth values, in signature order."""
    ins, outs = [], []
    for path, member, value in component.signature.flatten(component):
        (ins if member.flow == In else outs).append(Value.cast(value))
    return ins, outs


def overhead(n_in: int, n_out: int) -> dict:
    """Flip-flops the wrapper adds around a unit with ``n_in`` input and ``n_out`` output bits."""
    return {"ff": 2 * n_in + n_out + 6, "mux": n_out}


class PinWrapper(wiring.Component):
    """Registers around ``dut`` with 6 pins (see the module docstring).

    Latency: an input bit reaches the unit ``n_in + 2`` cycles after it is on ``sin`` (plus
    the ``load``); an output bit leaves on ``sout`` 2 cycles after ``capture`` plus one cycle
    per bit ahead of it. Throughput: one input bit and one output bit per cycle.
    """

    def __init__(self, dut: wiring.Component):
        self.dut = dut
        ins, outs = port_bits(dut)
        self.n_in = sum(len(v) for v in ins)
        self.n_out = sum(len(v) for v in outs)
        if self.n_in == 0 or self.n_out == 0:
            raise ValueError(f"PinWrapper: {type(dut).__name__} has {self.n_in} input and "
                             f"{self.n_out} output bits; it needs at least one of each")
        super().__init__({"clk": In(1), "rst": In(1), "sin": In(1), "load": In(1),
                          "capture": In(1), "sout": Out(1)})

    def elaborate(self, platform):
        m = Module()
        # the wrapper owns the clock; its own registers start from their init values
        m.domains.sync = ClockDomain("sync", reset_less=True)
        m.d.comb += ClockSignal("sync").eq(self.clk)

        rst_q, sin_q, load_q, cap_q, sout_q = (Signal(name=n) for n in
                                               ("rst_q", "sin_q", "load_q", "cap_q", "sout_q"))
        m.d.sync += [rst_q.eq(self.rst), sin_q.eq(self.sin), load_q.eq(self.load),
                     cap_q.eq(self.capture)]
        m.submodules.dut = ResetInserter({"sync": rst_q})(self.dut)

        ins, outs = port_bits(self.dut)
        chain = Signal(self.n_in)
        hold = Signal(self.n_in)
        m.d.sync += chain.eq(Cat(sin_q, chain[:-1]))
        with m.If(load_q):
            m.d.sync += hold.eq(chain)
        pos = 0
        for v in ins:
            m.d.comb += v.eq(hold[pos:pos + len(v)])
            pos += len(v)

        ochain = Signal(self.n_out)
        m.d.sync += [ochain.eq(Mux(cap_q, Cat(*outs), ochain >> 1)), sout_q.eq(ochain[0])]
        m.d.comb += self.sout.eq(sout_q)
        return m
