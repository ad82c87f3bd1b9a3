"""cocotb bench of the RTC's exported Verilog: ``rtc_core`` (the RTC, three memory ports) or
``rtc`` (the synthesizable one-RTC top: the RTC-MI's caches and a bus in front of one memory
port).

Pytest side, :func:`run_rtc`: every packet's ``RayIn`` lanes (``tb.units.traversal.ray_payloads``),
the scene's memory image behind the memory port(s) (``rtc_core``'s triangle port answers a
triangle index with the whole triangle, :func:`triangles`); the results and counters are
compared with ``model.rtc.trace`` by ``tb.units.rtc.finish`` / ``tb.harness.compare``, as for the Amaranth and
Verilator frame runs: every ray's triangle, t, u, v bit for bit, every counter of
``tb.harness.compare.COMPARED``.

Simulator side, :func:`rtc`: rays in with random bubbles, results out with random
back-pressure (recorded: the RTC reports rays in any order); every memory port answered from
the image after random delays, in random order, with request back-pressure.
"""
from __future__ import annotations

import time

import numpy as np

import cocotb

from tb.harness.cocotb.streams import (Memory, Pattern, Sink, Source, from_ints, load, read_ports, run, save,
                      start, to_ints)

# the memory read ports of each top, and the constant inputs
PORTS = {"rtc_core": ("node_mem", "list_mem", "tri_mem"), "rtc": ("mem",)}
BUSY = ("trav_busy", "list_busy", "int_busy", "packets_done", "cycles")


def run_rtc(image, rays, cfg, sim: str, run_dir, *, top: str = "rtc_core", seed: int = 1,
            idle: float = 0.1, stall: float = 0.2, mem_stall: float = 0.1,
            max_delay: int = 20, **build_kw):
    """``rays`` through ``image`` in the exported ``top`` of ``cfg``; returns
    ``(tb.units.rtc.RTCRun, runner Result)``. The run's ``mismatches`` and ``counter_mismatches()``
    are what the caller checks (empty when the Verilog agrees with the model)."""
    from model.raygen import setup
    from tb.harness.compare import COMPARED, FIELDS
    from tb.units.rtc import RTCRun, finish
    from tb.units.traversal import ray_payloads

    from rtl.rtc import HEADER

    from tb.harness.cocotb.runner import build, interface, pack, port_layout, run as run_bench, unpack
    if top not in PORTS:
        raise ValueError(f"top {top!r}: one of {', '.join(PORTS)}")
    rs = setup(rays, image.bounds, cfg.fmt)
    lanes = [lane for pk in ray_payloads(rays, rs, cfg) for lane in pk]
    dut = interface(top, cfg)
    result = port_layout(dut, "results")
    mems = {}
    for name in PORTS[top]:
        port = getattr(dut, name)
        mems[name] = {"addr_bits": len(port.req.payload.addr),
                      "data_bits": len(port.resp.payload.data)}
    consts = {k: int(getattr(image, k)) for k in HEADER if hasattr(dut, k)}
    counters = list(COMPARED) + list(BUSY) + [f"sub_busy__{j}" for j in range(cfg.trav_subunits)]
    if top == "rtc":
        counters += ["mem_reads"] + [f"{k}__{i}" for k in ("hits", "misses") for i in range(3)]
    params = {"seed": seed, "idle": idle, "stall": stall, "mem_stall": mem_stall,
              "max_delay": max_delay, "consts": consts, "mems": mems, "counters": counters,
              "result_bits": result.size}
    arrays = {"rays": pack(port_layout(dut, "rays"), lanes),
              "image": np.asarray(image.data, np.uint64)}
    if "tri_mem" in mems:          # triangle index -> the triangle (rtl/rtc.py)
        arrays["tri_items"] = triangles(image, cfg)
    r = run_bench("rtc", build(top, cfg, sim, **build_kw), run_dir, params=params,
                  arrays=arrays)
    got = unpack(result, r.arrays["results"])
    records = {k: np.array([p[k] for p in got], np.int64) for k in ("packet", "lane", *FIELDS)}
    c = r.values["counters"]
    c["sub_busy"] = [c.pop(f"sub_busy__{j}") for j in range(cfg.trav_subunits)]
    if top == "rtc":        # every word the bus asked for reached the memory port, once
        assert c["mem_reads"] == r.values["served"]["mem"], (c["mem_reads"], r.values["served"])
    run = finish(RTCRun, image, rays, cfg, records, cycles=c["cycles"],
                 seconds=r.values["seconds"], counters=c)
    return run, r


def triangles(image, cfg) -> np.ndarray:
    """Every triangle of ``image`` as the triangle port answers it (``rtl/rtc.py``'s
    ``tri_mem``: the low ``cfg.int_item_bits`` bits of its words, ``model.cache.item_values``
    with the int-cache's item geometry), ``(n_tris, words)`` flat vectors."""
    from model.cache import cache_geometry, item_values
    geom = cache_geometry(cfg, "int")
    return from_ints(item_values(image.data, geom, np.arange(image.n_tris), image.tri_base),
                     geom.item_bits)


@cocotb.test()
async def rtc(dut):
    """Every ray in, every result out; memory from the scene's image."""
    p, a = load()
    seed = p["seed"]
    image = a["image"]
    rays = Source(dut, "rays", to_ints(a["rays"]), hold=Pattern(p["idle"], seed))
    results = Sink(dut, "results", hold=Pattern(p["stall"], seed + 1), count=len(rays.payloads))
    tris = to_ints(a["tri_items"]) if "tri_items" in a else None
    read = {name: (tris.__getitem__ if name == "tri_mem" else lambda addr: int(image[addr]))
            for name in p["mems"]}
    mems = {name: Memory(dut, name, read[name], addr_bits=m["addr_bits"],
                         data_bits=m["data_bits"], rng=np.random.default_rng(seed + 10 + i),
                         max_delay=p["max_delay"], hold=Pattern(p["mem_stall"], seed + 20 + i))
            for i, (name, m) in enumerate(p["mems"].items())}
    agents = [rays, results, *mems.values()]
    await start(dut, p["consts"])
    t0 = time.perf_counter()
    cycles = await run(dut, agents, lambda: results.done)
    seconds = time.perf_counter() - t0
    counters = await read_ports(dut, p["counters"])
    save({"results": from_ints(results.got, p["result_bits"])}, cycles=cycles,
         seconds=seconds, counters=counters,
         served={name: len(m.addrs) for name, m in mems.items()})
