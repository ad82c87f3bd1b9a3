"""Precision study: image and ray error, hardware cost and run time against the FP format.

    saarcor bench precision [--scene PATH ...] [--mesh-dir DIR] [--formats E8M23,...]
                            [--res 256x191] [--out build/bench] [--no-plots] [--replot]

Writes ``OUT/precision.json`` and the plots in ``OUT/precision/`` (``--replot`` redraws them
and prints the tables from the JSON, without running).

For every scene and format (E, M) the golden model (``model.render``) renders the scene and is
compared with a float64 render of the same algorithm, scene and camera
(``model.reference.render64``):

* image: PSNR, worst pixel and share of pixels off by more than one level, on the 8-bit sRGB
  image the renderer writes;
* eye rays: the model's own rays (the format's values, exact in float64) traced in float64 on
  the scene's triangles — hit/miss flips, wrong-triangle hits, relative error of t;
* secondary rays: one shadow ray per eye hit and light, made as the renderer makes them at this
  format and traced as closest-hit rays by the model and by the float64 tracer — flips, and
  self-shadowing (the closest hit is the triangle the ray leaves);
* watertight leaks: rays through vertices and shared-edge points of closed meshes, from outside;
  a ray the model lets through (a miss or a first hit beyond the target) is a leak when the
  float64 test on the same ray and triangles crosses the surface an odd number of times up to
  the target (it enters the solid), and "grazing" when an even number (it touches a fold);
* hardware: Yosys ECP5 LUT4/FF/DSP of the adder, multiplier and divider at this format
  (``saarcor.bench.fp_cost``, cached under ``build/precision/synth``), and the scene's memory image bytes;
* run time: golden-model eye rays per second at this format (best of ``--repeat``).
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

from model.config import Config
from model.fp import FPFormat
from model.kdtree import build_kdtree
from model.layout import build_image
from model.raygen import Rays, setup
from model.raykind import RayKind
from model.reference import Reference, crossings64, render64
from model.render import prepare, render, to_srgb8
from model.rtc import trace
from model.scene import load_scene
from model.shading import Shader, surface_offset

from saarcor.args import (add_formats_arg, add_out_arg, add_res_arg, add_scene_arg,
                          parse_formats, res_from_args)
from saarcor.bench.fp_cost import fp_cost
from saarcor.outputs import write_atomic

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_FORMATS = ",".join([f"E8M{m}" for m in (23, 20, 18, 16, 14, 13, 12, 11, 10)]
                           + ["E7M16", "E6M16", "E6M13"])
MESH_NAMES = ("teapot", "bunny", "spot", "cruiser", "f-16", "dragon", "nefertiti")


# ------------------------------------------------------------------------------------------
# error measures
# ------------------------------------------------------------------------------------------

def image_error(img: np.ndarray, ref: np.ndarray) -> dict:
    """Error of a linear float image against a reference, on the 8-bit sRGB images
    (``model.render.to_srgb8``): PSNR (dB, inf if identical), worst pixel (levels, max over
    channels) and the share of pixels with a channel off by more than one level."""
    a = to_srgb8(np.asarray(img, np.float32)).astype(np.int32)
    b = to_srgb8(np.asarray(ref, np.float32)).astype(np.int32)
    if a.shape != b.shape:
        raise ValueError(f"image_error: shapes differ: {a.shape} vs {b.shape}")
    d = np.abs(a - b)
    mse = float((d.astype(np.float64) ** 2).mean())
    psnr = float("inf") if mse == 0 else 10 * np.log10(255.0 ** 2 / mse)
    per_px = d.max(axis=-1)
    return {"psnr_db": psnr, "worst_levels": int(per_px.max()),
            "share_off_gt_1_level": float((per_px > 1).mean())}


def ray_error(tri, t, ref_tri, ref_t) -> dict:
    """Hits against a reference on the same rays: hit/miss flips (either way), hits on a
    different triangle, and the relative error of t where both hit the same triangle."""
    tri, ref_tri = np.asarray(tri), np.asarray(ref_tri)
    n = len(tri)
    hit, ref_hit = tri >= 0, ref_tri >= 0
    both = hit & ref_hit
    same = both & (tri == ref_tri)
    rel = (np.abs(np.asarray(t, np.float64)[same] - np.asarray(ref_t, np.float64)[same])
           / np.abs(np.asarray(ref_t, np.float64)[same]))
    q = (lambda p: float(np.quantile(rel, p))) if rel.size else (lambda p: 0.0)
    return {"rays": int(n), "flips": int((hit != ref_hit).sum()),
            "flip_share": float((hit != ref_hit).mean()) if n else 0.0,
            "false_hits": int((hit & ~ref_hit).sum()), "false_misses": int((~hit & ref_hit).sum()),
            "wrong_triangle": int((both & (tri != ref_tri)).sum()),
            "wrong_triangle_share": float((both & (tri != ref_tri)).mean()) if n else 0.0,
            "t_rel_median": q(0.5), "t_rel_p99": q(0.99),
            "t_rel_max": float(rel.max()) if rel.size else 0.0}


# ------------------------------------------------------------------------------------------
# secondary rays and self-shadowing
# ------------------------------------------------------------------------------------------

def shadow_error(scene, prep, cfg: Config, rays: Rays, hits, ref: Reference) -> dict:
    """Shadow rays from the eye hits (every light), made at ``cfg.fmt`` as ``model.render``
    makes them, traced as closest-hit rays by the model and in float64."""
    fmt = cfg.fmt
    shader = Shader(scene, fmt, eps=surface_offset(prep.image.bounds))
    sel = np.nonzero(hits.tri >= 0)[0]
    if sel.size == 0 or not scene.lights:
        return {"rays": 0}
    surf = shader.surface(rays, sel, hits.tri[sel], hits.t[sel], hits.u[sel], hits.v[sel])
    org, dirn, tmax, parent = [], [], [], []
    for light in scene.lights:
        s, keep = shader.shadow_rays(rays, sel, surf, light)
        org.append(s.org), dirn.append(s.dir), tmax.append(s.tmax)
        parent.append(hits.tri[sel[keep]])
    org, dirn, tmax, parent = (np.concatenate(x) for x in (org, dirn, tmax, parent))
    srays = Rays.from_arrays(org, dirn, tmax, anyhit=np.zeros(len(org), bool))
    h, _ = trace(prep.image, srays, cfg)
    r_tri, r_t, _, _ = ref.trace(org, dirn, tmax)
    out = ray_error(h.tri, h.t, r_tri, r_t)
    out["self_hits"] = int((h.tri == parent).sum())
    out["self_hits_float64"] = int((r_tri == parent).sum())
    out["false_shadow"] = out.pop("false_hits")
    out["false_light"] = out.pop("false_misses")
    return out


# ------------------------------------------------------------------------------------------
# watertight leaks
# ------------------------------------------------------------------------------------------

def closed_meshes(mesh_dir: Path | None) -> dict:
    """Closed triangle meshes (trimesh): procedural primitives and the watertight real ones."""
    import trimesh
    out = {
        "icosphere": trimesh.creation.icosphere(subdivisions=4, radius=2.0),
        "cylinder": trimesh.creation.cylinder(radius=1.0, height=3.0, sections=40),
        "box": trimesh.creation.box(extents=(2.0, 3.0, 1.0)).subdivide().subdivide(),
    }
    if mesh_dir is not None:
        for name in ("dragon", "nefertiti", "bunny", "spot", "teapot"):
            path = Path(mesh_dir) / f"{name}.obj"
            if path.exists():
                m = trimesh.load(path, force="mesh", process=False)
                if m.is_watertight:
                    out[name] = m
    return out


def leak_rays(mesh, fmt: FPFormat, n_max: int = 20000, seed: int = 0, tilt: float = 0.5):
    """Rays from outside through the mesh's vertices and points of its shared edges, each
    entering every face around its target (directions drawn again where a tilted one does
    not). Returns (org, dir): the target is at t = 1."""
    rng = np.random.default_rng(seed)
    v = fmt.quantize(mesh.vertices)
    faces = np.asarray(mesh.faces)
    fn = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
    fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
    flat = faces.ravel()                                      # faces around each vertex,
    by_v = np.argsort(flat, kind="stable")                    # (V, max) padded with -1
    deg = np.bincount(flat, minlength=len(v))
    rank = np.arange(len(flat)) - np.r_[0, np.cumsum(deg)[:-1]][flat[by_v]]
    vf = np.full((len(v), deg.max()), -1)
    vf[flat[by_v], rank] = by_v // 3
    inv = np.asarray(mesh.edges_unique_inverse)
    order = np.argsort(inv, kind="stable")
    if np.any(np.bincount(inv) != 2):
        raise ValueError("leak_rays: the mesh is not closed (an edge without two faces)")
    ef = np.asarray(mesh.edges_face)[order].reshape(-1, 2)
    e = np.asarray(mesh.edges_unique)
    f = rng.random((len(e), 1))
    on_edge = fmt.quantize(v[e[:, 0]] * (1 - f) + v[e[:, 1]] * f)
    pts = np.concatenate([v, on_edge])
    w_ = max(vf.shape[1], 2)
    around = np.full((len(pts), w_), -1)
    around[:len(v), :vf.shape[1]] = vf
    around[len(v):, :2] = ef
    valid = around >= 0
    fa = fn[np.maximum(around, 0)]
    nsum = np.where(valid[:, :, None], fa, 0).sum(axis=1)
    nsum /= np.maximum(np.linalg.norm(nsum, axis=1, keepdims=True), 1e-300)
    chosen, dirs = [], []
    for _ in range(8):
        w = nsum + tilt * rng.normal(size=nsum.shape)
        w /= np.linalg.norm(w, axis=1, keepdims=True)
        enters = np.all(~valid | (np.einsum("kj,kmj->km", w, fa) > 0.05), axis=1)
        chosen.append(np.nonzero(enters)[0])
        dirs.append(w[enters])
    idx, first = np.unique(np.concatenate(chosen), return_index=True)
    w = np.concatenate(dirs)[first]
    pick = rng.choice(len(idx), size=min(n_max, len(idx)), replace=False)
    target, w = pts[idx[pick]], w[pick]
    size = np.ptp(mesh.vertices, axis=0).max()
    org = fmt.quantize(target + 0.5 * size * w)
    dirn = np.stack([fmt.sub(target[:, a], org[:, a]) for a in range(3)], axis=1)
    return org, dirn


def leaks(mesh, fmt: FPFormat, n_max: int = 20000, tris=None) -> dict:
    """Leak rays traced by the model at ``fmt``: a ray that misses or first hits beyond its
    target (t > 1 + 2^(6-M): the rounded direction passes the target within a few ulps).
    ``tris`` (K, 3, 3) replaces the mesh's triangles in the traced scene (tests: a hole)."""
    cfg = Config(fmt=fmt)
    closed = fmt.quantize(np.asarray(mesh.vertices)[np.asarray(mesh.faces)]).astype(np.float32)
    tris = closed if tris is None else fmt.quantize(tris).astype(np.float32)
    image = build_image(tris, build_kdtree(tris, cfg, cache_dir=None), cfg)
    org, dirn = leak_rays(mesh, fmt, n_max)
    h, _ = trace(image, Rays.from_arrays(org, dirn), cfg)
    tlim = 1 + 2.0 ** (6 - fmt.frac_bits)
    through = np.nonzero((h.tri < 0) | (h.t > tlim))[0]
    # the same rays and the closed mesh's triangles in float64: an odd number of crossings up to the target
    # means the ray enters the solid there (the model let it through: a leak); an even number
    # means it grazes a fold (enters and leaves within the tolerance) or starts inside
    n_cross = crossings64(closed.reshape(-1, 9).astype(np.float64),
                          org[through].astype(np.float64), dirn[through].astype(np.float64),
                          np.full(len(through), tlim))
    return {"rays": int(len(org)), "pass_through": int(len(through)),
            "leaks": int((n_cross % 2 == 1).sum()), "grazing": int((n_cross % 2 == 0).sum())}


# ------------------------------------------------------------------------------------------
# cost and run time
# ------------------------------------------------------------------------------------------

def memory_bytes(prep, fmt: FPFormat) -> dict:
    """Bytes of the memory image as laid out (floats are 32-bit binary32 patterns at every
    format) and as they would be with each float field narrowed to the format's width."""
    w = fmt.width
    n_nodes, n_list, n_tris = prep.tree.n_nodes, prep.tree.n_entries, len(prep.tris)
    packed_bits = n_nodes * (32 + w) + n_list * 32 + n_tris * (9 * w + 32)
    laid_bits = n_nodes * 64 + n_list * 32 + n_tris * 320
    return {"image_bytes": int(prep.image.data.nbytes), "geometry_bytes_32bit": laid_bits // 8,
            "geometry_bytes_packed": -(-packed_bits // 8), "nodes": n_nodes, "list": n_list,
            "triangles": n_tris}


def rays_per_second(prep, rays: Rays, cfg: Config, repeat: int = 3) -> float:
    rs = setup(rays, prep.image.bounds, cfg.fmt)
    trace(prep.image, rays, cfg, rs)                       # compiled and warm
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        trace(prep.image, rays, cfg, rs)
        best = min(best, time.perf_counter() - t0)
    return len(rays) / best


# ------------------------------------------------------------------------------------------
# the study
# ------------------------------------------------------------------------------------------

def study_scene(scene, formats, width: int, height: int, repeat: int = 3,
                reflect_depth: int = 3, log=print, *, reference=None,
                quick: bool = False) -> dict:
    """Every measure except leaks and hardware cost, per format, for one scene.
    ``reference``: the float64 tracer and image ``(Reference, image)`` when already made;
    ``quick``: the image and eye-ray measures only (no shadow rays, memory or timing)."""
    t0 = time.perf_counter()
    if reference is None:
        ref = Reference(scene)
        ref_img, _ = render64(ref, width, height, reflect_depth)
    else:
        ref, ref_img = reference
    out = {"scene": scene.name, "triangles": int(len(scene.tris)), "resolution": [width, height],
           "reference_seconds": time.perf_counter() - t0, "formats": {}}
    for fmt in formats:
        cfg = Config(fmt=fmt, reflect_depth=reflect_depth)
        t1 = time.perf_counter()
        try:
            prep = prepare(scene, cfg)
        except ValueError as e:                 # e.g. the scene's range exceeds the format
            out["formats"][str(fmt)] = {"error": f"{type(e).__name__}: {e}"}
            log(f"  {scene.name} {fmt}: {e}")
            continue
        res = render(scene, cfg, width, height, prepared=prep)
        eye = np.nonzero(res.rays.kind == RayKind.EYE)[0]
        er = Rays(res.rays.org[eye], res.rays.dir[eye], res.rays.tmax[eye], res.rays.kind[eye],
                  res.rays.pixel[eye], np.unique(np.r_[np.arange(0, len(eye), 64), len(eye)])
                  .astype(np.int64))
        # the eye rays are the first len(eye) rays in the model's packet order
        assert np.array_equal(eye, np.arange(len(eye)))
        eh = type(res.hits)(*(getattr(res.hits, f)[eye] for f in ("tri", "t", "u", "v")))
        r_tri, r_t, _, _ = ref.trace(er.org, er.dir)
        row = {"image": image_error(res.image, ref_img),
               "eye": ray_error(eh.tri, eh.t, r_tri, r_t),
               "rays_traced": int(len(res.rays)),
               "kdtree_depth": int(prep.tree.depth)}
        if quick:
            row["seconds"] = time.perf_counter() - t1
            out["formats"][str(fmt)] = row
            continue
        row.update({"shadow": shadow_error(scene, prep, cfg, er, eh, ref),
                    "memory": memory_bytes(prep, fmt),
                    "rays_per_second": rays_per_second(prep, er, cfg, repeat),
                    "seconds": time.perf_counter() - t1})
        out["formats"][str(fmt)] = row
        log(f"  {scene.name} {fmt}: PSNR {row['image']['psnr_db']:.1f} dB, eye flips "
            f"{row['eye']['flips']}, wrong tri {row['eye']['wrong_triangle']}, self "
            f"{row['shadow'].get('self_hits', 0)}, {row['rays_per_second'] / 1e6:.2f} M rays/s "
            f"({row['seconds']:.1f} s)")
    return out


def passes(row: dict, n_leaks: int, psnr_min: float = 40.0, flip_max: float = 1e-3) -> bool:
    """The study's rule for one format: its ``study_scene`` row rendered (no error), PSNR >=
    ``psnr_min``, eye-ray flips below ``flip_max``, and no leak (``n_leaks``)."""
    return bool("error" not in row and row["image"]["psnr_db"] >= psnr_min
                and row["eye"]["flip_share"] < flip_max and n_leaks == 0)


def smallest_m(scene_row: dict, leak_rows: dict, psnr_min=40.0, flip_max=1e-3) -> int | None:
    """Smallest M (E = 8) such that it and every larger M in the study pass (:func:`passes`)."""
    ms = sorted((int(k.split("M")[1]) for k in scene_row["formats"] if k.startswith("E8M")),
                reverse=True)
    best = None
    for m in ms:
        n_leaks = sum(v.get(f"E8M{m}", {"leaks": 0})["leaks"] for v in leak_rows.values())
        if not passes(scene_row["formats"][f"E8M{m}"], n_leaks, psnr_min, flip_max):
            break
        best = m
    return best


NARROW_CANDIDATES = tuple(FPFormat(8, m) for m in (23, 20, 18, 16, 14, 13, 12, 11, 10))


def narrowest_format(scene, width: int, height: int, *, candidates=NARROW_CANDIDATES,
                     psnr_min: float = 40.0, flip_max: float = 1e-3, leak_rays: int = 2000,
                     reflect_depth: int = 3, log=None) -> dict:
    """The narrowest FP format that renders ``scene`` safely by the study's rule
    (:func:`passes`): walking ``candidates`` from the first (the widest) on, a format passes
    when the golden model's ``width x height`` image at that format is within ``psnr_min`` dB
    PSNR of the float64 render, fewer than ``flip_max`` of its eye rays flip between hit and
    miss, and no ray of the closed meshes (``leak_rays`` per mesh) leaks through; the walk
    stops at the first format that fails, so the answer and every wider candidate pass.

    Returns ``{"fmt": FPFormat or None (not even the first candidate passes), "formats":
    {name: {"psnr_db", "flip_share", "leaks", "ok"} or {"error", "ok"}}, "rule", "seconds"}``.
    The cost is a float64 render and one model render per format tried (about a second each
    at 64x48 for the shipped scenes, with compiled kernels)."""
    t0 = time.perf_counter()
    ref = Reference(scene)
    ref_img, _ = render64(ref, width, height, reflect_depth)
    meshes = closed_meshes(None) if leak_rays else {}
    best, rows = None, {}
    for fmt in candidates:
        r = study_scene(scene, [fmt], width, height, reflect_depth=reflect_depth,
                        reference=(ref, ref_img), quick=True, log=lambda s: None)
        r = r["formats"][str(fmt)]
        if "error" in r:
            row = {"error": r["error"], "ok": False}
        else:
            n_leaks = sum(leaks(m, fmt, leak_rays)["leaks"] for m in meshes.values())
            row = {"psnr_db": float(r["image"]["psnr_db"]),
                   "flip_share": float(r["eye"]["flip_share"]), "leaks": n_leaks,
                   "ok": passes(r, n_leaks, psnr_min, flip_max)}
        rows[str(fmt)] = row
        if log is not None:
            print(f"narrowest format: {fmt}: {row}", file=log, flush=True)
        if not row["ok"]:
            break
        best = fmt
    return {"fmt": best, "formats": rows, "resolution": [width, height],
            "rule": {"psnr_min_db": psnr_min, "flip_share_max": flip_max,
                     "leak_rays_per_mesh": leak_rays, "leak_meshes": sorted(meshes)},
            "seconds": round(time.perf_counter() - t0, 2)}


def scene_paths(args) -> list[tuple[str, Path]]:
    # a relative path not found here is looked up in the checkout (the default scenes)
    out = [(Path(p).stem, Path(p) if Path(p).exists() or Path(p).is_absolute() else ROOT / p)
           for p in args.scene]
    if args.mesh_dir:
        for name in MESH_NAMES:
            p = Path(args.mesh_dir) / f"{name}.obj"
            if p.exists():
                out.append((name, p))
            else:
                print(f"precision: mesh {p} not found, skipped")
    return out


def jsonable(x):
    if isinstance(x, float) and not np.isfinite(x):
        return None if np.isnan(x) else ("inf" if x > 0 else "-inf")
    if isinstance(x, dict):
        return {k: jsonable(v) for k, v in x.items()}
    if isinstance(x, list):
        return [jsonable(v) for v in x]
    return x


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(
        prog="saarcor bench precision",
        description="Precision study: image/ray error, FP-unit cost and run time per format. "
                    "Writes OUT/precision.json and the plots in OUT/precision/.")
    add_scene_arg(ap, [str(Path("scenes") / f"{n}.toml") for n in
                       ("conference", "cornell", "office", "terrain")], repeat=True)
    ap.add_argument("--mesh-dir", metavar="DIR",
                    help="also the real meshes in this directory (teapot, bunny, spot, cruiser, "
                         "f-16, dragon, nefertiti .obj; missing ones are skipped with a "
                         "message), the watertight ones in the leak test too")
    add_formats_arg(ap, DEFAULT_FORMATS)
    add_res_arg(ap, "256x191",
                why="RES_BENCH with an odd height, which keeps pixel centres off a centred "
                    "camera's diagonals, where a room corner is an exact closest-hit tie")
    ap.add_argument("--reflect-depth", type=int, default=3,
                    help="reflection bounces (default 3)")
    ap.add_argument("--repeat", type=int, default=3,
                    help="timing repetitions, the best is kept (default 3)")
    ap.add_argument("--leak-rays", type=int, default=20000,
                    help="rays per closed mesh and format for the leak test (0: skip; "
                         "default 20000)")
    ap.add_argument("--no-synth", action="store_true",
                    help="do not run Yosys; use cached FP-unit figures only")
    add_out_arg(ap)
    ap.add_argument("--no-plots", action="store_true", help="no PNG plots")
    ap.add_argument("--replot", action="store_true",
                    help="no runs: redraw the plots and print the tables from OUT/precision.json")
    args = ap.parse_args(argv)
    out = Path(args.out) / "precision.json"
    plots = Path(args.out) / "precision"
    if args.replot:
        from saarcor.precision_plot import plot, tables
        result = json.loads(out.read_text())
        for p in plot(result, plots):
            print(f"precision: wrote {p}")
        print(tables(result))
        return result
    width, height = res_from_args(args, "saarcor bench precision")
    try:
        formats = parse_formats(args.formats)
    except ValueError as e:
        ap.error(str(e))
    result = {"machine": {"cpus": os.cpu_count(), "load_at_start": os.getloadavg()[0]},
              "resolution": [width, height], "formats": [str(f) for f in formats],
              "scenes": {}, "leaks": {}, "fp_units": {}}
    t_start = time.perf_counter()
    for fmt in formats:
        c = fp_cost(fmt, ("add", "mul", "div"), run=not args.no_synth)
        if c is not None:
            result["fp_units"][str(fmt)] = c
    if args.leak_rays:
        for name, mesh in closed_meshes(args.mesh_dir).items():
            result["leaks"][name] = {str(f): leaks(mesh, f, args.leak_rays) for f in formats}
            print(f"precision: leaks {name}: "
                  f"{ {k: (v['leaks'], v['grazing']) for k, v in result['leaks'][name].items()} } (leaks, grazing)", flush=True)
    for name, path in scene_paths(args):
        scene = load_scene(path)
        row = study_scene(scene, formats, width, height, args.repeat, args.reflect_depth,
                          log=lambda s: print(s, flush=True))
        row["smallest_m_psnr40_noleak_flips0.1pct"] = smallest_m(row, result["leaks"])
        result["scenes"][name] = row
    result["seconds"] = time.perf_counter() - t_start
    result["machine"]["load_at_end"] = os.getloadavg()[0]
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(out, json.dumps(jsonable(result), indent=1))
    print(f"precision: wrote {out}")
    if not args.no_plots:
        from saarcor.precision_plot import plot
        for p in plot(result, plots):
            print(f"precision: wrote {p}")
    return result


if __name__ == "__main__":
    main()
