"""cocotb bench of the list unit's exported Verilog (top ``list``).

Pytest side, :func:`run_list`: the golden model's leaf stream and expected ``TriRequest``
stream (``tb.units.list.leaf_stream``: the ``EV_LEAF`` / ``EV_TRI`` events of a traced scene), packed
into the ports' flat vectors; the scene's memory image serves the unit's memory port; the
counters are checked as the Amaranth bench checks them (``tb.units.list.check_counters``).

Simulator side, :func:`list_unit`: leaves in with random bubbles, ``TriRequest`` s out with
random back-pressure, each checked bit for bit and in order; the memory answers after random
delays in random order.
"""
from __future__ import annotations

import time

import numpy as np

import cocotb

from tb.harness.cocotb.streams import (Fields, Memory, Pattern, Sink, Source, load, read_ports, run, save,
                      start, to_ints)

COUNTERS = ("list_ops", "words", "busy")


def run_list(g, sim: str, run_dir, *, seed: int = 0, idle: float = 0.3, stall: float = 0.3,
             max_delay: int = 20, max_leaves: int | None = None, **build_kw):
    """Drive the leaves of ``g`` (a ``tb.units.list.Golden``) through the exported list unit in
    ``sim`` and check every output and the counters; returns the runner's Result."""
    from tb.units.list import check_counters, first_leaves, leaf_stream

    from tb.harness.cocotb.runner import build, fields, interface, pack, port_layout, run as run_bench
    every, _ = leaves, want = leaf_stream(g)
    if max_leaves is not None:
        leaves, want = first_leaves(leaves, want, max_leaves)
    unit = interface("list", g.cfg)
    tri = port_layout(unit, "tri")
    params = {"seed": seed, "idle": idle, "stall": stall, "max_delay": max_delay,
              "list_base": int(g.image.list_base), "tri_fields": fields(tri),
              "addr_bits": len(unit.mem.req.payload.addr), "data_bits": 64}
    arrays = {"leaves": pack(port_layout(unit, "leaf"), leaves), "tris": pack(tri, want),
              "image": np.asarray(g.image.data, np.uint64)}
    r = run_bench("list", build("list", g.cfg, sim, **build_kw), run_dir, params=params,
                  arrays=arrays)
    check_counters(r.values["counters"], g, leaves, want,
                   whole=len(leaves) == len(every))
    return r


@cocotb.test()
async def list_unit(dut):
    """The golden leaf stream in, the golden TriRequest stream out, bit for bit and in order."""
    p, a = load()
    seed = p["seed"]
    image = a["image"]
    leaf = Source(dut, "leaf", to_ints(a["leaves"]), hold=Pattern(p["idle"], seed))
    tri = Sink(dut, "tri", hold=Pattern(p["stall"], seed + 1), expect=to_ints(a["tris"]),
               fields=Fields(p["tri_fields"]))
    mem = Memory(dut, "mem", lambda addr: int(image[addr]), addr_bits=p["addr_bits"],
                 data_bits=p["data_bits"], rng=np.random.default_rng(seed + 2),
                 max_delay=p["max_delay"])
    await start(dut, {"list_base": p["list_base"]})
    t0 = time.perf_counter()
    cycles = await run(dut, [leaf, tri, mem], lambda: tri.done and leaf.done)
    seconds = time.perf_counter() - t0
    counters = await read_ports(dut, COUNTERS)
    save(cycles=cycles, seconds=seconds, counters=counters, entries=len(tri.got))
