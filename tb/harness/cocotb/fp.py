"""cocotb bench of the FP units' exported Verilog (``fp_add``, ``fp_mul``, ``fp_div``,
``fp_cmp``, ``fp_minmax``, ``fp_conv``), and of any fixed-latency datapath.

Pytest side: :func:`run_fp` takes the operations and the golden model's results from
``tb.units.fp.random_case`` (corner cases and random operands, the same vectors as the Amaranth
bench ``tb/units/fp.py``), exports the unit, and runs :func:`fixed_latency` in the simulator.

Simulator side: :func:`fixed_latency` drives the operations with random bubbles and stalls
(``en`` low) and checks ``o_valid`` in every cycle and every result at the exact cycle it must
appear (:class:`tb.harness.cocotb.streams.FixedLatency`). It reads the port names from its parameters,
so the intersection datapath (``tb/harness/cocotb/intersection.py``) uses it too.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

import cocotb

from tb.harness.cocotb.streams import FixedLatency, Pattern, from_ints, load, run, save, start

# tb.units.fp unit kind -> exported top (add: add and sub by the op bit; min: min and max)
TOPS = {"add": "fp_add", "mul": "fp_mul", "div": "fp_div", "cmp": "fp_cmp", "min": "fp_minmax",
        "conv": "fp_conv"}


def run_fp(kind: str, sim: str, run_dir, *, fmt=None, n: int = 300, seed: int = 0,
           p_bubble: float = 0.25, p_stall: float = 0.25, latency: int | None = None,
           **build_kw):
    """About ``n`` operations of unit ``kind`` (a key of :data:`TOPS`) through its exported
    Verilog in ``sim``; returns the :class:`tb.harness.cocotb.runner.Result` (``values``: cycles, ops,
    seconds). Raises :class:`tb.harness.cocotb.runner.BenchFailed` on any mismatch."""
    from model.config import Config
    from model.fp import BINARY32
    from tb.units.fp import random_case

    from tb.harness.cocotb.runner import build, elaborated_elsewhere
    fmt = fmt or BINARY32
    unit, ins, exp = random_case(kind, fmt, n, seed=seed, latency=latency)
    elaborated_elsewhere(unit)
    b = build(TOPS[kind], Config(fmt=fmt), sim, latency=latency, **build_kw)
    return run_fixed_latency(b, run_dir, ins, {"o": exp}, unit.latency, seed=seed,
                             p_bubble=p_bubble, p_stall=p_stall)


def run_fixed_latency(b, run_dir, inputs: dict, expect: dict, latency: int, *, seed: int = 0,
                      p_bubble: float = 0.25, p_stall: float = 0.25):
    """Run :func:`fixed_latency` on build ``b``: ``inputs`` / ``expect`` map port names to one
    value per operation (ints of at most 64 bits, or ``(n, words)`` flat vectors)."""
    from tb.harness.cocotb.runner import run as run_bench
    arrays = {f"in.{k}": _words(v) for k, v in inputs.items()}
    arrays.update({f"out.{k}": _words(v) for k, v in expect.items()})
    params = {"latency": latency, "seed": seed, "p_bubble": p_bubble, "p_stall": p_stall}
    return run_bench("fp", b, Path(run_dir), params=params, arrays=arrays)


def _words(v) -> np.ndarray:
    """One value per operation -> ``(n, words)`` uint64 (Python ints of any width too)."""
    if isinstance(v, list):
        return from_ints(v, max([1] + [int(x).bit_length() for x in v]))
    v = np.asarray(v)
    return v.astype(np.uint64).reshape(len(v), -1)


@cocotb.test()
async def fixed_latency(dut):
    """Every operation through the datapath with random bubbles and stalls; every output at
    its exact cycle, bit for bit."""
    from tb.harness.cocotb.streams import to_ints
    p, arrays = load()
    ins = {k[3:]: to_ints(v) for k, v in arrays.items() if k.startswith("in.")}
    expect = {k[4:]: to_ints(v) for k, v in arrays.items() if k.startswith("out.")}
    seed = p["seed"]
    unit = FixedLatency(dut, ins, expect, p["latency"], bubble=Pattern(p["p_bubble"], seed),
                        stall=Pattern(p["p_stall"], seed + 1),
                        rng=np.random.default_rng(seed + 2))
    await start(dut)
    t0 = time.perf_counter()
    cycles = await run(dut, [unit], lambda: unit.done, quiet=1000)
    seconds = time.perf_counter() - t0
    assert unit.checked == unit.n, f"{unit.checked} of {unit.n} results seen"
    save(cycles=cycles, ops=unit.checked, seconds=seconds)
