"""Traversal unit (``rtl/traversal.py``) against the golden model's event log (``tb/units/traversal.py``)."""
import random

import numpy as np
import pytest
from amaranth.hdl import Module, Signal
from amaranth.sim import Simulator

from model.config import Config
from model.traversal import classify
from rtl.traversal import ThreadState, Traversal, TravSubunit, _Threads
from tb.harness.common import run, synth_check
from tb.units.traversal import COMPARED, run_traversal, small_case

from .conftest import ROOT, TIMING, timing_changed


def check(r):
    assert not r.mismatches
    got = {k: r.counters[k] for k in COMPARED}
    want = {k: r.model[v] for k, v in COMPARED.items()}
    assert got == want
    assert r.counters["packets_done"] == len(r.packets_done)
    assert r.counters["trav_ops"] > 0 and r.leaf_requests == r.model["leaf_visits"] > 0


def test_traversal_replays_model_cornell(kd_cache):
    """2 packets of 64 rays, 4 threads: leaf requests, done and counters as in the model."""
    cfg = Config(threads=4)
    image, rays = small_case(ROOT / "scenes/cornell.toml", 16, 8, cfg, kd_cache)
    r = run_traversal(image, rays, cfg, seed=3)
    check(r)
    assert r.cycles == TIMING["traversal/cornell_16x8"], timing_changed("traversal/cornell_16x8",
                                                                        r.cycles)
    assert sorted(r.packets_done) == [0, 1]
    # the sub-units share the lanes statically: each did some of the work
    assert all(b > 0 for b in r.counters["sub_busy"])


def test_traversal_reuses_threads(kd_cache):
    """4 packets of 16 rays through 2 threads (threads are freed and reloaded), 2 sub-units."""
    cfg = Config(threads=2, tile_w=4, tile_h=4, trav_subunits=2)
    image, rays = small_case(ROOT / "scenes/office.toml", 8, 8, cfg, kd_cache)
    assert rays.n_packets == 4
    r = run_traversal(image, rays, cfg, seed=5, mem_latency=6)
    check(r)
    name = "traversal/office_8x8_reuse"
    assert r.cycles == TIMING[name], timing_changed(name, r.cycles)
    assert sorted(r.packets_done) == list(range(4))


@pytest.mark.parametrize("case", ["cornell_16x8", "office_8x8_reuse"])
def test_traversal_one_value_stack_replays_model(kd_cache, case):
    """``trav_stack="one_value"`` (one value and a keep bit a lane and level): the same leaves,
    done and counters as the model, whose pops take ``[value, tfar]`` or ``[tfar, value]``;
    a pop after a leaf first folds the lanes' intervals into N (a fold through the sub-units,
    no trav-op), so the cycles are pinned apart from the two-value stack's."""
    if case == "cornell_16x8":
        cfg = Config(threads=4, trav_stack="one_value")
        image, rays = small_case(ROOT / "scenes/cornell.toml", 16, 8, cfg, kd_cache)
        r = run_traversal(image, rays, cfg, seed=3)
    else:
        cfg = Config(threads=2, tile_w=4, tile_h=4, trav_subunits=2, trav_stack="one_value")
        image, rays = small_case(ROOT / "scenes/office.toml", 8, 8, cfg, kd_cache)
        r = run_traversal(image, rays, cfg, seed=5, mem_latency=6)
    check(r)
    assert r.model["pushes"] > rays.n_packets            # the stack was used
    name = {"cornell_16x8": "traversal/cornell_16x8_one_value",
            "office_8x8_reuse": "traversal/office_8x8_reuse_one_value"}[case]
    assert r.cycles == TIMING[name], timing_changed(name, r.cycles)
    assert sorted(r.packets_done) == list(range(rays.n_packets))


# the deep settings of the FPGA build (docs/fpga.md): every FP unit and the compare units
# deeper, block-RAM reads registered (fast_clock)
DEEP = dict(fast_clock=True, fp_add_latency=7, fp_mul_latency=5, fp_cmp_latency=3)


def test_traversal_fast_clock_replays_model(kd_cache):
    """The deep settings (longer sub-unit pipeline, registered result read, two-cycle decide):
    the same leaves, done and counters as the model, threads reused, 2 sub-units."""
    cfg = Config(threads=2, tile_w=4, tile_h=4, trav_subunits=2, **DEEP)
    image, rays = small_case(ROOT / "scenes/office.toml", 8, 8, cfg, kd_cache)
    r = run_traversal(image, rays, cfg, seed=5, mem_latency=6)
    check(r)
    assert sorted(r.packets_done) == list(range(4))
    # `busy` counts a cycle later (from a register): it covers every sub-unit's busy cycles
    # but the last one's at most, and no more than the cycles run
    c = r.counters
    assert max(c["sub_busy"]) - 1 <= c["busy"] <= r.cycles, c


def test_synchronous_subunits_step_queues_fill_together(kd_cache):
    """Synchronous sub-units take each step together, so their step queues hold the same
    number of steps in every cycle (the control engine reads the first one's room for all);
    8 threads on 2 sub-units fill the queues (4 steps deep without ``fast_clock``), and the
    leaves still replay the model."""
    cfg = Config(threads=8, tile_w=4, tile_h=4, trav_subunits=2,
                 **{**DEEP, "fast_clock": False})
    assert cfg.trav_sync
    image, rays = small_case(ROOT / "scenes/office.toml", 16, 16, cfg, kd_cache)
    full = []

    def monitor(dut):
        async def watch(ctx):
            async for _, _, *ready in ctx.tick().sample(*(s.step.ready for s in dut.subunits)):
                assert len(set(ready)) == 1, f"step queues differ: ready {ready}"
                full.append(not ready[0])
        return watch

    r = run_traversal(image, rays, cfg, seed=7, mem_latency=6, idle=0.0, monitor=monitor)
    check(r)
    assert sum(full) > 0, "the step queues never filled"


@pytest.mark.parametrize("sync", [True, False], ids=["sync", "async"])
def test_fast_step_queues_never_fill(kd_cache, sync):
    """``fast_clock``: each sub-unit's step queue is as deep as the threads (8), so the control
    engine dispatches without reading their room: no step is ever pushed into a full queue,
    more than 4 steps do wait in a queue at times, and the leaves replay the model."""
    cfg = Config(threads=8, tile_w=4, tile_h=4, trav_subunits=2, trav_sync=sync, **DEEP)
    image, rays = small_case(ROOT / "scenes/office.toml", 16, 16, cfg, kd_cache)
    most = [0] * cfg.trav_subunits

    def monitor(dut):
        subs = dut.subunits
        sigs = [x for s in subs for x in (s.step.valid, s.step.ready, s.can_start, s.go)]

        async def watch(ctx):
            level = [0] * len(subs)
            async for _, _, *v in ctx.tick().sample(*sigs):
                for j in range(len(subs)):
                    valid, ready, can, go = v[4 * j:4 * j + 4]
                    assert ready or not valid, f"a step pushed into sub-unit {j}'s full queue"
                    level[j] += (valid and ready) - (can and go)
                    most[j] = max(most[j], level[j])
        return watch

    r = run_traversal(image, rays, cfg, seed=7, mem_latency=6, idle=0.0, monitor=monitor)
    check(r)
    assert max(most) > 4, f"at most {most} steps waited: a 4-deep queue would have done"


@pytest.mark.parametrize("variant", ["default", "deep", "one_value"])
def test_subunit_classifies_like_model_at_fixed_latency(variant):
    """Steps through one sub-unit: each verdict (near/far masks) equals
    ``model.traversal.classify``; the first comes exactly ``lanes + STEP_LAT`` cycles after its
    transfer; steps of other threads queued behind it follow back to back (one lane per cycle,
    an empty step one cycle, no pipeline drain in between); the stored intervals equal the
    model's clipped near interval (N) and far interval (S[sp]). ``one_value``: N holds the
    interval each lane goes on with (a far-only lane's keeps tfar), and S[sp] read as a popped
    entry gives back tfar."""
    deep = variant == "deep"
    cfg = Config(threads=4, tile_w=4, tile_h=4, trav_subunits=1, kd_max_depth=4,
                 **(DEEP if deep else {}),
                 **({"trav_stack": "one_value"} if variant == "one_value" else {}))
    fmt, R = cfg.fmt, cfg.rays_per_subunit
    rng = np.random.default_rng(7)
    bits = lambda x: int(fmt.to_bits(np.float32(x)))
    steps = []     # (thread, axis, split, sp, mask, org, inv, tnear, tfar)
    for thread, axis, sp, mask in ((1, 1, 2, 0b1011_0110_1111_1011), (3, 0, 1, 0b0110_0000_0001),
                                   (0, 2, 0, 0), (2, 2, 3, 0xFFFF)):
        org = fmt.quantize(rng.uniform(-4, 4, (R, 3))).astype(np.float32)
        d = rng.normal(size=(R, 3)).astype(np.float32)
        d[3, 1] = 0.0                               # inv = inf: dist is +-inf or NaN
        inv = fmt.div(np.float32(1.0), fmt.quantize(d))
        tnear = fmt.quantize(rng.uniform(0, 2, R)).astype(np.float32)
        tfar = fmt.quantize(tnear + rng.uniform(0, 6, R)).astype(np.float32)
        split = np.float32(fmt.quantize(np.float32(rng.uniform(-1, 1))))
        steps.append((thread, axis, split, sp, mask, org, inv, tnear, tfar))
    want = []
    for thread, axis, split, sp, mask, org, inv, tnear, tfar in steps:
        dist = np.zeros(R, np.float32)
        tn, tf = tnear.copy(), tfar.copy()
        mn, mf = classify(split, axis, np.uint64(mask), R, org, inv, tn, tf, dist, *fmt.em)
        want.append((int(mn), int(mf), dist))

    dut = TravSubunit(cfg)
    got = {"res": [], "at": []}

    async def tb(ctx):
        for thread, axis, split, sp, mask, org, inv, tnear, tfar in steps:
            for lane in range(R):
                ctx.set(dut.ld_en, 1)
                ctx.set(dut.ld_thread, thread)
                ctx.set(dut.ld_lane, lane)
                ctx.set(dut.ld_org, [bits(x) for x in org[lane]])
                ctx.set(dut.ld_inv, [bits(x) for x in inv[lane]])
                ctx.set(dut.ld_tnear, bits(tnear[lane]))
                ctx.set(dut.ld_tfar, bits(tfar[lane]))
                await ctx.tick()
        ctx.set(dut.ld_en, 0)
        ctx.set(dut.res.ready, 1)
        cycle, sent = 0, 0
        while len(got["res"]) < len(steps):
            if sent < len(steps):
                thread, axis, split, sp, mask = steps[sent][:5]
                ctx.set(dut.step.payload, {"thread": thread, "axis": axis, "split": bits(split),
                                           "sp": sp, "cur": 0, "mask": mask})
                ctx.set(dut.step.valid, 1)
                sent += ctx.get(dut.step.ready)
            else:
                ctx.set(dut.step.valid, 0)
            if ctx.get(dut.res.valid):
                p = ctx.get(dut.res.payload)
                got["res"].append((p["near"], p["far"]))
                got["at"].append(cycle)
            await ctx.tick()
            cycle += 1
            assert cycle < 500
        ctx.set(dut.step.valid, 0)
        while not ctx.get(dut.idle):
            await ctx.tick()
        got["tfar_n"], got["tfar_s"] = {}, {}
        for thread, axis, split, sp, mask in (s[:5] for s in steps):
            for cur, key in ((0, "tfar_n"), (1, "tfar_s")):
                for lane in range(R):
                    ctx.set(dut.rq_thread, thread)
                    ctx.set(dut.rq_lane, lane)
                    ctx.set(dut.rq_sp, sp)
                    ctx.set(dut.rq_cur, cur)
                    for _ in range(dut.RQ_LAT):
                        await ctx.tick()
                    got[key][thread, lane] = ctx.get(dut.rq_tfar)

    run(dut, tb)
    assert got["res"] == [(mn, mf) for mn, mf, _ in want]
    lanes = [max(1, bin(s[4]).count("1")) for s in steps]     # an empty step takes one cycle
    # the first step was transferred in cycle 0 (the queue had room), the others queued
    # behind it: each verdict follows the previous one by the step's issue cycles
    assert dut.STEP_LAT == (2 + 3 + 3 + 1 + 2 if not deep else 2 + 7 + 5 + 3 + 2)
    assert got["at"][0] == lanes[0] + dut.STEP_LAT
    assert [b - a for a, b in zip(got["at"], got["at"][1:])] == lanes[1:]
    for (thread, axis, split, sp, mask, org, inv, tnear, tfar), (mn, _, dist) in zip(steps, want):
        act = [l for l in range(R) if mask >> l & 1]
        # near interval's tfar = min(tfar, dist); the far interval keeps tfar
        near = [(mn >> l) & 1 or variant != "one_value" for l in act]
        assert [got["tfar_n"][thread, l] for l in act] == \
            [bits(fmt.min(tfar[l], dist[l]) if nr else tfar[l]) for l, nr in zip(act, near)]
        assert [got["tfar_s"][thread, l] for l in act] == [bits(tfar[l]) for l in act]


@pytest.mark.parametrize("sync", [True, False], ids=["sync", "async"])
def test_traversal_subunit_modes(kd_cache, sync):
    """Synchronous and asynchronous sub-units: the same leaves, done and counters as the model
    (the office, 4 threads, 4 sub-units over 16-ray packets, so groups are often idle)."""
    cfg = Config(threads=4, tile_w=4, tile_h=4, trav_subunits=4, trav_sync=sync)
    image, rays = small_case(ROOT / "scenes/office.toml", 8, 8, cfg, kd_cache)
    r = run_traversal(image, rays, cfg, seed=9, mem_latency=8)
    check(r)
    assert sorted(r.packets_done) == list(range(rays.n_packets))


@pytest.mark.slow
@pytest.mark.parametrize("stack", ["two_values", "one_value"])
def test_traversal_synthesizes_without_latches(stack):
    """A small configuration through Yosys ``synth -flatten`` (memories become flip-flops)."""
    cfg = Config(threads=2, tile_w=2, tile_h=2, trav_subunits=2, kd_max_depth=2,
                 trav_stack=stack)
    stat = synth_check(Traversal(cfg), "traversal")
    assert "Number of cells" in stat or "cells" in stat


def test_thread_state_flags_follow_the_state_registers():
    """``fast_clock``'s registered state flags (``_Threads.in_states_q``) equal the decode of
    the state registers in every cycle, under random writes from writers of constant and of
    signal values, by thread index and by one-hot enable (at most one writer per thread)."""
    cfg = Config(threads=4, fast_clock=True)
    T, states = cfg.threads, list(ThreadState)
    m = Module()
    th = _Threads(cfg, 1)
    wait = (ThreadState.HAVE_NODE, ThreadState.POP, ThreadState.NEXTPASS)
    flags_a, flags_b = th.in_states_q(*wait), th.in_states_q(ThreadState.FREE)
    en = [Signal(name=f"en{i}") for i in range(2)]
    tgt = [Signal(range(T), name=f"tgt{i}") for i in range(2)]
    val = [Signal(ThreadState, name=f"val{i}") for i in range(2)]
    oh = Signal(T)
    with m.If(en[0]):
        th.set_state(m, tgt[0], ThreadState.POP)
    with m.If(en[1]):
        th.set_state(m, tgt[1], val[0])
    th.set(m, "state", None, val[1], onehot=oh)
    th.finish(m)
    rng = random.Random(21)

    async def bench(ctx):
        for _ in range(400):
            free = list(range(T))
            rng.shuffle(free)
            for i in range(2):
                ctx.set(en[i], rng.random() < 0.6)
                ctx.set(tgt[i], free[i])
                ctx.set(val[i], rng.choice(states))
            ctx.set(oh, sum(1 << t for t in free[2:] if rng.random() < 0.5))
            await ctx.tick()
            st = [ThreadState(ctx.get(th.state[t])) for t in range(T)]
            assert ctx.get(flags_a) == sum(1 << t for t in range(T) if st[t] in wait)
            assert ctx.get(flags_b) == sum(1 << t for t in range(T)
                                           if st[t] == ThreadState.FREE)

    sim = Simulator(m)
    sim.add_clock(1e-6)
    sim.add_testbench(bench)
    sim.run()
