"""``saarcor scene --scene PATH [--scene PATH ...]``: a summary of each scene (triangles, materials, lights, bounds,
load time); ``--prepare`` also builds its kd-tree and memory image and reports their cost."""
from __future__ import annotations

import numpy as np

from model.config import Config
from model.kdtree import build_kdtree, kdtree_stats
from model.layout import build_image
from model.scene import Scene, SceneError, load_scene
from saarcor.args import add_scene_arg


def main(argv: list[str] | None = None) -> int:
    import argparse
    import time
    ap = argparse.ArgumentParser(prog="saarcor scene", description="A summary of each scene "
                                 "file: triangles, materials, lights, bounds, load time.")
    add_scene_arg(ap, None, repeat=True, help="a scene to summarize")
    ap.add_argument("--prepare", action="store_true",
                    help="also build the kd-tree and the memory image (the standard Config): "
                         "build seconds, nodes, depth, image size, peak memory of the process")
    ap.add_argument("--no-cache", action="store_true",
                    help="with --prepare: build the kd-tree even when it is cached")
    args = ap.parse_args(argv)
    if not args.scene:
        ap.error("name a scene: --scene PATH (repeat for several)")
    for f in args.scene:
        t0 = time.perf_counter()
        try:
            s = load_scene(f)
        except SceneError as e:
            print(f"SceneError: {e}")
            return 1
        lo, hi = s.bounds()
        print(f"{f}: '{s.name}' {len(s)} triangles ({s.n_scene_tris} in scene order, dropped "
              f"{s.dropped}), {len(s.materials)} materials, {len(s.lights)} lights "
              f"({', '.join(l.kind for l in s.lights)}), bounds {np.round(lo, 2)}..{np.round(hi, 2)}, "
              f"loaded in {time.perf_counter() - t0:.2f} s")
        if args.prepare:
            _prepare_report(s, args.no_cache)
    return 0


def _prepare_report(s: Scene, no_cache: bool) -> None:
    """Print what preparing ``s`` for the chip costs: kd-tree, memory image, peak memory."""
    import resource
    import time

    cfg = Config()
    tris = cfg.fmt.quantize(s.tris).astype(np.float32)
    t0 = time.perf_counter()
    tree = build_kdtree(tris, cfg, **({"cache_dir": None} if no_cache else {}))
    t1 = time.perf_counter()
    image = build_image(tris, tree, cfg, tri_id=s.tri_id)
    t2 = time.perf_counter()
    st = kdtree_stats(tree, len(tris))
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20
    print(f"  kd-tree {'from the cache' if tree.from_cache else 'built'} in {t1 - t0:.1f} s: "
          f"{st['nodes']} nodes, depth {st['depth']}, {st['mean_nonempty_leaf_size']:.2f} "
          f"triangles per non-empty leaf; memory image {len(image.data)} words = "
          f"{image.data.nbytes / 2**20:.1f} MB in {t2 - t1:.1f} s; peak memory {rss:.2f} GB")


if __name__ == "__main__":
    raise SystemExit(main())
