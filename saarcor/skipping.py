"""What skipping unneeded work saves: golden-model counters (and RTC cycles in Verilator) with
each of the renderer's skips (``model.render.Skip``) turned off in turn, rays and packets that
never enter traversal, the chip built for the scene (``Config.for_scene``: resources, Verilator
build and run), and what a second run reuses (kd-tree cache, Verilator binaries). Writes
``build/bench/skipping.json``.

    saarcor bench skipping [--scene scenes/office.toml] [--res 128x96] [--rtl-cycles] [--elab]
                           [--second-run]
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from model.config import Config
from model.raygen import Rays, eye_rays, live_packets, select_packets, setup
from model.raykind import RayKind
from model.render import Skip, prepare, render
from model.scene import load_scene
from saarcor.outputs import write_atomic

KEYS = ("trav_ops", "int_ops", "trav_steps", "int_steps", "node_reads", "int_reads")


def _counters(res) -> dict:
    c = res.stats["counters"]
    return {"rays": res.stats["rays"], **{k: int(c[k]) for k in KEYS}}


def measure(scene_path: str, width: int, height: int, cfg: Config, rtl: bool = False,
            elab: bool = False, log=None) -> dict:
    log = sys.stderr if log is None else log
    scene = load_scene(scene_path)
    out: dict = {"scene": str(scene_path), "resolution": [width, height],
                 "config": {"reflect_depth": cfg.reflect_depth, "tile": [cfg.tile_w, cfg.tile_h]}}
    with tempfile.TemporaryDirectory() as cache:
        t = time.perf_counter()
        prep = prepare(scene, cfg, cache_dir=cache)
        first = time.perf_counter() - t
        t = time.perf_counter()
        prepare(scene, cfg, cache_dir=cache)
        second = time.perf_counter() - t
    out["kdtree_cache"] = {"prepare_cold_s": first, "prepare_cached_s": second,
                           "kdtree_build_s": prep.build_seconds, "from_cache": prep.from_cache}
    base = render(scene, cfg, width, height, prepared=prep)
    out["all_skips"] = _counters(base)
    for name in ("anyhit", "lights_behind", "nonreflective", "box_cull"):
        res = render(scene, cfg, width, height, prepared=prep, skip=Skip(**{name: False}))
        c = _counters(res)
        out[f"without_{name}"] = c
        out[f"saved_by_{name}"] = {k: c[k] - out["all_skips"][k] for k in KEYS}
        print(f"{name}: {out[f'saved_by_{name}']}", file=log)
    res = render(scene, cfg, width, height, prepared=prep, skip=Skip(empty_tiles=True))
    out["with_empty_tiles"] = {**_counters(res), "packets": res.stats["packets"],
                               "packets_skipped": res.stats["packets_skipped"]}
    # rays that miss the scene box start inactive; packets with no live ray do no traversal
    rays = eye_rays(scene.camera, width, height, cfg)
    rs = setup(rays, prep.image.bounds, cfg.fmt)
    live = rs.tnear <= rs.tfar
    pk_live = np.add.reduceat(live.astype(np.int64), rays.pk_start[:-1]) > 0
    out["box_miss"] = {"eye_rays": int(len(rays)), "miss_box": int((~live).sum()),
                       "packets": int(rays.n_packets), "packets_all_miss": int((~pk_live).sum())}
    if rtl:
        import tb.harness.verilator as vl
        tiny = cfg.replace(threads=2, tile_w=4, tile_h=4, trav_subunits=2, reflect_depth=0)
        small_prep = prepare(scene, tiny)
        small = render(scene, tiny, 32, 24, prepared=small_prep)
        sh = small.rays
        sel = np.flatnonzero(sh.kind == RayKind.SHADOW)
        # shadow rays of the small frame, re-packetized in 16s, with and without any-hit
        cyc = {}
        for anyhit in (True, False):
            r = Rays.from_arrays(sh.org[sel], sh.dir[sel], tmax=sh.tmax[sel], packet=16,
                                 kind=RayKind.SHADOW, anyhit=np.full(len(sel), anyhit))
            run = vl.run_frame(small_prep.image, r, tiny, mem_latency=4,
                               progress=False)
            if run.mismatches or run.counter_mismatches():
                raise AssertionError("RTC and model disagree on the shadow rays")
            cyc["anyhit" if anyhit else "closest_hit"] = {"cycles": run.cycles,
                                                          "int_ops": run.model["int_ops"]}
        out["rtl_shadow_rays_32x24"] = {"rays": int(len(sel)), **cyc}
        out["rtl_eye_rays_64x48"] = rtl_box_cull(scene, tiny, 64, 48, log)
        out["chip_eye_rays_64x48"] = chip_box_cull(scene, cfg, 64, 48, log)
    if elab:
        out["elaboration"] = elaboration(scene, cfg, log=log)
    return out


def _rtc_run(image, rays, cfg: Config, box_cull: bool = True) -> dict:
    import tb.harness.verilator as vl
    t = time.perf_counter()
    run = vl.run_frame(image, rays, cfg, mem_latency=4, progress=False, box_cull=box_cull)
    wall = time.perf_counter() - t
    if run.mismatches or run.counter_mismatches():
        raise AssertionError(f"RTC and model disagree: {run.mismatches[:4]} "
                             f"{run.counter_mismatches()}")
    return {"rays": int(len(rays)), "packets": int(rays.n_packets), "cycles": run.cycles,
            "trav_ops": run.counters["trav_ops"], "int_ops": run.counters["int_ops"],
            "binary_built": run.build.built, "build_s": round(run.build.seconds, 1),
            "wall_s": round(wall, 2), "sim_s": round(run.seconds, 2)}


def rtl_box_cull(scene, cfg: Config, width: int, height: int, log) -> dict:
    """The eye rays of a ``width x height`` frame on one RTC in Verilator (every ray and
    counter checked against the model): with the box cull, without it, and with the packets
    of empty tiles left out. The first run builds (or finds) the binary, the others reuse it."""
    prep = prepare(scene, cfg)
    rays = eye_rays(scene.camera, width, height, cfg)
    out = {"culled": _rtc_run(prep.image, rays, cfg)}
    print(f"RTC eye rays, box cull: {out['culled']}", file=log)
    out["not_culled"] = _rtc_run(prep.image, rays, cfg, box_cull=False)
    print(f"RTC eye rays, no box cull: {out['not_culled']}", file=log)
    keep = live_packets(rays, setup(rays, prep.image.bounds, cfg.fmt))
    live, _ = select_packets(rays, keep)
    out["empty_tiles_skipped"] = _rtc_run(prep.image, live, cfg)
    print(f"RTC eye rays, empty tiles skipped: {out['empty_tiles_skipped']}", file=log)
    return out


# the small chip of the chip measurements: 1 RTC of 2 threads, 2 sub-units, 4x4 packets,
# caches 1/1/9 KB, SDRAM latency 8
SMALL_CHIP = dict(rtcs=1, threads=2, tile_w=4, tile_h=4, trav_subunits=2, trav_cache_kb=1,
                  list_cache_kb=1, int_cache_kb=9, mem_latency=8)


def chip_box_cull(scene, base: Config, width: int, height: int, log) -> dict:
    """The eye rays of a ``width x height`` frame through the small chip (:data:`SMALL_CHIP`)
    in Verilator, with the slaves' box cull on and off (the host's ``box_cull`` register),
    every ray and counter checked against the model's frame with and without the cull. One
    binary serves both."""
    from tb.harness.chip import run_chip_frame
    small = base.replace(**SMALL_CHIP)
    prep = prepare(scene, small)
    out = {}
    for cull in (True, False):
        t = time.perf_counter()
        run = run_chip_frame(small, prep.image, scene.camera, width, height, box_cull=cull,
                             progress=False, log=log)
        wall = time.perf_counter() - t
        if run.mismatches:
            raise AssertionError(f"chip and model disagree: {run.mismatches[:4]}")
        rtc = run.counters["rtc"]
        got = {k: sum(x[k] for x in rtc) for k in ("trav_ops", "int_ops")}
        if got != {k: run.model[k] for k in got}:
            raise AssertionError(f"chip counters {got} differ from the model's {run.model}")
        out["culled" if cull else "not_culled"] = {
            "rays": run.rays, "cycles": run.cycles,
            "fps": round(small.clock_mhz * 1e6 / run.cycles, 1), **got,
            "binary_built": run.build.built, "wall_s": round(wall, 2)}
        print(f"chip eye rays, box cull {'on' if cull else 'off'}: "
              f"{out['culled' if cull else 'not_culled']}", file=log, flush=True)
    return out


def elaboration(scene, base: Config, width: int = 16, height: int = 16, log=None) -> dict:
    """The small chip (1 RTC of 2 threads, 1 KB caches) as configured and built for the scene
    (``Config.for_scene``): FP units, flip-flop and memory bits from the netlist
    (``saarcor.bench.resources``), the same after Yosys' proc/flatten/opt (``saarcor.bench.resources.yosys_resources``),
    the Verilator build and a ``width x height`` frame (every ray checked against the model);
    and, when it is narrower than the configured one, the ``for_scene`` chip at the narrowest
    safe FP format (:func:`saarcor.precision.narrowest_format` on a 128x95 image)."""
    from rtl.chip import Chip
    from tb.harness.chip import run_chip_frame
    from saarcor.precision import narrowest_format
    from saarcor.bench.resources import chip_resources, yosys_resources
    log = sys.stderr if log is None else log
    small = base.replace(**SMALL_CHIP)
    prep = prepare(scene, small)
    fit = small.for_scene(scene, prep.image, width, height)
    # the narrowest safe format, judged on a 128x95 image of the scene (4:3, odd height)
    narrow = narrowest_format(scene, 128, 95, reflect_depth=small.reflect_depth)
    out: dict = {"frame": [width, height],
                 "narrowest_fmt": {**narrow, "fmt": str(narrow["fmt"])}}
    # for_scene with the configured 32-bit addresses: what the narrower addresses save
    chips = [("as_configured", small, prep),
             ("for_scene_32bit_addresses", fit.replace(addr_bits=small.addr_bits), prep),
             ("for_scene", fit, prep)]
    if narrow["fmt"] is not None and narrow["fmt"] != fit.fmt:
        nprep = prepare(scene, small.replace(fmt=narrow["fmt"]))
        nfit = small.replace(fmt=narrow["fmt"]).for_scene(scene, nprep.image, width, height)
        chips.append(("for_scene_narrowest_fmt", nfit, nprep))
    for name, cfg, prep in chips:
        r = chip_resources(cfg)
        row = {"config": {k: getattr(cfg, k) for k in ("kd_max_depth", "rgs_lights",
                                                      "reflect_depth", "secondary_rays",
                                                      "addr_bits")}
                         | {"fmt": str(cfg.fmt)},
               "fp_units": r["totals"]["fp_units"], "fp_units_by_kind": r["fp_units"],
               "flipflop_bits": r["totals"]["flipflop_bits"],
               "memory_bits": r["totals"]["memory_bits"], "elaborate_s": r["seconds"],
               "yosys": {k: v for k, v in yosys_resources(lambda: Chip(cfg), "chip").items()
                         if k != "cells_by_type"}}
        runs = []
        for _ in range(2):              # the second run finds the binary built by the first
            t = time.perf_counter()
            run = run_chip_frame(cfg, prep.image, scene.camera, width, height, scene=scene,
                                 progress=False, log=log)
            wall = time.perf_counter() - t
            if run.mismatches:
                raise AssertionError(f"{name}: chip and model disagree: {run.mismatches[:4]}")
            runs.append({"binary_built": run.build.built, "build_s": round(run.build.seconds, 1),
                         "wall_s": round(wall, 2), "cycles": run.cycles,
                         "sim_s": round(run.seconds, 3), "rays": run.rays})
        row["verilator"] = runs
        out[name] = row
        print(f"elaboration {name}: {row}", file=log, flush=True)
    # the builder splits down to kd_max_depth, so a shallower stack means a shallower tree:
    # the stack's memory bits against the work of a frame (the golden model's eye rays)
    trade = []
    for depth in (12, 16, 20, fit.kd_max_depth):
        cfg = fit.replace(kd_max_depth=depth)
        with tempfile.TemporaryDirectory() as cache:
            p = prepare(scene, cfg, cache_dir=cache)
        res = render(scene, cfg.replace(reflect_depth=0, shadows=False), 64, 48, prepared=p)
        r = chip_resources(cfg)
        trade.append({"kd_max_depth": depth, "tree_depth": int(p.image.depth),
                      "memory_bits": r["totals"]["memory_bits"],
                      "flipflop_bits": r["totals"]["flipflop_bits"],
                      **{k: int(res.counters[k]) for k in KEYS}})
        print(f"stack depth {trade[-1]}", file=log, flush=True)
    out["stack_depth_64x48_eye"] = trade
    return out


def second_run(scene_path: str, width: int, height: int, log=None) -> dict:
    """``saarcor render`` twice with an empty cache directory (``SAARCOR_CACHE``):
    the first run compiles the model's numba kernels and builds the kd-tree, the second finds
    both cached."""
    import os
    import subprocess
    log = sys.stderr if log is None else log
    root = Path(__file__).resolve().parents[1]
    runs = []
    with tempfile.TemporaryDirectory() as cache, tempfile.TemporaryDirectory() as out:
        env = {**os.environ, "SAARCOR_CACHE": cache}
        env.pop("SAARCOR_NUMBA_CACHE_FIXED", None)
        for _ in range(2):
            t = time.perf_counter()
            subprocess.run([sys.executable, "-m", "saarcor", "render", "--scene", str(scene_path),
                            "--res", f"{width}x{height}", "--out", out, "--quiet"], env=env,
                           cwd=root, check=True)
            st = json.loads((Path(out) / "stats.json").read_text())
            runs.append({"wall_s": round(time.perf_counter() - t, 1),
                         "kdtree_from_cache": st["kdtree_from_cache"],
                         "kdtree_build_s": st["build_seconds"],
                         "render_s": st["render_seconds"]})
            print(f"model render run {len(runs)}: {runs[-1]}", file=log, flush=True)
    return {"resolution": [width, height], "first": runs[0], "second": runs[1]}


def main(argv=None) -> int:
    from saarcor.args import RES_QUICK, add_out_arg, add_res_arg, add_scene_arg, res_from_args, summary
    ap = argparse.ArgumentParser(prog="saarcor bench skipping", description=summary(__doc__))
    add_scene_arg(ap, "scenes/office.toml")
    add_res_arg(ap, RES_QUICK)
    ap.add_argument("--rtl-cycles", action="store_true",
                    help="also measure on the RTC in Verilator: shadow-ray cycles (32x24) and "
                         "eye rays with and without the box cull and empty tiles (64x48); "
                         "and on the small chip eye rays with its box cull on and off (64x48)")
    ap.add_argument("--elab", action="store_true",
                    help="also the small chip as configured against the chip built for the "
                         "scene (Config.for_scene): resources, Verilator build and a 16x16 "
                         "frame")
    add_out_arg(ap)
    ap.add_argument("--second-run", action="store_true",
                    help="also render the scene twice with an empty cache directory (numba "
                         "kernels and kd-tree built, then reused)")
    args = ap.parse_args(argv)
    w, h = res_from_args(args, "saarcor bench skipping")
    res = measure(args.scene, w, h, Config(), rtl=args.rtl_cycles, elab=args.elab)
    if args.second_run:
        res["second_run"] = second_run(args.scene, w, h)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "skipping.json"
    old = json.loads(path.read_text()) if path.exists() else {}
    old[Path(args.scene).stem] = res
    write_atomic(path, json.dumps(old, indent=1))
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
