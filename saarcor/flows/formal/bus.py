"""Formal harness for :class:`rtl.bus.RoundRobinBus`: the bus between free requesters and a free
memory, with its properties as Amaranth ``Assert`` statements.

The environment is unconstrained except for ``Assume`` statements that encode the port rules
(``docs/memory-interface.md``): every input stream (requests, memory responses) keeps ``valid``
and its payload until the transfer; a requester has at most ``max_pending`` requests of one tag
outstanding; the memory answers only requests it holds (labels ``{tag, id}`` it was given and has
not answered yet, each at most once). ``ready`` inputs are free. There is no reset after cycle 0.

Properties (``BusFormal.props`` maps each name to its source lines, ``BusFormal.names`` turns
the lines smtbmc reports back into names):

* ``one_grant``: at most one request is granted per cycle.
* ``fair``: while requester ``i`` holds a request, at most ``n - 1`` grants go to others.
* ``conserve``: for every label ``L = {tag, id}``, the requests of ``id`` with ``tag`` not yet
  answered equal the copies of ``L`` in flight: in the output register + held by the memory +
  in the broadcast register. So every response reaches the requester that asked, exactly once
  (a lost, duplicated or misrouted response breaks the count of its label).
* ``one_hot``: the response broadcast is ``valid`` at exactly the requester named by the label
  of the response last taken from memory, with that response's tag and data (and never two).
* ``req_payload``: the memory sees the address and ``{tag, id}`` of the request last granted.
* ``stream_out``: the bus keeps its outputs (``mem.req``, each ``resp``) until they are taken.

Helper invariants for k-induction (``helpers=True``, round-robin only): the internal grant pointer
``prio`` is ``< n`` and ``fair_count[i] + ((i - prio) mod n) <= n - 1`` (every grant to another
requester moves the pointer closer to a waiting one). They read ``prio`` inside the bus; if it is
renamed, :func:`internal_signal` says so.

Covers (``mode="cover"``; guard against vacuous proofs): each requester takes a response; each
requester waits for exactly ``n - 1`` other grants; one label is outstanding ``max_pending`` times.

Run: ``saarcor formal [--mode bmc|prove|cover] [--depth K] [--n N] [--policy fixed] [--keep DIR]``.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from amaranth.asserts import AnySeq    # 0.5: not re-exported by amaranth.hdl
from amaranth.hdl import (Assert, Assume, Cat, ClockDomain, Const, Cover, Elaboratable, Module,
                          Mux, Signal)

from rtl.bus import RoundRobinBus
from saarcor.flows.formal.smtbmc import run_smtbmc

__all__ = ["BusFormal", "internal_signal", "check_bus"]


def internal_signal(module: Module, name: str) -> Signal:
    """The signal called ``name`` driven in the elaborated ``module`` (for helper invariants)."""
    found = [s for s in module._driving.keys() if s.name == name]
    if len(found) != 1:
        raise LookupError(f"expected one signal named {name!r} in {type(module).__name__}, found "
                          f"{len(found)}: saarcor/flows/formal/bus.py reads the bus's internal {name!r} for "
                          "its induction invariants; update the name there")
    return found[0]


class BusFormal(Elaboratable):
    """``RoundRobinBus(n, ...)`` inside free stimulus with ``Assume`` port rules and ``Assert``
    properties (module docstring). Small widths keep the solver fast; the properties do not
    depend on them. ``bus_cls``: a subclass of :class:`RoundRobinBus` (tests use broken ones to
    show that each property can fail)."""

    def __init__(self, n: int = 3, *, tag_width: int = 1, addr_width: int = 2,
                 data_width: int = 2, policy: str = "round_robin", max_pending: int = 3,
                 helpers: bool | None = None, bus_cls=RoundRobinBus):
        if n < 2 or max_pending < 1:
            self._MustUse__silence = True       # no "never used" warning for a rejected harness
        if n < 2:
            raise ValueError(f"BusFormal n={n}: need at least two requesters to check arbitration")
        if max_pending < 1:
            raise ValueError(f"BusFormal max_pending={max_pending}: must be >= 1")
        self.n, self.tag_width, self.max_pending = n, tag_width, max_pending
        self.helpers = (policy == "round_robin") if helpers is None else helpers
        self.bus = bus_cls(n, addr_width=addr_width, tag_width=tag_width,
                                 data_width=data_width, policy=policy)
        self.props: dict[str, set] = {}     # property name -> {"file.py:line", ...}
        self.sync = ClockDomain("sync", reset_less=True)   # reset only by the initial state
        self.ports = [self.sync.clk]        # top-level ports for rtlil.convert

    def names(self, locations) -> set[str]:
        """Property names of smtbmc's ``file:line`` locations (``SmtbmcResult.failed``)."""
        found = {Path(loc).name for loc in locations}
        return {name for name, lines in self.props.items() if lines & found}

    def _check(self, m, kind, name, test):
        stmt = kind(test, src_loc_at=1)
        file, line = stmt.src_loc
        self.props.setdefault(name, set()).add(f"{Path(file).name}:{line}")
        m.d.comb += stmt

    @staticmethod
    def _held(m, s):
        """1 in a cycle where stream ``s`` broke the rules: ``valid`` was high and not taken in
        the previous cycle, and now ``valid`` dropped or the payload changed."""
        waiting = Signal()
        prev = Signal(len(s.payload.as_value()))
        m.d.sync += [waiting.eq(s.valid & ~s.ready), prev.eq(s.payload.as_value())]
        return waiting & ~(s.valid & (s.payload.as_value() == prev))

    def elaborate(self, platform):
        m = Module()
        m.domains.sync = self.sync
        n, tw, bus = self.n, self.tag_width, self.bus
        ins, mem = bus.inputs, bus.mem
        m.submodules.bus = bm = bus.elaborate(platform)   # a Module, to reach its internals
        bus._MustUse__used = True

        # --- free environment -------------------------------------------------------------
        for p in ins:
            m.d.comb += [p.req.valid.eq(AnySeq(1)),
                         p.req.payload.eq(AnySeq(len(p.req.payload.as_value()))),
                         p.resp.ready.eq(AnySeq(1))]
        m.d.comb += [mem.req.ready.eq(AnySeq(1)), mem.resp.valid.eq(AnySeq(1)),
                     mem.resp.payload.eq(AnySeq(len(mem.resp.payload.as_value())))]
        for s in [p.req for p in ins] + [mem.resp]:
            self._check(m, Assume, "stream_in", ~self._held(m, s))
        for s in [p.resp for p in ins] + [mem.req]:
            self._check(m, Assert, "stream_out", ~self._held(m, s))

        def fire(s):
            return s.valid & s.ready

        # --- at most one grant per cycle ---------------------------------------------------
        grants = [fire(p.req) for p in ins]
        self._check(m, Assert, "one_grant", sum(grants) <= 1)

        # --- fairness ----------------------------------------------------------------------
        fair = [Signal(range(n + 1), name=f"fair_count{i}") for i in range(n)]
        for i, p in enumerate(ins):
            others = sum(g for j, g in enumerate(grants) if j != i) != 0
            with m.If(~p.req.valid | p.req.ready):
                m.d.sync += fair[i].eq(0)
            with m.Elif(others & (fair[i] != n)):
                m.d.sync += fair[i].eq(fair[i] + 1)
            self._check(m, Assert, "fair", fair[i] <= n - 1)
            self._check(m, Cover, "cover_fair_bound", fair[i] == n - 1)
        if self.helpers:
            prio = internal_signal(bm, "prio")
            self._check(m, Assert, "helper_prio", prio < n)
            for i in range(n):
                dist = Mux(prio <= i, i - prio, i + n - prio)
                self._check(m, Assert, "helper_fair", fair[i] + dist <= n - 1)

        # --- request payload --------------------------------------------------------------
        last_req = Signal(len(mem.req.payload.as_value()))
        for i, p in enumerate(ins):
            with m.If(fire(p.req)):
                m.d.sync += last_req.eq(Cat(p.req.payload.addr, p.req.payload.tag,
                                            Const(i, bus.id_bits)))
        self._check(m, Assert, "req_payload",
                    ~mem.req.valid | (mem.req.payload.as_value() == last_req))

        # --- memory: answers only labels it holds -----------------------------------------
        labels = n << tw
        rtag = mem.resp.payload.tag
        self._check(m, Assume, "mem_labels", ~mem.resp.valid | (rtag[tw:] < n))
        count_bits = range(self.max_pending + 1)
        in_mem = [Signal(count_bits, name=f"in_mem{l}") for l in range(labels)]
        pending = [Signal(count_bits, name=f"pending{l}") for l in range(labels)]
        for l in range(labels):
            i, t = l >> tw, l & ((1 << tw) - 1)
            up = fire(mem.req) & (mem.req.payload.tag == l)
            down = fire(mem.resp) & (rtag == l)
            m.d.sync += in_mem[l].eq(in_mem[l] + up - down)
            self._check(m, Assume, "mem_holds", ~(mem.resp.valid & (rtag == l)) | (in_mem[l] != 0))

            p = ins[i]
            sent = fire(p.req) & (p.req.payload.tag == t)
            got = fire(p.resp) & (p.resp.payload.tag == t)
            m.d.sync += pending[l].eq(pending[l] + sent - got)
            self._check(m, Assume, "max_pending", ~(p.req.valid & (p.req.payload.tag == t)) |
                        (pending[l] < self.max_pending))
            in_out = mem.req.valid & (mem.req.payload.tag == l)
            in_bcast = p.resp.valid & (p.resp.payload.tag == t)
            self._check(m, Assert, "conserve", pending[l] == in_out + in_mem[l] + in_bcast)
        self._check(m, Cover, "cover_max_pending", pending[0] == self.max_pending)

        # --- response broadcast: one-hot, the label's requester, the memory's data --------
        b_valid = Signal()
        b_resp = Signal.like(mem.resp.payload)
        with m.If(fire(mem.resp)):
            m.d.sync += [b_valid.eq(1), b_resp.eq(mem.resp.payload)]
        with m.Elif(sum(fire(p.resp) for p in ins) != 0):
            m.d.sync += b_valid.eq(0)
        self._check(m, Assert, "one_hot", sum(p.resp.valid for p in ins) <= 1)
        for i, p in enumerate(ins):
            self._check(m, Assert, "one_hot", p.resp.valid == (b_valid & (b_resp.tag[tw:] == i)))
            self._check(m, Assert, "one_hot", ~p.resp.valid |
                        ((p.resp.payload.tag == b_resp.tag[:tw]) &
                         (p.resp.payload.data == b_resp.data)))
            self._check(m, Cover, "cover_response", fire(p.resp))
        return m


def check_bus(mode: str = "bmc", depth: int = 20, *, workdir=None, **kwargs):
    """Build :class:`BusFormal` (``kwargs``) and run SMT-BMC on it; returns ``(harness, result)``
    (:class:`saarcor.flows.formal.smtbmc.SmtbmcResult`; ``result.failed`` lists the source lines of
    failed assertions, see ``harness.props``)."""
    h = BusFormal(**kwargs)
    return h, run_smtbmc(h, ports=h.ports, mode=mode, depth=depth, name="bus_formal",
                         workdir=workdir)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="saarcor formal",
                                 description="Formal checks of the round-robin bus (SMT-BMC, "
                                 "yices). Exit status 1 if a property fails.")
    ap.add_argument("--mode", choices=["bmc", "prove", "cover"], default="bmc",
                    help="bmc: bounded model check; prove: k-induction; cover: the covers are "
                         "reached (default bmc)")
    ap.add_argument("--depth", type=int, default=None,
                    help="BMC/cover steps, or k for k-induction (default 20 / 20 / 4)")
    ap.add_argument("--n", type=int, default=3, help="requesters (default 3)")
    ap.add_argument("--tag-width", type=int, default=1, help="tag bits (default 1)")
    ap.add_argument("--policy", choices=["round_robin", "fixed"], default="round_robin",
                    help="arbitration (default round_robin; fixed priority fails 'fair')")
    ap.add_argument("--keep", metavar="DIR", default=None,
                    help="directory to keep the model, log and trace in")
    a = ap.parse_args(argv)
    depth = a.depth if a.depth is not None else {"bmc": 20, "prove": 4, "cover": 20}[a.mode]
    h, r = check_bus(a.mode, depth, workdir=a.keep, n=a.n, tag_width=a.tag_width,
                     policy=a.policy)
    print(f"{a.mode} depth {depth}, n={a.n}, policy={a.policy}: "
          f"{'PASSED' if r.passed else 'FAILED'} in {r.seconds:.1f} s")
    for loc in r.failed:
        print(f"  {'unreached' if a.mode == 'cover' else 'failed'}: "
              f"{', '.join(sorted(h.names([loc]))) or '?'} ({loc})")
    return 0 if r.passed else 1


if __name__ == "__main__":
    raise SystemExit(main())
