"""What skipping unneeded work saves: golden-model counters (and RTC cycles in Verilator) with
each of the renderer's skips (``model.render.Skip``) turned off in turn, rays and packets that
never enter traversal, and the kd-tree disk cache. Writes ``build/bench/skipping.json``.

    python -m tb.skipping [--scene scenes/office.toml] [--res 128x96] [--rtl]
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
from model.raygen import SHADOW, Rays, eye_rays, setup
from model.render import Skip, prepare, render
from model.scene import load_scene

KEYS = ("trav_ops", "int_ops", "trav_steps", "int_steps", "node_reads", "int_reads")


def _counters(res) -> dict:
    c = res.stats["counters"]
    return {"rays": res.stats["rays"], **{k: int(c[k]) for k in KEYS}}


def measure(scene_path: str, width: int, height: int, cfg: Config, rtl: bool = False,
            log=None) -> dict:
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
    for name in ("anyhit", "lights_behind", "nonreflective"):
        res = render(scene, cfg, width, height, prepared=prep, skip=Skip(**{name: False}))
        c = _counters(res)
        out[f"without_{name}"] = c
        out[f"saved_by_{name}"] = {k: c[k] - out["all_skips"][k] for k in KEYS}
        print(f"{name}: {out[f'saved_by_{name}']}", file=log)
    # rays that miss the scene box start inactive; packets with no live ray do no traversal
    rays = eye_rays(scene.camera, width, height, cfg)
    rs = setup(rays, prep.image.bounds, cfg.fmt)
    live = rs.tnear <= rs.tfar
    pk_live = np.add.reduceat(live.astype(np.int64), rays.pk_start[:-1]) > 0
    out["box_miss"] = {"eye_rays": int(len(rays)), "miss_box": int((~live).sum()),
                       "packets": int(rays.n_packets), "packets_all_miss": int((~pk_live).sum())}
    if rtl:
        import tb.verilator as vl
        tiny = cfg.replace(threads=2, tile_w=4, tile_h=4, trav_subunits=2, reflect_depth=0)
        small_prep = prepare(scene, tiny)
        small = render(scene, tiny, 32, 24, prepared=small_prep)
        sh = small.rays
        sel = np.flatnonzero(sh.kind == SHADOW)
        # shadow rays of the small frame, re-packetized in 16s, with and without any-hit
        cyc = {}
        for anyhit in (True, False):
            r = Rays.from_arrays(sh.org[sel], sh.dir[sel], tmax=sh.tmax[sel], packet=16,
                                 kind=SHADOW, anyhit=np.full(len(sel), anyhit))
            run = vl.run_frame(small_prep.image, r, tiny, mem_latency=4,
                               progress=False)
            if run.mismatches or run.counter_mismatches():
                raise AssertionError("RTC and model disagree on the shadow rays")
            cyc["anyhit" if anyhit else "closest_hit"] = {"cycles": run.cycles,
                                                          "int_ops": run.model["int_ops"]}
        out["rtl_shadow_rays_32x24"] = {"rays": int(len(sel)), **cyc}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m tb.skipping", description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="scenes/office.toml")
    ap.add_argument("--res", default="128x96", help="WxH (default 128x96)")
    ap.add_argument("--rtl", action="store_true",
                    help="also measure shadow-ray cycles on the RTC in Verilator (32x24)")
    ap.add_argument("--out", default="build/bench")
    args = ap.parse_args(argv)
    try:
        w, h = (int(x) for x in args.res.lower().split("x"))
    except ValueError:
        ap.error(f"--res {args.res!r}: expected WxH, e.g. 128x96")
    res = measure(args.scene, w, h, Config(), rtl=args.rtl)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "skipping.json"
    old = json.loads(path.read_text()) if path.exists() else {}
    old[Path(args.scene).stem] = res
    path.write_text(json.dumps(old, indent=1))
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
