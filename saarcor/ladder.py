"""The simulation ladder: a frame's cycles from five models of the chip, fastest first.

* ``model``: the golden model alone (``model.rtc.trace``): op counts, no timing;
* ``estimate``: ``model.timing``: a discrete-event model of the chip's resources replaying the
  golden model's event log (an estimate);
* ``sampled``: the RTL in Verilator on a few bands of tile rows (:func:`run_band`: the same
  camera, a sub-image through the frame registers), extrapolated to the frame with the
  estimate as control variate (:func:`sampled_frame`; an estimate);
* ``rtl``: the whole frame in Verilator (``tb.harness.chip.run_chip_frame``, exact);
* ``amaranth``: the whole frame in Amaranth's simulator (``tb.harness.chip.run_chip``, exact, tiny
  frames only).

A band is rows ``[y0, y0 + rows)`` of the full image: the host writes the full frame's camera
with its corner moved down by ``y0`` pixel steps (float64, then quantized, as a driver
would), the full width and ``rows`` as the height. The chip needs no change; the band's rays
are the golden model's eye rays for those registers (bit for bit what the chip makes), which
may differ from the full frame's rays of the same pixels in the last bits of the direction.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from model.config import Config
from saarcor.args import RES_BENCH, RES_QUICK, parse_res
from saarcor.outputs import write_atomic

__all__ = ["band_registers", "band_rays", "run_band", "choose_bands", "SampledRun",
           "sampled_frame"]


def _band_camera(cfg: Config, camera, width: int, height: int, y0: int):
    """The camera registers (pos, corner, dx, dy; format values) of a band starting at
    sample row ``y0`` of the full ``width x height`` frame."""
    from model.raygen import camera_basis
    n = cfg.oversampling
    pos, corner, dx, dy = camera_basis(camera.position, camera.look_at, camera.up,
                                       camera.fov_y, width * n, height * n)
    corner = corner + y0 * dy
    return tuple(cfg.fmt.quantize(v) for v in (pos, corner, dx, dy))


def band_registers(cfg: Config, image, camera, width: int, height: int, y0: int,
                   rows: int) -> dict:
    """The chip's host registers for sample rows ``[y0, y0 + rows)`` of the frame, eye rays
    only (``tb.harness.chip.frame_registers`` of a ``width x rows`` frame with the band's camera)."""
    from tb.harness.chip import frame_registers
    fmt, n = cfg.fmt, cfg.oversampling
    if n != 1:
        raise ValueError("bands of oversampled frames are not supported (oversampling=1)")
    regs = frame_registers(cfg, image, camera, width, rows)
    bits = lambda v: [int(b) for b in fmt.to_bits(np.asarray(v, np.float32))]  # noqa: E731
    for k, v in zip(("pos", "corner", "dx", "dy"),
                    _band_camera(cfg, camera, width, height, y0)):
        regs[k] = bits(v)
    regs["n_rays"] = width * rows
    return regs


def band_rays(cfg: Config, camera, width: int, height: int, y0: int, rows: int):
    """The golden model's eye rays of a band (``model.raygen.Rays``), as the chip makes them
    from :func:`band_registers`."""
    from model.raygen import Rays
    from model.rgs import eye_packets, packet_count
    pos, corner, dx, dy = _band_camera(cfg, camera, width, height, y0)
    tw, th = cfg.tile_w, cfg.tile_h
    total = width * rows
    d = np.empty((total, 3), np.float32)
    pixel = np.empty(total, np.int32)
    pk = np.empty(packet_count(width, rows, tw, th) + 1, np.int64)
    eye_packets(width, rows, tw, th, 1, width, corner, dx, dy, d, pixel, pk, *cfg.fmt.em)
    org = np.broadcast_to(pos, d.shape).astype(np.float32)
    return Rays(org, d, np.full(total, np.inf, np.float32), np.zeros(total, np.uint8),
                pixel, pk)


def run_band(cfg: Config, image, camera, width: int, height: int, y0: int, rows: int, *,
             build_root=None, build=None, check: bool = True, log=None,
             max_cycles: int = 100_000_000):
    """Sample rows ``[y0, y0 + rows)`` of the frame through the whole chip in Verilator (the
    binary of ``tb.harness.chip.chip_build``, or ``build``); every ray checked against the golden
    model when ``check``. Returns a ``tb.harness.chip.ChipRun`` (``eye`` = the band's rays)."""
    import sys

    from model.rtc import counter_totals, trace
    from rtl.rgs import SlaveResult

    from tb.harness import compare
    from tb.harness.chip import ChipRun, _finish, chip_blocks, chip_build, stuck
    from tb.harness.chip_frame import chip_counter_names
    from tb.harness.verilator import FrameError, _field, run_binary, write_blocks
    log = sys.stderr if log is None else log
    regs = band_registers(cfg, image, camera, width, height, y0, rows)
    rays = band_rays(cfg, camera, width, height, y0, rows)
    b = build or chip_build(cfg, len(image.data), build_root=build_root, log=log)
    names = chip_counter_names(cfg)
    golden = None
    if check:
        from concurrent.futures import ThreadPoolExecutor
        pool = ThreadPoolExecutor(max_workers=1)
        golden = pool.submit(trace, image, rays, cfg)
        pool.shutdown(wait=False)
    out = run_binary(b, lambda f: write_blocks(f, chip_blocks(cfg, image, regs)), cfg,
                     len(rays), max_cycles=max_cycles, progress=False, log=log,
                     desc="chip band (Verilator)", names=names, allow_limit=True,
                     res_ports=cfg.result_ports)
    lay = SlaveResult(cfg)
    records = {name: _field(out.results, off, wd)
               for name, off, wd in compare.record_fields(lay)}
    if out.status == 2:
        raise FrameError(stuck(cfg, rays, records, out.counters, max_cycles))
    if check:
        hits, ctrs = golden.result()
        run = _finish(cfg, image, records, out.cycles, out.seconds, out.counters,
                      (rays, rays, hits, counter_totals(ctrs), None))
    else:
        run = ChipRun(out.cycles, out.seconds, len(rays), {}, {}, eye=rays)
    run.build = b
    run.load_seconds = out.load_seconds          # the binary's CPU seconds: load, run loop
    run.cpu_seconds = out.load_seconds + out.seconds
    return run


def choose_bands(cfg: Config, height: int, fraction: float, *, bands: int = 2) -> list:
    """``(y0, rows)`` of ``bands`` bands of whole tile rows, together about ``fraction`` of
    the frame's rows (at least one tile row each), spread evenly over the frame (the centre of
    band i at (i + 0.5) / bands of the height)."""
    th = cfg.tile_h
    tile_rows = -(-height // th)
    per = max(1, int(round(fraction * tile_rows / bands)))
    bands = max(1, min(bands, tile_rows // per))
    out = []
    for i in range(bands):
        c = (i + 0.5) * tile_rows / bands
        r0 = int(min(max(0, round(c - per / 2)), tile_rows - per))
        y0 = r0 * th
        out.append((y0, min(per * th, height - y0)))
    return out


@dataclass
class SampledRun:
    cycles: float                 # the estimate for the frame (an estimate)
    plain_cycles: float           # without the control variate: band cycles x work ratio
    estimate_cycles: int          # the discrete-event estimate of the whole frame
    bands: list                   # per band: y0, rows, rtl cycles, estimated cycles, seconds
    seconds: float                # wall time of the whole method
    cpu_seconds: float            # CPU seconds: this process's and the Verilator binary's
    rays_checked: int
    mismatches: int


def sampled_frame(cfg: Config, image, camera, width: int, height: int, *, fraction=0.1,
                  bands: int = 1, build_root=None, build=None, work=None, rays=None,
                  check: bool = True, log=None) -> SampledRun:
    """The frame's cycles from the RTL on a few bands (:func:`choose_bands`), extrapolated:
    ``estimate(frame) x sum(rtl(band)) / sum(estimate(band))`` — the discrete-event estimate
    (``model.timing``) corrected by its error on the bands, each band simulated from cold
    caches in both. ``plain_cycles``: the band cycles scaled by the frame's int-ops + trav-ops
    over the bands' (no estimator). ``work``/``rays``: the full frame's
    ``model.timing.record_work`` and eye rays if already at hand."""
    from model.raygen import eye_rays
    from model.timing import estimate_events, record_work
    t0, c0 = time.perf_counter(), time.process_time()
    sim_cpu = 0.0
    if rays is None:
        rays = eye_rays(camera, width, height, cfg)
    if work is None:
        work = record_work(image, rays, cfg)
    full = estimate_events(cfg, work)
    work_full = _ops(work["totals"])
    rows_out = []
    rtl_sum = est_sum = work_sum = 0.0
    n_checked = n_bad = 0
    for y0, rows in choose_bands(cfg, height, fraction, bands=bands):
        tb = time.perf_counter()
        run = run_band(cfg, image, camera, width, height, y0, rows, build_root=build_root,
                       build=build, check=check, log=log)
        build = run.build
        sim_cpu += run.cpu_seconds
        wb = record_work(image, run.eye, cfg)
        est = estimate_events(cfg, wb)
        rtl_sum += run.cycles
        est_sum += est["cycles"]
        work_sum += _ops(wb["totals"])
        n_checked += run.rays if check else 0
        n_bad += len(run.mismatches)
        rows_out.append({"y0": y0, "rows": rows, "rtl_cycles": run.cycles,
                         "estimate_cycles": est["cycles"],
                         "seconds": round(time.perf_counter() - tb, 3)})
    cycles = full["cycles"] * rtl_sum / max(1.0, est_sum)
    plain = rtl_sum * work_full / max(1.0, work_sum)
    return SampledRun(cycles, plain, full["cycles"], rows_out, time.perf_counter() - t0,
                      time.process_time() - c0 + sim_cpu, n_checked, n_bad)


def _ops(totals: dict) -> float:
    """A frame's work for plain extrapolation: trav-ops + int-ops."""
    return float(totals["trav_ops"] + totals["int_ops"])


# --- the ladder bench -------------------------------------------------------------------------

# configurations of the ladder (name: Config fields); small chips keep the Verilator builds short
_SMALL = dict(tile_w=4, tile_h=4, trav_subunits=2)
LADDER_CONFIGS = {
    "1x1": dict(rtcs=1, threads=1, trav_cache_kb=8, list_cache_kb=8, int_cache_kb=18, **_SMALL),
    "1x4": dict(rtcs=1, threads=4, trav_cache_kb=8, list_cache_kb=8, int_cache_kb=18, **_SMALL),
    "1x16": dict(rtcs=1, threads=16, trav_cache_kb=8, list_cache_kb=8, int_cache_kb=18,
                 **_SMALL),
    "2x8-1KB": dict(rtcs=2, threads=8, trav_cache_kb=1, list_cache_kb=1, int_cache_kb=9,
                    **_SMALL),
    "4x4": dict(rtcs=4, threads=4, **_SMALL),
    "standard": dict(),
}
METHODS = ("model", "estimate", "sampled", "rtl", "amaranth")


def ideal_cycles(cfg: Config, trav_ops: int, int_ops: int) -> float:
    """The golden model's op counts as a cycle count: the busiest kind of unit at one
    operation a cycle (the paper's ideal, ``saarcor.sim.relative_performance``)."""
    return max(trav_ops / (cfg.rtcs * cfg.trav_subunits), int_ops / cfg.rtcs, 1)


def ladder_point(cfg: Config, scene_path: str, width: int, height: int, *, build_root=None,
                 fraction: float = 0.1, bands: int = 1, amaranth: bool = False,
                 check_bands: bool = False, log=None) -> dict:
    """Every rung of the ladder on one frame: cycles (or their estimate) and run time."""
    import sys

    from model.raygen import eye_rays
    from model.render import prepare
    from model.rtc import counter_totals, trace
    from model.scene import load_scene
    from model.timing import estimate_events, fps_error, record_work

    from tb.harness.chip import chip_build, run_chip
    log = sys.stderr if log is None else log
    scene = load_scene(scene_path)
    prep = prepare(scene, cfg)
    image = prep.image
    rays = eye_rays(scene.camera, width, height, cfg)
    b = chip_build(cfg, len(image.data), build_root=build_root, log=log)   # not timed
    # warm up: numba kernels loaded and compiled before anything is timed
    trace(image, rays, cfg)
    estimate_events(cfg, record_work(image, rays, cfg), np.arange(min(4, rays.n_packets)))
    out = {"scene": scene_path, "resolution": [width, height], "rays": len(rays),
           "config": cfg.to_dict(), "methods": {}}
    m = out["methods"]
    clock = lambda: (time.perf_counter(), time.process_time())  # noqa: E731
    # (a) the golden model: op counts -> the ideal cycle count
    w0, c0 = clock()
    _, ctrs = trace(image, rays, cfg)
    tot = counter_totals(ctrs)
    w1, c1 = clock()
    m["model"] = {"cycles": ideal_cycles(cfg, tot["trav_ops"], tot["int_ops"]),
                  "seconds": c1 - c0, "wall_seconds": w1 - w0}
    # (b) the estimate
    w0, c0 = clock()
    work = record_work(image, rays, cfg)
    tr = time.process_time() - c0
    est = estimate_events(cfg, work)
    w1, c1 = clock()
    m["estimate"] = {"cycles": est["cycles"], "seconds": c1 - c0, "wall_seconds": w1 - w0,
                     "seconds_trace": tr, "seconds_model": c1 - c0 - tr,
                     "cache": est["cache"]}
    # (c) sampled RTL (band rays not checked: the whole frame below checks every ray)
    s = sampled_frame(cfg, image, scene.camera, width, height, fraction=fraction, bands=bands,
                      build=b, log=log, check=check_bands, rays=rays)
    m["sampled"] = {"cycles": s.cycles, "seconds": s.cpu_seconds, "wall_seconds": s.seconds,
                    "plain_cycles": s.plain_cycles, "bands": s.bands,
                    "mismatches": s.mismatches}
    # (d) the whole frame in Verilator (a band of every row: the frame's own registers),
    # every ray checked; its time = the binary's CPU seconds (load and run loop) only
    w0 = time.perf_counter()
    r = run_band(cfg, image, scene.camera, width, height, 0, height, build=b, log=log)
    c = r.counters
    hr = {k: x["hits"] / max(1, x["hits"] + x["misses"]) for k, x in c["rtcmi"].items()}
    m["rtl"] = {"cycles": r.cycles, "seconds": r.cpu_seconds,
                "wall_seconds": time.perf_counter() - w0, "sim_seconds": r.seconds,
                "load_seconds": r.load_seconds, "mismatches": len(r.mismatches),
                "hit_rates": hr, "packets_per_rtc": c["packets"]}
    # (e) Amaranth's simulator (tiny frames)
    if amaranth:
        w0, c0 = clock()
        a = run_chip(cfg, image, scene.camera, width, height, max_cycles=10_000_000)
        w1, c1 = clock()
        m["amaranth"] = {"cycles": a.cycles, "seconds": c1 - c0, "wall_seconds": w1 - w0,
                         "mismatches": len(a.mismatches)}
    exact = r.cycles
    for k, v in m.items():
        v["fps"] = cfg.clock_mhz * 1e6 / max(1.0, v["cycles"])
        v["fps_error"] = fps_error(v["cycles"], exact)
        v["cycle_error"] = v["cycles"] / exact - 1
        v["speedup"] = m["rtl"]["seconds"] / max(v["seconds"], 1e-9)
    m["sampled"]["plain_cycle_error"] = m["sampled"]["plain_cycles"] / exact - 1
    return out


def _parse_points(spec: str) -> list:
    """``config:scene:WxH`` items, comma-separated."""
    pts = []
    for item in spec.split(","):
        name, scene, res = item.split(":")
        pts.append((name, scene, *parse_res(res)))
    return pts


_SCENES = ("cornell", "office", "conference", "terrain")
DEFAULT_POINTS = ",".join(
    [f"{c}:scenes/{s}.toml:{RES_QUICK}" for c in ("1x1", "1x4", "1x16", "2x8-1KB")
     for s in _SCENES] +
    [f"standard:scenes/{s}.toml:{RES_BENCH}" for s in _SCENES] +
    [f"4x4:scenes/{s}.toml:{RES_QUICK}" for s in _SCENES])


def plot_ladder(rows: list, path) -> None:
    """Run time per frame against |fps error|, one marker per method (log-log)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7.5, 5))
    style = {"model": ("o", "golden model (ideal cycles)"), "estimate": ("s", "estimate"),
             "sampled": ("^", "sampled RTL"), "rtl": ("D", "Verilator, whole frame"),
             "amaranth": ("v", "Amaranth simulator")}
    floor = 1e-4
    for meth, (mk, label) in style.items():
        xs = [p["methods"][meth]["seconds"] for p in rows if meth in p["methods"]]
        ys = [max(floor, 100 * abs(p["methods"][meth]["fps_error"])) for p in rows
              if meth in p["methods"]]
        if xs:
            ax.scatter(xs, ys, marker=mk, label=label, alpha=0.75)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.axhline(5, color="gray", ls=":", lw=1)
    ax.axhline(1, color="gray", ls="--", lw=1)
    ax.set_xlabel("CPU seconds per frame (binaries built, numba compiled)")
    ax.set_ylabel(f"|fps error| against Verilator, % (exact runs drawn at {floor:g} %)")
    ax.set_title("Simulation ladder: run time against error", fontsize=10)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def tables(rows: list) -> str:
    """The Markdown tables of ``docs/ladder.md`` from the bench's rows."""
    lines = ["| configuration | scene | res | Verilator cycles | Verilator CPU s (of it: "
             "image load) | estimate: fps error | × faster | sampled: fps error | × faster | "
             "plain extrapolation: fps error | golden model (ideal cycles): fps error |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for p in rows:
        m = p["methods"]
        if "rtl" not in m:
            continue
        pe = m["sampled"]["plain_cycle_error"]
        lines.append(
            f"| {p.get('name', '')} | {p['scene'].split('/')[-1].removesuffix('.toml')} | "
            f"{p['resolution'][0]}×{p['resolution'][1]} | {m['rtl']['cycles']:,} | "
            f"{m['rtl']['seconds']:.2f} ({m['rtl']['load_seconds']:.2f}) | "
            f"{100 * m['estimate']['fps_error']:+.2f} % | {m['estimate']['speedup']:.0f} | "
            f"{100 * m['sampled']['fps_error']:+.2f} % | {m['sampled']['speedup']:.1f} | "
            f"{-100 * pe / (1 + pe):+.1f} % | {100 * m['model']['fps_error']:+.0f} % |")
    return "\n".join(lines)


def summary(rows: list) -> dict:
    """Per method: median and worst |fps error|, median speed-up against Verilator."""
    out = {}
    for meth in METHODS:
        e = [abs(p["methods"][meth]["fps_error"]) for p in rows if meth in p["methods"]]
        sp = [p["methods"][meth]["speedup"] for p in rows if meth in p["methods"]]
        if e:
            out[meth] = {"points": len(e), "median_abs_fps_error": float(np.median(e)),
                         "max_abs_fps_error": float(np.max(e)),
                         "median_speedup": float(np.median(sp)), "min_speedup": float(np.min(sp))}
    return out


def main(argv=None) -> int:
    import argparse
    import json
    import os
    import sys
    from pathlib import Path

    from saarcor.args import add_out_arg
    ap = argparse.ArgumentParser(
        prog="saarcor bench ladder",
        description="The simulation ladder: golden model (ideal cycles), the discrete-event "
                    "estimate (model.timing), sampled RTL (bands in Verilator), the whole "
                    "frame in Verilator (exact) and optionally Amaranth's simulator, on "
                    "configurations x scenes x resolutions: run time per frame and fps error "
                    "against Verilator. Writes ladder.json and ladder.png.")
    ap.add_argument("--points", default=DEFAULT_POINTS,
                    help="config:scene:WxH items, comma-separated; configs: "
                         + ", ".join(LADDER_CONFIGS) + " (default: all five small ones on "
                         f"the four shipped scenes at {RES_QUICK} (RES_QUICK) and the standard "
                         f"chip at {RES_BENCH} (RES_BENCH))")
    ap.add_argument("--fraction", type=float, default=0.1,
                    help="share of the frame's tile rows the sampled RTL simulates (0.1)")
    ap.add_argument("--bands", type=int, default=1, help="bands of the sampled RTL (1)")
    ap.add_argument("--amaranth-points", default="1x4:scenes/cornell.toml:8x4",
                    help="points also run in Amaranth's simulator (same syntax as --points; "
                         "'' for none; default %(default)s: a tiny frame)")
    ap.add_argument("--build-dir", default=None, metavar="DIR",
                    help="Verilator build cache (default build/verilator)")
    add_out_arg(ap)
    ap.add_argument("--replot", action="store_true",
                    help="no runs: redraw ladder.png and print the tables from OUT/ladder.json")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.replot:
        rows = json.loads((out / "ladder.json").read_text())["points"]
        plot_ladder(rows, out / "ladder.png")
        print(tables(rows))
        print(json.dumps(summary(rows), indent=1))
        return 0
    rows = []
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    todo = [(p, False) for p in _parse_points(args.points)]
    if args.amaranth_points:
        todo += [(p, True) for p in _parse_points(args.amaranth_points)]
    for (name, scene, w, h), ama in todo:
        cfg = Config(**LADDER_CONFIGS[name])
        print(f"ladder: {name} {scene} {w}x{h}{' (+ Amaranth)' if ama else ''}", file=sys.stderr,
              flush=True)
        p = ladder_point(cfg, scene, w, h, build_root=args.build_dir, fraction=args.fraction,
                         bands=args.bands, amaranth=ama)
        p["name"] = name
        rows.append(p)
        m = p["methods"]
        print("  " + "; ".join(f"{k} {v['cycles']:.0f} cycles ({100 * v['fps_error']:+.2f} % "
                               f"fps) {v['seconds']:.3f} s" for k, v in m.items()),
              file=sys.stderr, flush=True)
        res = {"points": rows, "summary": summary(rows),
               "load_average": [load0, os.getloadavg()[0]],
               "seconds": time.perf_counter() - t0}
        write_atomic(out / "ladder.json", json.dumps(res, indent=1))
    plot_ladder(rows, out / "ladder.png")
    print(tables(rows))
    print(json.dumps(summary(rows), indent=1))
    return 0


if __name__ == "__main__":
    import sys
    sys.exit(main())


