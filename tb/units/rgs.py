"""RGS slave testbenches: ``EyeRays`` and ``RaySetup`` (``rtl/rgs/eye.py``) against the golden model.

Every ray out of the RTL is compared bit for bit, as the packed ``RayIn`` word that
``tb.units.traversal.ray_payloads`` builds from ``model.raygen.eye_rays`` + ``setup`` (the same
packing every RTC testbench feeds), plus its pixel index for eye rays. Both benches drive the
input with random bubbles and the output with random back-pressure (``tb.harness.common.drive`` /
``drain``), and return the transfer cycles, so the tests check latency and throughput too.

* :func:`run_eye_rays`: packet requests (tiles of a frame, in any order, with any packet ids)
  into ``EyeRays``; every ray of every requested tile checked.
* :func:`run_ray_setup`: rays (any origins, directions, tmax, any-hit flags) into ``RaySetup``.
* :func:`edge_rays`: random rays plus the edge cases of ray setup (zero and signed-zero
  direction components, |d| ties, origins on the box's face planes, infinities, tiny and huge
  components).
"""
from __future__ import annotations

import random
from dataclasses import dataclass, field

import numpy as np
from amaranth.lib import data, stream, wiring

from model.config import Config
from model.fp import FPFormat
from model.raygen import Rays, camera_registers, eye_rays, setup
from model.scene_data import Camera
from rtl.rgs import EyeRay, EyeRays, RaySetup
from rtl.rtc_streams import RayIn

from tb.harness.common import drain, drive, run
from tb.units.traversal import ray_payloads

__all__ = ["RGSRun", "run_eye_rays", "eye_ray_streams", "run_ray_setup", "ray_setup_streams",
           "edge_rays", "fields", "tile_grid", "axis_camera", "oblique_camera", "AXIS_BOX"]

# a box whose lo.x face plane holds the axis camera's position
AXIS_BOX = np.array([[0.5, -8.0, -2.0], [1.0, 8.0, 0.5]])


def axis_camera() -> Camera:
    """Looking exactly down -z: dx and dy have signed-zero z components (so the products
    px*dx_z, py*dy_z are ±0), and in a 15 x 12 image (half_h = 1.5, so dx = 0.25 and
    corner.x = -1.875) the middle column's x component cancels to exactly 0 (an infinite
    reciprocal);
    its position lies on :data:`AXIS_BOX`'s lo.x plane, so those rays take the flat rule."""
    fov = 2 * np.degrees(np.arctan(1.5))
    return Camera(np.array([0.5, 0.25, 3.0]), np.array([0.5, 0.25, 0.0]),
                  np.array([0.0, 1.0, 0.0]), fov)


def oblique_camera() -> Camera:
    return Camera(np.array([0.3, 0.9, 3.1]), np.array([-0.2, 0.1, 0.0]),
                  np.array([0.1, 1.0, 0.05]), 47.0)


@dataclass
class RGSRun:
    rays: int
    in_cycles: list                     # cycle of each input transfer (request or ray)
    out_cycles: list                    # cycle of each output transfer
    latency: int                        # the unit's documented latency
    mismatches: list = field(default_factory=list)   # (index, field, rtl, model)

    def describe(self, first: int = 10) -> str:
        lines = [f"{len(self.mismatches)} mismatching fields"]
        lines += [f"  ray {i}: {f} RTL {a}, model {b}" for i, f, a, b in self.mismatches[:first]]
        return "\n".join(lines)


def fields(value, prefix: str = "") -> dict:
    """A ``lib.data`` constant as ``{"ray.org[1]": int, ...}`` (for field-by-field reports)."""
    shape = value.shape()
    if isinstance(shape, data.StructLayout):
        out = {}
        for name, _ in shape:
            out.update(fields(value[name], f"{prefix}{name}."))
        return out
    if isinstance(shape, data.ArrayLayout):
        out = {}
        for i in range(shape.length):
            out.update(fields(value[i], f"{prefix[:-1]}[{i}]."))
        return out
    return {prefix[:-1]: int(value.as_value().value if isinstance(value, data.Const) else value)}


def _mismatches(layout, got: list, want: list) -> list:
    """Bit-for-bit comparison of payloads (dicts) as packed ``layout`` words, then by field."""
    out = []
    if len(got) != len(want):
        out.append((-1, "count", len(got), len(want)))
    for i, (g, w) in enumerate(zip(got, want)):
        gc, wc = layout.const(g), layout.const(w)
        if gc.as_value().value != wc.as_value().value:
            gf, wf = fields(gc), fields(wc)
            out += [(i, f, gf[f], wf[f]) for f in wf if gf[f] != wf[f]]
    return out


def tile_grid(width: int, height: int, cfg: Config) -> tuple[int, int]:
    """(tiles per row, tile rows) of a ``width x height`` image's sample image."""
    n = cfg.oversampling
    return -(-width * n // cfg.tile_w), -(-height * n // cfg.tile_h)


def _words(fmt: FPFormat, v) -> list[int]:
    return [int(x) for x in fmt.to_bits(np.asarray(v, np.float32))]


def eye_ray_streams(camera, width: int, height: int, cfg: Config, bounds, *, tiles=None,
                    packet_ids=None) -> tuple[dict, list, list]:
    """``EyeRays``' register values (format words: ``pos``, ``corner``, ``dx``, ``dy``,
    ``box_lo``, ``box_hi``), packet requests and expected ``EyeRay`` outputs for ``tiles``
    (as :func:`run_eye_rays` takes them): ``eye_rays`` + ``setup``, packed as every RTC bench
    packs rays, with each ray's pixel."""
    fmt = cfg.fmt
    rays = eye_rays(camera, width, height, cfg)
    bounds = np.asarray(bounds, np.float32)
    per_packet = ray_payloads(rays, setup(rays, bounds, fmt), cfg)
    tiles_x, tiles_y = tile_grid(width, height, cfg)
    tiles = list(range(tiles_x * tiles_y)) if tiles is None else list(tiles)
    ids = [100 + i for i in range(len(tiles))] if packet_ids is None else list(packet_ids)
    want = []
    for t, pid in zip(tiles, ids):
        for lane in per_packet[t]:
            r = int(rays.pk_start[t]) + lane["lane"]
            want.append({"ray": {**lane, "packet": pid}, "pixel": int(rays.pixel[r]),
                         "dir": _words(fmt, rays.dir[r])})
    pos, corner, dx, dy = camera_registers(camera, width, height, cfg)
    regs = {k: _words(fmt, v) for k, v in (("pos", pos), ("corner", corner), ("dx", dx),
                                            ("dy", dy), ("box_lo", bounds[0]),
                                            ("box_hi", bounds[1]))}
    reqs = [{"tile_x": t % tiles_x, "tile_y": t // tiles_x, "packet": pid}
            for t, pid in zip(tiles, ids)]
    return regs, reqs, want


def run_eye_rays(camera, width: int, height: int, cfg: Config, bounds, *, tiles=None,
                 packet_ids=None, seed: int = 1, idle: float = 0.0, stall: float = 0.0,
                 latencies: dict | None = None) -> RGSRun:
    """Request ``tiles`` (tile numbers of the frame's row-major tile order, default every tile
    in order; labelled ``packet_ids``, default 100 + position) from ``EyeRays`` with the camera
    registers of :func:`model.raygen.camera_registers` and the box ``bounds`` (2 x 3, format
    values); compare every ray with ``eye_rays`` + ``setup``. ``idle``: request bubbles,
    ``stall``: output back-pressure (probabilities per cycle)."""
    regs, reqs, want = eye_ray_streams(camera, width, height, cfg, bounds, tiles=tiles,
                                       packet_ids=packet_ids)
    dut = EyeRays(cfg, latencies)
    rng = random.Random(seed)
    sent, got = [], []

    async def feeder(ctx):
        for name, v in regs.items():
            ctx.set(getattr(dut, name), v)
        ctx.set(dut.width, width)
        ctx.set(dut.height, height)
        sent.extend(await drive(ctx, dut.req, reqs, rng=rng, idle=idle))

    run(dut, feeder, lambda ctx: drain(ctx, dut.o, len(want), rng=rng, stall=stall, out=got,
                                       timeout=1000))
    return RGSRun(len(want), sent, [c for c, _ in got], dut.latency,
                  _mismatches(EyeRay(cfg), [p for _, p in got], want))


def setup_inputs(rays: Rays, cfg: Config) -> list[dict]:
    """``RaySetupIn`` payloads of ``rays`` in packet order (packet = packet number)."""
    fmt = cfg.fmt
    bits = lambda x: fmt.to_bits(np.asarray(x, np.float32)).astype(np.int64)
    org, dirn, tmax = bits(rays.org), bits(rays.dir), bits(rays.tmax)
    out = []
    for p in range(rays.n_packets):
        a, b = int(rays.pk_start[p]), int(rays.pk_start[p + 1])
        out += [{"packet": p, "lane": r - a, "last": int(r == b - 1),
                 "org": [int(x) for x in org[r]], "dir": [int(x) for x in dirn[r]],
                 "tmax": int(tmax[r]), "anyhit": int(rays.anyhit[r])} for r in range(a, b)]
    return out


def ray_setup_streams(rays: Rays, bounds, cfg: Config) -> tuple[list, list]:
    """``RaySetup``'s inputs (:func:`setup_inputs`) and expected ``RayIn`` outputs
    (``model.raygen.setup`` against the box ``bounds``, packed by ``ray_payloads``)."""
    bounds = np.asarray(bounds, np.float32)
    want = [lane for pk in ray_payloads(rays, setup(rays, bounds, cfg.fmt), cfg) for lane in pk]
    return setup_inputs(rays, cfg), want


def run_ray_setup(rays: Rays, bounds, cfg: Config, *, seed: int = 1, idle: float = 0.0,
                  stall: float = 0.0, latencies: dict | None = None) -> RGSRun:
    """``rays`` through ``RaySetup`` against the box ``bounds``; every ``RayIn`` compared with
    ``model.raygen.setup``'s (packed by ``tb.units.traversal.ray_payloads``)."""
    fmt = cfg.fmt
    bounds = np.asarray(bounds, np.float32)
    inputs, want = ray_setup_streams(rays, bounds, cfg)
    dut = RaySetup(cfg, latencies)
    rng = random.Random(seed)
    sent, got = [], []

    async def feeder(ctx):
        ctx.set(dut.box_lo, _words(fmt, bounds[0]))
        ctx.set(dut.box_hi, _words(fmt, bounds[1]))
        sent.extend(await drive(ctx, dut.i, inputs, rng=rng, idle=idle))

    run(dut, feeder, lambda ctx: drain(ctx, dut.o, len(want), rng=rng, stall=stall, out=got,
                                       timeout=1000))
    return RGSRun(len(want), sent, [c for c, _ in got], dut.latency,
                  _mismatches(RayIn(cfg), [p for _, p in got], want))


def edge_rays(fmt: FPFormat, bounds, n_random: int = 64, seed: int = 1,
              packet: int = 16) -> Rays:
    """Random rays and the edge cases of ray setup against the box ``bounds`` (format values):
    direction components ±0 (infinite reciprocals), |d| ties between axes (the axis choice
    keeps the lowest), negative dominant axes (the swap), origins on each face plane with the
    direction in that plane (0 * inf: the ``flat`` rule) and off it, infinite, tiny and huge
    components, finite and infinite tmax, any-hit flags; in packets of ``packet`` rays."""
    rng = np.random.default_rng(seed)
    lo, hi = (np.asarray(b, np.float64) for b in bounds)
    big, tiny = fmt.max_finite / 4, fmt.min_normal * 2
    dirs, orgs, tmax = [], [], []
    centre = (lo + hi) / 2
    special = [(1, 1, 1), (-1, -1, -1), (1, -1, 0.5), (-2, 2, 2), (0.5, -3, -3), (0, 0, 1),
               (0, 0, -1), (0, 1, 0), (-0.0, -1, -0.0), (1, 0, 0), (-1, -0.0, 0.0),
               (0, 0, 0), (-0.0, -0.0, -0.0), (np.inf, 1, 0), (1, -np.inf, 2), (tiny, 1, tiny),
               (big, big, -big), (tiny, -tiny, tiny), (3, 4, -4), (-5, 5, 5)]
    for d in special:
        dirs.append(d)
        orgs.append(centre + rng.uniform(-0.3, 0.3, 3) * (hi - lo))
        tmax.append(np.inf)
    # origins on a face plane, direction in that plane (flat) or leaving it
    for a in range(3):
        for face in (lo[a], hi[a]):
            for sign_zero in (0.0, -0.0):
                o = centre + rng.uniform(-0.4, 0.4, 3) * (hi - lo)
                o[a] = face
                d = rng.normal(size=3)
                d[a] = sign_zero
                dirs.append(d)
                orgs.append(o)
                tmax.append(np.inf)
            o = centre.copy()
            o[a] = face
            d = rng.normal(size=3)
            dirs.append(d)
            orgs.append(o)
            tmax.append(float(rng.uniform(0.5, 4)))
    # outside the box, pointing away and towards; random rays
    for _ in range(n_random):
        o = centre + rng.normal(size=3) * (hi - lo)
        d = rng.normal(size=3)
        if rng.random() < 0.3:
            d[rng.integers(3)] = rng.choice([0.0, -0.0])
        dirs.append(d)
        orgs.append(o)
        tmax.append(np.inf if rng.random() < 0.5 else float(rng.uniform(0.01, 10)))
    org = fmt.quantize(np.array(orgs))
    dirn = fmt.quantize(np.array(dirs))
    anyhit = rng.random(len(dirs)) < 0.3
    return Rays.from_arrays(org, dirn, fmt.quantize(np.array(tmax)), packet=packet,
                            anyhit=anyhit)


# ---- secondary rays ------------------------------------------------------------------------------

@dataclass
class Hits:
    """Hits as the slave's secondary-ray datapath takes them (format values, float32)."""
    org: np.ndarray          # (N, 3) ray origin
    dir: np.ndarray          # (N, 3) ray direction
    t: np.ndarray            # (N,)
    u: np.ndarray
    v: np.ndarray
    nf: np.ndarray           # (N, 3) unit face normal
    nv: np.ndarray           # (N, 3, 3) vertex normals A, B, C
    eps: float

    def __len__(self) -> int:
        return len(self.t)

    def secondary(self, fmt: FPFormat) -> tuple:
        """``model.rgs.secondary_rays`` of every hit (hit i: ray i on triangle i): p0, g, n,
        r."""
        from model.rgs import secondary_rays
        i = np.arange(len(self), dtype=np.int64)
        return secondary_rays(self.org, self.dir, i, self.t, self.u, self.v, i, self.nf,
                              self.nv, np.float32(self.eps), *fmt.em)


def secondary_cases(fmt: FPFormat, n: int = 200, seed: int = 1) -> Hits:
    """Random hits plus the datapath's edge cases: face normals on either side of the ray,
    directions with zero and signed-zero components, u = v = 0, u + v = 1, t = 0, vertex
    normals that cancel (the interpolated normal is exactly zero: the face normal is used) or
    point away from the face normal (the shading normal is turned), tiny and huge
    directions."""
    rng = np.random.default_rng(seed)
    q = fmt.quantize

    def unit(x):
        return x / np.linalg.norm(x, axis=-1, keepdims=True)
    org = q(rng.uniform(-10, 10, (n, 3)))
    d = rng.normal(size=(n, 3)) * 10.0 ** rng.uniform(-2, 2, (n, 1))
    zero = rng.random((n, 3)) < 0.08
    d = np.where(zero, rng.choice([0.0, -0.0], (n, 3)), d)
    d[np.all(d == 0, axis=1), 2] = 1.0
    t = q(rng.uniform(0, 5, n) * (rng.random(n) > 0.05))
    u = rng.uniform(0, 1, n)
    v = rng.uniform(0, 1, n) * (1 - u)
    e = rng.integers(0, 5, n)
    u = np.where(e == 0, 0.0, np.where(e == 1, 1.0, u))
    v = np.where(e <= 1, 0.0, np.where(e == 2, 1 - u, v))
    nf = unit(rng.normal(size=(n, 3)))
    nv = unit(nf[:, None, :] + 0.4 * rng.normal(size=(n, 3, 3)))
    away = rng.random(n) < 0.1                 # vertex normals on the far side of the face
    nv[away] = -nv[away]
    cancel = rng.random(n) < 0.05              # n_A = -n_B, u = 0.5, v = 0: the sum is zero
    nv[cancel, 1] = -nv[cancel, 0]
    u[cancel], v[cancel] = 0.5, 0.0
    return Hits(org, q(d), t, q(u), q(v), q(nf), q(nv), float(q(1e-3)))


def _pack_rows(fmt: FPFormat, x: np.ndarray) -> list[int]:
    """Rows of format values (N, ...) as ints, element 0 in the low bits."""
    b = fmt.to_bits(np.asarray(x, np.float32)).astype(object).reshape(len(x), -1)
    w = fmt.width
    return [sum(int(v) << (w * i) for i, v in enumerate(row)) for row in b]


def secondary_ports(hits: Hits, fmt: FPFormat, tag_width: int) -> tuple[dict, dict]:
    """``SecondaryPipe``'s port values per hit and the model's (``model.rgs.secondary_rays``)
    outputs ``p0``, ``g``, ``n``, ``r``, ``o_tag``."""
    p0, g, nn, r = hits.secondary(fmt)
    tag = [i % (1 << tag_width) for i in range(len(hits))]
    eps = int(fmt.to_bits(np.float32(hits.eps)))
    ins = {"org": _pack_rows(fmt, hits.org), "dir": _pack_rows(fmt, hits.dir),
           "t": _pack_rows(fmt, hits.t), "u": _pack_rows(fmt, hits.u),
           "v": _pack_rows(fmt, hits.v), "nf": _pack_rows(fmt, hits.nf),
           "nv": _pack_rows(fmt, hits.nv), "eps": [eps] * len(hits), "tag": tag}
    outs = {"p0": _pack_rows(fmt, p0), "g": _pack_rows(fmt, g), "n": _pack_rows(fmt, nn),
            "r": _pack_rows(fmt, r), "o_tag": tag}
    return ins, outs


def run_secondary(hits: Hits, fmt: FPFormat, *, latencies=None, seed: int = 0,
                  p_bubble: float = 0.2, p_stall: float = 0.2, budget: dict | None = None):
    """Every hit through ``SecondaryPipe`` with random bubbles and stalls, every output checked
    at its exact cycle against the model (``tb.harness.common.FixedPipeRun``)."""
    from rtl.rgs import SecondaryPipe
    from tb.harness.common import run_fixed_pipe
    dut = SecondaryPipe(fmt, tag_width=max(1, len(hits).bit_length()), latencies=latencies,
                        budget=budget)
    ins, outs = secondary_ports(hits, fmt, dut.tag_width)
    return run_fixed_pipe(dut, ins, outs, seed=seed, p_bubble=p_bubble, p_stall=p_stall)


def refract_ports(hits: Hits, eta_in: np.ndarray, eta_out: np.ndarray, fmt: FPFormat,
                  tag_width: int) -> tuple[dict, dict]:
    """``SecondaryPipe(refract=True)``'s port values per hit (:func:`secondary_ports` and
    the material's ``eta_in``, ``eta_out`` (N,)) and the model's outputs: those of
    :func:`secondary_ports` and ``model.rgs.refraction_rays``' ``tp0``, ``tdir``, ``tir``."""
    from model.rgs import refraction_rays
    ins, outs = secondary_ports(hits, fmt, tag_width)
    i = np.arange(len(hits), dtype=np.int64)
    zero = np.zeros(len(hits), np.float32)
    org, d, tir, _, _ = refraction_rays(hits.org, hits.dir, i, hits.t, hits.u, hits.v, i,
                                        hits.nf, hits.nv, np.float32(hits.eps), zero,
                                        eta_in, eta_out, zero, np.zeros(3, np.float32),
                                        *fmt.em)
    ins.update(eta_in=_pack_rows(fmt, eta_in), eta_out=_pack_rows(fmt, eta_out))
    outs.update(tp0=_pack_rows(fmt, org), tdir=_pack_rows(fmt, d),
                tir=tir.astype(int).tolist())
    return ins, outs


def run_refract(hits: Hits, eta_in, eta_out, fmt: FPFormat, *, latencies=None, seed: int = 0,
                p_bubble: float = 0.2, p_stall: float = 0.2, budget: dict | None = None):
    """Every hit through ``SecondaryPipe(refract=True)``, checked like :func:`run_secondary`
    (the refracted ray against ``model.rgs.refraction_rays``)."""
    from rtl.rgs import SecondaryPipe
    from tb.harness.common import run_fixed_pipe
    dut = SecondaryPipe(fmt, tag_width=max(1, len(hits).bit_length()), latencies=latencies,
                        budget=budget, refract=True)
    ins, outs = refract_ports(hits, eta_in, eta_out, fmt, dut.tag_width)
    return run_fixed_pipe(dut, ins, outs, seed=seed, p_bubble=p_bubble, p_stall=p_stall)


def shadow_ports(hits: Hits, lights: np.ndarray, point: np.ndarray, fmt: FPFormat,
                 tag_width: int) -> tuple[dict, dict]:
    """``LightPipe``'s shadow-ray port values for every (hit, light) pair — the hits' ``p0``
    and ``g`` from the model's secondary rays, light vectors ``lights`` (L, 3) of kind
    ``point`` (L,); the colour inputs stay 0 — and the model's (``model.rgs.shadow_rays``)
    ``dir``, ``tmax``, ``cast``, ``o_tag``."""
    from model.rgs import shadow_rays
    p0, g, _, _ = hits.secondary(fmt)
    ins = {"p0": [], "g": [], "light": [], "point": []}
    outs = {"dir": [], "tmax": [], "cast": []}
    for vec, pt in zip(lights, point):
        vec = fmt.quantize(vec)
        d, cast = shadow_rays(p0, g, vec, bool(pt), *fmt.em)
        ins["p0"] += _pack_rows(fmt, p0)
        ins["g"] += _pack_rows(fmt, g)
        ins["light"] += _pack_rows(fmt, np.broadcast_to(vec, p0.shape))
        ins["point"] += [int(pt)] * len(p0)
        outs["dir"] += _pack_rows(fmt, d)
        outs["tmax"] += _pack_rows(fmt, np.full(len(p0), 1.0 if pt else np.inf, np.float32))
        outs["cast"] += cast.astype(int).tolist()
    tag = [i % (1 << tag_width) for i in range(len(ins["p0"]))]
    ins["tag"] = outs["o_tag"] = tag
    return ins, outs


def run_shadow(hits: Hits, lights, point, fmt: FPFormat, *, latencies=None, seed: int = 0,
               p_bubble: float = 0.2, p_stall: float = 0.2, budget: dict | None = None):
    """Every (hit, light) pair through ``LightPipe``, its shadow ray checked like
    :func:`run_secondary`."""
    from rtl.rgs import LightPipe
    from tb.harness.common import run_fixed_pipe
    n = len(hits) * len(lights)
    dut = LightPipe(fmt, tag_width=max(1, n.bit_length()), latencies=latencies, budget=budget)
    ins, outs = shadow_ports(hits, np.asarray(lights, np.float64), np.asarray(point), fmt,
                             dut.tag_width)
    return run_fixed_pipe(dut, ins, outs, seed=seed, p_bubble=p_bubble, p_stall=p_stall)


@dataclass
class ColourCases:
    """Inputs of the slave's colour arithmetic (``model.rgs.light_colour``, ``hit_colour``), one
    row per (hit, light): shadow direction ``ld``, shading normal ``n``, reflected direction
    ``r``, record constants ``kd``, ``ks`` (N, 3), ``shin``, ``kr`` (N,), light colour ``lc``
    (N, 3), ray weight ``wt`` (N,), registers ``amb`` and ``bg`` (3,)."""
    ld: np.ndarray
    n: np.ndarray
    r: np.ndarray
    kd: np.ndarray
    ks: np.ndarray
    shin: np.ndarray
    kr: np.ndarray
    lc: np.ndarray
    wt: np.ndarray
    amb: float
    bg: np.ndarray

    def __len__(self) -> int:
        return len(self.wt)


def colour_cases(fmt: FPFormat, n: int = 200, seed: int = 1) -> ColourCases:
    """Random (hit, light) pairs plus edge cases: the light behind the shading normal (no
    diffuse term), the reflection pointing at the light (the highlight's peak), a zero light
    vector (the light on the surface: 1 / sqrt(0) = inf, NaN, clamped to 0), exponents 0, 1
    and 1023, weights and colours large enough to saturate the fixed-point contribution, and
    zero constants."""
    rng = np.random.default_rng(seed)
    q = fmt.quantize

    def unit(x):
        return x / np.linalg.norm(x, axis=-1, keepdims=True)
    nn = unit(rng.normal(size=(n, 3)))
    ld = rng.normal(size=(n, 3)) * 10.0 ** rng.uniform(-2, 2, (n, 1))
    r = rng.normal(size=(n, 3)) * 10.0 ** rng.uniform(-1, 1, (n, 1))
    e = rng.integers(0, 8, n)
    ld[e == 0] = -ld[e == 0] * np.sign(np.sum(ld[e == 0] * nn[e == 0], axis=1))[:, None]
    ld[e == 1] = r[e == 1] * rng.uniform(0.5, 3, (int((e == 1).sum()), 1))
    ld[e == 2] = 0.0
    shin = rng.integers(0, 1024, n)
    shin[e == 3] = rng.choice([0, 1, 1023], int((e == 3).sum()))
    kd = rng.uniform(0, 1, (n, 3))
    ks = rng.uniform(0, 1, (n, 3))
    kd[e == 4] = 0.0
    lc = rng.uniform(0, 2, (n, 3))
    wt = rng.uniform(0, 1, n)
    lc[e == 5] *= 400.0                        # saturates the 24-bit contribution
    kr = rng.uniform(0, 1, n) * (rng.random(n) > 0.3)
    return ColourCases(q(ld), q(nn), q(r), q(kd), q(ks), shin.astype(np.int64), q(kr), q(lc),
                       q(wt), float(q(0.08)), q(np.array([0.2, 0.3, 300.0])))


def light_ports(c: ColourCases, lights: np.ndarray, point: np.ndarray, fmt: FPFormat,
                tag_width: int) -> tuple[dict, dict]:
    """``LightPipe``'s port values for the colour cases ``c`` (the shadow ray made from
    ``c.ld`` as origin offset: p0 = light - ld for a point light) and the model's outputs:
    the shadow ray (``model.rgs.shadow_rays``), the light's, ambient and reflection-miss
    contributions and the reflection weight (``model.rgs.light_colours``, ``hit_colours``)."""
    from model.rgs import FIX_BITS, hit_colours, light_colours, shadow_rays
    E, M = fmt.em
    n = len(c)
    light = fmt.quantize(np.asarray(lights, np.float64))[np.arange(n) % len(lights)]
    pt = np.asarray(point, bool)[np.arange(n) % len(lights)]
    p0 = fmt.quantize(np.where(pt[:, None], light.astype(np.float64) - c.ld, c.r))
    g = c.n
    dirs = np.empty((n, 3), np.float32)
    cast = np.empty(n, bool)
    for li in range(len(lights)):
        rows = np.arange(li, n, len(lights))
        dirs[rows], cast[rows] = shadow_rays(p0[rows], g[rows], light[li], bool(pt[li]), E, M)
    col = light_colours(dirs, c.n, c.r, c.kd, c.ks, c.shin, c.lc, c.wt, E, M)
    amb, wr, rmiss = hit_colours(c.kd, c.kr, np.float32(c.amb), c.bg, c.wt, E, M)
    tag = [i % (1 << tag_width) for i in range(n)]
    fix = lambda x: [sum(int(v) << (FIX_BITS * k) for k, v in enumerate(row))  # noqa: E731
                     for row in x]
    ins = {"p0": _pack_rows(fmt, p0), "g": _pack_rows(fmt, g), "light": _pack_rows(fmt, light),
           "point": pt.astype(int).tolist(), "n": _pack_rows(fmt, c.n),
           "r": _pack_rows(fmt, c.r), "kd": _pack_rows(fmt, c.kd), "ks": _pack_rows(fmt, c.ks),
           "kr": _pack_rows(fmt, c.kr), "shin": c.shin.tolist(), "lc": _pack_rows(fmt, c.lc),
           "wt": _pack_rows(fmt, c.wt), "amb": _pack_rows(fmt, np.full(n, c.amb, np.float32)),
           "bg": _pack_rows(fmt, np.broadcast_to(c.bg, (n, 3))), "tag": tag}
    outs = {"o_p0": _pack_rows(fmt, p0), "o_r": _pack_rows(fmt, c.r),
            "dir": _pack_rows(fmt, dirs),
            "tmax": _pack_rows(fmt, np.where(pt, 1.0, np.inf).astype(np.float32)),
            "cast": cast.astype(int).tolist(), "col": fix(col), "amb_col": fix(amb),
            "wr": _pack_rows(fmt, wr), "rmiss": fix(rmiss), "o_tag": tag}
    return ins, outs


def run_light(c: ColourCases, lights, point, fmt: FPFormat, *, latencies=None, seed: int = 0,
              p_bubble: float = 0.2, p_stall: float = 0.2, budget: dict | None = None):
    """Every colour case through ``LightPipe`` (light ``i % len(lights)`` for case i), every
    output checked at its exact cycle against the model (``tb.harness.common.FixedPipeRun``)."""
    from rtl.rgs import LightPipe
    from tb.harness.common import run_fixed_pipe
    dut = LightPipe(fmt, tag_width=max(1, len(c).bit_length()), latencies=latencies,
                    budget=budget)
    ins, outs = light_ports(c, lights, point, fmt, dut.tag_width)
    return run_fixed_pipe(dut, ins, outs, seed=seed, p_bubble=p_bubble, p_stall=p_stall)


def run_pool(hits: Hits, c: ColourCases, lights, point, fmt: FPFormat, *, budget: dict,
             copies: int, latencies=None, seed: int = 0, p_bubble: float = 0.2):
    """Every hit through the pool's ``SecondaryPipe`` and every colour case through its
    ``LightPipe`` copies at once (``rtl.rgs.ShadePool``), with random bubbles on both inputs:
    each input is offered until a slot of its datapath takes it (the slots checked against
    the phases: ``sec`` in phase 0, ``shd`` in the phases ``t0``), and every output is checked
    at its exact cycle (``latency`` after its input) against the model. Returns
    ``(pool, cycles, mismatches)``."""
    import random
    from rtl.rgs import ShadePool
    from tb.harness.common import run
    pool = ShadePool(fmt, max(1, len(hits).bit_length()), max(1, len(c).bit_length()),
                     latencies, budget, copies)
    streams = []
    for pipe, (ins, outs), phases in (
            (pool.sec, secondary_ports(hits, fmt, max(1, len(hits).bit_length())), {0}),
            (pool.shd, light_ports(c, lights, point, fmt, max(1, len(c).bit_length())),
             set(pool.t0))):
        ports = {k: getattr(pipe, k) for k in (*ins, *outs)}
        ports = {k: (p.as_value() if hasattr(p, "as_value") else p) for k, p in ports.items()}
        streams.append((pipe, ins, outs, ports, phases))
    rnd = random.Random(seed)
    bad: list = []
    total = {"cycles": 0}

    async def bench(ctx):
        nxt = [0] * len(streams)
        due: list[dict] = [{} for _ in streams]     # cycle -> item whose output is due
        cycle = 0
        while any(nxt[k] < len(s[1]["tag"]) or due[k] for k, s in enumerate(streams)):
            for k, (pipe, ins, outs, ports, phases) in enumerate(streams):
                n = len(ins["tag"])
                valid = nxt[k] < n and rnd.random() >= p_bubble
                for name in ins:
                    ctx.set(ports[name], ins[name][nxt[k]] if valid else
                            0 if name == "tag" else rnd.getrandbits(len(ports[name])))
                ctx.set(pipe.i_valid, valid)
                slot = ctx.get(pipe.i_slot)
                if slot != (cycle % pool.ii in phases):
                    bad.append(f"cycle {cycle}: {type(pipe).__name__} i_slot={slot}")
                item = due[k].pop(cycle, None)
                o_valid = ctx.get(pipe.o_valid)
                if o_valid != (item is not None):
                    bad.append(f"cycle {cycle}: {type(pipe).__name__} o_valid={o_valid}")
                if item is not None:
                    for name, want in outs.items():
                        got = ctx.get(ports[name])
                        if got != want[item]:
                            bad.append(f"cycle {cycle}, {type(pipe).__name__} item #{item}: "
                                       f"{name} = {got:#x}, expected {want[item]:#x}")
                if valid and slot:
                    due[k][cycle + pipe.latency] = nxt[k]
                    nxt[k] += 1
            await ctx.tick()
            cycle += 1
        total["cycles"] = cycle

    run(pool, bench)
    return pool, total["cycles"], bad


@dataclass
class TextureCases:
    """Textured hits for ``model.rgs.texture_kd`` and the RTL's ``Texture``: ``kd`` (N, 3),
    ``u``, ``v`` (N,), ``uv`` (N, 6) format values; ``tex`` (N,) the first texel's index in
    ``texels`` (-1: not textured), ``tw``, ``th`` (N,) texture sizes; ``texels`` (uint32 RGBA8
    words of every texture, row by row)."""
    kd: np.ndarray
    u: np.ndarray
    v: np.ndarray
    uv: np.ndarray
    tex: np.ndarray
    tw: np.ndarray
    th: np.ndarray
    texels: np.ndarray

    def __len__(self):
        return len(self.u)


TEXTURE_SIZES = ((1, 1), (2, 3), (5, 4), (8, 8), (17, 3), (300, 2))   # (width, height)


def texture_cases(fmt: FPFormat, n: int = 200, seed: int = 1) -> TextureCases:
    """Random textured hits on textures of the sizes ``TEXTURE_SIZES`` (1 texel, odd and
    power-of-two sizes, a wide one), with texture coordinates in [-3, 3) (the texture repeats,
    negative ones wrap), plus edge cases: coordinates on texel centres and edges, exact
    integers, tiny negatives (wrap to just below 1), huge values (no fraction), NaN and
    infinity, u = v = 0, untextured hits, texels of 0 and 255."""
    rng = np.random.default_rng(seed)
    q = fmt.quantize
    words, first = [], []
    for w, h in TEXTURE_SIZES:
        first.append(sum(x.size for x in words))
        t = rng.integers(0, 256, (h * w, 4)).astype(np.uint8)
        t[rng.random(h * w) < 0.2] = 255
        t[rng.random(h * w) < 0.2] = 0
        words.append(t.view("<u4").reshape(-1))
    texels = np.concatenate(words).astype(np.uint32)
    k = rng.integers(0, len(TEXTURE_SIZES), n)
    tw = np.array([TEXTURE_SIZES[i][0] for i in k], np.int64)
    th = np.array([TEXTURE_SIZES[i][1] for i in k], np.int64)
    tex = np.array(first, np.int64)[k]
    tex[rng.random(n) < 0.1] = -1
    u = rng.uniform(0, 1, n)
    v = rng.uniform(0, 1, n) * (1 - u)
    uv = rng.uniform(-3, 3, (n, 6))
    e = rng.integers(0, 10, n)
    sel = e == 0                                  # texel centres and edges, on every vertex
    uv[sel] = (rng.integers(-20, 40, (int(sel.sum()), 6)) / 2 + 0.5) / 8
    uv[e == 1] = rng.integers(-3, 4, (int((e == 1).sum()), 6))
    uv[e == 2] = -rng.uniform(0, 1e-6, (int((e == 2).sum()), 6))
    uv[e == 3] = rng.choice([1e9, -3e30, 2.0 ** 30 + 1], (int((e == 3).sum()), 6))
    uv[e == 4] = rng.choice([np.nan, np.inf, -np.inf, 0.25], (int((e == 4).sum()), 6))
    u[e == 5] = 0.0
    v[e == 5] = 0.0
    kd = rng.uniform(0, 1, (n, 3))
    with np.errstate(invalid="ignore", over="ignore"):
        return TextureCases(q(kd), q(u), q(v), q(uv), tex, tw, th, texels)


def texture_image(c: TextureCases) -> tuple[np.ndarray, np.ndarray]:
    """The textures of ``c`` as a memory image holds them (each from a word of its own, two
    texels a word, the low half first): ``(words uint64, addr)`` with ``addr`` (N,) each
    case's texture's first word (0 where untextured)."""
    firsts = sorted(set(int(t) for t in c.tex if t >= 0) | {0})
    ends = firsts[1:] + [len(c.texels)]
    words, where, at = [], {}, 0
    for f, e in zip(firsts, ends):
        t = c.texels[f:e]
        if t.size % 2:
            t = np.concatenate([t, np.zeros(1, np.uint32)])
        where[f] = at
        words.append(t.view("<u8"))
        at += t.size // 2
    return (np.concatenate(words), np.array([where.get(int(t), 0) for t in c.tex], np.int64))


class TextureBench(wiring.Component):
    """``rtl.rgs.Texture`` on its texel cache (``rtl.cache.Cache``, ``cache_bytes``) and an
    ``tb.harness.memory.IdealMemory`` holding ``words``; ``hold`` stalls the memory's answers."""

    def __init__(self, cfg: Config, words: np.ndarray, *, tag_width: int, cache_bytes: int = 256,
                 latency: int = 6):
        from model.cache import CacheGeometry
        from rtl.cache import Cache
        from tb.harness.memory import IdealMemory
        from rtl.rgs import TexIn, TexOut, Texture
        self.tex = Texture(cfg, tag_width)
        self.cache = Cache(CacheGeometry(size_bytes=cache_bytes, ways=1, line_items=1,
                                         item_bits=64, item_span=64, outstanding=2, queue=8,
                                         addr_width=cfg.addr_bits,
                                         mem_addr_width=cfg.addr_bits),
                           tag_width=1)
        self.mem = IdealMemory(words, addr_width=cfg.addr_bits, tag_width=len(self.cache.mem.req.payload.tag),
                               latency=latency)
        super().__init__({"i": wiring.In(stream.Signature(TexIn(cfg, tag_width))),
                          "o": wiring.Out(stream.Signature(TexOut(cfg, tag_width))),
                          "hold": wiring.In(1)})

    def elaborate(self, platform):
        from amaranth.hdl import Module
        m = Module()
        m.submodules.tex, m.submodules.cache, m.submodules.mem = self.tex, self.cache, self.mem
        wiring.connect(m, wiring.flipped(self.i), self.tex.i)
        wiring.connect(m, self.tex.o, wiring.flipped(self.o))
        wiring.connect(m, self.tex.mem, self.cache.port)
        wiring.connect(m, self.cache.mem, self.mem.port)
        m.d.comb += [self.mem.hold.eq(self.hold), self.cache.base.eq(0)]
        return m


def run_texture(c: TextureCases, cfg: Config, *, seed: int = 0, idle: float = 0.2,
                stall: float = 0.2, hold: float = 0.3) -> tuple[list, int]:
    """Every texture case through :class:`TextureBench` (input gaps with probability
    ``idle``, output back-pressure ``stall``, memory holds ``hold``): returns the mismatches
    against ``model.rgs.texture_kd`` (``(case, field, got, want)``, in order) and the cycles."""
    from tb.harness.common import drain, drive, run
    E, M = cfg.fmt.em
    from model.rgs import texture_kd
    want = texture_kd(c.kd, c.u, c.v, c.uv, c.tex, c.tw, c.th, c.texels, E, M)
    words, addr = texture_image(c)
    tag_width = max(1, len(c).bit_length())
    dut = TextureBench(cfg, words, tag_width=tag_width)
    fmt = cfg.fmt
    ins = [{"u": int(fmt.to_bits(c.u[i])), "v": int(fmt.to_bits(c.v[i])),
            "uv": _words(fmt, c.uv[i]), "addr": int(addr[i]), "tw": int(c.tw[i]),
            "th": int(c.th[i]), "on": int(c.tex[i] >= 0), "kd": _words(fmt, c.kd[i]),
            "tag": i} for i in range(len(c))]
    rng = random.Random(seed)
    got: list = []

    async def source(ctx):
        await drive(ctx, dut.i, ins, rng=random.Random(seed + 1), idle=idle)

    async def sink(ctx):
        await drain(ctx, dut.o, len(ins), rng=random.Random(seed + 2), stall=stall, out=got,
                    timeout=5000)

    async def holder(ctx):
        while True:
            ctx.set(dut.hold, int(rng.random() < hold))
            await ctx.tick()
    run(dut, source, sink, background=[holder])
    bad = []
    for k, (cycle, p) in enumerate(got):
        if p["tag"] != k:
            bad.append((k, "tag", p["tag"], k))
        w = _words(fmt, want[k])
        if list(p["kd"]) != w:
            bad.append((k, "kd", list(p["kd"]), w))
    return bad, (got[-1][0] if got else 0)
