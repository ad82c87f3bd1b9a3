"""Traversal unit testbench: replays the golden model's event log (``model.rtc.trace(...,
record=True)``).

The testbench feeds the packets' ``RayIn`` lanes (random bubbles), answers every
``LeafRequest`` with the model's ``LaneResult`` s for that leaf (random delays and bubbles),
answers ``PacketDone`` with a ``release`` (random delay) and checks:

* per packet, the ``LeafRequest`` s equal the model's ``EV_LEAF`` events with count > 0, in order
  (first entry, count, lane mask);
* every packet is done exactly once;
* the unit's counters equal the model's (``trav_ops``, ``trav_steps``, ``node_reads``,
  ``leaf_visits``, ``passes``, ``pushes``).

It also serves ``tb/units/rtc.py``: :func:`ray_payloads` makes the ``RayIn`` transfers of a ray set.
"""
from __future__ import annotations

import random
import time
from collections import defaultdict, deque
from dataclasses import dataclass, field

import numpy as np

from model.config import Config
from model.events import EV_INT, EV_LEAF, EV_RESULT
from model.rtc import counter_totals, trace
from tb.harness.memory import IdealMemory
from rtl.traversal import Traversal

from tb.harness.common import run

__all__ = ["ray_payloads", "leaf_results", "TravRun", "run_traversal", "small_case"]


def ray_payloads(rays, rs, cfg: Config) -> list[list[dict]]:
    """``RayIn`` payloads (dicts) per packet, lanes in order, ``last`` on the final lane."""
    fmt = cfg.fmt
    bits = lambda x: fmt.to_bits(np.asarray(x, np.float32)).astype(np.int64)
    # Config.int_test = "projection": the intersection unit's k is 0 and s the direction
    proj = cfg.int_test == "projection"
    org, inv, s = bits(rays.org), bits(rs.inv), bits(rays.dir if proj else rs.s)
    kk = np.zeros_like(rs.k) if proj else rs.k
    tnear, tfar, tmax = bits(rs.tnear), bits(rs.tfar), bits(rays.tmax)
    sign = (np.ascontiguousarray(rays.dir, np.float32).view(np.uint32) >> 31).astype(np.int64)
    octant = sign[:, 0] | (sign[:, 1] << 1) | (sign[:, 2] << 2)
    out = []
    for p in range(rays.n_packets):
        a, b = int(rays.pk_start[p]), int(rays.pk_start[p + 1])
        out.append([{
            "packet": p, "lane": r - a, "last": int(r == b - 1),
            "org": [int(x) for x in org[r]], "inv": [int(x) for x in inv[r]],
            "octant": int(octant[r]), "tnear": int(tnear[r]), "tfar": int(tfar[r]),
            "k": [int(x) for x in kk[r]], "s": [int(x) for x in s[r]], "tmax": int(tmax[r]),
            "anyhit": int(rays.anyhit[r]),
        } for r in range(a, b)])
    return out


def leaf_results(events: np.ndarray, rays, cfg: Config) -> dict[int, list]:
    """Per packet, per non-empty leaf in order: ``(first, count, mask, results)`` with
    ``results`` the ``LaneResult`` fields ``(lane, hit, t bits)`` of every lane of the leaf's
    mask, replayed from the model's ``EV_INT`` events (best hit so far of each lane)."""
    fmt = cfg.fmt
    tmax = fmt.to_bits(rays.tmax.astype(np.float32)).astype(np.int64)
    best_t: dict[int, np.ndarray] = {}
    has_hit: dict[int, np.ndarray] = {}
    out: dict[int, list] = defaultdict(list)
    pending = None
    for ev in events:
        kind, p = int(ev["kind"]), int(ev["packet"])
        if p not in best_t:
            a, b = int(rays.pk_start[p]), int(rays.pk_start[p + 1])
            best_t[p] = tmax[a:b].copy()
            has_hit[p] = np.zeros(b - a, bool)
        if kind == EV_LEAF:
            pending = (int(ev["first"]), int(ev["count"]), int(ev["mask"]))
        elif kind == EV_INT and (ev["flags"] & 2):
            # the model records binary32 bits; the stream carries format words
            t = np.array([ev["t"]], np.uint32).view(np.float32)
            best_t[p][ev["lane"]] = int(fmt.to_bits(t)[0])
            has_hit[p][ev["lane"]] = True
        elif kind == EV_RESULT:
            first, count, mask = pending
            if count > 0:
                lanes = [l for l in range(64) if mask >> l & 1]
                out[p].append((first, count, mask,
                               [(l, int(has_hit[p][l]), int(best_t[p][l])) for l in lanes]))
    return out


@dataclass
class TravRun:
    cycles: int
    leaf_requests: int
    packets_done: list
    counters: dict
    model: dict
    mismatches: list = field(default_factory=list)
    seconds: float = 0.0


def run_traversal(image, rays, cfg: Config, *, seed: int = 1, mem_latency: int = 8,
                  idle: float = 0.2, delay: int = 20, max_cycles: int = 200_000,
                  monitor=None) -> TravRun:
    """Simulate the traversal unit on ``rays`` through ``image`` (node port on an
    ``IdealMemory``) against the model's event log; returns counters and mismatches.
    ``monitor(dut)``: an ``async def (ctx)`` run in the background every cycle (invariant
    checks on the unit's ports)."""
    from amaranth.hdl import Module
    from amaranth.lib import wiring

    hits, ctrs, events = trace(image, rays, cfg, record=True)
    from model.raygen import setup
    rs = setup(rays, image.bounds, cfg.fmt)
    packets = ray_payloads(rays, rs, cfg)
    expect = leaf_results(events, rays, cfg)
    tot = counter_totals(ctrs)

    dut = Traversal(cfg)
    mem = IdealMemory(image.data, addr_width=32, tag_width=cfg.thread_bits, latency=mem_latency,
                      queue=cfg.threads + mem_latency)
    top = Module()
    top.submodules.trav, top.submodules.mem = dut, mem
    wiring.connect(top, dut.node, mem.port)

    rng = random.Random(seed)
    thread_packet: dict[int, int] = {}
    seen: dict[int, int] = defaultdict(int)
    mismatches: list = []
    done: list = []
    state = {"cycle": 0}

    async def feeder(ctx):
        ctx.set(dut.node_base, image.node_base)
        ctx.set(dut.root, image.root)
        for pk in packets:
            for lane in pk:
                while rng.random() < idle:
                    ctx.set(dut.rays.valid, 0)
                    await ctx.tick()
                ctx.set(dut.rays.payload, lane)
                ctx.set(dut.rays.valid, 1)
                while True:
                    _, _, ready, thread = await ctx.tick().sample(dut.rays.ready, dut.load_thread)
                    if ready:
                        break
                thread_packet[thread] = lane["packet"]
        ctx.set(dut.rays.valid, 0)

    async def responder(ctx):
        results: deque = deque()       # (due cycle, payload)
        releases: deque = deque()
        cycle = 0
        while len(done) < len(packets):
            if cycle > max_cycles:
                raise AssertionError(f"traversal: {len(done)} of {len(packets)} packets done "
                                     f"after {max_cycles} cycles")
            leaf_ready = rng.random() > 0.25
            done_ready = rng.random() > 0.25
            ctx.set(dut.leaf.ready, leaf_ready)
            ctx.set(dut.done.ready, done_ready)
            send = bool(results) and results[0][0] <= cycle and rng.random() > idle
            ctx.set(dut.result.valid, send)
            if send:
                ctx.set(dut.result.payload, results[0][1])
            rel = bool(releases) and releases[0][0] <= cycle
            ctx.set(dut.release.valid, rel)
            if rel:
                ctx.set(dut.release.payload, releases[0][1])
            _, _, lv, lp, dv, dp = await ctx.tick().sample(dut.leaf.valid, dut.leaf.payload,
                                                          dut.done.valid, dut.done.payload)
            cycle += 1
            if send:
                results.popleft()
            if rel:
                releases.popleft()
            if lv and leaf_ready:
                t = int(lp.thread)
                p = thread_packet[t]
                i = seen[p]
                seen[p] += 1
                got = (int(lp.first), int(lp.count), int(lp.mask))
                if i >= len(expect[p]) or got != expect[p][i][:3]:
                    want = expect[p][i][:3] if i < len(expect[p]) else None
                    mismatches.append(("leaf", p, i, got, want))
                    raise AssertionError(f"packet {p} leaf {i}: got {got}, model {want}")
                due = cycle + rng.randrange(delay + 1)
                res = expect[p][i][3]
                for j, (lane, hit, tb) in enumerate(res):
                    results.append((due, {"thread": t, "lane": lane, "hit": hit, "t": tb,
                                          "last": int(j == len(res) - 1)}))
            if dv and done_ready:
                t, p = int(dp.thread), int(dp.packet)
                if thread_packet.get(t) != p or p in done:
                    mismatches.append(("done", t, p))
                    raise AssertionError(f"done: thread {t} packet {p} (loaded: "
                                         f"{thread_packet.get(t)}, done before: {p in done})")
                n = int(rays.pk_start[p + 1] - rays.pk_start[p])
                if int(dp.mask) != (1 << n) - 1:
                    mismatches.append(("done mask", p, int(dp.mask)))
                    raise AssertionError(f"packet {p} done with lane mask {int(dp.mask):#x}, "
                                         f"it has {n} lanes")
                if seen[p] != len(expect[p]):
                    mismatches.append(("leaves", p, seen[p], len(expect[p])))
                    raise AssertionError(f"packet {p} done after {seen[p]} leaves; model "
                                         f"{len(expect[p])}")
                done.append(p)
                releases.append((cycle + rng.randrange(delay + 1), t))
        state["cycle"] = cycle
        state["counters"] = {name: ctx.get(getattr(dut, name)) for name in (
            "busy", "trav_ops", "trav_steps", "node_reads", "leaf_reqs", "passes", "pushes",
            "packets_done")}
        state["counters"]["sub_busy"] = [ctx.get(x) for x in dut.sub_busy]

    async def clock(ctx):
        await ctx.tick()
        state["t_first"] = time.process_time()     # after the simulator compiled the design

    run(top, feeder, responder, clock, background=[monitor(dut)] if monitor else ())
    secs = time.process_time() - state["t_first"]
    return TravRun(state["cycle"], sum(seen.values()), done, state["counters"], tot, mismatches,
                   secs)


COMPARED = {"trav_ops": "trav_ops", "trav_steps": "trav_steps", "node_reads": "node_reads",
            "leaf_reqs": "leaf_visits", "passes": "passes", "pushes": "pushes"}


def small_case(scene_path, width: int, height: int, cfg: Config, cache_dir):
    """(image, rays) for eye rays of a shipped scene at a tiny resolution."""
    from model.raygen import eye_rays
    from model.render import prepare
    from model.scene import load_scene
    scene = load_scene(scene_path)
    prep = prepare(scene, cfg, cache_dir=cache_dir)
    return prep.image, eye_rays(scene.camera, width, height, cfg)
