"""``saarcor verilator``: a frame of eye rays through one RTC (``rtl/rtc.py``) on ideal memories
(``--mem-latency`` cycles) in Verilator, every ray and counter compared with the golden model.
The harness is :mod:`tb.harness.verilator`."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from model.config import ConfigError
from saarcor.args import (SCENE, add_config_args, add_kd_cache_arg, add_res_arg, add_scene_arg,
                          config_and_res)
from tb.harness import compare
from tb.harness.tools import ToolMissing
from tb.harness.lfsr import add_stall_args
from tb.harness.verilator import BUILD_ROOT, FrameError, add_trace_args, run_frame


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(
        prog="saarcor verilator",
        description="Trace a frame of eye rays through one RTC (rtl/rtc.py) in Verilator and "
                    "compare every ray (triangle, t, u, v bits) and the counters with the golden "
                    "model. The binary is built once per configuration into build/verilator/ "
                    "and reused.",
        epilog="Example: saarcor verilator --scene scenes/office.toml --res 64x48 --threads 16 "
               "--mem-latency 20 --json build/verilator/office.json")
    add_scene_arg(ap, SCENE)
    add_res_arg(ap, "64x48", what="eye-ray image",
                why="one RTC: a quarter of RES_QUICK's pixels, as many rays per RTC as the "
                    "four-RTC chip's quick check")
    ap.add_argument("--idle", type=float, default=0.0,
                    help="fraction of cycles without a ray offered (0 .. 15/16, in steps of "
                         "1/16; default 0)")
    add_stall_args(ap, "each memory (in order, as behind a cache)")
    ap.add_argument("--max-cycles", type=int, default=100_000_000,
                    help="give up after this many cycles (default 100000000)")
    add_trace_args(ap)
    ap.add_argument("--json", metavar="FILE", help="write the figures as JSON")
    ap.add_argument("--build-dir", default=str(BUILD_ROOT), metavar="DIR",
                    help="where binaries are cached (default build/verilator)")
    add_kd_cache_arg(ap)
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    add_config_args(ap)
    args = ap.parse_args(argv)
    cfg, w, h = config_and_res(args, "saarcor verilator")
    latency = cfg.mem_latency
    if not Path(args.scene).exists():
        raise SystemExit(f"saarcor verilator: scene {args.scene!r} not found (try scenes/*.toml)")
    from tb.units.traversal import small_case
    image, rays = small_case(args.scene, w, h, cfg, args.kd_cache)
    try:
        r = run_frame(image, rays, cfg, mem_latency=latency, idle=args.idle, stall=args.stall,
                      seed=args.seed, mem_stall=args.mem_stall, max_cycles=args.max_cycles, trace_file=args.trace,
                      trace_from=args.trace_from, progress=not args.quiet, build_root=args.build_dir)
    except (ToolMissing, FrameError, ValueError, ConfigError) as e:
        raise SystemExit(f"saarcor verilator: {e}")
    cm = r.counter_mismatches()
    res = {"scene": args.scene, "res": [w, h], "mem_latency": latency, "idle": args.idle,
           "stall": args.stall, "mem_stall": args.mem_stall, "seed": args.seed, "config": cfg.to_dict(), "rays": r.rays,
           "packets": rays.n_packets, "cycles": r.cycles, "sim_cpu_s": round(r.seconds, 3),
           "cycles_per_s": round(r.cycles_per_s), "load_cycles": r.load_cycles,
           "load_cpu_s": round(r.load_seconds, 3), "built": r.build.built,
           "build_s": round(r.build.seconds, 1), "binary": str(r.build.binary),
           "mismatches": len(r.mismatches), "counter_mismatches": cm,
           "counters": r.counters, "model": r.model}
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(res, indent=1))
    print(f"{args.scene} {w}x{h}: {r.rays} rays, {r.cycles} cycles, "
          f"{r.cycles_per_s / 1e3:.1f} k cycles/s (CPU), "
          f"{'built in %.0f s' % r.build.seconds if r.build.built else 'cached binary'}; "
          f"{len(r.mismatches)} ray mismatches, counters "
          f"{'equal' if not cm else 'DIFFER: %s' % cm}")
    if r.mismatches or cm:
        print(compare.describe(r.mismatches, cm))
        print("saarcor verilator: the RTL differs from the golden model", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
