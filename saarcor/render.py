"""``saarcor render [--scene PATH] [options]``: a scene rendered by the golden model alone."""
from __future__ import annotations

import argparse
import sys

from model.config import ConfigError
from saarcor.args import (RES_BENCH, SCENE, add_config_args, add_out_arg, add_res_arg,
                          add_scene_arg, config_from_args, parse_res, resolve_scene)
from saarcor.outputs import OutputDir

OUTPUTS = ("image.png", "stats.json", "rays.npz", "hits.npz")
"""What ``saarcor render`` writes in ``--out``, all together (``saarcor.outputs.OutputDir``)."""


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="saarcor render",
        description="Render a scene with the golden model; writes image.png, stats.json, "
                    "rays.npz and hits.npz to --out. The image and counters depend on the "
                    "configuration options --fmt, --kd-*, --tile-w/--tile-h, --reflect-depth, "
                    "--oversampling and --shadows; the others size the chip and are only "
                    "recorded in stats.json.")
    add_scene_arg(ap, SCENE)
    add_res_arg(ap, RES_BENCH)
    add_out_arg(ap, "build/render")
    ap.add_argument("--no-cache", action="store_true",
                    help="don't read/write the kd-tree cache (~/.cache/saarcor/kdtree, or "
                         "$SAARCOR_CACHE/kdtree)")
    ap.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    add_config_args(ap)
    return ap


def main(argv=None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    try:
        res = parse_res(args.res)
    except argparse.ArgumentTypeError as e:
        ap.error(str(e))

    from model.render import prepare, render, write_outputs
    from model.scene import SceneError, load_scene
    try:
        cfg = config_from_args(args)
    except (ConfigError, ValueError) as e:
        print(f"saarcor render: impossible configuration: {e}", file=sys.stderr)
        return 2
    args.scene = resolve_scene(args.scene, "saarcor render")
    out = OutputDir(args.out, "saarcor render", owns=OUTPUTS).check()
    try:
        scene = load_scene(args.scene)
        prep = prepare(scene, cfg, cache_dir=None if args.no_cache else "default")
    except (SceneError, ConfigError) as e:
        print(f"saarcor render: {e}", file=sys.stderr)
        return 2
    result = render(scene, cfg, *res, progress=not args.quiet, prepared=prep)
    with out:
        paths = write_outputs(result, out)
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
