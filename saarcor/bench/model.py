"""Golden-model benchmark: trace-kernel and whole-render rays/s next to Embree, kd-tree build.

    saarcor bench model [--out build/bench] [--scene PATH] [--res 1024x768] [--build-copies 10]
                        [--all-rays-scene scenes/office.toml]

Writes ``<out>/model.json``:

* ``primary``: the golden model's primary rays per second (all cores, numba ``prange`` over
  packets, and one thread) for binary32 and a reduced format (E8M16), and Embree's (``embreex``,
  ``rtcIntersect1`` per ray, one thread) on the *same* rays of the same scene, measured in one
  run (best of ``--repeat``), plus hit/miss agreement between the model and Embree;
* ``render``: the whole render (``model.render.render``: eye rays, ray setup, trace, shading
  and the colour sums into the image; eye rays only, ``reflect_depth=0, shadows=False``;
  textures as ``Config.tex_cache_kb`` says), its rays per second and seconds (best of
  ``--repeat``, all numba threads and one) with its phases (``raygen``, ``setup``, ``trace``,
  ``shading``), next to Embree (one thread) tracing the same eye rays in the same run, and
  the ratio;
* ``render_all_rays`` (``--all-rays-scene``, default ``scenes/office.toml``): the same with
  every ray (shadows, reflections), Embree tracing all of them (closest hit, each ray's tmax);
* ``kdtree_build``: build seconds for a >= 1M-triangle scene (``--build-copies`` copies of the
  mesh, offset in space; no cache).

Default scene: ``--scene`` (any mesh or TOML scene; the README's figures use the Stanford
dragon, 100 k triangles); without it, the procedural ``scenes/terrain.toml``.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

from model.config import Config
from model.fp import FPFormat
from model.kdtree import build_kdtree
from model.raygen import eye_rays, setup
from model.render import prepare, render
from model.rtc import counter_totals, trace
from model.scene import load_scene
from saarcor.args import RES_PAPER, add_out_arg, add_res_arg, add_scene_arg, res_from_args
from saarcor.outputs import write_atomic

ROOT = Path(__file__).resolve().parents[2]


def best_time(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def primary(scene, fmt: FPFormat, res, repeat: int, embree) -> dict:
    cfg = Config(fmt=fmt)
    prep = prepare(scene, cfg, cache_dir=None)
    rays = eye_rays(scene.camera, *res, cfg)
    rs = setup(rays, prep.image.bounds, cfg.fmt)
    import numba
    hits, ctrs = trace(prep.image, rays, cfg, rs)          # compile + warm up
    dt = best_time(lambda: trace(prep.image, rays, cfg, rs), repeat)
    threads = numba.get_num_threads()
    numba.set_num_threads(1)                                # Embree's run is one thread too
    dt1 = best_time(lambda: trace(prep.image, rays, cfg, rs), repeat)
    numba.set_num_threads(threads)
    out = {"format": str(fmt), "rays": len(rays), "seconds": dt, "threads": threads,
           "rays_per_second": len(rays) / dt, "rays_per_second_1_thread": len(rays) / dt1,
           "hit_fraction": float((hits.tri >= 0).mean()),
           "counters": counter_totals(ctrs), "kdtree_depth": prep.tree.depth}
    if embree is not None:
        from model.oracle import Embree
        emb = Embree(prep.tris, scene.tri_id)
        e_hits = emb.intersect(rays.org, rays.dir)
        e_dt = best_time(lambda: emb.intersect(rays.org, rays.dir), repeat)
        out["embree_rays_per_second"] = len(rays) / e_dt
        out["ratio_to_embree"] = out["rays_per_second"] / out["embree_rays_per_second"]
        out["ratio_to_embree_1_thread"] = (out["rays_per_second_1_thread"]
                                           / out["embree_rays_per_second"])
        out["hit_agreement_with_embree"] = float(((hits.tri >= 0) == (e_hits[0] >= 0)).mean())
    return out


def render_speed(scene, res, repeat: int, embree, cfg: Config | None = None) -> dict:
    """The whole render's rays per second (eye rays only unless ``cfg`` says otherwise) and
    Embree's on the same rays, in one run: best of ``repeat``, all numba threads and one.
    ``phase_seconds`` (of the best run with all threads): ``raygen`` (eye rays), ``setup``
    (ray setup of every ray, timed apart: the render sets rays up inside its trace kernel),
    ``trace`` (the render's trace phase less ``setup``), ``shading`` (the rest: secondary
    rays, colours, sums, statistics)."""
    import numba
    cfg = cfg or Config(reflect_depth=0, shadows=False)
    prep = prepare(scene, cfg, cache_dir=None)

    def run():
        return render(scene, cfg, *res, prepared=prep)

    def best_run(k):
        best = None
        for _ in range(k):
            t0 = time.perf_counter()
            r = run()
            dt = time.perf_counter() - t0
            if best is None or dt < best[0]:
                best = (dt, r)
        return best

    result = run()                                          # compile + warm up
    dt, best = best_run(repeat)
    t_setup = best_time(lambda: setup(result.rays, prep.image.bounds, cfg.fmt), repeat)
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    dt1 = best_run(repeat)[0]
    numba.set_num_threads(threads)
    n = len(result.rays)
    ph = best.stats["render_phase_seconds"]
    out = {"rays": n, "rays_by_kind": result.stats["rays"], "threads": threads,
           "seconds": dt, "rays_per_second": n / dt,
           "seconds_1_thread": dt1, "rays_per_second_1_thread": n / dt1,
           "phase_seconds": {"raygen": ph["raygen"], "setup": t_setup,
                             "trace": max(0.0, ph["trace"] - t_setup),
                             "shading": dt - ph["raygen"] - ph["trace"]}}
    if embree is not None:
        from model.oracle import Embree
        emb = Embree(prep.tris, scene.tri_id)
        rays = result.rays
        tmax = None if np.isinf(rays.tmax).all() else rays.tmax
        emb.intersect(rays.org, rays.dir, tmax)
        e_dt = best_time(lambda: emb.intersect(rays.org, rays.dir, tmax), repeat)
        out["embree_seconds"] = e_dt
        out["embree_rays_per_second"] = n / e_dt
        out["ratio_to_embree"] = e_dt / dt
        out["ratio_to_embree_1_thread"] = e_dt / dt1
    return out


def _print_render(name: str, r: dict) -> None:
    ph = r["phase_seconds"]
    print(f"{name}: whole render {r['rays_per_second'] / 1e6:.2f} M rays/s ({r['seconds']:.3f} s,"
          f" {r['threads']} threads; raygen {ph['raygen']:.3f} + setup {ph['setup']:.3f} + trace "
          f"{ph['trace']:.3f} + shading {ph['shading']:.3f} s), "
          f"{r['rays_per_second_1_thread'] / 1e6:.2f} M rays/s (1 thread)"
          + (f"; Embree {r['embree_rays_per_second'] / 1e6:.2f} M rays/s (1 thread), ratio "
             f"{r['ratio_to_embree']:.2f} / {r['ratio_to_embree_1_thread']:.2f}"
             if "embree_seconds" in r else ""))


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(prog="saarcor bench model", description=__doc__.split("\n")[0])
    add_out_arg(ap)
    add_scene_arg(ap, None,
                  help="scene of the primary-ray and eye-ray render benchmarks and the kd-tree "
                       "build: a .toml scene or a bare mesh (default scenes/terrain.toml; the "
                       "README's figures use the Stanford dragon)")
    add_res_arg(ap, RES_PAPER)
    ap.add_argument("--repeat", type=int, default=3, help="timed repetitions (best is kept)")
    ap.add_argument("--build-copies", type=int, default=10,
                    help="copies of the mesh in the kd-tree build benchmark (>= 1M triangles)")
    ap.add_argument("--all-rays-scene", default=str(ROOT / "scenes" / "office.toml"),
                    metavar="PATH", help="scene of the whole-render benchmark with every ray "
                                         "(shadows, reflections; default scenes/office.toml); "
                                         "'none' skips it")
    args = ap.parse_args(argv)
    res = res_from_args(args, "saarcor bench model")
    mesh = args.scene
    if mesh is None:
        mesh = str(ROOT / "scenes" / "terrain.toml")
    scene = load_scene(mesh)
    try:
        import embreex  # noqa: F401  (test/bench dependency: is it installed?)
        embree = True
    except ImportError:
        embree = None
    import numba
    result = {"scene": scene.name, "source": mesh, "triangles": len(scene.tris),
              "resolution": list(res), "cores": os.cpu_count(),
              "numba_threads": numba.config.NUMBA_NUM_THREADS,
              "machine": platform.processor() or platform.machine(), "primary": []}
    for fmt in (FPFormat(8, 23), FPFormat(8, 16)):
        r = primary(scene, fmt, res, args.repeat, embree)
        result["primary"].append(r)
        print(f"{fmt}: model {r['rays_per_second'] / 1e6:.2f} M rays/s ({r['threads']} threads),"
              f" {r['rays_per_second_1_thread'] / 1e6:.2f} M rays/s (1 thread)"
              + (f"; Embree {r['embree_rays_per_second'] / 1e6:.2f} M rays/s (1 thread), ratio "
                 f"{r['ratio_to_embree']:.2f} / {r['ratio_to_embree_1_thread']:.2f}, "
                 f"hit agreement {r['hit_agreement_with_embree']:.5f}" if embree else ""))
    result["render"] = render_speed(scene, res, args.repeat, embree)
    _print_render("eye rays", result["render"])
    if args.all_rays_scene != "none":
        r = render_speed(load_scene(args.all_rays_scene), res, args.repeat, embree, Config())
        result["render_all_rays"] = dict(r, source=args.all_rays_scene)
        _print_render("all rays", r)
    # kd-tree build of >= 1M triangles: copies of the mesh side by side
    cfg = Config()
    tris = cfg.fmt.quantize(scene.tris).astype(np.float32)
    ext = float(np.ptp(tris.reshape(-1, 3), axis=0).max())
    copies = [tris + np.float32(1.1 * ext * i) * np.array([1, 0, 0], np.float32)
              for i in range(args.build_copies)]
    big = cfg.fmt.quantize(np.concatenate(copies)).astype(np.float32)
    build_kdtree(tris[:1000], cfg, cache_dir=None)                   # compile
    t0 = time.perf_counter()
    tree = build_kdtree(big, cfg, cache_dir=None)
    dt = time.perf_counter() - t0
    result["kdtree_build"] = {"triangles": len(big), "seconds": dt, "nodes": tree.n_nodes,
                              "depth": tree.depth}
    print(f"kd-tree build: {len(big)} triangles in {dt:.2f} s")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_atomic(out / "model.json", json.dumps(result, indent=1))
    print(f"wrote {out / 'model.json'}")
    return result


if __name__ == "__main__":
    main()
