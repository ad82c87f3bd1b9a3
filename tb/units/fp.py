"""Testbenches of the FP units (rtl/fp) against the golden model (model/fp.py).

One driver serves every unit: it presents one operation per cycle with random bubbles
(``i_valid`` = 0, operand ports filled with random bits) and random stalls (``en`` = 0), keeps a
cycle-exact reference of the pipeline (a shift register of the unit's latency that moves only
when ``en`` is 1) and checks ``o_valid`` on every cycle and ``o`` on every cycle it is valid,
against the model's expected result for that operation. A mismatch raises ``AssertionError``
naming the cycle, the operands, the unit's output and the model's.
"""
from __future__ import annotations

import random
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
from amaranth.sim import Simulator

from model.fp import FPFormat
from rtl.fp import FPAdd, FPCompare, FPDiv, FPFromInt, FPMinMax, FPMul, FPSqrt
from tb.units.fp_vectors import corner_pairs

UNITS = ("add", "sub", "mul", "div", "sqrt", "cmp", "min", "max", "conv")


@dataclass
class SimResult:
    ops: int            # operations checked
    cycles: int         # simulated clock cycles
    seconds: float      # wall time of the simulation (not of building the vectors)

    @property
    def cycles_per_s(self) -> float:
        return self.cycles / self.seconds if self.seconds else float("inf")


def simulate(dut, inputs: dict[str, np.ndarray], expected: np.ndarray, *, seed: int = 0,
             p_bubble: float = 0.0, p_stall: float = 0.0, vcd: str | None = None) -> SimResult:
    """Drive ``inputs`` (port name -> array of port values, one per operation) through ``dut``
    and check every output against ``expected`` on the exact cycle it must appear."""
    L = dut.latency
    names = list(inputs)
    ports = [getattr(dut, k) for k in names]
    widths = [len(p) for p in ports]
    cols = [np.asarray(inputs[k]).astype(np.int64).tolist() for k in names]
    want = np.asarray(expected).astype(np.int64).tolist()
    n = len(want)
    o_port = dut.o.as_value() if hasattr(dut.o, "as_value") else dut.o
    rnd = random.Random(seed)
    counts = {"cycles": 0}

    def fail(cycle, idx, got):
        ops = ", ".join(f"{k}={cols[j][idx]:#x}" for j, k in enumerate(names))
        raise AssertionError(f"{type(dut).__name__}: cycle {cycle}, op #{idx} ({ops}): "
                             f"o={got:#x}, model {want[idx]:#x}")

    async def bench(ctx):
        pipe = deque([None] * L)          # pipe[-1]: the operation at the output
        i = cycle = 0
        last = None
        while i < n or any(x is not None for x in pipe):
            en = p_stall == 0.0 or rnd.random() >= p_stall
            valid = i < n and (p_bubble == 0.0 or rnd.random() >= p_bubble)
            if valid:
                for p, c in zip(ports, cols):
                    ctx.set(p, c[i])
            else:
                for p, w in zip(ports, widths):
                    ctx.set(p, rnd.getrandbits(w))
            if (valid, en) != last:        # setting a port costs time: only on a change
                ctx.set(dut.i_valid, valid)
                ctx.set(dut.en, en)
                last = (valid, en)
            head = i if (L == 0 and valid) else (pipe[-1] if L else None)
            o_valid = ctx.get(dut.o_valid)
            if o_valid != (head is not None):
                raise AssertionError(f"{type(dut).__name__}: cycle {cycle}: o_valid={o_valid}, "
                                     f"expected {int(head is not None)}")
            if head is not None:
                got = ctx.get(o_port)
                if got != want[head]:
                    fail(cycle, head, got)
            if L:
                await ctx.tick()
            else:                          # combinational: no clock domain to tick
                await ctx.delay(1e-8)
            cycle += 1
            if en:
                if L:
                    pipe.pop()
                    pipe.appendleft(i if valid else None)
                if valid:
                    i += 1
        counts["cycles"] = cycle

    sim = Simulator(dut)
    if L:
        sim.add_clock(1e-8)
    sim.add_testbench(bench)
    t0 = time.perf_counter()
    if vcd:
        with sim.write_vcd(vcd):
            sim.run()
    else:
        sim.run()
    return SimResult(n, counts["cycles"], time.perf_counter() - t0)


# ---------------------------------------------------------------------------------------------
# units, their inputs and the model's expected outputs
# ---------------------------------------------------------------------------------------------

def make_unit(kind: str, fmt: FPFormat, latency=None, regs=None, **kw):
    """The RTL unit for ``kind`` (one of UNITS); ``latency=None`` takes the unit's default."""
    cls = {"add": FPAdd, "sub": FPAdd, "mul": FPMul, "div": FPDiv, "cmp": FPCompare,
           "min": FPMinMax, "max": FPMinMax, "conv": FPFromInt, "sqrt": FPSqrt}[kind]
    args = dict(kw)
    if latency is not None:
        args["latency"] = latency
    if regs is not None:
        args["regs"] = regs
    return cls(fmt, **args)


def expected(kind: str, fmt: FPFormat, a: np.ndarray, b: np.ndarray | None = None,
             op: np.ndarray | None = None, frac_bits: int = 0) -> np.ndarray:
    """The model's output encodings for unit ``kind`` (float32 carriers ``a``, ``b``; for
    add/sub and min/max an ``op`` bit per operation; for conv integers ``a``)."""
    if kind in ("add", "sub"):
        return np.where(op != 0, fmt.to_bits(fmt.sub(a, b)), fmt.to_bits(fmt.add(a, b)))
    if kind in ("min", "max"):
        return np.where(op != 0, fmt.to_bits(fmt.max(a, b)), fmt.to_bits(fmt.min(a, b)))
    if kind == "cmp":
        return (fmt.lt(a, b).astype(np.uint32) | fmt.le(a, b).astype(np.uint32) << 1
                | fmt.eq(a, b).astype(np.uint32) << 2)
    if kind == "conv":
        return fmt.to_bits(fmt.from_fixed(a, frac_bits))
    if kind == "sqrt":
        return fmt.to_bits(fmt.sqrt(a))
    return fmt.to_bits(getattr(fmt, kind)(a, b))


def pair_inputs(kind: str, fmt: FPFormat, a: np.ndarray, b: np.ndarray, rng: np.random.Generator):
    """Port values and expected outputs for operand arrays ``a``, ``b`` (float32 carriers)."""
    a = np.asarray(a, np.float32)
    b = np.asarray(b, np.float32)
    ins = {"a": fmt.to_bits(a), "b": fmt.to_bits(b)}
    op = None
    if kind in ("add", "sub", "min", "max"):
        op = rng.integers(0, 2, a.size)
        ins["op"] = op
    return ins, expected(kind, fmt, a, b, op)


def run_random(kind: str, fmt: FPFormat, n: int, *, latency=None, regs=None, seed: int = 0,
               p_bubble: float = 0.25, p_stall: float = 0.25, **kw) -> SimResult:
    """About ``n`` corner-case and random operations (tb.units.fp_vectors.corner_pairs) with random
    bubbles and stalls."""
    dut, ins, exp = random_case(kind, fmt, n, seed=seed, latency=latency, regs=regs, **kw)
    return simulate(dut, ins, exp, seed=seed, p_bubble=p_bubble, p_stall=p_stall)


def random_case(kind: str, fmt: FPFormat, n: int, *, seed: int = 0, latency=None, regs=None,
                **kw):
    """The unit and about ``n`` corner-case and random operations for it: ``(unit, port values,
    expected outputs)`` (also what the cocotb bench, ``tb/harness/cocotb/fp.py``, drives)."""
    rng = np.random.default_rng(seed)
    dut = make_unit(kind, fmt, latency, regs, **kw)
    if kind == "conv":
        ins, exp = conv_inputs(dut, n, rng)
    elif kind == "sqrt":
        a, b = corner_pairs(fmt, n, rng)
        a = rng.permutation(np.concatenate([a, np.abs(b)]))
        ins, exp = {"a": fmt.to_bits(a)}, expected("sqrt", fmt, a)
    else:
        a, b = corner_pairs(fmt, n, rng)
        perm = rng.permutation(a.size)
        ins, exp = pair_inputs(kind, fmt, a[perm], b[perm], rng)
    return dut, ins, exp


def conv_inputs(dut: FPFromInt, n: int, rng: np.random.Generator):
    """Integers for the converter: extremes, small values, powers of two and their
    neighbours (rounding ties), and uniformly random ones."""
    w = dut.int_width
    lo, hi = (-(1 << (w - 1)), (1 << (w - 1)) - 1) if dut.signed else (0, (1 << w) - 1)
    p2 = np.array([1 << k for k in range(w - 1 if dut.signed else w)], dtype=np.int64)
    special = np.concatenate([[0, 1, lo, hi, lo + 1, hi - 1], p2, p2 - 1, p2 + 1, p2 + p2 // 2,
                              p2 * 3 // 2 + 1, -p2, -p2 - 1, -(p2 * 3 // 2)])
    rand = rng.integers(lo, hi + 1, n, dtype=np.int64, endpoint=False)
    small = rng.integers(max(lo, -4096), min(hi, 4096) + 1, n // 4)
    x = np.concatenate([special, rand, small])
    x = x[(x >= lo) & (x <= hi)]
    x = rng.permutation(x)
    bits = x & ((1 << w) - 1)
    return {"a": bits}, expected("conv", dut.fmt, x, frac_bits=dut.frac_bits)


def run_exhaustive(kind: str, fmt: FPFormat, *, latency=1, **kw) -> SimResult:
    """Every operand pair of a tiny format, one per cycle (no bubbles or stalls: the random
    runs test the flow control)."""
    n = 1 << fmt.width
    dut = make_unit(kind, fmt, latency, **kw)
    if kind == "sqrt":                               # one operand: every encoding
        bits = np.arange(n, dtype=np.uint32)
        return simulate(dut, {"a": bits}, expected("sqrt", fmt, fmt.from_bits(bits)))
    A, B = np.meshgrid(np.arange(n, dtype=np.uint32), np.arange(n, dtype=np.uint32), indexing="ij")
    a, b = fmt.from_bits(A.ravel()), fmt.from_bits(B.ravel())
    ins = {"a": A.ravel(), "b": B.ravel()}          # raw encodings: denormal and NaN payloads too
    op = None
    if kind in ("add", "sub", "min", "max"):
        op = np.full(a.size, int(kind in ("sub", "max")))
        ins["op"] = op
    return simulate(dut, ins, expected(kind, fmt, a, b, op))
