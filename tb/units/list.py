"""Testbench of the list unit (``rtl/list.py``) against the golden model's event log.

:func:`golden` traces a few packets of a scene with ``model.rtc.trace(record=True)``; the list
unit's input stream is the model's ``EV_LEAF`` events with ``count > 0`` (thread = packet id
mod threads) and its expected output stream the ``EV_TRI`` events, in order, ``last`` on each
leaf's final entry. :func:`run_list` drives the inputs with random bubbles, drains the outputs
with random back-pressure, serves memory from the image (``IdealMemory`` or, to exercise
out-of-order responses, ``SDRAMMemory``) and checks every output and the counters.
"""
from __future__ import annotations

import random
import time
from dataclasses import dataclass

import numpy as np
from amaranth.hdl import Module
from amaranth.lib import wiring

from model.config import Config
from model.render import prepare
from model.raygen import eye_rays, setup
from model.events import EV_LEAF, EV_TRI
from model.rtc import C, trace
from model.scene import load_scene
from rtl.list import ListUnit
from tb.harness.memory import IdealMemory, SDRAMMemory

from tb.harness.common import drain, drive, run, watch

MASK64 = (1 << 64) - 1


@dataclass
class Golden:
    """A traced scene: memory image, rays, ray setup, results, counters and event log."""
    cfg: Config
    image: object
    rays: object
    setup: object
    hits: object
    counters: np.ndarray
    events: np.ndarray


def golden(scene_path, width: int, height: int, cfg: Config, cache_dir) -> Golden:
    """Trace the eye rays of a ``width x height`` image of ``scene_path`` with the event log."""
    scene = load_scene(scene_path)
    image = prepare(scene, cfg, cache_dir=cache_dir).image
    rays = eye_rays(scene.camera, width, height, cfg)
    rs = setup(rays, image.bounds, cfg.fmt)
    hits, ctrs, events = trace(image, rays, cfg, ray_setup=rs, record=True)
    return Golden(cfg, image, rays, rs, hits, ctrs, events)


def leaf_stream(g: Golden) -> tuple[list[dict], list[dict]]:
    """The list unit's input (``LeafRequest`` dicts) and expected output (``TriRequest`` dicts)."""
    ev, cfg = g.events, g.cfg
    leaves, tris = [], []
    i = 0
    while i < len(ev):
        kind, pid = int(ev["kind"][i]), int(ev["packet"][i])
        if kind == EV_LEAF and ev["count"][i] > 0:
            mask = int(ev["mask"][i])
            count = int(ev["count"][i])
            leaves.append({"thread": pid % cfg.threads, "first": int(ev["first"][i]),
                           "count": count, "mask": mask})
            # the model records the leaf's EV_TRI events next, interleaved with its EV_INTs
            j, seen = i + 1, 0
            while seen < count:
                if ev["kind"][j] == EV_TRI:
                    assert int(ev["mask"][j]) == mask
                    seen += 1
                    tris.append({"thread": pid % cfg.threads, "tri": int(ev["tri"][j]),
                                 "mask": mask, "last": int(seen == count)})
                j += 1
        i += 1
    return leaves, tris


def first_leaves(leaves: list, tris: list, n: int) -> tuple[list, list]:
    """The first ``n`` leaves of a :func:`leaf_stream` and their ``TriRequest`` s."""
    leaves = leaves[:n]
    return leaves, tris[:sum(lf["count"] for lf in leaves)]


def check_counters(counters: dict, g: Golden, leaves: list, tris: list, whole: bool) -> None:
    """The unit's ``list_ops`` and ``words`` after ``leaves``: one op per entry, the list words
    the leaves touch (``model.list.list_words``) and, for ``whole`` (every leaf of ``g``), the
    model's own totals. AssertionError on a difference."""
    from model.list import list_words
    want_words = sum(list_words(lf["first"], lf["count"]) for lf in leaves)
    assert counters["list_ops"] == len(tris), (counters, len(tris))
    assert counters["words"] == want_words, (counters, want_words)
    if whole:
        tot = g.counters.sum(axis=0)
        assert counters["list_ops"] == tot[C["list_ops"]], (counters, tot[C["list_ops"]])
        assert counters["words"] == tot[C["list_reads"]], (counters, tot[C["list_reads"]])


class ListBench(wiring.Component):
    """The list unit with a simulation memory on its port (ports of the unit passed through)."""

    def __init__(self, cfg: Config, image, *, latency: int = 20, outstanding: int = 8,
                 sdram: bool = False):
        addr_width = max(8, int(len(image.data) - 1).bit_length())
        self.dut = ListUnit(cfg, addr_width=addr_width, outstanding=outstanding)
        if sdram:
            self.memory = SDRAMMemory(image.data, addr_width=addr_width,
                                      tag_width=self.dut.tag_width, chips=4, clock_ratio=1,
                                      latency=latency, chip_queue=4)
        else:
            self.memory = IdealMemory(image.data, addr_width=addr_width,
                                      tag_width=self.dut.tag_width, latency=latency)
        self.list_base = image.list_base
        sig = self.dut.signature.members
        super().__init__({"leaf": sig["leaf"], "tri": sig["tri"],
                          "list_ops": sig["list_ops"], "words": sig["words"],
                          "busy": sig["busy"]})

    def elaborate(self, platform):
        m = Module()
        m.submodules.dut, m.submodules.memory = self.dut, self.memory
        wiring.connect(m, self.dut.mem, self.memory.port)
        wiring.connect(m, wiring.flipped(self.leaf), self.dut.leaf)
        wiring.connect(m, self.dut.tri, wiring.flipped(self.tri))
        m.d.comb += [self.dut.list_base.eq(self.list_base), self.list_ops.eq(self.dut.list_ops),
                     self.words.eq(self.dut.words), self.busy.eq(self.dut.busy)]
        return m


@dataclass
class ListRun:
    leaves: int
    entries: int
    cycles: int
    seconds: float
    words: int
    busy: int
    resp_tags: list

    @property
    def cycles_per_s(self) -> float:
        return self.cycles / self.seconds


def run_list(g: Golden, *, seed: int = 0, idle: float = 0.3, stall: float = 0.3,
             latency: int = 20, outstanding: int = 8, sdram: bool = False,
             max_leaves: int | None = None, streams=None) -> ListRun:
    """Feed the golden leaf stream to the list unit and check every ``TriRequest`` in order,
    then the counters against the model's ``list_ops`` / ``list_reads``.

    ``streams``: ``(leaves, expected)`` to use instead of :func:`leaf_stream` of ``g`` (then
    only ``g.cfg`` and ``g.image`` are read)."""
    leaves, want = leaf_stream(g) if streams is None else streams
    if max_leaves is not None:
        leaves, want = first_leaves(leaves, want, max_leaves)
    dut = ListBench(g.cfg, g.image, latency=latency, outstanding=outstanding, sdram=sdram)
    rng = random.Random(seed)
    got, counters = [], {}

    async def source(ctx):
        await drive(ctx, dut.leaf, leaves, rng=rng, idle=idle)

    async def sink(ctx):
        await drain(ctx, dut.tri, len(want), rng=rng, stall=stall, out=got, timeout=2000)
        await ctx.tick().repeat(2)
        counters.update(list_ops=ctx.get(dut.list_ops), words=ctx.get(dut.words),
                        busy=ctx.get(dut.busy), cycles=got[-1][0] + 3 if got else 0)

    tags = []
    resp = dut.dut.mem.resp

    async def monitor(ctx):
        await watch(ctx, resp.valid & resp.ready, resp.payload.tag, out=tags)

    t = time.perf_counter()
    run(dut, source, sink, background=[monitor])
    seconds = time.perf_counter() - t
    for i, ((cycle, p), w) in enumerate(zip(got, want)):
        if p != w:
            raise AssertionError(f"list unit: TriRequest #{i} at cycle {cycle}: {p}, "
                                 f"model {w}")
    assert len(got) == len(want)
    check_counters(counters, g, leaves, want, whole=max_leaves is None and streams is None)
    return ListRun(len(leaves), len(want), counters["cycles"], seconds, counters["words"],
                   counters["busy"], [tag for _, tag in tags])


if __name__ == "__main__":          # speed figure: python -m tb.units.list [width height]
    import sys
    import tempfile
    w, h = (int(x) for x in sys.argv[1:3]) if len(sys.argv) > 2 else (16, 16)
    g = golden("scenes/cornell.toml", w, h, Config(), tempfile.mkdtemp())
    for label, kw in (("ideal memory, 30% bubbles/back-pressure", {}),
                      ("no bubbles, 16 outstanding", dict(idle=0, stall=0, outstanding=16))):
        r = run_list(g, seed=1, **kw)
        print(f"ListUnit ({label}): {r.leaves} leaves, {r.entries} entries, {r.words} words, "
              f"{r.cycles} cycles in {r.seconds:.2f} s = {r.cycles_per_s:.0f} cycles/s")
