"""Testbench for ``tb/harness/memory.py``: data and tags, exact latency, SDRAM bandwidth per chip.

Also :func:`random_memory`, a testbench-side memory answering a word port in random order after
random delays (used by the cache and bus testbenches to stress their fill/broadcast logic).
"""
from __future__ import annotations

import random
from dataclasses import dataclass

import numpy as np

from tb.harness.memory import IdealMemory, SDRAMMemory, chip_of

from tb.harness.common import drain, drive, run

__all__ = ["random_memory", "MemoryRun", "run_memory", "sdram_bandwidth"]


async def random_memory(ctx, port, image, rng: random.Random, *, max_delay: int = 30,
                        stall: float = 0.3, log: list | None = None) -> None:
    """Serve ``port`` (server side of a word MemReadPort) from ``image``: each response after a
    random 1..``max_delay`` cycles, due responses in random order, requests back-pressured with
    probability ``stall``. Runs forever (add as a background testbench)."""
    pending, current, cycle = [], None, 0
    while True:
        ctx.set(port.req.ready, int(rng.random() >= stall))
        if current is None:
            due = [p for p in pending if p[0] <= cycle]
            if due:
                current = rng.choice(due)
                pending.remove(current)
        if current is not None:
            ctx.set(port.resp.payload, {"data": current[2], "tag": current[1]})
        ctx.set(port.resp.valid, int(current is not None))
        _, _, qv, qr, qp, sv, sr = await ctx.tick().sample(
            port.req.valid, port.req.ready, port.req.payload, port.resp.valid, port.resp.ready)
        if qv and qr:
            addr, tag = int(qp.addr), int(qp.tag)
            pending.append((cycle + rng.randint(1, max_delay), tag, int(image[addr])))
            if log is not None:
                log.append(addr)
        if sv and sr:
            current = None
        cycle += 1


@dataclass
class MemoryRun:
    sent: list            # cycle each request was accepted
    responses: list       # (cycle, {"data", "tag"}) in arrival order
    counters: dict        # hardware counters at the end


def run_memory(dut, addrs, *, seed: int = 0, idle: float = 0.0, stall: float = 0.0,
               tag_width: int | None = None) -> MemoryRun:
    """Send word reads ``addrs`` to ``dut`` (IdealMemory or SDRAMMemory), tags = request index
    modulo 2**tag_width, and collect every response."""
    rng = random.Random(seed)
    tw = len(dut.port.req.payload.tag) if tag_width is None else tag_width
    reqs = [{"addr": int(a), "tag": i % (1 << tw)} for i, a in enumerate(addrs)]
    sent, got, counters = [], [], {}

    async def source(ctx):
        sent.extend(await drive(ctx, dut.port.req, reqs, rng=rng, idle=idle))

    async def sink(ctx):
        await drain(ctx, dut.port.resp, len(reqs), rng=rng, stall=stall, out=got,
                    timeout=5_000)
        if isinstance(dut, IdealMemory):
            counters["reads"] = ctx.get(dut.reads)
        else:
            counters["words"] = [ctx.get(w) for w in dut.words]
            counters["busy"] = [ctx.get(b) for b in dut.busy]
            counters["cycles"] = ctx.get(dut.cycles)

    run(dut, source, sink)
    return MemoryRun(sent=sent, responses=got, counters=counters)


def sdram_bandwidth(chips: int, n_words: int, *, pattern: str = "spread", chip_bits: int = 16,
                    clock_ratio: int = 4, latency: int = 20, chip_queue: int = 4,
                    seed: int = 0) -> dict:
    """Stream ``n_words`` back-to-back reads into an SDRAMMemory and measure sustained bandwidth.

    ``pattern``: "spread" (consecutive words: every chip equally loaded), "random" (random
    words), "hot" (every read to chip 0). Bandwidth in bits per chip cycle: total over the window
    from the first to the last response, and per chip between its own first and last response.
    Also checks every response's data and tag (AssertionError on a mismatch).
    """
    rng = np.random.default_rng(seed)
    size = 4096
    image = rng.integers(0, 1 << 63, size, dtype=np.uint64)
    if pattern == "spread":
        addrs = np.arange(n_words) % size
    elif pattern == "random":
        addrs = rng.integers(0, size, n_words)
    elif pattern == "hot":
        cand = np.arange(size)
        cand = cand[chip_of(cand, chips) == 0]
        addrs = cand[np.arange(n_words) % len(cand)]
    else:
        raise ValueError(f"pattern={pattern!r}: use 'spread', 'random' or 'hot'")
    tag_width = max(1, (n_words - 1).bit_length())
    dut = SDRAMMemory(image, addr_width=12, tag_width=tag_width, chips=chips,
                      chip_bits=chip_bits, clock_ratio=clock_ratio, latency=latency,
                      chip_queue=chip_queue)
    r = run_memory(dut, addrs)
    seen = set()
    for cycle, p in r.responses:
        i = p["tag"]
        assert i not in seen, f"request {i} answered twice (cycle {cycle})"
        seen.add(i)
        assert p["data"] == int(image[addrs[i]]), f"request {i} (word {addrs[i]}): wrong data"
    assert len(seen) == n_words, f"{n_words - len(seen)} requests never answered"
    cycles = np.array([c for c, _ in r.responses])
    chip = chip_of(np.array([addrs[p["tag"]] for _, p in r.responses]), chips)
    per_chip = []
    for c in range(chips):
        cc = cycles[chip == c]
        per_chip.append(64 * (len(cc) - 1) / (cc[-1] - cc[0]) if len(cc) > 1 else 0.0)
    total = 64 * (n_words - 1) / (cycles[-1] - cycles[0])
    return {"chips": chips, "pattern": pattern, "words": n_words,
            "bits_per_cycle": total, "bits_per_cycle_per_chip": per_chip,
            "ideal_bits_per_cycle_per_chip": chip_bits / clock_ratio,
            "words_per_chip": r.counters["words"], "busy_per_chip": r.counters["busy"],
            "cycles": int(r.counters["cycles"]),
            "first_latency": int(r.responses[0][0] - r.sent[0])}
