"""``make sim``: a frame through the whole chip (``rtl/chip.py``), every ray checked.

The chip renders the frame: its RGS slaves make the eye rays in FP hardware from the camera
registers and, from the results, the shadow and reflection rays and every pixel's colour; its
RTCs trace the rays through their caches, the round-robin bus and the SDRAM model.
The simulation runs in Verilator (default; the binary is built once per configuration and
cached in ``build/verilator/``) or in Amaranth's simulator (``--backend amaranth``, small
frames). Every ray's result (triangle, t, u, v bits) and every pixel's colour is compared
with the golden model (``model.render``): a mismatch exits with status 1 and names the rays
or pixels.

Outputs in ``--out`` (default ``build/sim``):

* ``image.png``: the chip's own colour: every pixel the sum of what its RGS slaves computed
  for its rays (ambient, the Phong term of every light a shadow ray reached, reflections,
  background, textures bilinearly filtered by the slaves' texture units; ``model.shading``),
  checked pixel for pixel against the golden model. Where the chip makes no colour (eye-ray-only slaves,
  ``--eye-only``, lights without shadow rays) the chip's hits are shaded on the host instead.
* ``stats.json``: cycles, fps at ``clock_mhz``, the paper's relative performance (fps /
  fps_ideal), op counts, cache hit rates, memory traffic per SDRAM chip, unit and bus usage,
  mismatches, simulator speed and the whole configuration (see :func:`frame_stats`).
* ``rays.npz`` / ``hits.npz``: the rays and the chip's hits in the golden model's format.
* ``usage.png``: unit usage, memory-port usage and cache hit rates over the frame, and each
  SDRAM chip's share of the words (the counters sampled every ``--sample-every`` cycles).

CLI: ``saarcor sim [--scene PATH] [--res WxH] [--backend verilator|amaranth] [config options]
[--out DIR]`` (``--help``).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from model.config import Config
from model.raykind import RayKind
from saarcor.args import resolve_scene
from saarcor.outputs import OutputDir

__all__ = ["relative_performance", "frame_stats", "shade_eye_hits", "write_usage_plot",
           "main"]

ROOT = Path(__file__).resolve().parents[1]
UNITS = ("trav", "list", "int")
OUTPUTS = ("image.png", "stats.json", "rays.npz", "hits.npz", "usage.png")
"""What ``saarcor sim`` writes in ``--out``, all together (``saarcor.outputs.OutputDir``)."""


def shade_eye_hits(scene, cfg: Config, image, rays, hits, n_pixels: int) -> np.ndarray:
    """``(n_pixels, 3)`` linear colour of eye rays ``rays`` with hits ``hits`` (scene ids):
    background on a miss, else ambient + Phong of every light, unshadowed; the
    ``oversampling``² rays of a pixel averaged."""
    from model.shading import AMBIENT, Shader, surface_offset
    color = np.zeros((n_pixels, 3), np.float32)
    weight = np.float32(1.0 / cfg.oversampling ** 2)
    bg = np.asarray(scene.background, np.float32)
    hit = np.flatnonzero(hits.tri >= 0)
    miss = np.flatnonzero(hits.tri < 0)
    np.add.at(color, rays.pixel[miss], bg * weight)
    if hit.size:
        shader = Shader(scene, cfg.fmt, eps=surface_offset(image.bounds))
        surf = shader.surface(rays, hit, hits.tri[hit], hits.t[hit], hits.u[hit], hits.v[hit])
        local = AMBIENT * surf.albedo
        lit = np.ones(hit.size, np.float32)
        for light in scene.lights:
            local = local + shader.phong(rays.dir[hit], surf.n, surf.albedo, surf.mat, light,
                                         lit, surf.p0)
        np.add.at(color, rays.pixel[hit], local * weight)
    return color


def relative_performance(cfg, cycles: int, trav_ops: int, int_ops: int) -> dict:
    """fps, fps_ideal, the bound (trav or int) and their ratio for a frame of ``cycles``.

    Relative performance (the paper's measure) = fps / fps_ideal with
    ``fps_ideal = clock / max(trav_ops / (rtcs * trav_subunits), int_ops / rtcs)``: the
    frame's cycles against the cycles its traversal and intersection work would take at one
    operation per cycle on every sub-unit and intersection unit, so 100 % means the busiest
    kind of unit never waited. Both op counts are the chip's own counters (equal to the
    golden model's)."""
    trav = trav_ops / (cfg.rtcs * cfg.trav_subunits)
    inter = int_ops / cfg.rtcs
    ideal = max(trav, inter, 1)
    clock = cfg.clock_mhz * 1e6
    return {"fps": clock / cycles, "fps_ideal": clock / ideal,
            "relative_performance": ideal / cycles,
            "bound": "trav-ops" if trav >= inter else "int-ops",
            "trav_cycles_ideal": trav, "int_cycles_ideal": inter}


def _sum(per_rtc: list, key: str) -> int:
    return int(sum(x[key] for x in per_rtc))


def frame_stats(cfg: Config, run, *, scene: str, width: int, height: int, backend: str,
                wall: float) -> dict:
    """The figures of a chip frame (``run``: a :class:`tb.harness.chip.ChipRun`) as ``stats.json``."""
    c, cyc = run.counters, max(1, run.cycles)
    rtc = c["rtc"]
    trav, inter, lst = _sum(rtc, "trav_ops"), _sum(rtc, "int_ops"), _sum(rtc, "list_ops")
    perf = relative_performance(cfg, cyc, trav, inter)
    def cache_stats(k):                  # one kind of slave cache, summed over the slaves
        hh, mm = sum(x[k] for x in c["hits"]), sum(x[k] for x in c["misses"])
        return {"hits": hh, "misses": mm, "hit_rate": hh / max(1, hh + mm),
                "memory_words": sum(x[k] for x in c["grants"])}
    def rtcmi_stats(k):                  # one RTC-MI cache (shared, or the private ones summed)
        x = c["rtcmi"][k]
        hh, mm = x["hits"], x["misses"]
        out = {"hits": hh, "misses": mm, "hit_rate": hh / max(1, hh + mm),
               "memory_words": x["grants"]}
        if cfg.cache_topology == "shared":   # its bus: requests a cycle, cycles someone waited
            out["bus"] = {"busy": (hh + mm) / cyc, "wait": x["waits"] / cyc}
            # the share of the frame the cache lost, by reason (rtl/cache.py STALLS)
            out["stalls"] = {k: v / cyc for k, v in x["stalls"].items()}
        return out
    cache = {k: rtcmi_stats(k) for k in UNITS}
    seconds = cyc / (cfg.clock_mhz * 1e6)
    words = c["mem_words"]
    total = max(1, sum(words))
    memory = {"words": int(c["mem_reads"]), "bytes": 8 * int(c["mem_reads"]),
              "bandwidth_mb_s": 8 * c["mem_reads"] / seconds / 1e6,
              "per_chip": [{"words": int(wd), "share": wd / total, "busy": b / cyc}
                           for wd, b in zip(words, c["mem_busy"])]}
    if getattr(run, "samples", None) is not None and len(run.samples) > 2 and c["mem_busy"]:
        memory["saturated_share"] = sdram_saturated_share(cfg, run.samples)
    sub = [[x[f"sub_busy{j}"] / cyc for j in range(cfg.trav_subunits)] for x in rtc]
    units = {"trav": float(np.mean([x["trav_busy"] for x in rtc])) / cyc,
             "trav_subunits": float(np.mean(sub)),
             "list": float(np.mean([x["list_busy"] for x in rtc])) / cyc,
             "int": float(np.mean([x["int_busy"] for x in rtc])) / cyc,
             "per_rtc": [{"trav": x["trav_busy"] / cyc, "trav_subunits": s,
                          "list": x["list_busy"] / cyc, "int": x["int_busy"] / cyc}
                         for x, s in zip(rtc, sub)]}
    from rtl.rtc import STALL_UNITS
    from rtl.stalls import REASONS
    stalls = {u: {rs: float(np.mean([x[f"{u}_{rs}"] for x in rtc])) / cyc for rs in REASONS}
              for u in STALL_UNITS}
    slaves_c = c.get("slave", [])
    if slaves_c:                         # the RGS slaves (rtl/chip.py Chip.SLAVE_COUNTERS)
        stalls["slave"] = {rs: float(np.mean([x[rs] for x in slaves_c])) / cyc
                           for rs in REASONS}
    stalls["per_rtc"] = [{**{u: {rs: x[f"{u}_{rs}"] / cyc for rs in REASONS}
                             for u in STALL_UNITS},
                          **({"slave": {rs: sl[rs] / cyc for rs in REASONS}}
                             if slaves_c else {})}
                         for x, sl in zip(rtc, slaves_c or [None] * len(rtc))]
    from model.raykind import RayKind
    kinds = np.bincount(run.frame_rays.kind, minlength=len(RayKind))
    slaves = c.get("slave", [])
    return {
        "scene": scene, "resolution": [width, height], "backend": backend,
        "rays": {k.label: int(kinds[k]) for k in RayKind.made(cfg.refraction)}, "rays_total": run.rays,
        "cycles": run.cycles, "clock_mhz": cfg.clock_mhz, **perf,
        "trav_ops": trav, "int_ops": inter, "list_ops": lst,
        "cache_topology": cfg.cache_topology, "cache": cache, "shade_cache": cache_stats("shade"), "tex_cache": cache_stats("tex"),
        "memory": memory,
        "units": units,
        "stalls": stalls,
        "slaves": {"secondary_busy": [x["sec_busy"] / cyc for x in slaves],
                   # the slaves' FP pool (Config.rgs_fp_pool): per datapath, the share of its
                   # input slots it took (mean over the slaves)
                   **({"pool": pool_fill(cfg, slaves)} if cfg.rgs_fp_pool and slaves else {}),
                   # refracted rays into each slave's RTC (Config.refraction; its counter)
                   **({"rays_refract": [x["rays_refract"] for x in slaves]}
                      if cfg.refraction else {})},
        "bus": {"words_per_cycle": c["mem_reads"] / cyc},
        # the chip's result streams (Config.result_ports): records a cycle, and the share of
        # the streams' cycles that carried one
        "output": {"ports": cfg.result_ports, "records_per_cycle": c["records_out"] / cyc,
                   "busy": c["records_out"] / (cyc * cfg.result_ports)},
        "packets_per_rtc": c["packets"],
        "mismatches": len(run.mismatches),
        "sim_seconds": round(run.seconds, 3),
        "sim_cycles_per_second": round(run.cycles / max(run.seconds, 1e-9)),
        "wall_seconds": round(wall, 2),
        # wall seconds of the frame's steps (tb.harness.chip.run_chip_frame; saarcor sim adds the
        # scene, the kd-tree and the outputs)
        "wall_phases": dict(run.timings),
        "build": {"built": bool(run.build and run.build.built),
                  "seconds": round(run.build.seconds, 1) if run.build else 0},
        "image": ("the chip's colour (ambient + Phong, shadows, reflections"
                  + (", textures" if cfg.tex_cache_kb > 0 else "; no texture unit") + "), "
                  "equal to the golden model's pixel for pixel"
                  if run.color is not None and not run.mismatches else
                  "the chip's eye-ray hits shaded on the host (ambient + Phong, unshadowed)"),
        "config": cfg.to_dict(),
        "counters": c,
    }


UNIT_NAMES = {"trav": "traversal", "list": "list unit", "int": "intersection"}
PLOT_NAMES = {**UNIT_NAMES, "slave": "RGS slave"}
LIMIT_BUSY = 0.85        # a unit working this share of the cycles is the limit
LIMIT_SDRAM = 0.70       # an SDRAM chip's data bus busy this share: memory bandwidth
LIMIT_BUS_WAIT = 0.30    # requests waiting on an RTC-MI cache's bus this share: the bus
LIMIT_OUTPUT = 0.75      # the result streams carrying a record this share of their cycles,
LIMIT_OUTPUT_BLOCKED = 0.5   # with the RGS slaves blocked this share: the chip's output
LIMIT_POOL = 0.85        # a datapath on the slaves' FP pool taking inputs in this share of its
                         # slots, the RTC units not the limit: the pool


SATURATED = 0.80         # an SDRAM chip this busy in a slice of the frame is saturated there


def sdram_saturated_share(cfg: Config, samples: np.ndarray) -> float:
    """The share of the frame's cycles in which the busiest SDRAM chip's data bus was busy at
    least :data:`SATURATED` of the time (the frame in :data:`USAGE_BINS` slices of the
    counter samples): a frame can saturate memory in its middle and average below any
    threshold (cold caches at its start, the last packets at its end)."""
    from tb.harness.chip_frame import chip_counter_names
    col = {n: i + 2 for i, n in enumerate(chip_counter_names(cfg))}
    _, d = _rebin(samples, USAGE_BINS)
    cyc = np.maximum(d[:, 0], 1e-9)
    busy = np.max([d[:, col[f"chip{k}_busy"]] / cyc for k in range(cfg.mem_chips)], axis=0)
    return float(d[busy >= SATURATED, 0].sum() / max(d[:, 0].sum(), 1e-9))


def pool_fill(cfg, slaves: list) -> dict:
    """Per datapath on the slaves' pool of FP units, the share of its input slots it took,
    the mean over the slaves (``rtl.rgs.POOL_COUNTERS``; the datapaths this chip has)."""
    from rtl.rgs import pool_entries
    out = {}
    for name, n in pool_entries(cfg).items():
        out[name] = float(np.mean([x[f"pool_{name}"] / max(1, n * x["pool_intervals"])
                                   for x in slaves]))
    return out


def limiter(stats: dict) -> dict:
    """The frame's measured limit from the chip's counters (``stats``: :func:`frame_stats`):
    ``{"limit": short name, "why": a sentence with the figures}``.

    The rule, in order: a unit kind working at least ``LIMIT_BUSY`` of the cycles (mean over
    the RTCs) is the limit; else the chip's result streams, when they carry a record
    ``LIMIT_OUTPUT`` of their cycles and the RGS slaves are blocked ``LIMIT_OUTPUT_BLOCKED``
    (results wait for the output, the RTCs behind them); else look at the unit that works most and at what it waits for
    most: for memory, an SDRAM chip whose data bus is busy ``LIMIT_SDRAM`` or more over the
    frame, or :data:`SATURATED` or more in at least half of it (``memory.saturated_share``), is
    memory bandwidth, an RTC-MI cache bus on which requests wait ``LIMIT_BUS_WAIT`` of the cycles is
    the bus, else memory latency (misses); blocked is back-pressure from the next unit (or,
    for intersection, the RGS slave taking results); starved is too little work in flight
    (too few packets for the threads, or the RGS not making rays fast enough). Before those
    two: a datapath on the slaves' FP pool (``--rgs-fp-pool``) taking an input in
    ``LIMIT_POOL`` of its slots is the pool, the slaves' pace."""
    st, rtcs = stats["stalls"], stats["config"]["rtcs"]
    work = {u: st[u]["work"] for u in UNIT_NAMES}
    top = max(work, key=work.get)
    if work[top] >= LIMIT_BUSY:
        return {"limit": f"{top}-bound",
                "why": f"the {UNIT_NAMES[top]} works {100 * work[top]:.0f} % of the cycles"}
    out, sl = stats.get("output"), st.get("slave")
    if out and sl and out["busy"] >= LIMIT_OUTPUT and sl["blocked"] >= LIMIT_OUTPUT_BLOCKED:
        return {"limit": "output-bound",
                "why": f"the chip's {out['ports']} result stream(s) carry a record "
                       f"{100 * out['busy']:.0f} % of the cycles and the RGS slaves are "
                       f"blocked {100 * sl['blocked']:.0f} % (raise --result-ports)"}
    reasons = {k: v for k, v in st[top].items() if k != "work"}
    why = max(reasons, key=reasons.get)
    pool = stats.get("slaves", {}).get("pool")
    if why != "memory" and pool and max(pool.values()) >= LIMIT_POOL:
        d = max(pool, key=pool.get)
        cfg = stats["config"]
        what = f"its {POOL_NAMES[d]} takes an input in {100 * pool[d]:.0f} % of its slots"
        return {"limit": "slave-pool-bound",
                "why": f"the RGS slaves' pool of {cfg['rgs_fp_adders']} adders and "
                       f"{cfg['rgs_fp_muls']} multipliers sets the pace: {what}, and the busiest "
                       f"unit, the {UNIT_NAMES[top]}, works {100 * work[top]:.0f} % of the "
                       f"cycles and is {'blocked' if why == 'blocked' else 'without input'} "
                       f"{100 * reasons[why]:.0f} % of them (a larger pool: "
                       f"--rgs-fp-adders, --rgs-fp-muls)"}
    share = f"{100 * reasons[why]:.0f} %"
    head = (f"the busiest unit, the {UNIT_NAMES[top]}, works {100 * work[top]:.0f} % of the "
            f"cycles and")
    if why == "memory":
        chips = [x["busy"] for x in stats["memory"]["per_chip"]]
        buses = {k: v["bus"]["wait"] for k, v in stats["cache"].items() if "bus" in v}
        sat = stats["memory"].get("saturated_share", 0.0)
        if chips and (max(chips) >= LIMIT_SDRAM or sat >= 0.5):
            return {"limit": "memory-bandwidth-bound",
                    "why": f"{head} waits for memory {share}; the busiest SDRAM chip's data "
                           f"bus is busy {100 * max(chips):.0f} % of the frame and at least "
                           f"{100 * SATURATED:.0f} % in {100 * sat:.0f} % of it"}
        if buses and max(buses.values()) >= LIMIT_BUS_WAIT:
            k = max(buses, key=buses.get)
            return {"limit": "bus-bound",
                    "why": f"{head} waits for memory {share}; requests wait on the {k} "
                           f"cache's bus {100 * buses[k]:.0f} % of the cycles"}
        hit = stats["cache"][top]["hit_rate"]
        return {"limit": "memory-latency-bound",
                "why": f"{head} waits for memory {share} (its cache hits "
                       f"{100 * hit:.1f} %; no SDRAM chip or bus near full)"}
    if why == "blocked":
        nxt = {"trav": "the list unit", "list": "the intersection unit",
               "int": "the RGS slave or the traversal"}[top]
        return {"limit": "back-pressure",
                "why": f"{head} is blocked by {nxt} {share}"}
    packets = sum(stats["packets_per_rtc"])
    sl = st.get("slave")
    rgs = (f"; the RGS slaves work {100 * sl['work']:.0f} %, are blocked "
           f"{100 * sl['blocked']:.0f} % and wait for memory {100 * sl['memory']:.0f} %"
           if sl else "")
    return {"limit": "starved",
            "why": f"{head} has nothing to do {share}: {packets} packets for {rtcs} RTCs x "
                   f"{stats['config']['threads']} threads (a small frame, or the RGS not "
                   f"making rays fast enough){rgs}"}


POOL_NAMES = {"sec": "secondary-ray datapath", "light": "light datapath",
              "eye": "eye-ray datapath", "setup": "ray setup", "tex_coord": "texture coordinates",
              "tex_filter": "texture filter"}

USAGE_BINS = 120           # usage.png: the frame in this many equal slices of cycles
USAGE_RTC_ROWS = 4         # usage.png: one row per RTC up to this many, else their mean
REASON_COLOURS = {"work": "#2ca02c", "memory": "#ff7f0e", "blocked": "#d62728",
                  "starved": "#bbbbbb"}


def _rebin(samples: np.ndarray, bins: int) -> tuple[np.ndarray, np.ndarray]:
    """Cumulative counter samples (column 0 the cycle) -> ``(mid cycles, per-bin increments)``
    over ``bins`` equal slices of the frame (linear between samples: the sampling interval
    does not show)."""
    cyc = np.concatenate([[0], samples[:, 0]]).astype(float)
    vals = np.vstack([np.zeros((1, samples.shape[1])), samples]).astype(float)
    edges = np.linspace(0, cyc[-1], min(bins, max(2, len(cyc) - 1)) + 1)
    at = np.stack([np.interp(edges, cyc, vals[:, j]) for j in range(vals.shape[1])], axis=1)
    return (edges[1:] + edges[:-1]) / 2, np.diff(at, axis=0)


def write_usage_plot(cfg: Config, samples: np.ndarray, names: list[str], path: Path,
                     title: str) -> None:
    """``usage.png``, read at a glance: the frame in :data:`USAGE_BINS` equal slices of cycles
    (the counters sampled every ``--sample-every`` cycles, interpolated, so no sampling noise).

    One row per RTC (up to :data:`USAGE_RTC_ROWS`; more RTCs: their mean), a column per unit
    (traversal, list, intersection, and the RTC's RGS slave): its cycles stacked as working, waiting for memory,
    blocked by the next unit and starved (``rtl/stalls.py``). The last row: the caches' hit
    rates (a slice with fewer than 20 lookups is left out), each SDRAM chip's data-bus use and
    its share of the words. The legends sit outside the data."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from rtl.rtc import STALL_UNITS
    from rtl.stalls import REASONS
    col = {n: i + 2 for i, n in enumerate(names)}      # column 0: cycle; 1: results
    mid, d = _rebin(samples, USAGE_BINS)
    dc = np.maximum(d[:, 0], 1e-9)
    many = cfg.rtcs > USAGE_RTC_ROWS
    rows = [None] if many else list(range(cfg.rtcs))
    units = list(STALL_UNITS) + (["slave"] if "slave0_work" in col else [])
    fig, ax = plt.subplots(len(rows) + 1, len(units),
                           figsize=(3.4 * len(units) + 1, 2.3 * (len(rows) + 1) + 0.9),
                           squeeze=False)

    def share(r, u, reason):
        rs = range(cfg.rtcs) if r is None else [r]
        name = "slave{q}_" + reason if u == "slave" else "rtc{q}_" + f"{u}_{reason}"
        return sum(d[:, col[name.format(q=q)]] for q in rs) / len(rs) / dc

    for i, r in enumerate(rows):
        for j, u in enumerate(units):
            a = ax[i, j]
            parts = [100 * share(r, u, rs) for rs in REASONS]
            a.stackplot(mid, *parts, colors=[REASON_COLOURS[x] for x in REASONS],
                        linewidth=0)
            a.set_ylim(0, 100)
            a.set_title((f"RTC {r}: " if r is not None else
                         f"mean of {cfg.rtcs} RTCs: ") + PLOT_NAMES[u], fontsize=9)
            if j == 0:
                a.set_ylabel("% of cycles")
    a = ax[-1, 0]
    shared = cfg.cache_topology == "shared"
    for k in UNITS:
        srcs = [f"rtcmi_{k}"] if shared else [f"rtc{r}_{k}" for r in range(cfg.rtcs)]
        hh = sum(d[:, col[f"{x}_hits"]] for x in srcs)
        mm = sum(d[:, col[f"{x}_misses"]] for x in srcs)
        rate = np.where(hh + mm >= 20, 100 * hh / np.maximum(hh + mm, 1), np.nan)
        a.plot(mid, rate, label=f"{k} cache")
    a.set_ylim(0, 102)
    a.set_ylabel("hit rate, %")
    a.set_title("RTC-MI caches" + (" (shared)" if shared else " (all RTCs')"), fontsize=9)
    a.legend(fontsize=7, loc="upper left", bbox_to_anchor=(0, -0.25), ncol=3, frameon=False)
    a = ax[-1, 1]
    chips = [k for k in range(cfg.mem_chips) if f"chip{k}_busy" in col]
    for k in chips:
        a.plot(mid, 100 * d[:, col[f"chip{k}_busy"]] / dc, lw=0.8, label=f"chip {k}")
    a.plot(mid, 100 * d[:, col["mem_reads"]] / dc, color="k", ls="--",
           label="words/cycle x 100")
    a.set_ylim(0, 105)
    a.set_title("SDRAM: each chip's data bus busy, %", fontsize=9)
    a.legend(fontsize=7, loc="upper left", bbox_to_anchor=(0, -0.25),
             ncol=min(5, len(chips) + 1), frameon=False)
    for a in ax[-1, 3:]:
        a.axis("off")
    a = ax[-1, 2]
    last = samples[-1]
    words = np.array([last[col[f"chip{k}_words"]] for k in chips], float)
    a.bar(chips, 100 * words / max(1, words.sum()))
    a.set_title("SDRAM: each chip's share of the words, %", fontsize=9)
    a.set_xlabel("SDRAM chip")
    a.set_xticks(chips)
    for a in ax[-1, :2]:
        a.set_xlabel("cycle")
    handles = [plt.Rectangle((0, 0), 1, 1, color=REASON_COLOURS[x]) for x in REASONS]
    labels = ["working", "waiting for memory", "blocked by the next unit", "starved (no input)"]
    h = fig.get_figheight()
    fig.text(0.5, 1 - 0.12 / h, title, ha="center", va="top", fontsize=10)
    fig.legend(handles, labels, loc="upper center", ncol=4, fontsize=9, frameon=False,
               bbox_to_anchor=(0.5, 1 - 0.3 / h))
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.65 / h))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def build_parser() -> argparse.ArgumentParser:
    from saarcor.args import (RES_QUICK, SCENE, add_backend_arg, add_config_args,
                              add_kd_cache_arg, add_out_arg, add_res_arg, add_scene_arg)

    from tb.harness.lfsr import add_stall_args
    from tb.harness.verilator import add_trace_args
    ap = argparse.ArgumentParser(
        prog="saarcor sim",
        description="Render a frame through the whole SaarCOR chip (RGS, RTCs, caches, bus, "
                    "SDRAM model) in Verilator or Amaranth's simulator, check every ray against "
                    "the golden model, and write image.png, stats.json, rays.npz, hits.npz "
                    "and usage.png. Exit status 1 on any mismatching ray.",
        epilog="Example: saarcor sim --scene scenes/office.toml --res 256x192 --rtcs 4")
    add_scene_arg(ap, SCENE)
    add_res_arg(ap, RES_QUICK)
    add_backend_arg(ap)
    ap.add_argument("--fidelity", choices=("estimate", "sampled", "rtl"), default="rtl",
                    help="rtl: the whole frame on the simulated chip (exact cycles); sampled: "
                         "a band of tile rows in Verilator, extrapolated with the estimate; "
                         "estimate: the discrete-event model alone (model/timing.py), no "
                         "simulator. estimate and sampled cover eye rays only (as "
                         "--eye-only) and mark their cycles and fps as estimates in "
                         "stats.json (docs/ladder.md); default rtl")
    add_out_arg(ap, "build/sim")
    add_trace_args(ap)
    add_stall_args(ap, "the SDRAM model")
    ap.add_argument("--sample-every", type=int, default=0, metavar="CYCLES",
                    help="counter sampling interval for usage.png (default: about 1000 "
                         "samples over the frame, guessing 20 cycles a ray per RTC; the plot "
                         "slices the frame into 120 equal parts whatever the interval)")
    ap.add_argument("--max-cycles", type=int, default=100_000_000,
                    help="give up after this many cycles, naming what did not finish "
                         "(default 100000000)")
    add_kd_cache_arg(ap)
    ap.add_argument("--eye-only", action="store_true",
                    help="eye rays only: the slaves make no shadow or reflection rays (the "
                         "image is then the eye hits shaded on the host, unshadowed)")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    ap.add_argument("--for-scene", action="store_true",
                    help="build the chip for what the scene needs (Config.for_scene): the "
                         "stack as deep as its kd-tree, as many light registers as it has "
                         "lights, no reflection hardware without mirrors, no texture unit "
                         "without textures, memory addresses as wide as its image; the frame "
                         "is the same, the chip smaller")
    add_config_args(ap)
    ap.add_argument(
        "--narrowest-fmt", action="store_true",
        help="instead of --fmt, the narrowest FP format (E8, M from 23 down) whose golden-model "
             "render of the scene stays within 40 dB PSNR of a float64 render, flips fewer "
             "than 0.1 %% of the eye rays and lets no ray through a closed mesh "
             "(saarcor.precision.narrowest_format, on a 128-pixel-wide image of the frame's "
             "aspect); "
             "the choice goes to stats.json")
    return ap


def sim_estimate(args, cfg: Config, scene, prep, width: int, height: int, t0: float,
                 out, extra: dict | None = None) -> int:
    """``saarcor sim --fidelity estimate|sampled``: ``stats.json`` with the estimated cycles
    and fps (marked as estimates) and the entries of ``extra``, ``image.png``, ``rays.npz``
    and ``hits.npz`` from the golden model's eye-ray hits (shaded as ``saarcor sim`` shades
    the chip's)."""
    import sys

    from PIL import Image

    from model.raygen import eye_rays
    from model.render import to_srgb8, write_rays_hits
    from model.timing import estimate_events, record_work
    from saarcor.ladder import sampled_frame

    if args.trace:
        raise SystemExit(f"sim: --trace needs --fidelity rtl (no waveform at {args.fidelity})")
    if not getattr(args, "eye_only", True):
        print(f"sim: --fidelity {args.fidelity} models eye-ray frames only: the frame is "
              "estimated as with --eye-only", file=sys.stderr)
    if args.stall or args.mem_stall:
        print("sim: --stall/--mem-stall are not modelled by the estimate (no back-pressure, "
              "fixed memory latency)", file=sys.stderr)
    rays = eye_rays(scene.camera, width, height, cfg)
    work = record_work(prep.image, rays, cfg)
    hits, tot = work["hits"], work["totals"]
    est = estimate_events(cfg, work)
    stats = {"scene": args.scene, "resolution": [width, height], "fidelity": args.fidelity,
             "estimate": True, "eye_only": True, "rays": {RayKind.EYE.label: len(rays)},
             "rays_total": len(rays),
             "trav_ops": tot["trav_ops"], "int_ops": tot["int_ops"],
             "list_ops": tot["list_ops"], "clock_mhz": cfg.clock_mhz}
    if args.fidelity == "estimate":
        cycles = est["cycles"]
        stats.update(cache_estimate=est["cache"], packets_per_rtc_estimate=est["packets_per_rtc"],
                     method="model.timing: discrete-event model of the chip replaying the "
                            "golden model's event log (docs/ladder.md)")
    else:
        s = sampled_frame(cfg, prep.image, scene.camera, width, height, rays=rays, work=work,
                          build_root=getattr(args, "build_root", None), check=True)
        if s.mismatches:
            print(f"sim: {s.mismatches} rays of the bands differ from the golden model",
                  file=sys.stderr)
        cycles = s.cycles
        stats.update(bands=s.bands, estimate_cycles=s.estimate_cycles,
                     band_rays_checked=s.rays_checked, band_mismatches=s.mismatches,
                     method="saarcor.ladder.sampled_frame: bands of tile rows in Verilator, the "
                            "whole frame's estimate scaled by rtl/estimate on the bands")
    perf = relative_performance(cfg, max(1, int(round(cycles))), tot["trav_ops"],
                                tot["int_ops"])
    stats.update({"cycles_estimated": cycles, "fps_estimated": perf["fps"],
                  "relative_performance_estimated": perf["relative_performance"],
                  "fps_ideal": perf["fps_ideal"], "bound": perf["bound"],
                  "wall_seconds": round(time.perf_counter() - t0, 2),
                  "image": "the golden model's eye-ray hits shaded on the host (ambient + "
                           "Phong, unshadowed), as for --fidelity rtl",
                  "config": cfg.to_dict(), **(extra or {})})
    color = shade_eye_hits(scene, cfg, prep.image, rays, hits, width * height)
    with out:
        out.write_json("stats.json", stats)
        Image.fromarray(to_srgb8(color.reshape(height, width, 3))).save(out.file("image.png"))
        write_rays_hits(out, rays, hits)
    print(f"{args.scene} {width}x{height} on {cfg.rtcs} RTC(s) ({args.fidelity}): {len(rays)} "
          f"rays, ESTIMATED {cycles:.0f} cycles = {perf['fps']:.1f} fps at "
          f"{cfg.clock_mhz:g} MHz (an estimate, docs/ladder.md); -> {out.dir}/")
    return 0


def main(argv=None) -> int:
    from saarcor.args import config_and_res
    ap = build_parser()
    args = ap.parse_args(argv)
    cfg, w, h = config_and_res(args, "saarcor sim")
    from model.scene import SceneError
    try:
        args.scene = resolve_scene(args.scene, "saarcor sim")
    except SceneError as e:
        raise SystemExit(f"saarcor sim: {e}")
    if args.fidelity != "rtl" and args.backend != "verilator":
        raise SystemExit(f"saarcor sim: --backend {args.backend} has no effect with --fidelity "
                         f"{args.fidelity} (estimate runs no simulator, sampled runs "
                         "Verilator); drop --backend or use --fidelity rtl")
    for name in ("sample_every", "max_cycles"):
        if getattr(args, name) < (0 if name == "sample_every" else 1):
            raise SystemExit(f"saarcor sim: --{name.replace('_', '-')} "
                             f"{getattr(args, name)}: must be "
                             f"{'>= 0 (0: automatic)' if name == 'sample_every' else '>= 1'}")
    if args.trace and args.backend == "amaranth" and not args.trace.endswith(".vcd"):
        raise SystemExit("sim: --backend amaranth writes VCD waveforms only: name the file *.vcd")
    from model.render import prepare, to_srgb8, write_rays_hits
    from model.scene import SceneError, load_scene

    from tb.harness.chip import run_chip, run_chip_frame
    from tb.harness.chip_frame import chip_counter_names
    from tb.harness.compare import ResultError, describe
    from tb.harness.verilator import FrameError
    from tb.harness.tools import ToolMissing
    out = OutputDir(args.out, "saarcor sim", owns=OUTPUTS).check()
    t0 = time.perf_counter()
    try:
        scene = load_scene(args.scene)
    except SceneError as e:
        raise SystemExit(f"sim: {e}")
    phases = {"scene_s": time.perf_counter() - t0}
    extra = {}
    if args.narrowest_fmt:
        if args.fmt:
            raise SystemExit("sim: give --fmt or --narrowest-fmt, not both")
        narrow = pick_format(scene, w, h, cfg, quiet=args.quiet)
        cfg = cfg.replace(fmt=narrow["fmt"])
        extra["narrowest_fmt"] = {**narrow, "fmt": str(narrow["fmt"])}
    t1 = time.perf_counter()
    prep = prepare(scene, cfg, cache_dir=args.kd_cache)
    phases["kdtree_s"] = time.perf_counter() - t1
    if args.for_scene:
        try:
            cfg = cfg.for_scene(scene, prep.image, w, h)
        except ValueError as e:
            raise SystemExit(f"sim: {e}")
    frame_scene = None if args.eye_only else scene
    if args.fidelity != "rtl":
        return sim_estimate(args, cfg, scene, prep, w, h, t0, out, extra)
    n_rays = w * h * cfg.oversampling ** 2
    every = args.sample_every or max(64, _guess_cycles(cfg, n_rays) // 1000)
    log = sys.stderr
    try:
        if args.backend == "verilator":
            r = run_chip_frame(cfg, prep.image, scene.camera, w, h, stall=args.stall,
                               mem_stall=args.mem_stall, seed=args.seed,
                               max_cycles=args.max_cycles, trace_file=args.trace,
                               trace_from=args.trace_from, progress=not args.quiet, log=log,
                               sample_every=every, scene=frame_scene)
        else:
            if not args.quiet:
                print(f"sim: Amaranth's simulator, {n_rays} rays (a few hundred cycles/s "
                      "for the standard chip: use tiny frames)", file=log)
            r = run_chip(cfg, prep.image, scene.camera, w, h, stall=args.stall,
                         mem_stall=args.mem_stall, seed=args.seed, max_cycles=args.max_cycles,
                         sample_every=every, vcd=args.trace, scene=frame_scene)
    except (FrameError, ResultError, ToolMissing, ValueError) as e:
        raise SystemExit(f"sim: {e}")
    wall = time.perf_counter() - t0

    stats = frame_stats(cfg, r, scene=args.scene, width=w, height=h, backend=args.backend,
                        wall=wall)
    stats.update(extra)
    stats["limiter"] = limiter(stats)
    t2 = time.perf_counter()
    from PIL import Image
    if r.color is not None and not r.mismatches:
        color = r.color                 # the chip's colour, checked against the model
    else:
        color = shade_eye_hits(scene, cfg, prep.image, r.eye, r.hits, w * h)
    with out:
        Image.fromarray(to_srgb8(color.reshape(h, w, 3))).save(out.file("image.png"))
        write_rays_hits(out, r.frame_rays, r.frame_hits)
        if r.samples is not None and len(r.samples):
            write_usage_plot(cfg, r.samples, chip_counter_names(cfg), out.file("usage.png"),
                             f"{Path(args.scene).stem} {w}x{h}, {cfg.rtcs} RTCs x "
                             f"{cfg.threads} threads ({args.backend})")
        phases.update(r.timings)
        phases["outputs_s"] = time.perf_counter() - t2
        stats["wall_phases"] = {k: round(v, 3) for k, v in phases.items()}
        if r.build is not None and r.build.built:
            stats["build"]["phases"] = json.loads(
                (r.build.dir / "build.json").read_text())["phases"]
        out.write_json("stats.json", stats)
    built = stats["build"]
    lim = stats["limiter"]
    print(f"{args.scene} {w}x{h} on {cfg.rtcs} RTC(s) ({args.backend}"
          f"{', built in %.0f s' % built['seconds'] if built['built'] else ''}): "
          f"{r.rays} rays, {r.cycles} cycles = {stats['fps']:.1f} fps at {cfg.clock_mhz:g} "
          f"MHz; relative performance {100 * stats['relative_performance']:.1f} % "
          f"({lim['limit']}: {lim['why']}); cache hit rates "
          + ", ".join(f"{k} {100 * v['hit_rate']:.1f} %" for k, v in stats["cache"].items())
          + f"; {len(r.mismatches)} mismatching rays; simulated at "
          f"{stats['sim_cycles_per_second']:,} cycles/s; -> {out.dir}/")
    if r.mismatches:
        print(describe(r.mismatches, rays=r.frame_rays), file=log)
        print("sim: reproduce with a waveform: the same command with --trace mismatch.fst "
              "(and --trace-from CYCLE to skip the frame's start)", file=log)
        return 1
    return 0


def pick_format(scene, w: int, h: int, cfg: Config, *, quiet: bool = False) -> dict:
    """:func:`saarcor.precision.narrowest_format` for ``scene`` with ``cfg``'s reflection depth,
    on a 128-pixel-wide image of the frame's aspect ratio (``w x h``) with an odd height (a
    centred camera's diagonals, where a room's corner is an exact closest-hit tie, then miss
    the pixel centres; a few such pixels would decide the PSNR of a tiny image); exits naming
    the scene when not even binary32 passes."""
    from saarcor.precision import narrowest_format
    sw = 128
    sh = max(1, round(sw * h / w)) | 1
    r = narrowest_format(scene, sw, sh, reflect_depth=cfg.reflect_depth,
                         log=None if quiet else sys.stderr)
    if r["fmt"] is None:
        raise SystemExit(f"sim: --narrowest-fmt: {scene.name} fails the precision rule even "
                         f"at binary32 ({r['formats']}); run without --narrowest-fmt")
    if not quiet:
        print(f"sim: narrowest safe format {r['fmt']} (checked at {sw}x{sh} in "
              f"{r['seconds']:.1f} s)", file=sys.stderr)
    return r


def _guess_cycles(cfg: Config, rays: int) -> int:
    """A rough frame length for the default sampling interval: 20 cycles a ray per RTC."""
    return 20 * rays // max(1, cfg.rtcs)


if __name__ == "__main__":
    sys.exit(main())
