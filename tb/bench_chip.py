"""Relative performance of the chip on a frame (Verilator; every ray checked).

Relative performance (the paper's measure) = fps / fps_ideal with
``fps_ideal = clock / max(trav_ops / (rtcs * trav_subunits), int_ops / rtcs)``: the frame's
cycles against the cycles its traversal and intersection work would take at one operation per
cycle on every sub-unit and intersection unit, so 100 % means the busiest kind of unit never
waited. Both op counts are the chip's own counters (equal to the golden model's).

Run: ``.venv/bin/python -m tb.bench_chip [--scene S] [--res WxH] [config options] [--out DIR]``
(``--help``); writes ``DIR/chip_<scene>_<W>x<H>.json``. With ``--seeds N`` it runs the frame
N times instead on one Verilator binary, run i with its own LFSR seed i, result
back-pressure (i mod 16) / 16 and random memory latency (SDRAM responses held in
(7 i mod 13) / 16 of the cycles), and checks that no ray is lost or duplicated, every ray is
bit-exact and no run deadlocks (``DIR/chip_stalls_<scene>_<W>x<H>.json``).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from model.config import ConfigError

__all__ = ["relative_performance", "main"]


def relative_performance(cfg, cycles: int, trav_ops: int, int_ops: int) -> dict:
    """fps, fps_ideal, the bound (trav or int) and their ratio for a frame of ``cycles``."""
    trav = trav_ops / (cfg.rtcs * cfg.trav_subunits)
    inter = int_ops / cfg.rtcs
    ideal = max(trav, inter, 1)
    clock = cfg.clock_mhz * 1e6
    return {"fps": clock / cycles, "fps_ideal": clock / ideal,
            "relative_performance": ideal / cycles,
            "bound": "trav-ops" if trav >= inter else "int-ops",
            "trav_cycles_ideal": trav, "int_cycles_ideal": inter}


def main(argv=None) -> int:
    from model.render import prepare
    from model.scene import load_scene
    from rtl.export import add_config_args, config_from_args

    from .chip import run_chip_frame
    from .verilator import FrameError
    ap = argparse.ArgumentParser(
        prog="python -m tb.bench_chip",
        description="Render a frame of eye rays on the chip (rtl/chip.py) in Verilator, check "
                    "every ray against the golden model, and report cycles, fps and the "
                    "paper's relative performance (fps / fps_ideal).")
    ap.add_argument("--scene", default="scenes/office.toml", help="scene TOML (default office)")
    ap.add_argument("--res", default="256x192", help="image WxH (default 256x192)")
    ap.add_argument("--stall", type=float, default=0.0,
                    help="fraction of cycles the results are back-pressured (default 0)")
    ap.add_argument("--mem-stall", type=float, default=0.0,
                    help="fraction of cycles the SDRAM model holds its responses: random "
                         "memory latency (default 0)")
    ap.add_argument("--seed", type=int, default=1, help="LFSR seed of --stall/--mem-stall")
    ap.add_argument("--max-cycles", type=int, default=20_000_000,
                    help="give up after this many cycles, naming the packets and RTCs that did "
                         "not finish (default 20000000)")
    ap.add_argument("--seeds", type=int, default=0,
                    help="run N seeds of back-pressure and memory-latency jitter instead "
                         "(stall bench); default 0")
    ap.add_argument("--out", default="build/bench", help="output directory (build/bench)")
    ap.add_argument("--kd-cache", default="default", help="kd-tree cache directory")
    add_config_args(ap)
    args = ap.parse_args(argv)
    try:
        cfg = config_from_args(args)
        w, h = (int(x) for x in args.res.lower().split("x"))
    except ConfigError as e:
        raise SystemExit(f"tb.bench_chip: {e}")
    except ValueError:
        raise SystemExit(f"tb.bench_chip: --res {args.res!r}: write WxH, e.g. 256x192")
    scene = load_scene(args.scene)
    prep = prepare(scene, cfg, cache_dir=args.kd_cache)
    if args.seeds:
        return stall_bench(cfg, prep.image, scene.camera, w, h, args.seeds,
                           Path(args.out) / f"chip_stalls_{Path(args.scene).stem}_{w}x{h}.json",
                           max_cycles=args.max_cycles)
    t0 = time.perf_counter()
    try:
        r = run_chip_frame(cfg, prep.image, scene.camera, w, h, stall=args.stall,
                           mem_stall=args.mem_stall, seed=args.seed,
                           max_cycles=args.max_cycles)
    except FrameError as e:
        raise SystemExit(f"tb.bench_chip: {e}")
    wall = time.perf_counter() - t0
    c = r.counters
    trav = sum(x["trav_ops"] for x in c["rtc"])
    inter = sum(x["int_ops"] for x in c["rtc"])
    perf = relative_performance(cfg, r.cycles, trav, inter)
    hits = {k: sum(x[k] for x in c["hits"]) for k in ("trav", "list", "int")}
    miss = {k: sum(x[k] for x in c["misses"]) for k in ("trav", "list", "int")}
    out = {"scene": args.scene, "res": [w, h], "stall": args.stall, "mem_stall": args.mem_stall,
           "seed": args.seed, "rays": r.rays, "cycles": r.cycles,
           "mismatches": len(r.mismatches), "trav_ops": trav, "int_ops": inter,
           "clock_mhz": cfg.clock_mhz, **perf,
           "cache_hit_rate": {k: hits[k] / max(1, hits[k] + miss[k]) for k in hits},
           "mem_words": c["mem_words"], "packets_per_rtc": c["packets"],
           "sim_cpu_s": round(r.seconds, 2), "cycles_per_s": round(r.cycles / max(r.seconds, 1e-9)),
           "wall_s": round(wall, 1), "built": r.build.built, "build_s": round(r.build.seconds, 1),
           "config": cfg.to_dict(), "counters": c}
    Path(args.out).mkdir(parents=True, exist_ok=True)
    path = Path(args.out) / f"chip_{Path(args.scene).stem}_{w}x{h}.json"
    path.write_text(json.dumps(out, indent=1))
    print(f"{args.scene} {w}x{h}: {r.rays} rays, {r.cycles} cycles, {len(r.mismatches)} "
          f"mismatches; fps {perf['fps']:.1f} at {cfg.clock_mhz:g} MHz, ideal "
          f"{perf['fps_ideal']:.1f} ({perf['bound']}-bound): relative performance "
          f"{100 * perf['relative_performance']:.1f} %; -> {path}")
    return 1 if r.mismatches else 0


def stall_bench(cfg, image, camera, w: int, h: int, seeds: int, path: Path, *,
                max_cycles: int = 2_000_000) -> int:
    """Run the frame with ``seeds`` patterns of result back-pressure and memory-latency
    jitter; every run must deliver every ray exactly once, bit-exact, before the cycle
    limit."""
    from tqdm import tqdm

    from tb.compare import ResultError

    from .chip import run_chip_frame
    from .verilator import FrameError
    runs, failures = [], []
    for seed in tqdm(range(1, seeds + 1), desc="stall seeds", unit="run"):
        kw = {"stall": (seed % 16) / 16, "mem_stall": (7 * seed % 13) / 16, "seed": seed}
        try:
            r = run_chip_frame(cfg, image, camera, w, h, progress=False,
                               max_cycles=max_cycles, **kw)
            runs.append({**kw, "cycles": r.cycles, "mismatches": len(r.mismatches)})
            if r.mismatches:
                failures.append({**kw, "what": f"{len(r.mismatches)} mismatching rays"})
        except (FrameError, ResultError) as e:     # deadlock (cycle limit), lost or duplicated
            failures.append({**kw, "what": str(e)})
    cyc = [x["cycles"] for x in runs]
    out = {"runs": len(runs), "failures": failures, "cycles_min": min(cyc, default=0),
           "cycles_max": max(cyc, default=0), "config": cfg.to_dict(), "res": [w, h],
           "per_run": runs}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=1))
    print(f"{seeds} seeds: {len(failures)} failures (lost, duplicated, wrong or deadlocked), "
          f"cycles {out['cycles_min']}..{out['cycles_max']}; -> {path}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
