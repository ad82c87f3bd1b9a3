"""Where a unit's cycles go: every cycle of a unit counted as working, waiting for memory,
blocked by the next unit or starved of input — counters in the chip (they cost no cycle and the
Verilog keeps them), so a frame's summary names the measured limiter.

A cycle of the unit is, in this order of precedence:

* **work**: the unit did an operation (its op counter advanced: a trav-op, a list word, a
  triangle test);
* **memory**: else it waits for memory: a request of its memory port is outstanding (accepted,
  not yet answered) or offered and not taken;
* **blocked**: else its output holds a transfer the next unit does not take (back-pressure);
* **starved**: else it has nothing to do (no input).

The op counter advances a cycle after the operation (it is a register), so the unit's memory and
output conditions are registered once to line up: cycle ``t`` is counted in cycle ``t + 1``.
Over a frame ``work + memory + blocked + starved`` is the cycles since reset less one (the last
cycle is counted the cycle after).
"""
from __future__ import annotations

from amaranth.hdl import Cat, Module, Signal
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from .common import COUNTER_BITS

__all__ = ["StallCounters", "REASONS"]

REASONS = ("work", "memory", "blocked", "starved")
"""The counters of :class:`StallCounters`, in precedence order."""


class StallCounters(wiring.Component):
    """The four counters of one unit (see the module docstring).

    Ports (In): ``ops`` (the unit's op counter), per memory port ``req_valid[i]``,
    ``req_ready[i]``, ``resp[i]`` (a response transfer), ``out_valid``, ``out_ready`` (its
    output stream; a unit with several outputs gives ``out_valid & ~out_ready`` of any). Out:
    ``work``, ``memory``, ``blocked``, ``starved`` (``COUNTER_BITS`` each).
    ``outstanding_bits``: the width of the outstanding-request count (at least the unit's most
    requests in flight); ``ports``: its memory ports (0: none, never waiting for memory).
    Latency: a cycle is counted one cycle later; no effect on the unit.
    """

    def __init__(self, outstanding_bits: int = 10, ports: int = 1):
        self.outstanding_bits, self.ports = outstanding_bits, ports
        mem = ({"req_valid": In(1).array(ports), "req_ready": In(1).array(ports),
                "resp": In(1).array(ports)} if ports else {})
        super().__init__({
            "ops": In(COUNTER_BITS), **mem, "out_valid": In(1), "out_ready": In(1),
            **{r: Out(COUNTER_BITS) for r in REASONS}})

    def elaborate(self, platform):
        m = Module()
        outstanding = Signal(self.outstanding_bits)
        waiting = Signal()
        if self.ports:
            ps = range(self.ports)
            issued = sum(self.req_valid[i] & self.req_ready[i] for i in ps)
            answered = sum(self.resp[i] for i in ps)
            m.d.sync += outstanding.eq(outstanding + issued - answered)
            offered = Cat(*(self.req_valid[i] & ~self.req_ready[i] for i in ps)).any()
            m.d.comb += waiting.eq((outstanding != 0) | offered)
        blocked = self.out_valid & ~self.out_ready
        # the conditions of cycle t beside the op counter's change in cycle t
        waiting_q, blocked_q = Signal(), Signal()
        ops_q, started = Signal(COUNTER_BITS), Signal()
        m.d.sync += [waiting_q.eq(waiting), blocked_q.eq(blocked), ops_q.eq(self.ops),
                     started.eq(1)]
        with m.If(started):
            with m.If(self.ops != ops_q):
                m.d.sync += self.work.eq(self.work + 1)
            with m.Elif(waiting_q):
                m.d.sync += self.memory.eq(self.memory + 1)
            with m.Elif(blocked_q):
                m.d.sync += self.blocked.eq(self.blocked + 1)
            with m.Else():
                m.d.sync += self.starved.eq(self.starved + 1)
        return m
