"""Checks of a loaded scene: does the FP format hold it (an error), and two sanity probes run on
load (warnings). The rules are in ``docs/scenes.md`` ("Checks on load").

* :func:`check_format` (called by ``model.render.prepare``, so every command gets it): the
  hardware forms differences of coordinates (vertex - ray origin, box corner - ray origin,
  light - surface point) and, in the triangle test and the ray setup, products of up to three
  of them (the edge functions are products of two sheared differences, the distance numerator
  ``tz`` multiplies an edge function by a third). So the scene's extent ``D`` (the largest side
  of the box around every vertex, the camera position and look-at point and the point lights)
  must satisfy

  - ``D**3 <= fmt.max_finite`` (an error beyond: such products overflow), and a
    :class:`~model.scene_data.SceneWarning` when ``D**3 > fmt.max_finite / RANGE_MARGIN``
    (RANGE_MARGIN = 2: one binade of headroom, for the
    sums of such products and their rounding: a 32 x 24 image of a test scene of scene-sized
    triangles with a light and a mirror, against binary32, has in E5M10 225 of 768 pixels off
    by more than 24 levels at ``D**3`` = 0.98 x max_finite, 70 as at small scales at 0.5 x;
    in E6M12 370 at 1.19 x, at most 9 as at small scales at 0.71 x), and every coordinate
    ``<= fmt.max_finite / RANGE_MARGIN``;
  - ``G**3 >= fmt.min_normal * 2**(M + 1)``, ``G`` the extent of the triangles alone (a far
    camera does not make small triangles safe): a product of three differences at the
    scene's scale keeps M + 1 bits (the mantissa's precision) above the flush-to-zero
    threshold, so a product one unit in the last place of ``G**3`` is still a normal number,
    not zero.

  A scene outside these limits is a :class:`~model.config.ConfigError` naming the format, the
  extent (and where it comes from), the limit and what to do (more exponent bits, or scale).

* :func:`light_warnings`: a point light closer than ``LIGHT_ON_SURFACE`` (1e-4) x the scene
  box's diagonal to a triangle lies on a surface (the shading moves secondary-ray origins off
  the surface by that same 1e-4 x diagonal, so such a light is on either side at random: the
  surface gets shadow speckle).
* :func:`camera_warnings`: a grid of probe rays from the camera (float64 Möller-Trumbore, a
  sanity probe, not the hardware); when every ray that hits something hits the back of a
  triangle (face normal ``(B - A) x (C - A)`` pointing away from the camera: the shading
  turns the normal toward the ray, ``model/rgs/secondary.py``), the camera is inside a closed
  mesh.

:func:`scene_warnings` runs both probes; ``model.scene.load_scene`` calls it and emits each
message as a :class:`~model.scene_data.SceneWarning`.
"""
from __future__ import annotations

import math
import warnings

import numpy as np

from .config import ConfigError
from .fp import FPFormat
from .scene_data import SceneWarning

RANGE_MARGIN = 2.0
"""``D**3`` and every coordinate stay at or below ``max_finite / RANGE_MARGIN``."""
LIGHT_ON_SURFACE = 1e-4
"""A point light nearer than this fraction of the scene box's diagonal to a triangle warns."""
PROBE_GRID = (9, 7)
"""Camera probe rays (columns x rows)."""
PROBE_GRID_LARGE = (3, 3)
"""The probe's grid when ``PROBE_GRID`` would test more than the budget."""
PROBE_FULL_MAX = 200_000
"""The probe's budget: ``PROBE_FULL_MAX`` x 63 ray-triangle tests (every triangle of a
200 000-triangle scene against the 9 x 7 grid); triangles whose projection cannot meet a ray
are not tested (cost: a projection of every vertex)."""
PROBE_ASPECT = 4 / 3
"""Image aspect ratio the probe assumes (the scene does not fix the resolution)."""
_CHUNK = 1 << 16          # triangles per block of the vectorised probes (bounded temporaries)


# ---------------------------------------------------------------------------------------------
# the FP format must hold the scene
# ---------------------------------------------------------------------------------------------

def format_limits(fmt: FPFormat) -> tuple[float, float, float]:
    """(smallest extent, largest extent, largest coordinate) ``fmt`` holds (the module
    docstring's rules)."""
    d_max = (fmt.max_finite / RANGE_MARGIN) ** (1 / 3)
    d_min = (fmt.min_normal * 2.0 ** (fmt.frac_bits + 1)) ** (1 / 3)
    return d_min, d_max, fmt.max_finite / RANGE_MARGIN


def _bounds(tris: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) float64 of every vertex, one column at a time (a reduction over axis 0 of the
    (N*3, 3) view is ~20x slower); NaN if any vertex is NaN."""
    v = np.asarray(tris).reshape(-1, 3)
    return (np.array([v[:, a].min() for a in range(3)], np.float64),
            np.array([v[:, a].max() for a in range(3)], np.float64))


def _cube(x: float) -> float:
    """x**3, inf instead of Python's OverflowError."""
    return x ** 3 if x < 1e100 else math.inf


def _min3(x: np.ndarray) -> np.ndarray:
    """Minimum over the last axis of length 3 (faster than ``x.min(axis=-1)``)."""
    return np.minimum(np.minimum(x[..., 0], x[..., 1]), x[..., 2])


def _max3(x: np.ndarray) -> np.ndarray:
    return np.maximum(np.maximum(x[..., 0], x[..., 1]), x[..., 2])


def _scene_points(scene) -> tuple[np.ndarray, list[str]]:
    """The corners of the triangles' box, then the camera and point-light positions, float64;
    with a name for each row (for messages)."""
    pts = list(_bounds(scene.tris))
    names = ["the triangles", "the triangles"]
    cam = getattr(scene, "camera", None)
    if cam is not None:
        pts += [np.asarray(cam.position, np.float64), np.asarray(cam.look_at, np.float64)]
        names += ["the camera position", "the camera's look_at"]
    for i, light in enumerate(getattr(scene, "lights", None) or []):
        if light.kind == "point" and light.position is not None:
            pts.append(np.asarray(light.position, np.float64))
            names.append(f"point light {i}")
    return np.stack(pts), names


def _fits(fmt: FPFormat, extent: float, geometry: float, coord: float) -> bool:
    d_min, d_max, c_max = format_limits(fmt)
    return extent <= d_max and coord <= c_max and geometry >= d_min


def _advice(fmt: FPFormat, extent: float, geometry: float, coord: float) -> str:
    """What to do: the narrowest wider exponent (same fraction bits) that holds the scene, and
    the factor to scale it by to fit ``fmt``, where either exists."""
    d_min, d_max, c_max = format_limits(fmt)
    geometry = max(geometry, 1e-300)
    wider = next((f for f in (FPFormat(e, fmt.frac_bits) for e in range(fmt.exp_bits + 1, 9))
                  if _fits(f, extent, geometry, coord)), None)
    how = "(a TOML transform's 'scale', or rescale the mesh)"
    if d_min > d_max:
        scale, why = None, f"no scale fits {fmt}"
    elif extent / geometry > d_max / d_min:
        scale = None
        why = (f"no scale fits {fmt}: the scene's extent is {extent / geometry:.3g} times its "
               f"triangles', {fmt}'s largest extent only {d_max / d_min:.3g} times its "
               "smallest (bring the camera and lights closer)")
    elif extent > d_max or coord > c_max:
        scale = (f"scale the scene down by at least {max(extent / d_max, coord / c_max):.3g}x "
                 f"{how}")
    else:
        scale = f"scale the scene up by at least {d_min / geometry:.3g}x {how}"
    use = (f"use a format with more exponent bits ({wider} is the narrowest with "
           f"M{fmt.frac_bits} that holds this scene)") if wider is not None else None
    none = f"no format with M{fmt.frac_bits} and at most 8 exponent bits holds it as it is"
    if use and scale:
        text = f"{use}, or {scale}"
    elif use:
        text = f"{use}; {why}"
    elif scale:
        text = f"{scale}; {none}"
    else:
        text = f"{none}, and {why}"
    return text[0].upper() + text[1:]


def _span(pts: np.ndarray, names: list[str], what: str) -> tuple[float, str]:
    """(largest side of the points' box, a phrase saying where it comes from)."""
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    ax = int(np.argmax(hi - lo))
    return float(hi[ax] - lo[ax]), (
        f"{what} {hi[ax] - lo[ax]:.4g} along {'xyz'[ax]} (from {lo[ax]:.4g}, "
        f"{names[int(np.argmin(pts[:, ax]))]}, to {hi[ax]:.4g}, "
        f"{names[int(np.argmax(pts[:, ax]))]})")


def check_format(scene, fmt: FPFormat) -> None:
    """Raise :class:`ConfigError` if ``fmt`` cannot represent the scene's arithmetic (the module
    docstring's rules): its extent (triangles, camera, look_at, point lights) is too large, a
    coordinate is too large, or the triangles' own extent too small. Cheap: a min and a max per
    axis over the vertices."""
    if np.asarray(scene.tris).size == 0:
        return
    pts, names = _scene_points(scene)
    if not np.isfinite(pts).all():
        return                      # NaN/inf: the kd-tree builder reports them
    extent, where = _span(pts, names, "the scene spans")
    geometry, where_g = _span(pts[:2], names[:2], "its triangles span")
    coord = float(np.abs(pts).max())
    d_min, d_max, c_max = format_limits(fmt)
    empty = "" if d_min <= d_max else (
        f"; {fmt} holds no scene at all (its smallest extent {d_min:.4g} exceeds its "
        f"largest {d_max:.4g})")
    d_hard = fmt.max_finite ** (1 / 3)
    if d_max < extent <= d_hard and coord <= c_max and geometry >= d_min:
        warnings.warn(SceneWarning(
            f"FP format {fmt} barely holds the scene: {where}; extent**3 = "
            f"{_cube(extent):.4g} is within a factor {RANGE_MARGIN:g} of {fmt}'s largest finite "
            f"value {fmt.max_finite:.4g}, where sums of the triangle test's products can "
            "overflow for triangles as large as the scene (small triangles are safe). "
            f"{_advice(fmt, extent, geometry, coord)}"), stacklevel=2)
        return
    if extent > d_hard:
        what = (f"{where}; the triangle test and the ray setup form products of up to three "
                f"coordinate differences, so extent**3 = {_cube(extent):.4g} must stay at or "
                f"below {fmt}'s largest finite value {fmt.max_finite:.4g}, i.e. extent <= "
                f"{d_hard:.4g} (below {d_max:.4g} to be safe for scene-sized triangles); "
                "beyond it results overflow to infinity (triangles vanish from "
                "the image, or the kd-tree build fails)")
    elif coord > c_max:
        what = (f"its largest coordinate {coord:.4g} exceeds {c_max:.4g}, half {fmt}'s largest "
                f"finite value {fmt.max_finite:.4g} (coordinates and their sums would "
                "overflow to infinity)")
    elif geometry < d_min:
        what = (f"{where_g}; products of three coordinate differences must keep the "
                f"mantissa's {fmt.frac_bits + 1} bits above {fmt}'s smallest normal "
                f"{fmt.min_normal:.4g} (below it they flush to zero: an empty or wrong image), "
                f"so extent**3 = {_cube(geometry):.4g} must be at least {fmt.min_normal:.4g} x "
                f"2**{fmt.frac_bits + 1}, i.e. extent >= {d_min:.4g}")
    else:
        return
    raise ConfigError(f"FP format {fmt} cannot represent the scene: {what}{empty}. "
                      f"{_advice(fmt, extent, geometry, coord)}")


# ---------------------------------------------------------------------------------------------
# sanity probes (warnings)
# ---------------------------------------------------------------------------------------------

def _point_triangle_distance(p: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Distance from point ``p`` (3,) to each triangle of ``tris`` (K, 3, 3), float64:
    the distance to the plane where the point projects inside the triangle, else the distance
    to the nearest edge."""
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    n = np.cross(b - a, c - a)
    nn = np.einsum("ij,ij->i", n, n)
    inside = np.ones(len(tris), bool)
    seg = np.full(len(tris), np.inf)
    for s, e in ((a, b), (b, c), (c, a)):
        edge, rel = e - s, p - s
        inside &= np.einsum("ij,ij->i", np.cross(edge, rel), n) >= 0
        ee = np.einsum("ij,ij->i", edge, edge)
        t = np.clip(np.einsum("ij,ij->i", rel, edge) / ee, 0.0, 1.0)
        d = rel - t[:, None] * edge
        seg = np.minimum(seg, np.sqrt(np.einsum("ij,ij->i", d, d)))
    plane = np.abs(np.einsum("ij,ij->i", p - a, n)) / np.sqrt(nn)
    return np.where(inside, plane, seg)


def light_warnings(scene) -> list[str]:
    """A message for each point light within ``LIGHT_ON_SURFACE`` x the box diagonal of a
    triangle. Triangles' bounding boxes widened by that distance filter the candidates; the
    exact distance is computed only for those (cost: two comparisons per triangle and light)."""
    lights = [(i, np.asarray(lt.position, np.float64)) for i, lt in enumerate(scene.lights)
              if lt.kind == "point" and lt.position is not None]
    if not lights or len(scene.tris) == 0:
        return []
    tris = np.asarray(scene.tris)
    lo, hi = _bounds(tris)
    diag = float(np.linalg.norm(hi - lo))
    eps = LIGHT_ON_SURFACE * diag
    # triangles whose box, widened by pad (a little more than eps, for the float32 rounding
    # of the light position), contains the light: first along the box's longest axis (one
    # pass over the triangles), then the other two axes on those
    pad = 2 * eps + 1e-6 * float(max(np.abs(lo).max(), np.abs(hi).max()))
    ax = int(np.argmax(hi - lo))
    out = []
    span = None
    for i, p in lights:
        if (p < lo - pad).any() or (p > hi + pad).any():
            continue                                  # outside the scene box: far from all
        if span is None:
            col = tris[:, :, ax]
            span = (_min3(col), _max3(col))
        q = p.astype(np.float32)
        cand = np.flatnonzero((span[0] <= q[ax] + np.float32(pad))
                              & (span[1] >= q[ax] - np.float32(pad)))
        sub = tris[cand]
        near = ((_min3(sub.transpose(0, 2, 1)) <= q + np.float32(pad))
                & (_max3(sub.transpose(0, 2, 1)) >= q - np.float32(pad))).all(axis=1)
        cand = cand[near]
        if cand.size == 0:
            continue
        d = _point_triangle_distance(p, tris[cand].astype(np.float64))
        k = int(np.argmin(d))
        if d[k] < eps:
            out.append(f"point light {i} at {p.tolist()} lies on a surface: {d[k]:.3g} from "
                       f"triangle {int(scene.tri_id[cand[k]])} (scene order), below "
                       f"{LIGHT_ON_SURFACE:g} x the scene box diagonal ({eps:.3g}); the "
                       "surfaces around it will be covered in shadow speckle. Move the light "
                       "off the surface (e.g. 1% of the room's size into the room)")
    return out


def _camera_frame(camera) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(position, forward, right, up): the camera's orthonormal frame, float64."""
    pos = np.asarray(camera.position, np.float64)
    fwd = np.asarray(camera.look_at, np.float64) - pos
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.asarray(camera.up, np.float64))
    right /= np.linalg.norm(right)
    return pos, fwd, right, np.cross(right, fwd)


def _probe_grid(camera, nx: int, ny: int) -> tuple[np.ndarray, np.ndarray]:
    """Image-plane coordinates (at distance 1 along the view) of the centres of an nx x ny
    grid of cells: (xs (nx,), ys (ny,))."""
    half_h = math.tan(math.radians(camera.fov_y) / 2)
    half_w = half_h * PROBE_ASPECT
    return (((np.arange(nx) + 0.5) / nx * 2 - 1) * half_w,
            ((np.arange(ny) + 0.5) / ny * 2 - 1) * half_h)


def _candidates(tris: np.ndarray, frame, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """Indices of the triangles a probe ray may hit: those straddling the camera plane, and
    those in front of it whose projection's bounding box contains a grid point (a triangle
    wholly behind the camera cannot be hit: every ray point with t > 0 is in front)."""
    o, fwd, right, up = frame
    basis = np.stack([fwd, right, up], axis=1)                    # (3, 3): columns
    sx, sy = xs[1] - xs[0], ys[1] - ys[0]
    out = []
    for k0 in range(0, len(tris), 4 * _CHUNK):
        w = (tris[k0:k0 + 4 * _CHUNK].astype(np.float64) - o) @ basis      # (K, 3, 3)
        pos = w[..., 0] > 0
        front = pos[:, 0] & pos[:, 1] & pos[:, 2]
        straddle = ~front & (pos[:, 0] | pos[:, 1] | pos[:, 2])
        zs = np.where(front[:, None], w[..., 0], 1.0)
        ok = front.copy()
        for c, g, step in ((1, xs, sx), (2, ys, sy)):
            p = w[..., c] / zs
            lo, hi = _min3(p), _max3(p)
            tol = 1e-9 * (1.0 + np.abs(lo) + np.abs(hi))
            i_lo = np.maximum(np.ceil((lo - tol - g[0]) / step), 0)
            i_hi = np.minimum(np.floor((hi + tol - g[0]) / step), len(g) - 1)
            ok &= i_lo <= i_hi
        out.append(np.flatnonzero(straddle | ok) + k0)
    return np.concatenate(out) if out else np.zeros(0, np.int64)


def probe_camera(scene, grid: tuple[int, int] = PROBE_GRID) -> tuple[int, int, int] | None:
    """Cast ``grid`` probe rays from the camera through the image plane against the triangles
    (float64 Möller-Trumbore on the triangles whose projection can meet a ray, every ray at
    once). Returns (rays, rays that hit, rays whose nearest hit is a back face:
    ``dot(d, (B - A) x (C - A)) > 0``), or None when the scene is too big for the budget
    (more than ``PROBE_FULL_MAX`` x 63 ray-triangle tests even on the ``PROBE_GRID_LARGE``
    grid: the probe is skipped)."""
    tris = np.asarray(scene.tris)
    frame = _camera_frame(scene.camera)
    budget = PROBE_FULL_MAX * PROBE_GRID[0] * PROBE_GRID[1]
    for g in dict.fromkeys([grid, PROBE_GRID_LARGE]):
        xs, ys = _probe_grid(scene.camera, *g)
        cand = _candidates(tris, frame, xs, ys)
        if len(cand) * len(xs) * len(ys) <= budget:
            break
    else:
        return None
    o, fwd, right, up = frame
    X, Y = np.meshgrid(xs, ys)
    d = fwd + X.reshape(-1, 1) * right + Y.reshape(-1, 1) * up       # (R, 3)
    R = len(d)
    best_t = np.full(R, np.inf)
    back = np.zeros(R, bool)
    lo, hi = _bounds(tris)
    t_min = 1e-9 * float(np.linalg.norm(hi - lo))
    dT = d.T
    cols = np.arange(R)
    for k0 in range(0, len(cand), _CHUNK):
        t = tris[cand[k0:k0 + _CHUNK]].astype(np.float64)
        a = t[:, 0]
        e1, e2 = t[:, 1] - a, t[:, 2] - a
        tv = o - a
        n = np.cross(e1, e2)
        q = np.cross(tv, e1)
        dn = n @ dT                               # (K, R): d . n; det = -d . n
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            inv = -1.0 / dn
            u = (np.cross(e2, tv) @ dT) * inv
            v = (q @ dT) * inv
            tt = np.einsum("ij,ij->i", e2, q)[:, None] * inv
            hit = (dn != 0) & (u >= 0) & (v >= 0) & (u + v <= 1) & (tt > t_min)
        tt = np.where(hit, tt, np.inf)
        j = np.argmin(tt, axis=0)
        tj = tt[j, cols]
        closer = tj < best_t
        best_t = np.where(closer, tj, best_t)
        back = np.where(closer, dn[j, cols] > 0, back)
    hits = np.isfinite(best_t)
    return R, int(hits.sum()), int((back & hits).sum())


def camera_warnings(scene) -> list[str]:
    """A message when every probe ray that hits something hits a back face."""
    if len(scene.tris) == 0 or scene.camera is None:
        return []
    probe = probe_camera(scene)
    if probe is None:
        return []
    rays, hits, backs = probe
    if hits == 0 or backs < hits:
        return []
    return [f"the camera at {np.asarray(scene.camera.position).tolist()} sees only back faces "
            f"(all {hits} of {rays} probe rays that hit a triangle hit its back, the side its "
            "face normal (B - A) x (C - A) points away from): the camera is inside a closed "
            "mesh (or behind a surface facing away from it, e.g. under a terrain) and the "
            "image shows that object from inside. Move the camera out, or, if the mesh is "
            "meant as a room seen from inside, make its faces point inward (box/sphere "
            "'inward = true', or reverse the winding)"]


def scene_warnings(scene) -> list[str]:
    """The messages of both probes (empty for a sane scene)."""
    return light_warnings(scene) + camera_warnings(scene)


def warn_scene(scene, stacklevel: int = 3) -> None:
    """Emit every :func:`scene_warnings` message as a :class:`SceneWarning`."""
    for msg in scene_warnings(scene):
        warnings.warn(SceneWarning(f"{scene.source}: {msg}"), stacklevel=stacklevel)
