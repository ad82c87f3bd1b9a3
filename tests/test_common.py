"""Shared RTL pieces (``rtl/common.py``): the priority encoder and the round-robin pick."""
import random

import pytest
from amaranth.hdl import Module, Signal
from amaranth.sim import Simulator

from rtl.common import lowest, rr_pick


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
