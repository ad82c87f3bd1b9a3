"""The whole chip (``rtl/chip.py``) on a frame, against the golden model.

* :func:`frame_registers`: what the host writes into the chip's registers for a frame: image
  constants, scene box, the camera as ``model.raygen.eye_rays`` quantizes it, image and tile
  counts, the number of rays.
* :class:`~tb.harness.chip_frame.ChipFrame`: the chip with :class:`~tb.harness.memory.SDRAMMemory` (``cfg.mem_chips`` chips,
  the configuration's clock ratio and latency) behind its port, loadable (Verilator: one
  binary per configuration serves every scene and camera) or preloaded (Amaranth simulation);
  LFSR back-pressure on the results.
* :func:`run_chip` (Amaranth's simulator) and :func:`run_chip_frame` (Verilator): one frame;
  every ray's result against ``model.rtc.trace`` of the model's eye rays (``tb/harness/compare.py``),
  and the chip's counters; the two give the same cycle count.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from model.config import Config
from model.raygen import camera_registers, eye_rays
from model.rgs import FIX_FRAC
from model.rtc import counter_totals, trace
from rtl.chip import Chip, counter_names
from rtl.cache import STALLS as CACHE_STALLS
from rtl.rtcmi import CACHES

from tb.harness import compare
from tb.harness.chip_frame import REGISTERS, ChipFrame, chip_consts, chip_counter_names

# the chip's Verilator binary holds this many memory words at least (64 MB, any scene up to
# about a million triangles), so one build per configuration serves every scene
CHIP_MIN_MEM_WORDS = 1 << 23

__all__ = ["CHIP_MIN_MEM_WORDS", "chip_build", "frame_registers", "ChipFrame", "ChipRun", "run_chip", "run_chip_frame",
           "chip_consts", "chip_counter_names", "const_values", "chip_blocks"]


def frame_registers(cfg: Config, image, camera, width: int, height: int,
                    scene=None, box_cull: bool = True) -> dict:
    """The chip's host registers for a ``width x height`` frame of ``camera`` (values as the
    chip's ports take them: format words as their bit patterns). With ``scene`` the slaves make
    its secondary rays (a shadow ray per light, if ``cfg.shadows``; reflections, and refracted
    rays with ``cfg.refraction``, to ``cfg.reflect_depth``) from the image's slave records;
    without, eye rays only.
    ``box_cull=False`` turns the slaves' box cull off (only to measure what it saves)."""
    from model.shading import Shader, frame_colour_registers, surface_offset
    fmt, n = cfg.fmt, cfg.oversampling
    sw, sh = width * n, height * n
    pos, corner, dx, dy = camera_registers(camera, width, height, cfg)
    bits = lambda v: [int(b) for b in fmt.to_bits(np.asarray(v, np.float32))]  # noqa: E731
    lights = scene.lights if scene is not None and cfg.shadows else []
    if len(lights) > cfg.rgs_lights:
        raise ValueError(f"the scene has {len(lights)} lights; the chip's slaves hold "
                         f"rgs_lights={cfg.rgs_lights}: raise --rgs-lights")
    transmits = [m for m in (scene.materials if scene is not None else []) if m.transmit > 0]
    if transmits and cfg.reflect_depth > 0 and not cfg.refraction:
        raise ValueError("the scene has a material that transmits (refracted rays), the "
                         "chip's RGS slaves make none: set refraction=True (--refraction "
                         "true)")
    if cfg.refraction and any(m.texture is not None for m in transmits):
        raise ValueError("a material that transmits has a texture: the slaves' records hold "
                         "its refraction constants where a texture's coordinates go "
                         "(model.layout.REC_KT); give it no texture")
    depth = cfg.reflect_depth if scene is not None else 0
    rec_base = image.shading_header()["rec_base"]
    if (lights or depth) and not rec_base:
        raise ValueError("the memory image has no slave records (build it with shading data: "
                         "model.render.prepare) but the frame has secondary rays")
    vecs, point = [], 0
    if lights:
        shader = Shader(scene, fmt, eps=0.0)
        for li, light in enumerate(lights):
            v, pt = shader.light_vector(light)
            vecs.append(bits(v))
            point |= int(pt) << li
    vecs += [[0, 0, 0]] * (max(1, cfg.rgs_lights) - len(vecs))
    eps = fmt.quantize(surface_offset(image.bounds))
    col = frame_colour_registers(scene, fmt, n * n) if scene is not None else None
    lcols = [bits(c) for c in col["lights"][:len(lights)]] if col is not None else []
    lcols += [[0, 0, 0]] * (max(1, cfg.rgs_lights) - len(lcols))
    regs = {
        "node_base": image.node_base, "list_base": image.list_base,
        "tri_base": image.tri_base, "root": image.root, "rec_base": rec_base,
        "box_lo": bits(image.bounds[0]), "box_hi": bits(image.bounds[1]),
        "pos": bits(pos), "corner": bits(corner), "dx": bits(dx), "dy": bits(dy),
        "width": width, "height": height,
        "tiles_x": -(-sw // cfg.tile_w), "tiles_y": -(-sh // cfg.tile_h),
        "eps": bits([eps])[0], "light_point": point, "n_lights": len(lights),
        "reflect_depth": depth,
        "amb": bits([col["amb"]])[0] if col is not None else 0,
        "bg": bits(col["bg"]) if col is not None else [0, 0, 0],
        "w_eye": bits([col["w_eye"]])[0] if col is not None else 0,
        "eye_miss": [int(x) for x in col["eye_miss"]] if col is not None else [0, 0, 0],
        "colour": int(col is not None and cfg.secondary_rays),
        "box_cull": int(box_cull),
    }
    for li, v in enumerate(vecs):
        regs[f"light{li}"] = v
    for li, v in enumerate(lcols):
        regs[f"lcol{li}"] = v
    return regs


_GOLDEN: list = []      # the last golden frame: (its inputs, its result)


def golden_frame(cfg: Config, image, camera, width: int, height: int, scene=None,
                 box_cull: bool = True):
    """What the chip must report for the frame of :func:`frame_registers`: ``(eye rays, every
    ray with its id, their hits, the model's counter totals, the pixels' fixed-point colour
    sums or None)``. With ``scene``: ``model.render.render``'s ray tree (the same rays in the
    same packets as the slaves make them) and its colour (with textures where the slaves have
    a texture unit, ``cfg.tex_cache_kb > 0``) — None where the chip makes no colour:
    eye-ray-only slaves, or a scene with lights rendered without shadow rays (the slaves shade
    only with the lights they cast shadow rays to); without ``scene``: ``model.rtc.trace`` of
    the eye rays. The last frame's result is kept: a stall bench asks for the same frame with
    every seed (the same objects, configuration and size give the same result).
    ``box_cull=False``: the frame without the box cull (``model.render.Skip``)."""
    objects, values = (image, camera, scene), (cfg, width, height, box_cull)
    if _GOLDEN:
        (o, v), out = _GOLDEN[0]
        if all(a is b for a, b in zip(o, objects)) and v == values:
            return out
    out = _golden_frame(cfg, image, camera, width, height, scene, box_cull)
    _GOLDEN[:] = [((objects, values), out)]
    return out


def _golden_frame(cfg: Config, image, camera, width: int, height: int, scene=None,
                  box_cull: bool = True):
    eye = eye_rays(camera, width, height, cfg)
    if scene is None:
        hits, ctrs = trace(image, eye, cfg, box_cull=box_cull)
        return eye, eye, hits, counter_totals(ctrs), None
    from model.render import Prepared, Skip, render
    res = render(scene, cfg, width, height,
                 prepared=Prepared(image, None, np.zeros((0, 3, 3), np.float32), 0.0, False),
                 skip=Skip(box_cull=box_cull))
    colour = res.colour if cfg.secondary_rays and (cfg.shadows or not scene.lights) else None
    return eye, res.rays, res.hits, res.counters, colour


def colour_mismatches(records: dict, eye, colour: np.ndarray) -> tuple[list, np.ndarray]:
    """The chip's pixel colours (:func:`record_colour`) against the model's fixed-point sums
    ``colour`` ((pixels, 3)): ``(pixel, "colour", chip, model)`` for every pixel that differs
    (three 24-bit channels packed, red lowest) and the chip's image ((pixels, 3) float32)."""
    got = record_colour(records, eye, len(colour))
    pack = lambda c: int(c[0]) | int(c[1]) << 24 | int(c[2]) << 48  # noqa: E731
    bad = [(int(p), "colour", pack(got[p]), pack(colour[p]))
           for p in np.flatnonzero(np.any(got != colour, axis=1))]
    return bad, (got / float(1 << FIX_FRAC)).astype(np.float32)


def record_colour(records: dict, eye, n_pixels: int) -> np.ndarray:
    """The colour sums ((n_pixels, 3) int64) of the chip's records (every record adds its
    ``col`` to the pixel of its eye ray: ``packet``, ``lane``)."""
    pk = np.asarray(eye.pk_start, np.int64)
    ray = pk[np.asarray(records["packet"], np.int64)] + np.asarray(records["lane"], np.int64)
    out = np.zeros((n_pixels, 3), np.int64)
    col = np.stack([np.asarray(records[f"col{c}"], np.int64) for c in range(3)], axis=1)
    np.add.at(out, eye.pixel[ray], col)
    return out


@dataclass
class ChipRun:
    cycles: int
    seconds: float
    rays: int
    counters: dict                 # the chip's counters (per RTC, caches, memory)
    model: dict                    # the model's counter totals
    mismatches: list = field(default_factory=list)
    hits: object = None            # the chip's hits of the eye rays (model.rtc.Hits, scene ids)
    eye: object = None             # the frame's eye rays (model.raygen.Rays) the hits belong to
    frame_rays: object = None      # every ray of the frame (eye, shadow, reflection), with ids
    frame_hits: object = None      # the chip's hits of every ray
    color: np.ndarray | None = None   # the chip's colour image ((pixels, 3) float32 linear),
                                      # where it makes one (golden_frame)
    build: object = None           # the Verilator binary (tb.harness.verilator.FrameBuild), if any
    # counters every ``sample_every`` cycles: columns cycle, results, then chip_counter_names
    samples: np.ndarray | None = None
    # wall seconds of the frame's host-side steps (run_chip_frame): build, input file,
    # simulation, golden model, check
    timings: dict = field(default_factory=dict)


def const_values(cfg: Config, regs: dict, *, stall: float = 0.0, seed: int = 1,
                 mem_stall: float = 0.0) -> dict:
    """``{name: value}`` of :func:`chip_consts` for a frame's registers ``regs``."""
    from tb.harness.lfsr import lfsr_seeds, sixteenths
    seeds = lfsr_seeds(seed, 3)
    vals = {"stall_q": sixteenths(stall, "stall"), "seed": seeds[1],
            "mem_stall_q": sixteenths(mem_stall, "mem_stall"), "mem_seed": seeds[2]}
    for k, vec in REGISTERS.items():
        if vec:
            vals.update({f"{k}_{i}": regs[k][i] for i in range(3)})
        else:
            vals[k] = regs[k]
    for li in range(max(1, cfg.rgs_lights)):
        vals.update({f"light{li}_{i}": regs[f"light{li}"][i] for i in range(3)})
        vals.update({f"lcol{li}_{i}": regs[f"lcol{li}"][i] for i in range(3)})
    return vals


def chip_blocks(cfg: Config, image, regs: dict, *, stall: float = 0.0, seed: int = 1,
                mem_stall: float = 0.0) -> list:
    """The load blocks of a frame for :class:`ChipFrame`: the memory image and the
    constants (:func:`chip_consts` order)."""
    from tb.harness.frame import SEL_CONST, SEL_IMAGE
    vals = const_values(cfg, regs, stall=stall, seed=seed, mem_stall=mem_stall)
    consts = np.array([vals[n] for n in chip_consts(cfg)], np.uint64)
    return [(SEL_IMAGE, 0, np.asarray(image.data, np.uint64)), (SEL_CONST, 0, consts)]


def run_chip_frame(cfg: Config, image, camera, width: int, height: int, *, stall: float = 0.0,
                   seed: int = 1, mem_stall: float = 0.0, max_cycles: int = 100_000_000,
                   trace_file=None, trace_from: int = 0, progress: bool = True,
                   mem_words: int | None = None, build_root=None, log=None,
                   sample_every: int = 0, scene=None, box_cull: bool = True) -> ChipRun:
    """One frame through :class:`ChipFrame` in Verilator (built once per configuration),
    every ray compared with the golden model as :func:`run_chip` does in pysim. ``stall``:
    result back-pressure; ``mem_stall``: random memory latency (both fractions of cycles,
    LFSRs seeded by ``seed``); ``trace_file`` from run cycle ``trace_from``; the counters
    every ``sample_every`` cycles in ``ChipRun.samples``; ``scene``: with its secondary rays,
    ``box_cull``: the slaves' box cull on or off (:func:`frame_registers`)."""
    import sys

    from rtl.rgs import SlaveResult

    from tb.harness.verilator import FrameError, _field, _trace_kind, run_binary, write_blocks
    log = sys.stderr if log is None else log
    regs = frame_registers(cfg, image, camera, width, height, scene, box_cull)
    rays = eye_rays(camera, width, height, cfg)
    words = len(image.data)
    if mem_words is not None and words > mem_words:
        raise ValueError(f"the memory image has {words} words, mem_words={mem_words} holds "
                         "fewer (leave mem_words out to size the binary from the image)")
    import time
    t0 = time.perf_counter()
    b = chip_build(cfg, words if mem_words is None else mem_words,
                   trace=_trace_kind(trace_file), build_root=build_root, log=log)
    took = {"build_s": time.perf_counter() - t0}
    names = chip_counter_names(cfg)

    def timed(key, f, *a):
        t = time.perf_counter()
        try:
            return f(*a)
        finally:
            took[key] = time.perf_counter() - t

    # the golden model traces the frame while the simulation runs (another thread; numba
    # releases the GIL)
    from concurrent.futures import ThreadPoolExecutor
    pool = ThreadPoolExecutor(max_workers=1)
    golden = pool.submit(timed, "golden_s", golden_frame, cfg, image, camera, width, height,
                         scene, box_cull)
    pool.shutdown(wait=False)
    t1 = time.perf_counter()
    out = run_binary(b, lambda f: timed("input_s", write_blocks, f, chip_blocks(
                         cfg, image, regs, stall=stall, seed=seed, mem_stall=mem_stall)),
                     cfg, len(rays), max_cycles=max_cycles, trace_file=trace_file,
                     trace_from=trace_from, progress=progress, log=log,
                     desc="chip (Verilator)", names=names, allow_limit=True,
                     sample_every=sample_every, ray_bit=_record_bit(cfg, "shade"),
                     res_ports=cfg.result_ports,
                     total=lambda wait=False: (len(golden.result()[1])
                                               if wait or golden.done() else None))
    took["simulation_s"] = time.perf_counter() - t1 - took.get("input_s", 0.0)
    t2 = time.perf_counter()
    golden.result()
    took["golden_wait_s"] = time.perf_counter() - t2
    lay = SlaveResult(cfg)
    records = {name: _field(out.results, off, wd)
               for name, off, wd in compare.record_fields(lay)}
    if out.status == 2:
        raise FrameError(stuck(cfg, rays, records, out.counters, max_cycles,
                               golden.result()[1]))
    t3 = time.perf_counter()
    run = _finish(cfg, image, records, out.cycles, out.seconds, out.counters,
                  golden.result())
    took["check_s"] = time.perf_counter() - t3
    run.build, run.samples = b, out.samples
    run.timings = {k: round(v, 3) for k, v in took.items()}
    return run


def _record_bit(cfg: Config, name: str) -> int:
    """The bit offset of field ``name`` in the chip's result record (``SlaveResult``)."""
    from rtl.rgs import SlaveResult
    return next(off for f, off, _ in compare.record_fields(SlaveResult(cfg)) if f == name)


def chip_build(cfg: Config, mem_words: int, *, trace=False, build_root=None, log=None):
    """The Verilator binary of :class:`ChipFrame` for ``cfg`` holding at least ``mem_words``
    words (rounded up to a power of two, at least :data:`CHIP_MIN_MEM_WORDS`): built, or found
    in ``build_root`` (default ``build/verilator``). Returns a ``tb.harness.verilator.FrameBuild``."""
    import os

    from tb.harness.verilator import BUILD_ROOT, BUILD_ROOT_ENV, _pow2, build
    build_root = build_root or os.environ.get(BUILD_ROOT_ENV) or BUILD_ROOT
    return build(cfg, mem_words=_pow2(mem_words, CHIP_MIN_MEM_WORDS), ray_slots=0,
                 mem_latency=cfg.mem_latency, trace=trace, root=build_root,
                 log=log, top="chip")


def stuck(cfg: Config, rays, records: dict, c: dict, max_cycles: int, every=None) -> str:
    """What did not finish by the cycle limit: the eye packets (tiles) with results missing
    and, per RTC, the packets it was given against those its traversal finished. ``rays``: the
    eye rays; ``every``: all the frame's rays (with their eye ray's id), if not just those."""
    every = rays if every is None else every
    n = len(rays.pk_start) - 1
    ids = np.asarray(every.eye, np.int64)
    tile = np.searchsorted(rays.pk_start, ids, side="right") - 1
    sizes = np.bincount(tile, minlength=n)
    ray_rec = np.asarray(records.get("shade", np.zeros(len(records["packet"]), np.int64))) == 0
    got = np.bincount(np.asarray(records["packet"], np.int64)[ray_rec], minlength=n)
    missing = [int(p) for p in np.flatnonzero(got[:n] < sizes)]
    per_rtc = [f"RTC {r}: {c[f'packets{r}']} packets in, {c[f'rtc{r}_packets_done']} done"
               for r in range(cfg.rtcs)]
    return (f"chip (Verilator): {int(ray_rec.sum())} of {len(ids)} results after "
            f"max_cycles={max_cycles}; packets never finished: {missing[:20]}; "
            f"{'; '.join(per_rtc)}; rays into the RTCs {c['rays_in']} (a deadlock, or raise "
            "the cycle limit)")


def _finish(cfg: Config, image, records: dict, cycles: int, seconds: float, c: dict,
            golden) -> ChipRun:
    """Compare result ``records`` (``SlaveResult`` fields) with the model's ``golden``
    (:func:`golden_frame`); counters ``c`` by :func:`chip_counter_names`."""
    eye, rays, hits, model_totals, colour = golden
    shade = np.asarray(records["shade"]) == 1
    by_ray = compare.results_by_id({k: np.asarray(v)[~shade] for k, v in records.items()},
                                   rays, eye.pk_start)
    chip_hits = compare.hits_of(by_ray, cfg, image)
    counters = {"cycles": cycles, "rays_in": c["rays_in"], "results_out": c["results_out"],
                # every record on the result streams: ray results and the hits' ambient records
                "records_out": int(len(shade)),
                "mem_reads": c["mem_reads"],
                "packets": [c[f"packets{s}"] for s in range(cfg.rtcs)],
                # the SDRAM chips' counters (none when the memory is not the SDRAM model)
                "mem_words": [c[f"chip{k}_words"] for k in range(cfg.mem_chips)
                              if f"chip{k}_words" in c],
                "mem_busy": [c[f"chip{k}_busy"] for k in range(cfg.mem_chips)
                             if f"chip{k}_busy" in c],
                "rtc": [{k: c[f"rtc{r}_{k}"] for k in counter_names(cfg)}
                        for r in range(cfg.rtcs)],
                "slave": [{k: c[f"slave{r}_{k}"] for k in Chip.SLAVE_COUNTERS}
                          for r in range(cfg.rtcs)]}
    shared = cfg.cache_topology == "shared"
    for k in ("hits", "misses", "grants"):   # per RTC: its slave's caches, its own RTC-MI's
        counters[k] = [{**({} if shared else {cc: c[f"rtc{r}_{cc}_{k}"] for cc in CACHES}),
                        "shade": c[f"slave{r}_shade_{k}"], "tex": c[f"slave{r}_tex_{k}"]}
                       for r in range(cfg.rtcs)]
    # the RTC-MI's three caches as a whole (shared, or the private ones added up)
    counters["rtcmi"] = {
        cc: ({k: c[f"rtcmi_{cc}_{k}"] for k in ("hits", "misses", "grants", "waits")}
             | {"stalls": {k: c[f"rtcmi_{cc}_{k}"] for k in CACHE_STALLS}}
             if shared else {**{k: sum(x[cc] for x in counters[k])
                                for k in ("hits", "misses", "grants")}, "waits": 0})
        for cc in CACHES}
    n_eye = len(eye)
    from model.rtc import Hits
    eye_hits = Hits(*(getattr(chip_hits, f)[:n_eye] for f in ("tri", "t", "u", "v")))
    mismatches = compare.result_mismatches(by_ray, compare.expected(hits, cfg, image))
    color = None
    if colour is not None:
        bad, color = colour_mismatches(records, eye, colour)
        mismatches += bad
    return ChipRun(cycles, seconds, len(rays), counters, model_totals, mismatches,
                   eye_hits, eye, rays, chip_hits, color=color)


def run_chip(cfg: Config, image, camera, width: int, height: int, *, stall: float = 0.0,
             seed: int = 1, mem_stall: float = 0.0, max_cycles: int = 1_000_000,
             sample_every: int = 0, vcd: str | None = None, scene=None,
             box_cull: bool = True) -> ChipRun:
    """One frame through :class:`ChipFrame` in Amaranth's simulator (memory image and
    registers preloaded), every ray compared with the golden model; the same cycles as
    :func:`run_chip_frame` in Verilator for the same ``stall`` and ``seed``; ``sample_every``
    and the samples as there; ``vcd``: a waveform of the whole run; ``scene``: with its
    secondary rays; ``box_cull`` as there."""
    from amaranth.sim import Simulator

    from rtl.rgs import SlaveResult
    regs = frame_registers(cfg, image, camera, width, height, scene, box_cull)
    rays = eye_rays(camera, width, height, cfg)
    top = ChipFrame(cfg, mem_words=len(image.data), verilog_memories=False,
                    preload={"image": image.data,
                             "consts": const_values(cfg, regs, stall=stall, seed=seed,
                                                    mem_stall=mem_stall)})
    sim = Simulator(top)
    sim.add_clock(1e-8)
    got, info, rows = [], {}, []
    names = chip_counter_names(cfg)
    ports = cfg.result_ports
    wd = len(top.res_data) // ports

    def unpack(v: int) -> list[int]:
        return [(v >> (32 * i)) & 0xFFFFFFFF for i in range(len(names))]

    async def bench(ctx):
        ctx.set(top.start, 1)
        await ctx.tick()
        ctx.set(top.start, 0)
        t0 = time.process_time()
        cycles = 0
        while cycles < max_cycles:
            _, _, fin, valid, data, ctrs, cyc = await ctx.tick().sample(
                top.finished, top.res_valid, top.res_data, top.counters, top.cycles)
            for i in range(ports):          # the result streams' transfers, in port order
                if (valid >> i) & 1:
                    got.append((data >> (i * wd)) & ((1 << wd) - 1))
            if fin:
                break
            cycles += 1
            if sample_every and cycles % sample_every == 0:
                rows.append([cycles, len(got), *unpack(int(ctrs))])
        info.update(seconds=time.process_time() - t0, finished=bool(fin), cycles=int(cyc),
                    counters=int(ctrs))

    sim.add_testbench(bench)
    if vcd:
        with sim.write_vcd(vcd):
            sim.run()
    else:
        sim.run()
    if not info["finished"]:
        raise AssertionError(f"chip frame: {len(got)} of {len(rays)} results after "
                             f"{max_cycles} cycles (deadlock?)")
    lay = SlaveResult(cfg)
    records = {name: np.array([(v >> off) & ((1 << wd) - 1) for v in got], np.int64)
               for name, off, wd in compare.record_fields(lay)}
    c = dict(zip(names, unpack(info["counters"])))
    run = _finish(cfg, image, records, info["cycles"], info["seconds"], c,
                  golden_frame(cfg, image, camera, width, height, scene, box_cull))
    if sample_every:
        rows.append([info["cycles"], len(got), *unpack(info["counters"])])
        run.samples = np.array(rows, np.int64)
    return run
