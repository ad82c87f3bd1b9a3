"""cocotb bench of the traversal unit's exported Verilog (top ``traversal``).

Pytest side, :func:`run_traversal`: the golden model's streams for the unit, as the Amaranth
bench ``tb/units/traversal.py`` makes them: every packet's ``RayIn`` lanes (``ray_payloads``) and,
per packet, its non-empty leaves in order with the ``LaneResult`` s the intersection unit
answers each with (``leaf_results``, from the model's event log); the scene's memory image
serves the node port. The counters are checked against the model's (``tb.units.traversal.COMPARED``).

Simulator side, :func:`traversal`: rays in with random bubbles (each packet's thread read from
``load_thread``); every ``LeafRequest`` checked against the packet's next model leaf (first,
count, lane mask) and answered with the model's ``LaneResult`` s after a random delay; every
``PacketDone`` checked (the thread's packet, once, all its lanes, after all its leaves) and
answered with a ``release`` after a random delay; random back-pressure on both; node reads
answered after random delays in random order.
"""
from __future__ import annotations

import time

import numpy as np

import cocotb

from tb.harness.cocotb.streams import (Fields, Memory, Mismatch, Pattern, Sink, Source, load, read,
                      read_ports, run, save, start, to_ints)

COUNTERS = ("busy", "trav_ops", "trav_steps", "node_reads", "leaf_reqs", "passes", "pushes",
            "packets_done")


def run_traversal(image, rays, cfg, sim: str, run_dir, *, seed: int = 1, idle: float = 0.2,
                  stall: float = 0.25, delay: int = 20, max_delay: int = 12, **build_kw):
    """``rays`` through ``image`` in the exported traversal unit of ``cfg``, against the
    model's event log; returns the runner's Result (``values["counters"]``)."""
    from model.raygen import setup
    from model.rtc import counter_totals, trace
    from tb.units.traversal import COMPARED, leaf_results, ray_payloads

    from tb.harness.cocotb.runner import build, fields, interface, pack, port_layout, run as run_bench
    hits, ctrs, events = trace(image, rays, cfg, record=True)
    rs = setup(rays, image.bounds, cfg.fmt)
    lanes = [lane for pk in ray_payloads(rays, rs, cfg) for lane in pk]
    expect = leaf_results(events, rays, cfg)
    leaf_rows, res_rows = [], []
    for p in range(rays.n_packets):
        for first, count, mask, results in expect.get(p, []):
            for lane, hit, t in results:
                res_rows.append((len(leaf_rows), lane, hit, t))
            leaf_rows.append((p, first, count, mask))
    unit = interface("traversal", cfg)
    params = {"seed": seed, "idle": idle, "stall": stall, "delay": delay,
              "max_delay": max_delay, "node_base": int(image.node_base),
              "root": int(image.root), "n_packets": int(rays.n_packets),
              "lanes": np.diff(rays.pk_start).astype(int).tolist(),
              "leaf_fields": fields(port_layout(unit, "leaf")),
              "result_fields": fields(port_layout(unit, "result")),
              "done_fields": fields(port_layout(unit, "done")),
              "addr_bits": len(unit.node.req.payload.addr), "data_bits": 64,
              "sub_units": cfg.trav_subunits}
    arrays = {"rays": pack(port_layout(unit, "rays"), lanes),
              "ray_packet": np.array([x["packet"] for x in lanes], np.int64),
              "leaves": np.array(leaf_rows, np.uint64).reshape(-1, 4),
              "results": np.array(res_rows, np.uint64).reshape(-1, 4),
              "image": np.asarray(image.data, np.uint64)}
    r = run_bench("traversal", build("traversal", cfg, sim, **build_kw), run_dir,
                  params=params, arrays=arrays)
    got, model = r.values["counters"], counter_totals(ctrs)
    bad = {k: (got[k], model[v]) for k, v in COMPARED.items() if got[k] != model[v]}
    assert not bad, f"traversal counters differ from the model (RTL, model): {bad}"
    assert got["packets_done"] == rays.n_packets
    return r


@cocotb.test()
async def traversal(dut):
    """The golden rays in; leaf requests and packet completions checked and answered."""
    p, a = load()
    seed = p["seed"]
    rng = np.random.default_rng(seed + 5)
    image = a["image"]
    leaf_f, res_f, done_f = (Fields(p[k]) for k in ("leaf_fields", "result_fields",
                                                     "done_fields"))
    expect: dict[int, list] = {q: [] for q in range(p["n_packets"])}
    for q, first, count, mask in a["leaves"].tolist():
        expect[q].append([(first, count, mask), []])
    flat = [leaf for q in range(p["n_packets"]) for leaf in expect[q]]
    for i, lane, hit, t in a["results"].tolist():
        flat[i][1].append((lane, hit, t))
    ray_packet = a["ray_packet"].tolist()
    thread_packet: dict[int, int] = {}
    seen = {q: 0 for q in expect}
    done: list[int] = []

    def loaded(cycle, i):
        thread_packet[read(dut.load_thread, "load_thread")] = ray_packet[i]

    def leaf_req(cycle, payload):
        f = leaf_f.split(payload)
        t = f["thread"]
        q = thread_packet[t]
        i = seen[q]
        seen[q] += 1
        got = (f["first"], f["count"], f["mask"])
        want = expect[q][i][0] if i < len(expect[q]) else None
        if got != want:
            raise Mismatch(f"LeafRequest at cycle {cycle}: packet {q} leaf {i}: (first, count, "
                           f"mask) = {got}, model {want}")
        due = cycle + 1 + int(rng.integers(p["delay"] + 1))
        res = expect[q][i][1]
        for j, (lane, hit, tb) in enumerate(res):
            results.push(res_f.pack(thread=t, lane=lane, hit=hit, t=tb,
                                    last=int(j == len(res) - 1)), due)

    def packet_done(cycle, payload):
        f = done_f.split(payload)
        t, q = f["thread"], f["packet"]
        if thread_packet.get(t) != q or q in done:
            raise Mismatch(f"PacketDone at cycle {cycle}: thread {t} packet {q} (loaded: "
                           f"{thread_packet.get(t)}, done before: {q in done})")
        if f["mask"] != (1 << p["lanes"][q]) - 1:
            raise Mismatch(f"PacketDone at cycle {cycle}: packet {q} lane mask {f['mask']:#x}, "
                           f"it has {p['lanes'][q]} lanes")
        if seen[q] != len(expect[q]):
            raise Mismatch(f"PacketDone at cycle {cycle}: packet {q} after {seen[q]} leaves, "
                           f"model {len(expect[q])}")
        done.append(q)
        release.push(t, cycle + 1 + int(rng.integers(p["delay"] + 1)))

    rays = Source(dut, "rays", to_ints(a["rays"]), hold=Pattern(p["idle"], seed),
                  on_transfer=loaded)
    results = Source(dut, "result", hold=Pattern(p["idle"], seed + 1))
    release = Source(dut, "release")
    leaf = Sink(dut, "leaf", hold=Pattern(p["stall"], seed + 2), on_transfer=leaf_req)
    dones = Sink(dut, "done", hold=Pattern(p["stall"], seed + 3), on_transfer=packet_done)
    node = Memory(dut, "node", lambda addr: int(image[addr]), addr_bits=p["addr_bits"],
                  data_bits=p["data_bits"], rng=np.random.default_rng(seed + 4),
                  max_delay=p["max_delay"])
    await start(dut, {"node_base": p["node_base"], "root": p["root"]})
    t0 = time.perf_counter()
    cycles = await run(dut, [rays, results, release, leaf, dones, node],
                       lambda: len(done) == p["n_packets"] and release.done)
    seconds = time.perf_counter() - t0
    counters = await read_ports(dut, COUNTERS + tuple(f"sub_busy__{j}"
                                                      for j in range(p["sub_units"])))
    save(cycles=cycles, seconds=seconds, counters=counters,
         leaf_requests=sum(seen.values()))
