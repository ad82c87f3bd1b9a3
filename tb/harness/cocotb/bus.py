"""cocotb bench of the round-robin bus's exported Verilog (top ``bus``: 3 requesters).

Pytest side, :func:`run_bus`: requester ``i`` reads the 64-bit words the golden model's unit
``i`` (0 traversal, 1 list, 2 intersection) read while tracing a scene
(``model.rtc.memory_trace``), tags in turn (a tag is reused only once its response is back);
the scene's memory image answers on the bus's memory port.

Simulator side, :func:`bus`: every requester with random bubbles and response back-pressure;
the memory answers after random delays in random order, with request back-pressure; it records
every transfer and every cycle's request handshakes. :func:`check_bus` applies the Amaranth
bench's rules (``tb/units/bus.py``) to them: every response reaches the requester that asked, once,
with the word at its address (``Outstanding``); at most one grant per cycle and round-robin
fairness in every cycle (``GrantCheck``); the grant and request/response counters.
"""
from __future__ import annotations

import time

import numpy as np

import cocotb

from tb.harness.cocotb.streams import (Memory, Pattern, Sink, Source, Watch, from_ints, load, read_ports, run,
                      save, start, to_ints)

N = 3
UNITS = ("trav", "list", "int")


def run_bus(g, sim: str, run_dir, *, n: int = 200, seed: int = 0, idle: float = 0.3,
            stall: float = 0.3, mem_stall: float = 0.2, max_delay: int = 20, **build_kw):
    """The first ``n`` word reads of each unit of traced scene ``g`` (a ``tb.units.list.Golden``)
    through the exported bus; returns the runner's Result."""
    from model.rtc import memory_trace

    from tb.harness.cocotb.runner import build, interface, pack, port_layout, run as run_bench
    bus = interface("bus", g.cfg)
    tags = 1 << len(bus.inputs[0].req.payload.tag)
    trace = memory_trace(g.events, g.image)
    arrays = {"image": np.asarray(g.image.data, np.uint64)}
    for i, unit in enumerate(UNITS):
        addrs = trace[unit][:n]
        arrays[f"reqs{i}"] = pack(port_layout(bus, f"inputs__{i}__req"),
                                  [{"addr": int(a), "tag": j % tags} for j, a in enumerate(addrs)])
    params = {"seed": seed, "idle": idle, "stall": stall, "mem_stall": mem_stall,
              "max_delay": max_delay, "addr_bits": len(bus.mem.req.payload.addr),
              "data_bits": 64, "in_addr_bits": len(bus.inputs[0].req.payload.addr),
              "resp_bits": port_layout(bus, "inputs__0__resp").size}
    r = run_bench("bus", build("bus", g.cfg, sim, **build_kw), run_dir, params=params,
                  arrays=arrays)
    check_bus(r, bus, arrays)
    return r


def check_bus(r, bus, arrays) -> None:
    """The Amaranth bench's rules (``tb/units/bus.py``) on what the cocotb bench recorded: grants
    cycle by cycle (``GrantCheck``), every response against its requester's reads in flight
    (``Outstanding``, replayed in cycle order), the counters."""
    from tb.units.bus import GrantCheck, Outstanding

    from tb.harness.cocotb.runner import port_layout, unpack
    a, c = r.arrays, r.values["counters"]
    check = GrantCheck(N)
    for cycle, hs in enumerate(a["handshakes"].tolist()):
        check.step(cycle, hs[0::2], hs[1::2])
    assert not check.violations, "; ".join(check.violations[:5])
    sent = [len(arrays[f"reqs{i}"]) for i in range(N)]
    for i in range(N):
        reqs = unpack(port_layout(bus, f"inputs__{i}__req"), arrays[f"reqs{i}"])
        resps = unpack(port_layout(bus, f"inputs__{i}__resp"), a[f"resps{i}"])
        assert len(resps) == sent[i], f"requester {i}: {len(resps)} responses, {sent[i]} reads"
        # a response comes at least a cycle after its request: in a cycle, requests first
        events = sorted([(cy, 0, q) for cy, q in zip(a[f"sent{i}"].tolist(), reqs)] +
                        [(cy, 1, q) for cy, q in zip(a[f"resp_cycles{i}"].tolist(), resps)],
                        key=lambda e: e[:2])
        o = Outstanding(i, arrays["image"])
        for _, kind, q in events:
            if kind == 0:
                o.sent(q["tag"], q["addr"])
            else:
                o.received(q["tag"], q["data"])
        assert not o.tags, f"requester {i}: reads left without a response {o.tags}"
    assert [c[f"grants__{i}"] for i in range(N)] == sent == check.grants, (c, sent)
    assert c["req_cycles"] == c["resp_cycles"] == sum(sent), c


@cocotb.test()
async def bus(dut):
    """Three requesters' golden word streams through the bus to a random-order memory; the
    requests, responses and every cycle's request handshakes are recorded for the checks."""
    p, a = load()
    seed = p["seed"]
    image = a["image"]
    ab = p["in_addr_bits"]
    agents, sinks, sources, handshakes = [], [], [], []
    for i in range(N):
        reqs = to_ints(a[f"reqs{i}"])
        busy: set = set()                 # tags in flight: a tag is reused once it is back

        def may_send(j, busy=busy, reqs=reqs):
            return reqs[j] >> ab not in busy

        def sent(cycle, j, busy=busy, reqs=reqs):
            busy.add(reqs[j] >> ab)

        def received(cycle, payload, busy=busy):
            busy.discard(payload >> p["data_bits"])

        src = Source(dut, f"inputs__{i}__req", reqs, hold=Pattern(p["idle"], seed + 10 * i),
                     may_send=may_send, on_transfer=sent)
        sink = Sink(dut, f"inputs__{i}__resp", hold=Pattern(p["stall"], seed + 10 * i + 1),
                    count=len(reqs), on_transfer=received)
        agents += [src, sink]
        sources.append(src)
        sinks.append(sink)
    names = [f"inputs__{i}__req__{x}" for i in range(N) for x in ("valid", "ready")]
    agents.append(Watch(dut, names, lambda cycle, v: handshakes.append(v)))
    agents.append(Memory(dut, "mem", lambda addr: int(image[addr]), addr_bits=p["addr_bits"],
                         data_bits=p["data_bits"], rng=np.random.default_rng(seed + 2),
                         max_delay=p["max_delay"], hold=Pattern(p["mem_stall"], seed + 3)))
    await start(dut)
    t0 = time.perf_counter()
    cycles = await run(dut, agents, lambda: all(s.done for s in sinks))
    seconds = time.perf_counter() - t0
    counters = await read_ports(dut, [f"grants__{i}" for i in range(N)]
                                + ["req_cycles", "resp_cycles", "cycles"])
    out = {"handshakes": np.array(handshakes, np.uint8).reshape(-1, 2 * N)}
    for i in range(N):
        out[f"sent{i}"] = np.array(sources[i].cycles, np.int64)
        out[f"resp_cycles{i}"] = np.array(sinks[i].cycles, np.int64)
        out[f"resps{i}"] = from_ints(sinks[i].got, p["resp_bits"])
    save(out, cycles=cycles, seconds=seconds, counters=counters)
