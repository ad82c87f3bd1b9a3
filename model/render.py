"""Render a scene with the golden model: build, trace every ray kind, shade, write outputs.

``prepare`` quantizes the scene to the hardware format, builds (or loads) the kd-tree and lays
out the memory image; ``render`` traces eye rays, shadow rays for every light, reflections and
refracted rays (off materials that transmit) to ``cfg.reflect_depth``, all as 64-ray packets
through :func:`model.rtc.trace`, and shades.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numba
import numpy as np

from .config import Config
from .kdtree import build_kdtree, kdtree_stats
from .layout import MemoryImage, build_image
from .raygen import Rays, eye_rays, live_packets, select_packets, setup
from .raykind import RayKind
from .rgs import CHUNK, FIX_FRAC
from .rtc import COUNTERS, Hits, counter_totals, trace
from .scene_checks import check_format
from .shading import Shader, frame_colour_registers, shading_data, surface_offset

CHUNK_PACKETS = 4096


@dataclass
class Prepared:
    image: MemoryImage
    tree: object
    tris: np.ndarray          # quantized triangles in memory order
    build_seconds: float
    from_cache: bool
    cached: dict = field(default_factory=dict)    # per-scene data render() reuses


def prepare(scene, cfg: Config, cache_dir="default") -> Prepared:
    """Quantize the scene, build (or load) its kd-tree and lay out its memory image, shading
    data included (``model.shading.shading_data``: the RGS slave reads its records). First
    :func:`model.scene_checks.check_format`: a ConfigError if ``cfg.fmt`` cannot represent the
    scene's extent."""
    check_format(scene, cfg.fmt)
    tris = cfg.fmt.quantize(scene.tris).astype(np.float32)
    kw = {} if cache_dir == "default" else {"cache_dir": cache_dir}
    tree = build_kdtree(tris, cfg, **kw)
    image = build_image(tris, tree, cfg, tri_id=scene.tri_id,
                        shading=shading_data(scene, cfg.fmt))
    return Prepared(image, tree, tris, tree.build_seconds, tree.from_cache)


def trace_rays(image: MemoryImage, rays: Rays, cfg: Config, progress=None,
               box_cull: bool = True) -> tuple[Hits, np.ndarray]:
    """Trace in chunks of packets (so a progress bar can advance); same result as one call."""
    if progress is None or rays.n_packets <= CHUNK_PACKETS:
        hits, ctrs = trace(image, rays, cfg, box_cull=box_cull)
        if progress is not None:
            progress.update(len(rays))
        return hits, ctrs
    parts, ctr_parts = [], []
    for p0 in range(0, rays.n_packets, CHUNK_PACKETS):
        p1 = min(p0 + CHUNK_PACKETS, rays.n_packets)
        a, b = rays.pk_start[p0], rays.pk_start[p1]
        sub = Rays(rays.org[a:b], rays.dir[a:b], rays.tmax[a:b], rays.kind[a:b],
                   rays.pixel[a:b], rays.pk_start[p0:p1 + 1] - a, rays.anyhit[a:b])
        h, c = trace(image, sub, cfg, box_cull=box_cull)
        parts.append(h)
        ctr_parts.append(c)
        if progress is not None:
            progress.update(len(sub))
    hits = Hits(*(np.concatenate([getattr(h, f) for h in parts]) for f in ("tri", "t", "u", "v")))
    return hits, np.concatenate(ctr_parts)


@dataclass
class RenderResult:
    image: np.ndarray                     # (H, W, 3) float32 linear colour
    rays: Rays                            # every ray traced, in trace order
    hits: Hits
    counters: dict                        # totals over every packet
    counters_by_kind: dict
    stats: dict = field(default_factory=dict)
    colour: np.ndarray | None = None      # (H*W, 3) int64: the pixels' fixed-point sums


@dataclass(frozen=True)
class Skip:
    """Work the renderer leaves out (on by default; off only to measure what it saves):
    ``anyhit``: a shadow ray ends at its first hit; ``lights_behind``: no shadow ray toward a
    light behind the surface; ``nonreflective``: no reflection ray off a material with
    ``reflect == 0``; ``box_cull``: a ray that misses the scene box never enters traversal
    (``model.raygen.setup``). ``empty_tiles`` (off by default, because the RGS slaves send
    every tile): a packet none of whose rays meets the scene box is not traced at all; its
    rays are misses (they would be anyway: with the box cull such a packet does no traversal
    step, but in the RTC it still takes a thread and its rays' input and output cycles)."""
    anyhit: bool = True
    lights_behind: bool = True
    nonreflective: bool = True
    box_cull: bool = True
    empty_tiles: bool = False


def render(scene, cfg: Config, width: int, height: int, progress: bool = False,
           prepared: Prepared | None = None, skip: Skip = Skip(),
           textures: bool | None = None) -> RenderResult:
    """Render a frame: eye rays, shadow rays per light, reflections and refracted rays (off
    materials with ``transmit > 0``) to ``cfg.reflect_depth``,
    each ray's colour contribution as the RGS slave computes it (``model.shading``), summed per
    pixel in fixed point. ``textures``: filter the textures (default: if the chip has a
    texture unit, ``cfg.tex_cache_kb > 0``); False leaves kd as the records hold it."""
    return _render(scene, cfg, width, height, progress, prepared, skip, textures)


def _render(scene, cfg, width, height, progress, prepared, skip, textures) -> RenderResult:
    if textures is None:
        textures = cfg.tex_cache_kb > 0
    t0 = time.perf_counter()
    prep = prepared or prepare(scene, cfg)
    t_build = time.perf_counter() - t0
    image = prep.image
    shader = _shader(prep, scene, cfg.fmt, textures)
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=width * height * cfg.oversampling ** 2, unit="ray", unit_scale=True,
                   desc="tracing", leave=False)

    t1 = time.perf_counter()
    all_rays, all_hits, all_ctrs = [], [], []
    skipped = [0]                          # packets not traced (empty tiles)
    t_trace = [0.0]                        # seconds in ray setup and tracing
    n_samples = cfg.oversampling ** 2
    acc = np.zeros((width * height, 3), np.int64)     # fixed-point colour sums (FIX_FRAC)

    def run(rays: Rays):
        if bar is not None and len(rays) and rays.kind[0] != RayKind.EYE:
            bar.total += len(rays)          # secondary rays are known only once they are made
            bar.refresh()
        traced = rays
        if skip.empty_tiles:
            keep = live_packets(rays, setup(rays, image.bounds, cfg.fmt, skip.box_cull))
            traced, idx = select_packets(rays, keep)
            skipped[0] += int((~keep).sum())
        t = time.perf_counter()
        got, ctrs = trace_rays(image, traced, cfg, bar, box_cull=skip.box_cull)
        t_trace[0] += time.perf_counter() - t
        if traced is rays:
            hits = got
        else:
            hits = Hits(np.full(len(rays), -1, np.int32), np.full(len(rays), np.inf, np.float32),
                        np.zeros(len(rays), np.float32), np.zeros(len(rays), np.float32))
            for f in ("tri", "t", "u", "v"):
                getattr(hits, f)[idx] = getattr(got, f)
        all_rays.append(rays)
        all_hits.append(hits)
        all_ctrs.append((rays, ctrs))
        return hits

    rays = eye_rays(scene.camera, width, height, cfg)
    t_raygen = time.perf_counter() - t1
    col = frame_colour_registers(scene, cfg.fmt, n_samples)
    weight = np.full(len(rays), col["w_eye"], np.float32)
    miss_col = col["eye_miss"].reshape(1, 3)           # one row: every eye ray's
    # the rays of one depth: the eye rays, then per source set its reflection rays and its
    # refracted rays (those only where a material transmits), each traced as a set of its own
    level = [(rays, weight, miss_col)]
    for depth in range(cfg.reflect_depth + 1):
        nxt = []
        for rays, weight, miss_col in level:
            if len(rays) == 0:
                continue
            hits = run(rays)
            hit = np.flatnonzero(hits.tri >= 0)
            if hit.size == 0:
                add_misses(acc, rays.pixel, hits.tri, miss_col)
                continue
            sh = shader.shade(rays, hit, hits.tri, hits.t, hits.u, hits.v, weight, col,
                              cull_behind=skip.lights_behind)
            # misses, ambient terms and, without shadow rays, every light's term (zero where
            # no shadow ray is cast) in one pass
            add_trace_colours(acc, rays.pixel, hits.tri, miss_col, hit, sh.ambient, sh.light,
                              not cfg.shadows)
            for li in range(len(scene.lights) if cfg.shadows else 0):
                srays, keep = shader.shaded_shadow_rays(rays, hit, sh, li)
                if not skip.anyhit:
                    srays.anyhit = np.zeros(len(srays), bool)
                if not len(srays):
                    continue
                lit = np.flatnonzero(run(srays).tri < 0)
                add_colours(acc, srays.pixel, lit, sh.light[li][keep[lit]])
            if depth == cfg.reflect_depth:
                continue
            rrays, keep = shader.reflection_rays(rays, hit, sh, cull_matte=skip.nonreflective)
            nxt.append((rrays, sh.wr[keep], sh.miss[keep]))
            if shader.transmit.any():
                trays, _, twt, tmiss = shader.refraction_rays(rays, hit, sh, hits.tri, hits.t,
                                                              hits.u, hits.v, weight, col)
                nxt.append((trays, twt, tmiss))
        level = nxt
    if bar is not None:
        bar.close()
    t_render = time.perf_counter() - t1

    rays_all = all_rays[0] if len(all_rays) == 1 else Rays.concat(all_rays)
    hits_all = all_hits[0] if len(all_hits) == 1 else Hits(
        *(np.concatenate([getattr(h, f) for h in all_hits]) if all_hits else np.zeros(0)
          for f in ("tri", "t", "u", "v")))
    by_kind: dict = {}
    for r, c in all_ctrs:
        name = RayKind(int(r.kind[0])).label if len(r) else RayKind.EYE.label
        tot = counter_totals(c)
        tot_k = by_kind.setdefault(name, {k: 0 for k in COUNTERS})
        for k in COUNTERS:
            tot_k[k] = max(tot_k[k], tot[k]) if k == "max_stack" else tot_k[k] + tot[k]
    totals = {k: (max(v[k] for v in by_kind.values()) if k == "max_stack"
                  else sum(v[k] for v in by_kind.values())) if by_kind else 0 for k in COUNTERS}
    counts = np.bincount(rays_all.kind, minlength=len(RayKind))
    stats = {
        "scene": scene.name,
        "resolution": [width, height],
        "config": cfg.to_dict(),
        "triangles": int(len(scene.tris)),
        "triangles_dropped": dict(scene.dropped),
        "rays": {RayKind(k).label: int(c) for k, c in enumerate(counts) if c},
        "rays_total": int(len(rays_all)),
        "packets": int(sum(r.n_packets for r in all_rays)),
        "packets_skipped": skipped[0],
        "counters": totals,
        "counters_by_kind": by_kind,
        "memory_reads_64bit": {"trav": totals["node_reads"], "list": totals["list_reads"],
                               "int": totals["int_reads"]},
        # packet steps including idle lanes: the share of lanes doing work in each unit
        "lane_utilization": {
            "trav": totals["trav_ops"] / max(1, totals["trav_steps"] * cfg.packet_size),
            "int": totals["int_ops"] / max(1, totals["int_steps"] * cfg.packet_size)},
        "kdtree": _kdtree_stats(prep),
        "memory_image_bytes": int(image.data.nbytes),
        "build_seconds": round(prep.build_seconds, 4),
        "kdtree_from_cache": bool(prep.from_cache),
        "prepare_seconds": round(t_build, 4),
        "render_seconds": round(t_render, 4),
        # where the render's time went: eye rays, ray setup and tracing (of every ray kind),
        # the rest (shading, secondary rays, colour sums)
        "render_phase_seconds": {"raygen": round(t_raygen, 4), "trace": round(t_trace[0], 4),
                                 "shading": round(t_render - t_raygen - t_trace[0], 4)},
        "rays_per_second": round(len(rays_all) / max(t_render, 1e-9), 1),
    }
    img = colour_image(acc)
    return RenderResult(img.reshape(height, width, 3), rays_all, hits_all, totals, by_kind,
                        stats, colour=acc)


def _shader(prep: Prepared, scene, fmt, textures: bool) -> Shader:
    """The scene's :class:`~model.shading.Shader`, made once per prepared scene."""
    key = ("shader", fmt, textures)
    shader = prep.cached.get(key)
    if shader is None or shader.scene is not scene:
        shader = prep.cached[key] = Shader(scene, fmt, eps=surface_offset(prep.image.bounds),
                                           textures=textures)
    return shader


def _kdtree_stats(prep: Prepared) -> dict:
    if prep.tree is None:
        return {}
    if "kdtree_stats" not in prep.cached:
        prep.cached["kdtree_stats"] = kdtree_stats(prep.tree, len(prep.tris))
    return dict(prep.cached["kdtree_stats"])


@numba.njit(cache=True)
def add_colours(acc, pixel, rows, vals):
    """The per-pixel sums: ``acc[pixel[rows[i]]] += vals[i]`` for every i (``vals`` of one row:
    the same contribution for every i). Integer sums: the order does not matter."""
    one = vals.shape[0] == 1
    for i in range(rows.shape[0]):
        p = pixel[rows[i]]
        j = 0 if one else i
        for c in range(3):
            acc[p, c] += vals[j, c]


@numba.njit(cache=True)
def add_misses(acc, pixel, tri, miss_col):
    """``acc[pixel[r]] += miss_col[r]`` for every ray r that missed (``tri[r] < 0``;
    ``miss_col`` of one row: the same for every ray)."""
    one = miss_col.shape[0] == 1
    for r in range(tri.shape[0]):
        if tri[r] < 0:
            p = pixel[r]
            j = 0 if one else r
            for c in range(3):
                acc[p, c] += miss_col[j, c]


@numba.njit(cache=True)
def add_trace_colours(acc, pixel, tri, miss_col, hit, ambient, light, lights):
    """The sums of one trace's own contributions: :func:`add_misses`, then for every hit i
    (ray ``hit[i]``) ``ambient[i]`` and, if ``lights``, ``light[j, i]`` of every light j.
    Integer sums: the same as adding them one kind after another."""
    add_misses(acc, pixel, tri, miss_col)
    for i in range(hit.shape[0]):
        p = pixel[hit[i]]
        for c in range(3):
            v = ambient[i, c]
            if lights:
                for j in range(light.shape[0]):
                    v += light[j, i, c]
            acc[p, c] += v


@numba.njit(cache=True, parallel=True)
def colour_image(acc):
    """The fixed-point sums as float32 colours: ``float32(acc / 2**FIX_FRAC)``."""
    out = np.empty(acc.shape, np.float32)
    scale = np.float64(1 << FIX_FRAC)
    n = acc.shape[0]
    for ch in numba.prange((n + CHUNK - 1) // CHUNK):
        for i in range(ch * CHUNK, min(n, ch * CHUNK + CHUNK)):
            for c in range(acc.shape[1]):
                out[i, c] = np.float32(np.float64(acc[i, c]) / scale)
    return out


def to_srgb8(img: np.ndarray) -> np.ndarray:
    x = np.clip(img, 0, 1)
    x = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return (x * 255 + 0.5).astype(np.uint8)


def write_rays_hits(out_dir: Path, rays: Rays, hits: Hits) -> None:
    """``rays.npz`` (origin, direction, tmax, kind, pixel, packet_start) and ``hits.npz``
    (tri in scene order or -1, t, u, v) in ``out_dir`` (a folder, or an object whose
    ``file(name)`` gives the path to write, ``saarcor.outputs.OutputDir``). Uncompressed: zlib took longer than
    the render itself (office 1024x768: 4-5 s against 0.2-0.3 s for the 2.5x larger files)."""
    path = out_dir.file if hasattr(out_dir, "file") else (lambda name: Path(out_dir) / name)
    np.savez(path("rays.npz"), origin=rays.org, direction=rays.dir, tmax=rays.tmax,
             kind=rays.kind, pixel=rays.pixel, packet_start=rays.pk_start)
    np.savez(path("hits.npz"), tri=hits.tri.astype(np.int32), t=hits.t, u=hits.u, v=hits.v)


def write_outputs(result: RenderResult, out_dir: Path) -> dict:
    """image.png, stats.json, rays.npz, hits.npz in ``out_dir`` (a folder, or a
    ``saarcor.outputs.OutputDir``, which stages them until its ``commit``); returns the final
    paths."""
    from PIL import Image
    if hasattr(out_dir, "file"):                 # saarcor.outputs.OutputDir: staged files
        out, path = Path(out_dir.dir), out_dir.file
    else:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        path = lambda name: out / name        # noqa: E731
    Image.fromarray(to_srgb8(result.image)).save(path("image.png"))
    write_rays_hits(out_dir if hasattr(out_dir, "file") else out, result.rays, result.hits)
    path("stats.json").write_text(json.dumps(result.stats, indent=2))
    return {name: out / name for name in ("image.png", "stats.json", "rays.npz", "hits.npz")}
