"""Threads sweep: cycles of one RTC (Amaranth RTL, ideal memories) for 1, 2, 4, 8, 16 packets in
flight, and the speedup over one thread next to the paper's (8 -> 7.5x, 16 -> 12.2x).

Run: ``saarcor bench threads [--scene scenes/cornell.toml] [--res 64x64]
[--thread-counts 1,2,4,8,16] [--backend verilator|amaranth] [--out build/bench]
[--name threads.json] [configuration options: --tile-w 4 --tile-h 4 --trav-subunits 2
--trav-sync true --mem-latency 20 ...]``. Every run is checked against the golden model (ray
results and counters; a mismatch is an error). ``--backend verilator`` (default) runs the RTC
through ``tb.harness.verilator`` (one build of 1-2 minutes per thread count, cached in
build/verilator/, then ~2*10^5 cycles/s); ``--backend amaranth`` runs it in
Amaranth's simulator (self-stimulating, no Python per cycle), a few hundred cycles per second:
keep the image tiny (e.g. 16x16).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from model.config import Config, ConfigError
from saarcor.outputs import write_atomic

PAPER = {8: 7.5, 16: 12.2}


def sweep(scene: str, width: int, height: int, cfg: Config, threads: list[int], latency: int,
          cache_dir="default", log=None, backend: str = "amaranth") -> dict:
    log = sys.stderr if log is None else log
    from tb.units.rtc import run_rtc_free
    from tb.units.traversal import small_case
    if backend not in ("amaranth", "verilator"):
        raise ValueError(f"backend={backend!r}: choose 'amaranth' or 'verilator'")
    runs = []
    for t in threads:
        c = cfg.replace(threads=t)
        image, rays = small_case(scene, width, height, c, cache_dir)
        t0 = time.perf_counter()
        if backend == "verilator":
            from tb.harness.verilator import run_frame
            r = run_frame(image, rays, c, mem_latency=latency, progress=False, log=log)
        else:
            r = run_rtc_free(image, rays, c, mem_latency=latency)
        if r.mismatches or r.counter_mismatches():
            raise AssertionError(f"threads={t}: {len(r.mismatches)} ray mismatches, counters "
                                 f"{r.counter_mismatches()} (RTL differs from the model)")
        runs.append({"threads": t, "cycles": r.cycles, "rays": r.rays,
                     "packets": rays.n_packets, "sim_cpu_s": round(r.seconds, 2),
                     "sim_cycles_per_s": round(r.cycles_per_s, 1),
                     "wall_s": round(time.perf_counter() - t0, 1), "counters": r.counters})
        if backend == "verilator":
            runs[-1]["build_s"] = round(r.build.seconds, 1)     # 0: a cached binary
        print(f"threads={t}: {r.cycles} cycles, {r.cycles_per_s:.0f} cycles/s (CPU)",
              file=log, flush=True)
    base = runs[0]["cycles"] if runs and runs[0]["threads"] == 1 else None
    for run in runs:
        run["speedup"] = round(base / run["cycles"], 3) if base else None
        run["paper_speedup"] = PAPER.get(run["threads"])
    return {"scene": scene, "res": [width, height], "mem_latency": latency, "sim": backend,
            "config": cfg.to_dict(), "runs": runs,
            "note": "speedup = cycles(1 thread) / cycles(n threads) on the same rays; the paper's "
                    "figures are for whole frames of the standard chip"}


def main(argv=None) -> dict:
    from saarcor.args import (SCENE, add_backend_arg, add_config_args, add_out_arg, add_res_arg,
                              add_scene_arg, config_from_args, parse_res)
    ap = argparse.ArgumentParser(
        prog="saarcor bench threads",
        description=__doc__.splitlines()[0] + " Configuration defaults as Config's except "
                    "4x4 packet tiles (16 rays) and 2 traversal sub-units; --threads is "
                    "replaced by the sweep's --thread-counts, the memories' latency is "
                    "--mem-latency.")
    add_scene_arg(ap, SCENE)
    add_res_arg(ap, "64x64", why="one RTC run once per thread count, five Verilator builds: "
                                 "a small frame")
    ap.add_argument("--thread-counts", default="1,2,4,8,16",
                    help="comma list of thread counts to sweep (default 1,2,4,8,16)")
    add_backend_arg(ap, help="simulator: verilator (tb.harness.verilator) or amaranth "
                             "(Amaranth's simulator, small images)")
    add_out_arg(ap)
    ap.add_argument("--name", help="output file name (default threads.json)")
    add_config_args(ap)
    ap.set_defaults(tile_w=4, tile_h=4, trav_subunits=2)
    args = ap.parse_args(argv)
    if args.threads is not None:
        ap.error("--threads: this bench sweeps the thread count; give the list as "
                 "--thread-counts 1,2,4")
    try:
        w, h = parse_res(args.res)
        threads = [int(x) for x in args.thread_counts.split(",")]
    except (ValueError, argparse.ArgumentTypeError):
        ap.error(f"--res {args.res!r} / --thread-counts {args.thread_counts!r}: write WxH "
                 f"(e.g. 16x16) and a comma list (1,2,4)")
    try:
        cfg = config_from_args(args)
        for t in threads:
            cfg.replace(threads=t)
    except (ConfigError, ValueError) as e:
        ap.error(str(e))
    res = sweep(args.scene, w, h, cfg, threads, cfg.mem_latency, backend=args.backend)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    out_file = out / (args.name or "threads.json")
    write_atomic(out_file, json.dumps(res, indent=1))
    print(f"wrote {out_file}")
    for run in res["runs"]:
        print(f"{run['threads']:>3} threads: {run['cycles']:>8} cycles  speedup "
              f"{run['speedup']}  (paper {run['paper_speedup']})")
    return res


if __name__ == "__main__":
    main()
