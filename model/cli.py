"""Command line of the golden model: ``python -m model render SCENE [options]``."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .config import Config, ConfigError
from .fp import FPFormat


def parse_res(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--res {text!r}: expected WIDTHxHEIGHT, e.g. 256x192")
    if w < 1 or h < 1 or w * h > 16384 * 16384:
        raise argparse.ArgumentTypeError(f"--res {text!r}: width and height must be >= 1")
    return w, h


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m model",
                                description="SaarCOR golden model: bit-exact ray tracing of a "
                                            "scene in the hardware's arithmetic.")
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("render", help="render a scene; writes image.png, stats.json, rays.npz, "
                                      "hits.npz",
                       formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    r.add_argument("scene", help="a scene file (.toml, see docs/scenes.md) or a bare mesh "
                                 "(.obj .ply .stl .glb .off; the camera frames it, one light)")
    r.add_argument("--res", type=parse_res, default=(256, 192), metavar="WxH",
                   help="image resolution in pixels")
    r.add_argument("--out", type=Path, default=Path("build/render"),
                   help="output directory")
    r.add_argument("--exp-bits", type=int, default=8, help="FP exponent width E")
    r.add_argument("--frac-bits", type=int, default=23,
                   help="FP fraction width M (10..23 for the precision study)")
    r.add_argument("--reflect-depth", type=int, default=Config.reflect_depth,
                   help="maximum reflection bounces (0: none)")
    r.add_argument("--oversampling", type=int, default=1,
                   help="n: n x n rays per pixel on a regular sub-pixel grid")
    r.add_argument("--no-shadows", action="store_true", help="lights cast no shadow rays")
    r.add_argument("--kd-depth", type=int, default=Config.kd_max_depth,
                   help="maximum kd-tree depth d (sizes the traversal stack)")
    r.add_argument("--leaf-size", type=int, default=Config.kd_leaf_size,
                   help="make a kd-tree leaf at or below this many triangles")
    r.add_argument("--tile", type=parse_res, default=(8, 8), metavar="WxH",
                   help="packet tile (at most 64 rays)")
    r.add_argument("--no-cache", action="store_true", help="don't read/write the kd-tree cache")
    r.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    from .render import prepare, render, write_outputs
    from .scene import SceneError, load_scene
    try:
        cfg = Config(fmt=FPFormat(args.exp_bits, args.frac_bits),
                     reflect_depth=args.reflect_depth, oversampling=args.oversampling,
                     shadows=not args.no_shadows, kd_max_depth=args.kd_depth,
                     kd_leaf_size=args.leaf_size, tile_w=args.tile[0], tile_h=args.tile[1])
    except (ConfigError, ValueError) as e:
        print(f"error: impossible configuration: {e}", file=sys.stderr)
        return 2
    try:
        scene = load_scene(args.scene)
    except SceneError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    prep = prepare(scene, cfg, cache_dir=None if args.no_cache else "default")
    result = render(scene, cfg, *args.res, progress=not args.quiet, prepared=prep)
    paths = write_outputs(result, args.out)
    if not args.quiet:
        s = result.stats
        print(f"{s['scene']}: {s['triangles']} triangles, {s['rays_total']} rays "
              f"({', '.join(f'{k} {v}' for k, v in s['rays'].items())}) in "
              f"{s['render_seconds']:.2f} s ({s['rays_per_second'] / 1e6:.2f} M rays/s); "
              f"kd-tree depth {s['kdtree'].get('depth')}, build {s['build_seconds']:.2f} s")
        c = s["counters"]
        print(f"trav-ops {c['trav_ops']}, int-ops {c['int_ops']}, list-ops {c['list_ops']}; "
              f"64-bit reads: trav {c['node_reads']}, list {c['list_reads']}, "
              f"int {c['int_reads']}")
        print("wrote " + ", ".join(str(p) for p in paths.values()))
    return 0
