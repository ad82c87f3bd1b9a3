"""Scene loader: a TOML scene description or a bare mesh file -> :class:`Scene`.

``load_scene(path)`` reads ``.toml`` scenes (format: ``docs/scenes.md``) and bare meshes
(``.obj .ply .stl .glb .gltf .off`` through trimesh, ``process=False`` so faces keep the file's
order). The result holds world-space float32 triangles in *scene order* (TOML: objects in file
order, each object's instances in order, each instance's faces in load order), with
``tri_id`` giving each kept triangle's index in that order. Degenerate triangles (a repeated
vertex or exactly zero area after rounding to float32) are dropped and counted; every other
bad input raises :class:`SceneError` with a message naming the problem and how to fix it.

Run ``python -m model.scene FILE...`` for a summary of each scene.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .scene_data import (DEFAULT_BACKGROUND, MESH_SUFFIXES, Camera, Light, Material, Scene,
                         SceneError, auto_camera, finish_pieces, grey_material, load_mesh_file)
from .scene_toml import load_toml

__all__ = ["load_scene", "Scene", "SceneError", "Camera", "Light", "Material",
           "DEFAULT_BACKGROUND", "MESH_SUFFIXES"]


def _load_bare_mesh(path: Path) -> Scene:
    piece = load_mesh_file(path, f"{path}")
    tris, ids, n, mat, uv, normals, ndeg = finish_pieces([(piece, 0, f"{path}")])
    if len(tris) == 0:
        raise SceneError(f"{path}: no triangles left after dropping {ndeg} degenerate ones; "
                         "the mesh is empty")
    cam = auto_camera(tris)
    fwd = cam.look_at - cam.position
    right = np.cross(fwd, cam.up)
    right /= np.linalg.norm(right)
    dist = float(np.linalg.norm(fwd))
    light = Light("point", cam.position + 0.2 * dist * (right + cam.up), None,
                  np.array([1.0, 1.0, 1.0]))
    return Scene(path.stem, tris, ids, n, mat, uv, normals, [grey_material()], [light], cam,
                 np.array(DEFAULT_BACKGROUND), {"degenerate": ndeg, "nonfinite": 0}, str(path))


def load_scene(path: str | Path) -> Scene:
    """Load a ``.toml`` scene or a bare mesh file (see the module docstring)."""
    path = Path(path)
    if not path.exists():
        raise SceneError(f"scene file '{path}' does not exist; check the path "
                         "(shipped scenes are in scenes/, e.g. scenes/cornell.toml)")
    if path.is_dir():
        raise SceneError(f"'{path}' is a directory; give a .toml scene or a mesh file")
    suffix = path.suffix.lower()
    if suffix == ".toml":
        return load_toml(path)
    if suffix in MESH_SUFFIXES:
        return _load_bare_mesh(path)
    raise SceneError(f"'{path}': unknown scene type '{path.suffix}'; use a .toml scene or a "
                     f"mesh file ({', '.join(MESH_SUFFIXES)})")


def _main(argv: list[str] | None = None) -> int:
    import argparse
    import time
    ap = argparse.ArgumentParser(prog="python -m model.scene", description=__doc__.split("\n")[0])
    ap.add_argument("files", nargs="+")
    ap.add_argument("--prepare", action="store_true",
                    help="also build the kd-tree and the memory image (the standard Config): "
                         "build seconds, nodes, depth, image size, peak memory of the process")
    ap.add_argument("--no-cache", action="store_true",
                    help="with --prepare: build the kd-tree even when it is cached")
    args = ap.parse_args(argv)
    for f in args.files:
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

    from .config import Config
    from .kdtree import build_kdtree, kdtree_stats
    from .layout import build_image
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
    raise SystemExit(_main())
