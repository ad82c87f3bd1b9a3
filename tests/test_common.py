"""Shared RTL pieces (``rtl/common.py``): the priority encoder, the round-robin pick, the
constant multiply, the stream register and the two-write-port memory."""
import random

import pytest
from amaranth.hdl import Array, Cat, Module, Signal
from amaranth.sim import Simulator

from rtl.common import (PacketMemory, SkidBuffer, TwoWriteMemory, lowest, rr_pick,
                        rr_pick_next, rr_pick_onehot, times_const)
from tb.harness.common import drain, drive, run


@pytest.mark.parametrize("n", [1, 2, 3, 5, 8, 9, 17, 32, 64])
def test_lowest_is_a_priority_encoder(n):
    """Every input up to 9 bits, random and one-hot ones above: ``any`` and the index of the
    lowest set bit (0 when no bit is set)."""
    m = Module()
    bits = Signal(n)
    anyb, idx = lowest(m, bits, "t")
    rng = random.Random(n)
    vals = list(range(1 << n)) if n <= 9 else \
        [rng.getrandbits(n) for _ in range(200)] + [1 << j for j in range(n)] + [0, (1 << n) - 1]
    got = []

    async def tb(ctx):
        for v in vals:
            ctx.set(bits, v)
            got.append((ctx.get(anyb), ctx.get(idx)))

    sim = Simulator(m)
    sim.add_testbench(tb)
    sim.run()
    assert got == [(int(v != 0), (v & -v).bit_length() - 1 if v else 0) for v in vals]


def test_rr_pick_starts_at_the_pointer():
    """The first requesting index at or after the pointer, wrapping around."""
    m = Module()
    req, ptr = Signal(8), Signal(3)
    anyb, idx = rr_pick(m, req, ptr, "t")
    cases = [(r, p) for r in (0, 1, 0x80, 0x81, 0x5A, 0xFF, 0x10) for p in range(8)]
    got = []

    async def tb(ctx):
        for r, p in cases:
            ctx.set(req, r)
            ctx.set(ptr, p)
            got.append((ctx.get(anyb), ctx.get(idx)))

    sim = Simulator(m)
    sim.add_testbench(tb)
    sim.run()
    want = [(1, next((p + i) % 8 for i in range(8) if r >> ((p + i) % 8) & 1)) if r else (0, None)
            for r, p in cases]
    assert [(a, i if a else None) for a, i in got] == want


def _rr_ref(r, p, n=8):
    return next(((p + i) % n for i in range(n) if r >> ((p + i) % n) & 1), None)


def test_rr_pick_onehot_is_the_pick():
    """The one-hot form of the round-robin pick, for every request vector and pointer."""
    m = Module()
    req, ptr = Signal(8), Signal(3)
    oh = Signal(8)
    m.d.comb += oh.eq(rr_pick_onehot(req, ptr))
    got = []

    async def tb(ctx):
        for r in range(256):
            for p in range(8):
                ctx.set(req, r)
                ctx.set(ptr, p)
                got.append(ctx.get(oh))

    sim = Simulator(m)
    sim.add_testbench(tb)
    sim.run()
    want = [0 if _rr_ref(r, p) is None else 1 << _rr_ref(r, p)
            for r in range(256) for p in range(8)]
    assert got == want


@pytest.mark.parametrize("copies", [1, 2])
def test_rr_pick_next_leaves_out_the_taken_request(copies):
    """``rr_pick_next``: the pick of the cycle after, from the requests then, less the one
    picked in this cycle when ``drop`` (a handshake) is high in this cycle; ``select`` reads
    the picked element with either copy of the registered picks."""
    m = Module()
    req, ptr, drop = Signal(8), Signal(3), Signal()
    anyb, idx, oh, select = rr_pick_next(m, req, ptr, drop, "t", copies=copies)
    # select(): the picked element of an Array and the picked bit of a Value
    words = Array(Signal(16, name=f"w{t}") for t in range(8))
    bits = Signal(8)
    w_sel, b_sel = Signal(16), Signal()
    m.d.comb += [w_sel.eq(select(words)), b_sel.eq(select(bits, copies - 1))]
    rng = random.Random(5)
    steps = [(rng.randrange(256), rng.randrange(8), rng.randrange(2)) for _ in range(400)]
    got = []

    async def tb(ctx):
        for r, p, d in steps:
            ctx.set(req, r)
            ctx.set(ptr, p)
            ctx.set(drop, d)
            ctx.set(bits, rng.getrandbits(8))
            for w in words:
                ctx.set(w, rng.getrandbits(16))
            i = ctx.get(idx)
            assert ctx.get(w_sel) == ctx.get(words[i])
            if copies == 1 or ctx.get(anyb):    # copy 1 resets elsewhere: no pick then
                assert ctx.get(b_sel) == (ctx.get(bits) >> i) & 1
            got.append((ctx.get(anyb), i, ctx.get(oh)))
            await ctx.tick()

    sim = Simulator(m)
    sim.add_clock(1e-6)
    sim.add_testbench(tb)
    sim.run()
    # reference: this cycle's pick comes from last cycle's requests, less last cycle's pick
    # when last cycle dropped it
    prev_pick = None
    for k in range(1, len(steps)):
        r, p, d = steps[k - 1]
        if d and prev_pick is not None:
            r &= ~(1 << prev_pick)
        want = _rr_ref(r, p)
        a, i, o = got[k]
        assert (a, i if a else None, o) == (int(want is not None), want,
                                            0 if want is None else 1 << want), k
        prev_pick = i if a else None


def test_rr_pick_next_copies_survive_synthesis():
    """``copies=2``: Yosys's synth_ecp5 keeps the second copy of the registered picks (it
    resets to other values, so it is not merged into the first), and each copy drives its
    own half of a wide select."""
    from amaranth.lib import wiring
    from amaranth.lib.wiring import In, Out
    from tb.harness.common import synth_ecp5_json

    class Top(wiring.Component):
        def __init__(self):
            super().__init__({"req": In(8), "ptr": In(3), "drop": In(1),
                              **{f"w{t}": In(32) for t in range(8)}, "q": Out(32)})

        def elaborate(self, platform):
            m = Module()
            _, _, _, select = rr_pick_next(m, self.req, self.ptr, self.drop, "t", copies=2)
            words = Array(getattr(self, f"w{t}") for t in range(8))
            m.d.sync += self.q.eq(Cat(select(words, 0)[:16], select(words, 1)[16:]))
            return m

    cells = synth_ecp5_json(Top())["modules"]["top"]["cells"]
    ffs = [n for n, c in cells.items() if c["type"] == "TRELLIS_FF"]
    for reg in ("t_pick_q", "t_less_pick_q", "t_drop_q"):
        assert any(f"{reg}_" in n or n.endswith(reg) for n in ffs), reg
        assert any(f"{reg}1" in n for n in ffs), f"{reg}1 merged away"


@pytest.mark.parametrize("k", [0, 1, 2, 3, 5, 7, 10, 64, 255])
def test_times_const_multiplies(k):
    """``v * k`` as shifts and adds: random 20-bit values and the extremes, wide enough for
    the whole product."""
    m = Module()
    v, o = Signal(20), Signal(29)
    m.d.comb += o.eq(times_const(v, k))
    rng = random.Random(k)
    vals = [0, 1, (1 << 20) - 1] + [rng.getrandbits(20) for _ in range(100)]
    got = []

    async def tb(ctx):
        for x in vals:
            ctx.set(v, x)
            got.append(ctx.get(o))

    sim = Simulator(m)
    sim.add_testbench(tb)
    sim.run()
    assert got == [x * k for x in vals]
    with pytest.raises(ValueError, match="k=-1"):
        times_const(v, -1)


@pytest.mark.parametrize("idle,stall", [(0.0, 0.0), (0.3, 0.0), (0.0, 0.5), (0.3, 0.6)])
def test_skid_buffer_passes_every_payload_in_order(idle, stall):
    """Random bubbles and back-pressure: every payload once, in order; with neither, each
    one cycle after it was taken, one a cycle."""
    dut = SkidBuffer(8)
    src, snk = random.Random(1), random.Random(2)
    vals = [src.getrandbits(8) for _ in range(300)]
    sent, got = [], []

    async def source(ctx):
        sent.extend(await drive(ctx, dut.i, vals, rng=src, idle=idle))

    run(dut, source, lambda ctx: drain(ctx, dut.o, len(vals), rng=snk, stall=stall, out=got))
    assert [p for _, p in got] == vals
    if idle == stall == 0:
        assert sent == list(range(sent[0], sent[0] + len(vals)))
        assert [c for c, _ in got] == [c + 1 for c in sent]


def test_skid_buffer_ready_does_not_follow_the_consumer():
    """``i.ready`` is a register: within a cycle it does not change with ``o.ready`` (an
    :class:`~rtl.common.OutputStage` would pass ``o.ready`` through)."""
    dut = SkidBuffer(8)
    seen = []

    async def tb(ctx):
        ctx.set(dut.i.valid, 1)
        for cycle in range(8):
            ctx.set(dut.i.payload, cycle)
            ctx.set(dut.o.ready, 0)
            r0 = ctx.get(dut.i.ready)
            ctx.set(dut.o.ready, 1)
            r1 = ctx.get(dut.i.ready)
            ctx.set(dut.o.ready, cycle >= 4)       # the consumer stalls, then takes
            seen.append((r0, r1, ctx.get(dut.o.valid), ctx.get(dut.o.payload)))
            await ctx.tick()

    sim = Simulator(dut)
    sim.add_clock(1e-8)
    sim.add_testbench(tb)
    sim.run()
    assert all(r0 == r1 for r0, r1, _, _ in seen), seen
    # 0 taken into o, 1 into the skid, then ready low until the output moves in cycle 4
    assert [r for r, _, _, _ in seen] == [1, 1, 0, 0, 0, 1, 1, 1]
    assert [(v, p) for _, _, v, p in seen][1:] == [(1, 0)] * 4 + [(1, 1), (1, 5), (1, 6)]


@pytest.mark.parametrize("kind", [TwoWriteMemory, PacketMemory])
def test_two_write_memory_reads_as_one_memory_with_two_write_ports(kind):
    """Each port owns blocks for a while (never both the same block), writes words of them,
    often the word being read and both ports in one cycle; a block changes owner from time to
    time; every word read was written since its block's owner took it (the slave's use) and
    the read enable is random: every cycle the same read data as a ``lib.memory.Memory`` with
    two write ports and a read port beside it. Both builds of the slave's ray store and
    pending buffers (``Config.rgs_store``): two banks and a live-value table, a bank per
    block."""
    from amaranth.lib import data
    from amaranth.lib.memory import Memory
    layout = data.StructLayout({"a": 5, "b": 7})
    depth, block = 16, 4
    m = Module()
    m.submodules.dut = dut = kind(layout, depth, block)
    m.submodules.ref = ref = Memory(shape=layout, depth=depth, init=[])
    rw = [ref.write_port(), ref.write_port()]
    rr = ref.read_port()
    for p, q in zip(dut.w, rw):
        m.d.comb += [q.addr.eq(p.addr), q.data.eq(p.data), q.en.eq(p.en)]
    m.d.comb += [rr.addr.eq(dut.r.addr), rr.en.eq(dut.r.en)]
    rng = random.Random(5)
    pairs = []

    async def tb(ctx):
        owner = [b % 2 for b in range(depth // block)]
        written = set()                      # words written since their block's owner took it
        for _ in range(3000):
            if rng.random() < 0.05:          # a block changes owner: its words are stale
                b = rng.randrange(depth // block)
                owner[b] ^= 1
                written -= set(range(b * block, b * block + block))
            readable = sorted(written)
            ra = rng.choice(readable) if readable and rng.random() < 0.9 else None
            for i, p in enumerate(dut.w):
                mine = [b for b in range(depth // block) if owner[b] == i]
                en = bool(mine) and rng.random() < 0.6
                a = ra if en and ra is not None and owner[ra // block] == i and \
                    rng.random() < 0.3 else \
                    (rng.choice(mine) * block + rng.randrange(block) if mine else 0)
                ctx.set(p.addr, a)
                ctx.set(p.data.as_value(), rng.getrandbits(12))
                ctx.set(p.en, en)
                if en:
                    written.add(a)
            ctx.set(dut.r.addr, ra if ra is not None else 0)
            ctx.set(dut.r.en, ra is not None and rng.random() < 0.8)
            await ctx.tick()
            pairs.append((ctx.get(dut.r.data.as_value()), ctx.get(rr.data.as_value())))

    sim = Simulator(m)
    sim.add_clock(1e-8)
    sim.add_testbench(tb)
    sim.run()
    assert pairs == [(b, b) for _, b in pairs] and len({b for _, b in pairs}) > 100


@pytest.mark.parametrize("kind", [TwoWriteMemory, PacketMemory])
def test_two_write_memory_block_must_divide_the_depth(kind):
    for block in (0, 3, 32):
        with pytest.raises(ValueError, match="block"):
            kind(8, 16, block)


@pytest.mark.parametrize("poison", [False, True])
def test_block_ram_poisons_colliding_reads_only_when_asked(monkeypatch, poison):
    """Random reads and writes, often to the row being read, with random read enables: every
    read returns what a plain ``Memory`` returns, except (with ``SAARCOR_RAM_POISON=1``) a read
    of a row written in its cycle, which returns the row inverted, held while the enable is
    low."""
    from amaranth.lib import data
    from amaranth.lib.memory import Memory
    from rtl.common import BlockRAM, POISON_ENV
    monkeypatch.setenv(POISON_ENV, "1" if poison else "0")
    layout = data.StructLayout({"a": 5, "b": 7})
    m = Module()
    m.submodules.dut = dut = BlockRAM(shape=layout, depth=8)
    m.submodules.ref = ref = Memory(shape=layout, depth=8, init=[])
    dw, dr = dut.write_port(), dut.read_port()
    rw, rr = ref.write_port(), ref.read_port()
    rng = random.Random(9)
    seen = []

    async def tb(ctx):
        hit = False
        for _ in range(2000):
            wa, ra = rng.randrange(8), rng.randrange(8)
            if rng.random() < 0.3:
                ra = wa
            we, re, wd = rng.random() < 0.6, rng.random() < 0.7, rng.getrandbits(12)
            for w in (dw, rw):
                ctx.set(w.addr, wa)
                ctx.set(w.data.as_value(), wd)
                ctx.set(w.en, we)
            for r in (dr, rr):
                ctx.set(r.addr, ra)
                ctx.set(r.en, re)
            if re:
                hit = we and wa == ra
            await ctx.tick()
            seen.append((hit, ctx.get(dr.data.as_value()), ctx.get(rr.data.as_value())))

    sim = Simulator(m)
    sim.add_clock(1e-8)
    sim.add_testbench(tb)
    sim.run()
    assert sum(h for h, _, _ in seen) > 100
    assert all(d == (r ^ 0xfff if poison and h else r) for h, d, r in seen)


def test_block_ram_needs_synchronous_opaque_reads():
    from amaranth.back import rtlil
    from rtl.common import BlockRAM

    def convert(transparent=False, domain="sync"):
        m = Module()
        m.submodules.mem = mem = BlockRAM(shape=4, depth=4)
        w = mem.write_port()
        r = mem.read_port(domain=domain, transparent_for=(w,) if transparent else ())
        return rtlil.convert(m, ports=[w.addr, w.data, w.en, r.addr, r.data])
    for kw in ({"domain": "comb"}, {"transparent": True}):
        with pytest.raises(ValueError, match="synchronous and not transparent"):
            convert(**kw)
    assert "no_rw_check" in convert()
