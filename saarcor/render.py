"""Command line of the golden model: ``saarcor render SCENE [options]`` (or
``python -m model render``)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from model.config import ConfigError
from saarcor.args import parse_res


def build_parser() -> argparse.ArgumentParser:
    # every Config field as an option, generated from the dataclass in one place
    from saarcor.args import add_config_args
    p = argparse.ArgumentParser(prog="saarcor",
                                description="SaarCOR golden model: bit-exact ray tracing of a "
                                            "scene in the hardware's arithmetic.")
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("render", help="render a scene; writes image.png, stats.json, rays.npz, "
                                      "hits.npz",
                       description="Render a scene with the golden model; writes image.png, "
                                   "stats.json, rays.npz and hits.npz to --out. The image and "
                                   "counters depend on the configuration options --fmt, "
                                   "--kd-*, --tile-w/--tile-h, --reflect-depth, --oversampling "
                                   "and --shadows; the others size the chip and are only "
                                   "recorded in stats.json.")
    r.add_argument("scene", help="a scene file (.toml, see docs/scenes.md) or a bare mesh "
                                 "(.obj .ply .stl .glb .off; the camera frames it, one light)")
    r.add_argument("--res", type=parse_res, default=(256, 192), metavar="WxH",
                   help="image resolution in pixels (default 256x192)")
    r.add_argument("--out", type=Path, default=Path("build/render"),
                   help="output directory (default build/render)")
    r.add_argument("--no-cache", action="store_true",
                   help="don't read/write the kd-tree cache (~/.cache/saarcor/kdtree, or "
                        "$SAARCOR_CACHE/kdtree)")
    r.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    add_config_args(r)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    from saarcor.args import config_from_args

    from model.render import prepare, render, write_outputs
    from model.scene import SceneError, load_scene
    try:
        cfg = config_from_args(args)
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
