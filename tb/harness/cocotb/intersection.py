"""cocotb benches of the intersection datapath's and unit's exported Verilog (tops
``intersect_pipe`` and ``intersection``).

:func:`run_pipe`: ray/triangle tests (``tb.units.intersection.random_tests``: hits, exact edge and
vertex hits, degenerate triangles, overflow, tiny values; or ``golden_tests``: a traced
scene's int-ops) through the fixed-latency datapath, every output at its exact cycle: the FP
units' bench (:func:`tb.harness.cocotb.fp.fixed_latency`) with the datapath's ports
(``tb.units.intersection.pipe_ports``).

:func:`run_unit`: the unit's streams from the golden model's event log, as the Amaranth bench
``tb/units/intersection.py`` makes them (``unit_streams``): the packets' rays loaded, the
``TriRequest`` s fed with random bubbles, every ``LaneResult`` and (after each ``PacketDone``)
every ``RayResult`` checked bit for bit and in order under random back-pressure
(:func:`intersection_unit`); the triangle port answers a triangle index with the whole
triangle after random delays, in random order; counters as ``tb.units.intersection.unit_counters``.
"""
from __future__ import annotations

import time

import numpy as np

import cocotb

from tb.harness.cocotb.streams import (Fields, Memory, Pattern, Sink, Source, load, read_ports, run, save,
                      start, to_ints)


def run_pipe(tests, sim: str, run_dir, *, fmt=None, seed: int = 0, p_bubble: float = 0.2,
             p_stall: float = 0.2, **build_kw):
    """``tests`` (a ``tb.units.intersection.PipeTests``) through the exported ``intersect_pipe``."""
    from model.config import Config
    from model.fp import BINARY32
    from tb.units.intersection import pipe_ports

    from tb.harness.cocotb.fp import run_fixed_latency
    from tb.harness.cocotb.runner import build, interface
    cfg = Config(fmt=fmt or BINARY32)
    pipe = interface("intersect_pipe", cfg)
    ins, outs = pipe_ports(tests, cfg.fmt, pipe.tag_width)
    b = build("intersect_pipe", cfg, sim, **build_kw)
    return run_fixed_latency(b, run_dir, ins, outs, pipe.latency, seed=seed,
                             p_bubble=p_bubble, p_stall=p_stall)


def run_unit(g, sim: str, run_dir, *, max_leaves: int | None = None, seed: int = 0,
             idle: float = 0.3, stall: float = 0.3, max_delay: int = 20, **build_kw):
    """The first ``max_leaves`` leaves (all: the whole image, then the model's own counters
    too) of traced scene ``g`` (a ``tb.units.list.Golden``; at most ``threads`` packets) through the
    exported intersection unit of ``g.cfg``; returns the runner's Result."""
    from tb.units.intersection import unit_counters, unit_streams

    from tb.harness.cocotb.rtc import triangles
    from tb.harness.cocotb.runner import build, fields, interface, pack, port_layout, run as run_bench
    s = unit_streams(g, max_leaves)
    unit = interface("intersection", g.cfg)
    lay = {k: port_layout(unit, k) for k in ("ray_in", "tri_in", "lane_out", "done", "result")}
    params = {"seed": seed, "idle": idle, "stall": stall, "max_delay": max_delay,
              "lane_fields": fields(lay["lane_out"]), "result_fields": fields(lay["result"]),
              "addr_bits": len(unit.mem.req.payload.addr),
              "data_bits": len(unit.mem.resp.payload.data)}
    arrays = {"rays": pack(lay["ray_in"], s.rays), "tris": pack(lay["tri_in"], s.tris),
              "lanes": pack(lay["lane_out"], s.lanes), "done": pack(lay["done"], s.done),
              "results": pack(lay["result"], s.results), "tri_items": triangles(g.image, g.cfg)}
    r = run_bench("intersection", build("intersection", g.cfg, sim, **build_kw), run_dir,
                  params=params, arrays=arrays)
    c = r.values["counters"]
    bad = [(k, c[k], w) for k, w in unit_counters(s, g, whole=max_leaves is None) if c[k] != w]
    assert not bad, f"intersection unit counters (name, RTL, model): {bad}"
    assert r.values["fetched"] == len(s.tris), (r.values["fetched"], len(s.tris))
    return r


@cocotb.test()
async def intersection_unit(dut):
    """Rays loaded, then the golden TriRequests; LaneResults, then (after each PacketDone)
    RayResults checked against the model's, bit for bit and in order."""
    p, a = load()
    seed = p["seed"]
    tris = to_ints(a["tri_items"])
    rays = Source(dut, "ray_in", to_ints(a["rays"]), hold=Pattern(p["idle"], seed))
    tri_in = Source(dut, "tri_in", to_ints(a["tris"]), hold=Pattern(p["idle"], seed + 1),
                    may_send=lambda i: rays.done)
    lanes = Sink(dut, "lane_out", hold=Pattern(p["stall"], seed + 2),
                 expect=to_ints(a["lanes"]), fields=Fields(p["lane_fields"]))
    done = Source(dut, "done", to_ints(a["done"]), may_send=lambda i: lanes.done)
    results = Sink(dut, "result", hold=Pattern(p["stall"], seed + 3),
                   expect=to_ints(a["results"]), fields=Fields(p["result_fields"]))
    mem = Memory(dut, "mem", tris.__getitem__, addr_bits=p["addr_bits"],
                 data_bits=p["data_bits"], rng=np.random.default_rng(seed + 4),
                 max_delay=p["max_delay"])
    await start(dut)
    t0 = time.perf_counter()
    cycles = await run(dut, [rays, tri_in, lanes, done, results, mem],
                       lambda: lanes.done and results.done)
    seconds = time.perf_counter() - t0
    counters = await read_ports(dut, ("int_ops", "tris", "busy"))
    save(cycles=cycles, seconds=seconds, counters=counters, fetched=len(mem.addrs))
