"""Ray tracing core (golden model): traversal -> list -> intersection for 64-ray packets.

``trace_packet`` is one packet's life in the RTC: per direction octant present in the packet
(see ``docs/architecture.md``) a pass walks the kd-tree with a per-packet stack and an
active-lane mask; leaves go through the list unit to the intersection unit; results return to
traversal, which terminates rays whose closest hit lies in the current cell. ``trace`` runs
all packets (compiled, parallel over packets) and sums the hardware's operation counters.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from .fp import sign_bit
from .intersection import TRI_WORDS, fetch_triangle, intersect
from .list import list_entry, list_words
from .traversal import LEAF, bits_to_f32, classify, clip_far, clip_near, decode_node, pop, push

# per-packet counters; the names are the keys of the statistics
COUNTERS = (
    "passes",          # octant passes (1 per packet unless its rays' direction signs disagree)
    "trav_steps",      # packet steps at inner nodes (idle lanes included)
    "trav_ops",        # active ray x inner node
    "node_reads",      # 64-bit node fetches (inner and leaf), one per packet visit
    "leaf_visits",     # packet visits of non-empty leaves
    "list_ops",        # triangle addresses emitted by the list unit
    "list_reads",      # 64-bit words read by the list unit
    "int_steps",       # packet x triangle (one triangle fetch each)
    "int_ops",         # active ray x triangle
    "int_reads",       # 64-bit words read by the intersection unit (5 per triangle)
    "pushes",
    "max_stack",
)
C = {name: i for i, name in enumerate(COUNTERS)}
N_COUNTERS = len(COUNTERS)


@numba.njit(cache=True)
def trace_packet(mem, node_base, list_base, tri_base, root, depth,
                 lanes, org, dirn, inv, kk, ss, tnear0, tfar0, tmax, anyhit,
                 hit_t, hit_tri, hit_u, hit_v, ctr, E, M):
    n = lanes.shape[0]
    tnear = np.empty(n, np.float32)
    tfar = np.empty(n, np.float32)
    dist = np.empty(n, np.float32)
    best = np.empty(n, np.float32)
    s_node = np.empty(depth + 1, np.int64)
    s_mask = np.empty(depth + 1, np.uint64)
    s_near = np.empty((depth + 1, n), np.float32)
    s_far = np.empty((depth + 1, n), np.float32)
    tri = np.empty(9, np.float32)
    o = np.empty(3, np.float32)
    k3 = np.empty(3, np.int64)
    s3 = np.empty(3, np.float32)

    # rays start active if their clipped interval is non-empty; group lanes by octant
    live = np.uint64(0)
    octant = np.empty(n, np.int64)
    for l in range(n):
        r = lanes[l]
        tnear[l] = tnear0[r]
        tfar[l] = tfar0[r]
        best[l] = tmax[r]            # hits must lie in (0, tmax): t_best starts at the ray's end
        hit_t[r] = np.float32(np.inf)
        hit_tri[r] = -1
        hit_u[r] = np.float32(0.0)
        hit_v[r] = np.float32(0.0)
        octant[l] = (sign_bit(dirn[r, 0]) | (sign_bit(dirn[r, 1]) << 1) |
                     (sign_bit(dirn[r, 2]) << 2))
        if tnear[l] <= tfar[l]:
            live |= np.uint64(1) << np.uint64(l)
    terminated = np.uint64(0)

    for oc in range(8):
        mask = np.uint64(0)
        for l in range(n):
            if octant[l] == oc and (live & (np.uint64(1) << np.uint64(l))):
                mask |= np.uint64(1) << np.uint64(l)
        if mask == 0:
            continue
        ctr[0] += 1
        node = np.int64(root)
        sp = 0
        while mask:
            kind, field, hi = decode_node(mem[node_base + node])
            ctr[3] += 1
            if kind != LEAF:
                # ---- traversal unit: inner node
                split = bits_to_f32(hi)
                ctr[1] += 1
                for l in range(n):
                    if mask & (np.uint64(1) << np.uint64(l)):
                        ctr[2] += 1
                mnear, mfar = classify(split, kind, mask, lanes, org, inv, tnear, tfar, dist, E, M)
                first_lane = 0
                while not (mask & (np.uint64(1) << np.uint64(first_lane))):
                    first_lane += 1
                negative = sign_bit(dirn[lanes[first_lane], kind])
                near = field + 1 if negative else field
                far = field if negative else field + 1
                if mnear and mfar:
                    sp = push(sp, far, mfar, dist, tnear, tfar, s_node, s_mask, s_near, s_far, n)
                    if sp > ctr[11]:
                        ctr[11] = sp
                    ctr[10] += 1
                    clip_near(mnear, dist, tfar, n)
                    node, mask = near, mnear
                elif mnear:
                    clip_near(mnear, dist, tfar, n)
                    node, mask = near, mnear
                else:
                    clip_far(mfar, dist, tnear, n)
                    node, mask = far, mfar
                continue
            # ---- leaf: list unit -> intersection unit -> back to traversal
            count = field
            first = np.int64(hi)
            if count > 0:
                ctr[4] += 1
                ctr[6] += list_words(first, count)
            for j in range(count):
                ti = list_entry(mem, list_base, first + j)
                ctr[5] += 1
                ctr[7] += 1
                ctr[9] += TRI_WORDS
                sid = fetch_triangle(mem, tri_base, ti, tri)
                for l in range(n):
                    if not (mask & (np.uint64(1) << np.uint64(l))):
                        continue
                    if terminated & (np.uint64(1) << np.uint64(l)):
                        continue     # a shadow ray that already hit in this leaf
                    r = lanes[l]
                    ctr[8] += 1
                    for a in range(3):
                        o[a] = org[r, a]
                        k3[a] = kk[r, a]
                        s3[a] = ss[r, a]
                    hit, t, u, v = intersect(tri, o, k3, s3, E, M)
                    if hit and t > np.float32(0.0) and t < best[l]:
                        best[l] = t
                        hit_t[r] = t
                        hit_tri[r] = sid
                        hit_u[r] = u
                        hit_v[r] = v
                        if anyhit[r]:
                            terminated |= np.uint64(1) << np.uint64(l)
            # rays whose closest hit lies in this cell are finished
            for l in range(n):
                bit = np.uint64(1) << np.uint64(l)
                if (mask & bit) and hit_tri[lanes[l]] >= 0 and best[l] <= tfar[l]:
                    terminated |= bit
            sp, node, mask = pop(sp, terminated, tnear, tfar, s_node, s_mask, s_near, s_far, n)


@numba.njit(cache=True, parallel=True)
def trace_all(mem, node_base, list_base, tri_base, root, depth,
              pk_start, org, dirn, inv, kk, ss, tnear0, tfar0, tmax, anyhit,
              hit_t, hit_tri, hit_u, hit_v, ctrs, E, M):
    n_packets = pk_start.shape[0] - 1
    for p in numba.prange(n_packets):
        lanes = np.arange(pk_start[p], pk_start[p + 1])
        trace_packet(mem, node_base, list_base, tri_base, root, depth,
                     lanes, org, dirn, inv, kk, ss, tnear0, tfar0, tmax, anyhit,
                     hit_t, hit_tri, hit_u, hit_v, ctrs[p], E, M)


@dataclass
class Hits:
    """Per-ray results: ``tri`` is the scene-order triangle id or -1; t = inf on a miss."""
    tri: np.ndarray      # (N,) int32
    t: np.ndarray        # (N,) float32
    u: np.ndarray        # (N,) float32
    v: np.ndarray        # (N,) float32


def trace(image, rays, cfg, ray_setup=None) -> tuple[Hits, np.ndarray]:
    """Trace every packet of ``rays`` through ``image``; returns hits and per-packet counters
    (an int64 array ``(n_packets, N_COUNTERS)``, columns named by ``COUNTERS``)."""
    from .raygen import setup
    n = len(rays)
    sizes = np.diff(rays.pk_start)
    if sizes.size and sizes.max() > 64:
        raise ValueError(f"a packet has {sizes.max()} rays; at most 64 (the active mask width)")
    rs = ray_setup if ray_setup is not None else setup(rays, image.bounds, cfg.fmt)
    hit_t = np.empty(n, np.float32)
    hit_tri = np.empty(n, np.int32)
    hit_u = np.empty(n, np.float32)
    hit_v = np.empty(n, np.float32)
    ctrs = np.zeros((rays.n_packets, N_COUNTERS), np.int64)
    if n:
        E, M = cfg.fmt.em
        trace_all(image.data, image.node_base, image.list_base, image.tri_base, image.root,
                  image.depth, rays.pk_start, rays.org, rays.dir, rs.inv, rs.k, rs.s,
                  rs.tnear, rs.tfar, rays.tmax.astype(np.float32), rays.anyhit.astype(np.bool_),
                  hit_t, hit_tri, hit_u, hit_v, ctrs, E, M)
    return Hits(hit_tri, hit_t, hit_u, hit_v), ctrs


def counter_totals(ctrs: np.ndarray) -> dict:
    tot = {name: int(ctrs[:, i].sum()) for i, name in enumerate(COUNTERS)}
    tot["max_stack"] = int(ctrs[:, C["max_stack"]].max()) if len(ctrs) else 0
    return tot
