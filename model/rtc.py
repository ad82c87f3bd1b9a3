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

from .events import EV_DONE, EV_LEAF, EV_NODE, EV_RESULT, EV_TRI, decode, record
from .intersection import fetch_triangle, shared_axes, test_triangle
from .intersection_projection import split_k
from .lanes import borrow, popcount
from .layout import HDR_PROJECTION, LEAF, TRI_WORDS
from .list import leaf_entries
from .fp import flush_in
from .rgs import flushed_box, setup_one
from .traversal import (bits_to_f32, classify, classify32, decide, decode_node, pass_masks,
                        pop, start_packet, terminate)

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
TASK_PACKETS = 16      # packets a parallel task traces one after another (in one scratch)


@numba.njit(cache=True)
def scatter_step(n_tasks):
    """The stride of :func:`scatter_task`: near the golden section of ``n_tasks`` and coprime
    to it (so ``j -> j * step % n_tasks`` visits every task once)."""
    step = max(1, int(n_tasks * 0.6180339887))
    while True:
        a, b = step, n_tasks
        while b:
            a, b = b, a % b
        if a == 1:
            return step
        step += 1


@numba.njit(cache=True, inline="always")
def scatter_task(j, step, n_tasks):
    """The task a parallel loop's iteration ``j`` traces. numba's threading layers (OpenMP,
    workqueue) give each thread one contiguous range of iterations whatever the chunk size;
    packets differ widely in work (most miss the scene, the ones on the object are deep), so
    contiguous ranges of the image leave one thread idle while the other finishes. The
    golden-section stride spreads each thread's range evenly over the image (a task's
    packets stay neighbours)."""
    return (j * step) % n_tasks


@numba.njit(cache=True, error_model="numpy")
def packet_scratch(depth):
    """The per-lane state of one packet (up to 64 lanes), made once and reused for every
    packet a task traces (:func:`trace_packet` sets every value it reads)."""
    return (np.empty(64, np.float32), np.empty(64, np.float32), np.empty(64, np.float32),
            np.empty(64, np.int64), np.empty(64, np.float32), np.empty(64, np.float32),
            np.empty(64, np.float32), np.empty(depth + 1, np.int64),
            np.empty(depth + 1, np.uint64), np.empty((depth + 1, 64), np.float32),
            np.empty((depth + 1, 64), np.float32), np.empty(9, np.float32),
            np.empty(64, np.int64), np.empty(64, np.int64), np.empty((3, 64), np.float32),
            np.empty((3, 64), np.float32), np.empty(8, np.uint64),
            np.empty((3, 64), np.float32), np.empty(64, np.int8), np.empty(64, np.float32),
            np.empty(64, np.float32), np.empty(64, np.float32))


@numba.njit(cache=True, error_model="numpy")
def trace_packet(mem, node_base, list_base, tri_base, root, depth, one,
                 r0, n, org, dirn, inv, kk, ss, tnear0, tfar0, tmax, anyhit,
                 hit_t, hit_tri, hit_u, hit_v, ctr, E, M, pid, rec, rec_n, scratch):
    """Trace the packet of rays ``r0 .. r0+n-1`` (lane l = ray r0 + l), packet id ``pid``,
    in the arrays ``scratch`` (:func:`packet_scratch`); ``one``: the traversal stack keeps one
    value a lane (``Config.trav_stack``).

    ``rec`` (K, 8) int64: when K > 0, every unit's input/output events are appended at row
    ``rec_n[0]`` (``model.events``); recording stops (rec_n[0] > K) when the buffer is full."""
    (tnear, tfar, best, b_tri, b_u, b_v, dist, s_node, s_mask, s_near, s_far, tri, entries,
     octant, lo_t, linv_t, masks, ls_t, st, ht, hu, hv) = scratch
    # every array as a borrowed view (the caller keeps them alive): no reference counting
    # in the loops below
    mem, org, dirn, tnear0, tfar0, tmax, anyhit = (borrow(mem), borrow(org), borrow(dirn),
                                                   borrow(tnear0), borrow(tfar0), borrow(tmax),
                                                   borrow(anyhit))
    hit_t, hit_tri, hit_u, hit_v, ctr, rec, rec_n = (borrow(hit_t), borrow(hit_tri),
                                                     borrow(hit_u), borrow(hit_v), borrow(ctr),
                                                     borrow(rec), borrow(rec_n))
    tnear, tfar, best, b_tri, b_u, b_v, dist = (borrow(tnear), borrow(tfar), borrow(best),
                                                borrow(b_tri), borrow(b_u), borrow(b_v),
                                                borrow(dist))
    s_node, s_mask, s_near, s_far, tri, entries = (borrow(s_node), borrow(s_mask),
                                                   borrow(s_near), borrow(s_far), borrow(tri),
                                                   borrow(entries))
    octant, lo_t, linv_t, masks = borrow(octant), borrow(lo_t), borrow(linv_t), borrow(masks)
    # the intersection unit's lanes by component, and its per-lane outcomes
    lanes = (lo_t, borrow(ls_t), borrow(st), borrow(ht), borrow(hu), borrow(hv))
    ls_t = lanes[1]
    # the read-only ray data the units keep locally, per lane
    lo = borrow(org[r0:r0 + n])
    linv = borrow(inv[r0:r0 + n])
    lk = borrow(kk[r0:r0 + n])
    # the image's triangles are projection records (Config.int_test): the intersection unit
    # keeps the rays' directions instead of the shear constants
    proj = (mem[4] >> np.uint64(HDR_PROJECTION)) & np.uint64(1) == np.uint64(1)
    ls = borrow(dirn[r0:r0 + n]) if proj else borrow(ss[r0:r0 + n])
    # dynamic per-lane state: the traversal's interval, the intersection's best hit
    for l in range(n):
        tnear[l] = tnear0[r0 + l]
        tfar[l] = tfar0[r0 + l]
        best[l] = tmax[r0 + l]         # hits must lie in (0, tmax)
        b_tri[l] = -1
        b_u[l] = 0
        b_v[l] = 0
    c_passes = c_trav_steps = c_trav_ops = c_node_reads = c_leaf_visits = 0
    c_list_ops = c_list_reads = c_int_ops = c_pushes = c_max_stack = 0

    live = start_packet(dirn, r0, n, tnear, tfar, octant)
    terminated = np.uint64(0)
    if live:
        for l in range(n):              # by axis, for the binary32 classify and intersection
            for a in range(3):
                lo_t[a, l] = lo[l, a]
                linv_t[a, l] = linv[l, a]
                ls_t[a, l] = ls[l, a]
    pass_masks(octant, live, n, masks)
    for oc in range(8):
        mask = masks[oc]
        if mask == 0:
            continue
        c_passes += 1
        axes = shared_axes(mask, lk)     # a pass's rays (one octant) mostly share them
        node = np.int64(root)
        sp = 0
        while mask:
            kind, field, hi = decode_node(mem[node_base + node])
            c_node_reads += 1
            if kind != LEAF:
                # ---- traversal unit: the sub-units classify, the decide engine moves on
                c_trav_steps += 1
                c_trav_ops += popcount(mask)
                if E == 8 and M == 23:
                    mnear, mfar = classify32(bits_to_f32(hi), kind, mask, n, lo_t, linv_t,
                                             tnear, tfar, dist, lo, linv)
                else:
                    mnear, mfar = classify(bits_to_f32(hi), kind, mask, n, lo, linv, tnear,
                                           tfar, dist, E, M)
                if rec.shape[0]:
                    record(rec, rec_n, EV_NODE, pid, oc, node, mask, mnear, mfar, sp)
                node, mask, sp, pushed = decide(oc, kind, field, mnear, mfar, sp, dist, tnear,
                                                tfar, s_node, s_mask, s_near, s_far, n, one)
                if pushed:
                    c_pushes += 1
                    c_max_stack = max(c_max_stack, sp)
                continue
            # ---- leaf: list unit -> intersection unit -> back to traversal
            count = field
            first = np.int64(hi)
            if rec.shape[0]:
                record(rec, rec_n, EV_LEAF, pid, oc, node, mask, first, count, sp)
            if count > 0:
                c_leaf_visits += 1
                if count > entries.shape[0]:
                    entries = np.empty(count, np.int64)
                c_list_reads += leaf_entries(mem, list_base, first, count, entries)
            for j in range(count):
                ti = entries[j]
                c_list_ops += 1
                sid = fetch_triangle(mem, tri_base, ti, tri)
                tk = np.int64(-1)
                if proj:
                    tk = split_k(tri)
                if rec.shape[0]:
                    record(rec, rec_n, EV_TRI, pid, oc, ti, mask, sid, 0, 0)
                c_int_ops += test_triangle(tri, sid, ti, mask, lo, lk, ls, best, b_tri, b_u, b_v,
                                           E, M, rec, rec_n, pid, n, lanes, axes, tk)
            # back in traversal; a shadow ray keeps testing the rest of the leaf it hits in
            # (its lane is in the leaf's mask), as the pipelined hardware does
            terminated = terminate(mask, terminated, b_tri, anyhit, r0, best, tfar)
            if rec.shape[0]:
                record(rec, rec_n, EV_RESULT, pid, oc, node, mask, terminated, 0, sp)
            sp, node, mask = pop(sp, terminated, tnear, tfar, s_node, s_mask, s_near, s_far,
                                 n, one)

    if rec.shape[0]:
        record(rec, rec_n, EV_DONE, pid, 0, 0, live, terminated, 0, 0)
    for l in range(n):
        r = r0 + l
        hit_tri[r] = b_tri[l]
        hit_t[r] = best[l] if b_tri[l] >= 0 else np.float32(np.inf)
        hit_u[r] = b_u[l]
        hit_v[r] = b_v[l]
    ctr[0] += c_passes
    ctr[1] += c_trav_steps
    ctr[2] += c_trav_ops
    ctr[3] += c_node_reads
    ctr[4] += c_leaf_visits
    ctr[5] += c_list_ops
    ctr[6] += c_list_reads
    ctr[7] += c_list_ops               # one triangle fetch per emitted address
    ctr[8] += c_int_ops
    ctr[9] += TRI_WORDS * c_list_ops
    ctr[10] += c_pushes
    ctr[11] = max(ctr[11], c_max_stack)


@numba.njit(cache=True, parallel=True, error_model="numpy")
def trace_all(mem, node_base, list_base, tri_base, root, depth, one,
              pk_start, org, dirn, inv, kk, ss, tnear0, tfar0, tmax, anyhit,
              hit_t, hit_tri, hit_u, hit_v, ctrs, E, M):
    n_packets = pk_start.shape[0] - 1
    no_rec = np.zeros((0, 8), np.int64)
    no_n = np.zeros(1, np.int64)
    n_tasks = (n_packets + TASK_PACKETS - 1) // TASK_PACKETS
    step = scatter_step(n_tasks)
    for j in numba.prange(n_tasks):
        task = scatter_task(j, step, n_tasks)
        scratch = packet_scratch(depth)
        for p in range(task * TASK_PACKETS, min(n_packets, (task + 1) * TASK_PACKETS)):
            trace_packet(mem, node_base, list_base, tri_base, root, depth, one,
                         pk_start[p], pk_start[p + 1] - pk_start[p], org, dirn, inv, kk, ss,
                         tnear0, tfar0, tmax, anyhit, hit_t, hit_tri, hit_u, hit_v, ctrs[p], E,
                         M, p, no_rec, no_n, scratch)


@numba.njit(cache=True, parallel=True, error_model="numpy")
def trace_all_setup(mem, node_base, list_base, tri_base, root, depth, one, lo, hi, scene_ids,
                    pk_start, org, dirn, inv, kk, ss, tnear0, tfar0, tmax, anyhit,
                    hit_t, hit_tri, hit_u, hit_v, ctrs, E, M):
    """:func:`trace_all` with the ray setup of ``model.rgs.setup_rays`` (box ``[lo, hi]``, the
    box cull on) in the same tasks: each packet's rays are set up (into ``inv`` ... ``tfar0``)
    just before it is traced. ``hit_tri`` gets the scene-order ids (``scene_ids``: the image's
    ids with -1 appended, so a miss stays -1)."""
    n_packets = pk_start.shape[0] - 1
    no_rec = np.zeros((0, 8), np.int64)
    no_n = np.zeros(1, np.int64)
    lo_f, hi_f = flushed_box(lo, hi, E)
    n_tasks = (n_packets + TASK_PACKETS - 1) // TASK_PACKETS
    step = scatter_step(n_tasks)
    for j in numba.prange(n_tasks):
        task = scatter_task(j, step, n_tasks)
        scratch = packet_scratch(depth)
        for p in range(task * TASK_PACKETS, min(n_packets, (task + 1) * TASK_PACKETS)):
            r0 = pk_start[p]
            r1 = pk_start[p + 1]
            for r in range(r0, r1):
                (inv[r, 0], inv[r, 1], inv[r, 2], kk[r, 0], kk[r, 1], kk[r, 2], ss[r, 0],
                 ss[r, 1], ss[r, 2], tnear0[r], tfar0[r], _) = setup_one(
                    flush_in(org[r, 0], E), flush_in(org[r, 1], E), flush_in(org[r, 2], E),
                    flush_in(dirn[r, 0], E), flush_in(dirn[r, 1], E),
                    flush_in(dirn[r, 2], E), flush_in(tmax[r], E), lo_f[0], lo_f[1],
                    lo_f[2], hi_f[0], hi_f[1], hi_f[2], E, M)
            trace_packet(mem, node_base, list_base, tri_base, root, depth, one,
                         r0, r1 - r0, org, dirn, inv, kk, ss, tnear0, tfar0, tmax, anyhit,
                         hit_t, hit_tri, hit_u, hit_v, ctrs[p], E, M, p, no_rec, no_n, scratch)
            for r in range(r0, r1):
                hit_tri[r] = scene_ids[hit_tri[r]]


@numba.njit(cache=True, error_model="numpy")
def trace_recorded(mem, node_base, list_base, tri_base, root, depth, one,
                   pk_start, org, dirn, inv, kk, ss, tnear0, tfar0, tmax, anyhit,
                   hit_t, hit_tri, hit_u, hit_v, ctrs, E, M, rec, rec_n):
    """Packets one after another (packet order), appending every event to ``rec``."""
    scratch = packet_scratch(depth)
    for p in range(pk_start.shape[0] - 1):
        trace_packet(mem, node_base, list_base, tri_base, root, depth, one,
                     pk_start[p], pk_start[p + 1] - pk_start[p], org, dirn, inv, kk, ss, tnear0,
                     tfar0, tmax, anyhit, hit_t, hit_tri, hit_u, hit_v, ctrs[p], E, M,
                     p, rec, rec_n, scratch)


@dataclass
class Hits:
    """Per-ray results: ``tri`` is the scene-order triangle id or -1; t = inf on a miss.

    The hardware reports a hit triangle by its index in the memory image (the int-cache keeps
    only its 9 vertex words); :func:`trace` maps it to the scene-order id stored in the
    triangle's fifth word (``MemoryImage.scene_ids``; ``MemoryImage.tri_index`` maps back)."""
    tri: np.ndarray      # (N,) int32
    t: np.ndarray        # (N,) float32
    u: np.ndarray        # (N,) float32
    v: np.ndarray        # (N,) float32


def trace(image, rays, cfg, ray_setup=None, record: bool = False, box_cull: bool = True):
    """Trace every packet of ``rays`` through ``image``.

    ``box_cull=False``: rays that miss the scene box traverse anyway (``model.raygen.setup``;
    only to measure what the cull saves).

    Returns ``(hits, counters)`` — counters an int64 array ``(n_packets, N_COUNTERS)``,
    columns named by ``COUNTERS`` — or, with ``record=True``, ``(hits, counters, events)``
    where ``events`` is the event log of every unit (``model.events.EVENT_DTYPE``; packets traced one
    after another, for RTL testbenches and memory-access traces; slower, for small runs)."""
    if record:
        hits, ctrs, rows = trace_rows(image, rays, cfg, ray_setup, box_cull)
        return hits, ctrs, decode(rows)
    if ray_setup is None and box_cull:
        return _trace_with_setup(image, rays, cfg)
    args, _, out = _kernel_args(image, rays, cfg, ray_setup, box_cull)
    if len(rays):
        trace_all(*args)
    return out()


def _trace_with_setup(image, rays, cfg):
    """:func:`trace` with the ray setup done in the tracing kernel (``trace_all_setup``)."""
    from .raygen import RaySetup
    n = len(rays)
    rs = RaySetup(np.empty((n, 3), np.float32), np.empty((n, 3), np.int64),
                  np.empty((n, 3), np.float32), np.empty(n, np.float32), np.empty(n, np.float32))
    args, ctrs, out = _kernel_args(image, rays, cfg, rs, True)
    if not n:
        return out()
    (mem, node_base, list_base, tri_base, root, depth, one, pk_start, org, dirn, inv, kk, ss,
     tnear, tfar, tmax, anyhit, hit_t, hit_tri, hit_u, hit_v, ctrs, E, M) = args
    b = np.asarray(image.bounds, np.float32)
    trace_all_setup(mem, node_base, list_base, tri_base, root, depth, one, b[0].copy(),
                    b[1].copy(), image.scene_id_table(), pk_start, org, dirn, inv, kk, ss,
                    tnear, tfar, tmax, anyhit, hit_t, hit_tri, hit_u, hit_v, ctrs, E, M)
    return Hits(hit_tri, hit_t, hit_u, hit_v), ctrs


def trace_rows(image, rays, cfg, ray_setup=None, box_cull: bool = True):
    """:func:`trace` with the event log as the recording kernel writes it: ``(hits, counters,
    rows)``, ``rows`` an int64 array ``(events, 8)`` (``model.events``: column 0 the kind, the
    others by ``events._COLUMNS``), for consumers that read a few columns of a large log."""
    args, ctrs, out = _kernel_args(image, rays, cfg, ray_setup, box_cull)
    cap = max(1024, 24 * len(rays))
    while True:
        rec = np.zeros((cap, 8), np.int64)
        rec_n = np.zeros(1, np.int64)
        ctrs[:] = 0
        if len(rays):
            trace_recorded(*args, rec, rec_n)
        if rec_n[0] <= cap:
            return (*out(), rec[:rec_n[0]])
        cap = int(rec_n[0])


def _kernel_args(image, rays, cfg, ray_setup, box_cull):
    """The tracing kernels' arguments (result arrays included), the counter array among them
    and a function returning ``(hits, counters)`` once a kernel has filled them."""
    from .raygen import setup
    n = len(rays)
    sizes = np.diff(rays.pk_start)
    if sizes.size and sizes.max() > 64:
        raise ValueError(f"a packet has {sizes.max()} rays; at most 64 (the active mask width)")
    if image.projection != (cfg.int_test == "projection"):
        raise ValueError(f"the memory image's triangles are "
                         f"{'projection records' if image.projection else 'vertices'} but "
                         f"cfg.int_test={cfg.int_test!r}: build the image with the same Config")
    rs = ray_setup if ray_setup is not None else setup(rays, image.bounds, cfg.fmt, box_cull)
    hit_t = np.empty(n, np.float32)
    hit_tri = np.empty(n, np.int32)
    hit_u = np.empty(n, np.float32)
    hit_v = np.empty(n, np.float32)
    ctrs = np.zeros((rays.n_packets, N_COUNTERS), np.int64)
    E, M = cfg.fmt.em
    # C-contiguous whatever the caller's layout (eye rays' origins are Fortran-ordered, a
    # chunk of them neither): numba compiles a kernel per array layout, so one layout keeps
    # one compiled (and cached) kernel for every call
    org = np.ascontiguousarray(rays.org, np.float32)
    dirn = np.ascontiguousarray(rays.dir, np.float32)
    args = (image.data, image.node_base, image.list_base, image.tri_base, image.root,
            image.depth, cfg.trav_stack == "one_value", np.ascontiguousarray(rays.pk_start), org, dirn, rs.inv, rs.k, rs.s,
            rs.tnear, rs.tfar, np.ascontiguousarray(rays.tmax, np.float32),
            np.ascontiguousarray(rays.anyhit, np.bool_),
            hit_t, hit_tri, hit_u, hit_v, ctrs, E, M)
    return args, ctrs, lambda: (Hits(image.scene_ids(hit_tri), hit_t, hit_u, hit_v), ctrs)


def _ranges(start: np.ndarray, length: np.ndarray) -> np.ndarray:
    """``arange(start[i], start[i] + length[i])`` for every i, concatenated (vectorized)."""
    start, length = np.asarray(start, np.int64), np.asarray(length, np.int64)
    total = int(length.sum())
    offset = np.repeat(np.cumsum(length) - length, length)
    return np.repeat(start, length) + np.arange(total, dtype=np.int64) - offset


def _leaves(events: np.ndarray) -> np.ndarray:
    """The non-empty leaves' events (the list unit's input)."""
    return events[(events["kind"] == EV_LEAF) & (events["count"] > 0)]


def item_trace(events: np.ndarray) -> dict:
    """Item addresses each unit asks its cache for, in event order: node indices (trav),
    list-entry indices (list), triangle indices (int)."""
    kind = events["kind"]
    leaf = _leaves(events)
    return {"trav": events["node"][(kind == EV_NODE) | (kind == EV_LEAF)].astype(np.int64),
            "list": _ranges(leaf["first"], leaf["count"]),
            "int": events["tri"][kind == EV_TRI].astype(np.int64)}


def memory_trace(events: np.ndarray, image) -> dict:
    """64-bit word addresses each unit reads, in event order: ``{"trav", "list", "int"}``
    (a leaf reads every list word its entries touch once: two entries per word)."""
    kind = events["kind"]
    leaf = _leaves(events)
    w0 = leaf["first"] >> 1
    w1 = (leaf["first"] + leaf["count"] - 1) >> 1
    tri = events["tri"][kind == EV_TRI].astype(np.int64)
    return {"trav": image.node_base + events["node"][(kind == EV_NODE) | (kind == EV_LEAF)],
            "list": image.list_base + _ranges(w0, w1 - w0 + 1),
            "int": (image.tri_base + TRI_WORDS * tri[:, None] + np.arange(TRI_WORDS)).ravel()}


def counter_totals(ctrs: np.ndarray) -> dict:
    tot = {name: int(ctrs[:, i].sum()) for i, name in enumerate(COUNTERS)}
    tot["max_stack"] = int(ctrs[:, C["max_stack"]].max()) if len(ctrs) else 0
    return tot
