"""cocotb bench of the RGS slave's exported Verilog (tops ``ray_setup`` and ``rgs_eye``).

Pytest side: the streams of the Amaranth bench ``tb/units/rgs.py`` (``ray_setup_streams``: rays with
the edge cases of ray setup, ``edge_rays``, and the model's ``RayIn`` s; ``eye_ray_streams``:
packet requests and the model's eye rays with their pixels), the box and camera registers as
constant inputs (a register of three format words is one vector, word 0 in the low bits).

Simulator side, :func:`stream_map`: one input stream with random bubbles, one output stream
with random back-pressure, every output checked bit for bit and in order.
"""
from __future__ import annotations

import time

import cocotb

from tb.harness.cocotb.streams import Fields, Pattern, Sink, Source, load, run, save, start, to_ints


def _vector(words, width: int) -> int:
    return sum(int(w) << (width * i) for i, w in enumerate(words))


def _run(top: str, cfg, sim: str, run_dir, consts: dict, inputs: list, want: list, *,
         in_port: str, out_port: str, seed: int, idle: float, stall: float, **build_kw):

    from tb.harness.cocotb.runner import build, fields, interface, pack, port_layout, run as run_bench
    dut = interface(top, cfg)
    out = port_layout(dut, out_port)
    params = {"seed": seed, "idle": idle, "stall": stall, "consts": consts,
              "in_port": in_port, "out_port": out_port, "out_fields": fields(out)}
    arrays = {"inputs": pack(port_layout(dut, in_port), inputs), "expect": pack(out, want)}
    return run_bench("rgs", build(top, cfg, sim, **build_kw), run_dir, params=params,
                     arrays=arrays)


def run_ray_setup(rays, bounds, cfg, sim: str, run_dir, *, seed: int = 1, idle: float = 0.25,
                  stall: float = 0.25, **build_kw):
    """``rays`` through the exported ``ray_setup`` against the box ``bounds``."""
    from tb.units.rgs import _words, ray_setup_streams
    inputs, want = ray_setup_streams(rays, bounds, cfg)
    w = cfg.fmt.width
    consts = {"box_lo": _vector(_words(cfg.fmt, bounds[0]), w),
              "box_hi": _vector(_words(cfg.fmt, bounds[1]), w), "box_cull": 1}
    return _run("ray_setup", cfg, sim, run_dir, consts, inputs, want, in_port="i",
                out_port="o", seed=seed, idle=idle, stall=stall, **build_kw)


def run_eye_rays(camera, width: int, height: int, cfg, bounds, sim: str, run_dir, *,
                 tiles=None, packet_ids=None, seed: int = 1, idle: float = 0.25,
                 stall: float = 0.25, **build_kw):
    """Packet requests for ``tiles`` of a ``width x height`` frame through the exported
    ``rgs_eye``; every eye ray (and its pixel) against the model's."""
    from tb.units.rgs import eye_ray_streams
    regs, reqs, want = eye_ray_streams(camera, width, height, cfg, bounds, tiles=tiles,
                                       packet_ids=packet_ids)
    consts = {k: _vector(v, cfg.fmt.width) for k, v in regs.items()}
    consts.update(width=width, height=height, box_cull=1)
    return _run("rgs_eye", cfg, sim, run_dir, consts, reqs, want, in_port="req",
                out_port="o", seed=seed, idle=idle, stall=stall, **build_kw)


@cocotb.test()
async def stream_map(dut):
    """One stream in, one stream out: every output against the model's, in order."""
    p, a = load()
    seed = p["seed"]
    src = Source(dut, p["in_port"], to_ints(a["inputs"]), hold=Pattern(p["idle"], seed))
    sink = Sink(dut, p["out_port"], hold=Pattern(p["stall"], seed + 1),
                expect=to_ints(a["expect"]), fields=Fields(p["out_fields"]))
    await start(dut, p["consts"])
    t0 = time.perf_counter()
    cycles = await run(dut, [src, sink], lambda: sink.done)
    save(cycles=cycles, seconds=time.perf_counter() - t0, outputs=len(sink.got))
