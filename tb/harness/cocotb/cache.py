"""cocotb bench of a cache's exported Verilog (tops ``cache_trav``, ``cache_list``,
``cache_int``: ``rtl/cache.py`` with that unit's item geometry from the configuration).

Pytest side, :func:`run_cache`: the item addresses the golden model's unit asked for while
tracing a scene (``model.rtc.item_trace``: node, list-entry or triangle indices, in order), the
scene's memory image behind the cache; the responses, the hit/miss sequence and the counters are
checked by ``tb.units.cache.check_cache_run``, the check of the Amaranth bench (data = the item in
memory, request order, hit/miss and counters = ``model.cache.CacheModel``).

Simulator side, :func:`cache`: requests in with random bubbles, responses out with random
back-pressure (each checked against the memory's item, bit for bit and in order, as it
arrives); the memory answers line fetches after random delays in random order.
"""
from __future__ import annotations

import time

import numpy as np

import cocotb

from tb.harness.cocotb.streams import (Fields, Memory, Pattern, Sink, Source, Watch, from_ints, load,
                      read_ports, run, save, start, to_ints)

BASES = {"trav": "node_base", "list": "list_base", "int": "tri_base"}


def run_cache(unit: str, g, sim: str, run_dir, *, n: int | None = None, seed: int = 0,
              idle: float = 0.2, stall: float = 0.3, max_delay: int = 20, **build_kw):
    """The first ``n`` item requests of unit ``unit`` ('trav', 'list', 'int') in traced scene
    ``g`` (a ``tb.units.list.Golden``) through the exported ``cache_<unit>`` of ``g.cfg``; every
    check of ``tb.units.cache.check_cache_run``. Returns the runner's Result and the ``CacheRun``."""
    from model.cache import cache_geometry, item_values
    from model.rtc import item_trace
    from tb.units.cache import CacheRun, check_cache_run

    from tb.harness.cocotb.runner import build, fields, interface, pack, port_layout, run as run_bench, unpack
    top = f"cache_{unit}"
    geom = cache_geometry(g.cfg, unit)
    addrs = item_trace(g.events)[unit][:n]
    base = int(getattr(g.image, BASES[unit]))
    image = np.asarray(g.image.data, np.uint64)
    cache = interface(top, g.cfg)
    tags = 1 << len(cache.port.req.payload.tag)
    reqs = [{"addr": int(x), "tag": i % tags} for i, x in enumerate(addrs)]
    want = [{"data": d, "tag": q["tag"]}
            for d, q in zip(item_values(image, geom, addrs, base), reqs)]
    resp = port_layout(cache, "port__resp")
    params = {"seed": seed, "idle": idle, "stall": stall, "max_delay": max_delay, "base": base,
              "resp_fields": fields(resp), "addr_bits": len(cache.mem.req.payload.addr),
              "data_bits": 64}
    arrays = {"reqs": pack(port_layout(cache, "port__req"), reqs), "resps": pack(resp, want),
              "image": image}
    r = run_bench("cache", build(top, g.cfg, sim, **build_kw), run_dir, params=params,
                  arrays=arrays)
    a, c = r.arrays, r.values["counters"]
    got = unpack(resp, a["resps"])
    cr = CacheRun(responses=list(zip(a["resp_cycles"].tolist(), got)),
                  sent=a["sent"].tolist(),
                  lookups=[(int(cy), bool(h)) for cy, h in a["lookups"]],
                  hits=c["hits"], misses=c["misses"], words_fetched=len(a["fetched"]),
                  cycles=r.values["cycles"])
    check_cache_run(cr, geom, image, addrs, reqs, base)
    return r, cr


@cocotb.test()
async def cache(dut):
    """Item requests in, items out (checked as they arrive), lookups and fetches recorded."""
    p, a = load()
    seed = p["seed"]
    image = a["image"]
    want = to_ints(a["resps"])
    lookups = []
    req = Source(dut, "port__req", to_ints(a["reqs"]), hold=Pattern(p["idle"], seed))
    resp = Sink(dut, "port__resp", hold=Pattern(p["stall"], seed + 1), expect=want,
                fields=Fields(p["resp_fields"]))
    mem = Memory(dut, "mem", lambda addr: int(image[addr]), addr_bits=p["addr_bits"],
                 data_bits=p["data_bits"], rng=np.random.default_rng(seed + 2),
                 max_delay=p["max_delay"])
    watch = Watch(dut, ["lookup_hit"], lambda cycle, v: lookups.append((cycle, v[0])),
                  cond="lookup_valid")
    await start(dut, {"base": p["base"]})
    t0 = time.perf_counter()
    cycles = await run(dut, [req, resp, mem, watch], lambda: resp.done)
    seconds = time.perf_counter() - t0
    counters = await read_ports(dut, ("hits", "misses"))
    bits = sum(w for _, _, w in p["resp_fields"])
    save({"resps": from_ints(resp.got, bits), "resp_cycles": np.array(resp.cycles),
          "sent": np.array(req.cycles), "lookups": np.array(lookups, np.int64).reshape(-1, 2),
          "fetched": np.array(mem.addrs, np.int64)},
         cycles=cycles, seconds=seconds, counters=counters)
