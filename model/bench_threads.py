"""Threads sweep: cycles of one RTC (Amaranth RTL, ideal memories) for 1, 2, 4, 8, 16 packets in
flight, and the speedup over one thread next to the paper's (8 -> 7.5x, 16 -> 12.2x).

Run: ``.venv/bin/python -m model.bench_threads [--scene scenes/cornell.toml] [--res 16x16]
[--tile 4x4] [--subunits 2] [--latency 20] [--threads 1,2,4,8,16] [--sim amaranth|verilator]
[--out build/bench]``; writes ``<out>/threads.json``. Every run is checked against the golden
model (ray results and counters; a mismatch is an error). ``--sim amaranth`` (default) runs the
RTC in Amaranth's simulator (self-stimulating, no Python per cycle), a few hundred cycles per
second: keep the image small. ``--sim verilator`` runs it through ``tb.verilator`` (one build
of about a minute per thread count, cached in build/verilator/, then ~10^5 cycles/s), for
bigger images.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from .config import Config

PAPER = {8: 7.5, 16: 12.2}


def sweep(scene: str, width: int, height: int, cfg: Config, threads: list[int], latency: int,
          cache_dir="default", log=sys.stderr, sim: str = "amaranth") -> dict:
    from tb.rtc import run_rtc_free
    from tb.traversal import small_case
    if sim not in ("amaranth", "verilator"):
        raise ValueError(f"sim={sim!r}: choose 'amaranth' or 'verilator'")
    runs = []
    for t in threads:
        c = cfg.replace(threads=t)
        image, rays = small_case(scene, width, height, c, cache_dir)
        t0 = time.perf_counter()
        if sim == "verilator":
            from tb.verilator import run_frame
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
        if sim == "verilator":
            runs[-1]["build_s"] = round(r.build.seconds, 1)     # 0: a cached binary
        print(f"threads={t}: {r.cycles} cycles, {r.cycles_per_s:.0f} cycles/s (CPU)",
              file=log, flush=True)
    base = runs[0]["cycles"] if runs and runs[0]["threads"] == 1 else None
    for run in runs:
        run["speedup"] = round(base / run["cycles"], 3) if base else None
        run["paper_speedup"] = PAPER.get(run["threads"])
    return {"scene": scene, "res": [width, height], "mem_latency": latency, "sim": sim,
            "config": cfg.to_dict(), "runs": runs,
            "note": "speedup = cycles(1 thread) / cycles(n threads) on the same rays; the paper's "
                    "figures are for whole frames of the standard chip"}


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="scenes/cornell.toml")
    ap.add_argument("--res", default="16x16", help="image WxH (default 16x16)")
    ap.add_argument("--tile", default="4x4", help="packet tile WxH (default 4x4: 16 rays)")
    ap.add_argument("--subunits", type=int, default=2, help="traversal sub-units (default 2)")
    ap.add_argument("--latency", type=int, default=20, help="memory latency in cycles (>= 2)")
    ap.add_argument("--threads", default="1,2,4,8,16")
    ap.add_argument("--sim", default="amaranth", choices=("amaranth", "verilator"),
                    help="simulator: amaranth (pysim, small images) or verilator (tb.verilator)")
    ap.add_argument("--out", default="build/bench")
    args = ap.parse_args(argv)
    try:
        w, h = (int(x) for x in args.res.lower().split("x"))
        tw, th = (int(x) for x in args.tile.lower().split("x"))
        threads = [int(x) for x in args.threads.split(",")]
    except ValueError:
        raise SystemExit(f"bench_threads: --res {args.res!r} / --tile {args.tile!r} / --threads "
                         f"{args.threads!r}: write WxH (e.g. 16x16) and a comma list (1,2,4)")
    cfg = Config(tile_w=tw, tile_h=th, trav_subunits=args.subunits)
    res = sweep(args.scene, w, h, cfg, threads, args.latency, sim=args.sim)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "threads.json").write_text(json.dumps(res, indent=1))
    for run in res["runs"]:
        print(f"{run['threads']:>3} threads: {run['cycles']:>8} cycles  speedup "
              f"{run['speedup']}  (paper {run['paper_speedup']})")
    return res


if __name__ == "__main__":
    main()
