"""Relative performance of the chip on a frame (Verilator; every ray checked).

The figures are those of ``make sim``'s ``stats.json`` (:func:`saarcor.sim.frame_stats`; the
paper's relative performance is :func:`saarcor.sim.relative_performance`).

Run: ``saarcor bench chip [--scene PATH] [--res WxH] [config options] [--out DIR]``
(``--help``); writes ``DIR/chip_<scene>_<W>x<H>.json``. With ``--seeds N`` it runs the frame
N times instead on one Verilator binary (seeds 1..N, or from ``--first-seed K`` on: a long
bench split over machines), run i with its own LFSR seed i, result
back-pressure (i mod 16) / 16 and random memory latency (SDRAM responses held in
(7 i mod 13) / 16 of the cycles), and checks that no ray is lost or duplicated, every ray is
bit-exact and no run deadlocks (``DIR/chip_stalls_<scene>_<W>x<H>.json``; with the slaves'
FP units shared, ``..._add<A>_mul<M>.json``).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from saarcor.outputs import check_out, write_atomic

__all__ = ["main", "stall_bench"]


def main(argv=None) -> int:
    from model.render import prepare
    from model.scene import load_scene
    from saarcor.args import (RES_BENCH, add_config_args, add_kd_cache_arg, add_out_arg,
                              add_res_arg, add_scene_arg, config_and_res)

    from tb.harness.chip import run_chip_frame
    from tb.harness.lfsr import add_stall_args
    from saarcor.sim import frame_stats
    from tb.harness.verilator import FrameError
    ap = argparse.ArgumentParser(
        prog="saarcor bench chip",
        description="Render a frame on the chip (rtl/chip.py) in Verilator — eye rays and the "
                    "shadow and reflection rays the slaves make — check every ray against the "
                    "golden model, and report cycles, fps and the paper's relative performance "
                    "(fps / fps_ideal).")
    add_scene_arg(ap, "scenes/office.toml")
    add_res_arg(ap, RES_BENCH)
    add_stall_args(ap, "the SDRAM model")
    ap.add_argument("--max-cycles", type=int, default=20_000_000,
                    help="give up after this many cycles, naming the packets and RTCs that did "
                         "not finish (default 20000000)")
    ap.add_argument("--seeds", type=int, default=0,
                    help="run N seeds of back-pressure and memory-latency jitter instead "
                         "(stall bench); default 0")
    ap.add_argument("--first-seed", type=int, default=1,
                    help="the stall bench's first seed: seeds K..K+N-1 (default 1), to split a "
                         "long bench into parts that run on different machines")
    ap.add_argument("--eye-only", action="store_true",
                    help="eye rays only (no shadow or reflection rays)")
    add_out_arg(ap)
    add_kd_cache_arg(ap)
    add_config_args(ap)
    args = ap.parse_args(argv)
    cfg, w, h = config_and_res(args, "saarcor bench chip")
    check_out(args.out, "saarcor bench chip")           # before any build or frame
    scene = load_scene(args.scene)
    prep = prepare(scene, cfg, cache_dir=args.kd_cache)
    frame_scene = None if args.eye_only else scene
    tag = "_eye" if args.eye_only else ""
    if cfg.rgs_budget():                 # the slaves' FP units shared: a file of its own
        tag += f"_add{cfg.rgs_fp_adders}_mul{cfg.rgs_fp_muls}" + ("_pool" if cfg.rgs_fp_pool
                                                                   else "")
    if args.seeds:
        part = f"_from{args.first_seed}" if args.first_seed != 1 else ""
        return stall_bench(cfg, prep.image, scene.camera, w, h, args.seeds,
                           Path(args.out) /
                           f"chip_stalls_{Path(args.scene).stem}_{w}x{h}{tag}{part}.json",
                           max_cycles=args.max_cycles, scene=frame_scene,
                           first_seed=args.first_seed)
    t0 = time.perf_counter()
    try:
        r = run_chip_frame(cfg, prep.image, scene.camera, w, h, stall=args.stall,
                           mem_stall=args.mem_stall, seed=args.seed,
                           max_cycles=args.max_cycles, scene=frame_scene)
    except FrameError as e:
        raise SystemExit(f"saarcor.bench.chip: {e}")
    out = {"stall": args.stall, "mem_stall": args.mem_stall, "seed": args.seed,
           **frame_stats(cfg, r, scene=args.scene, width=w, height=h, backend="verilator",
                         wall=time.perf_counter() - t0)}
    Path(args.out).mkdir(parents=True, exist_ok=True)
    path = Path(args.out) / f"chip_{Path(args.scene).stem}_{w}x{h}{tag}.json"
    write_atomic(path, json.dumps(out, indent=1))
    print(f"{args.scene} {w}x{h}: {r.rays} rays, {r.cycles} cycles, {len(r.mismatches)} "
          f"mismatches; fps {out['fps']:.1f} at {cfg.clock_mhz:g} MHz, ideal "
          f"{out['fps_ideal']:.1f} ({out['bound']}-bound): relative performance "
          f"{100 * out['relative_performance']:.1f} %; -> {path}")
    return 1 if r.mismatches else 0


def stall_bench(cfg, image, camera, w: int, h: int, seeds: int, path: Path, *,
                max_cycles: int = 2_000_000, scene=None, first_seed: int = 1) -> int:
    """Run the frame (with ``scene``: its secondary rays too) with ``seeds`` patterns of result
    back-pressure and memory-latency jitter (seeds ``first_seed`` … ``first_seed + seeds - 1``);
    every run must deliver every ray exactly once, bit-exact, before the cycle limit."""
    if first_seed < 1:
        raise ValueError(f"first_seed={first_seed}: the LFSR seeds start at 1")
    from tqdm import tqdm

    from tb.harness.compare import ResultError

    from tb.harness.chip import run_chip_frame
    from tb.harness.verilator import FrameError
    runs, failures = [], []
    for seed in tqdm(range(first_seed, first_seed + seeds), desc="stall seeds", unit="run"):
        kw = {"stall": (seed % 16) / 16, "mem_stall": (7 * seed % 13) / 16, "seed": seed}
        try:
            r = run_chip_frame(cfg, image, camera, w, h, progress=False,
                               max_cycles=max_cycles, scene=scene, **kw)
            runs.append({**kw, "cycles": r.cycles, "mismatches": len(r.mismatches)})
            if r.mismatches:
                failures.append({**kw, "what": f"{len(r.mismatches)} mismatching rays"})
        except (FrameError, ResultError) as e:     # deadlock (cycle limit), lost or duplicated
            failures.append({**kw, "what": str(e)})
    cyc = [x["cycles"] for x in runs]
    out = {"runs": len(runs), "failures": failures, "cycles_min": min(cyc, default=0),
           "secondary_rays": scene is not None, "first_seed": first_seed,
           "cycles_max": max(cyc, default=0), "config": cfg.to_dict(), "res": [w, h],
           "per_run": runs}
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, json.dumps(out, indent=1))
    print(f"{seeds} seeds ({first_seed}..{first_seed + seeds - 1}): {len(failures)} failures "
          f"(lost, duplicated, wrong or deadlocked), cycles "
          f"{out['cycles_min']}..{out['cycles_max']}; -> {path}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
