"""A fast cycle estimate of the whole chip (``rtl/chip.py``) for a frame: cycles and fps,
without simulating the RTL.

The golden model's event log (``model.rtc.trace(..., record=True)``, ``model/events.py``) says
what every packet does: the nodes it visits with their lane masks, its leaves, the triangles
the list unit emits, its stack pops and octant passes. :func:`estimate_events` replays that
work on a discrete-event model of the chip's resources, in time order, one action of one
thread at a time (numba, no per-cycle loop):

* RGS master and slaves: tiles in row-major order, each RTC holding two tiles ahead (one in
  its slave's queue, one in generation), the next tile to the RTC whose loader takes one;
  the loader writes one ray a cycle into a free thread;
* traversal: one node fetch a cycle (one request register), the control engine (two cycles
  per event, two per popped stack entry, two per pass), step queues of 4 entries, synchronous
  or asynchronous sub-units (a step occupies a sub-unit ``max(a, 1)`` cycles for ``a`` active
  lanes, its verdict ``a + 11`` cycles after it started), the decide engine (one step a
  cycle, in dispatch order), the next fetch two cycles after the verdict;
* list unit: one leaf at a time, one word request a cycle, ``list_outstanding`` words in
  flight, one triangle address a cycle, in order;
* intersection unit: ``int_tri_slots`` triangle slots, one fetch a cycle, one lane test a cycle
  in slot order, results ``35 + 1`` cycles after the issue of the leaf's last test (binary32
  latencies); read-out one ray a cycle, the chip's result port one ray a cycle for all RTCs;
* caches: the RTL's hit/miss rule (``model/cache.py``: set-associative, FIFO replacement, a
  hit under a miss waits for the line), one access a cycle, hits 3 cycles, ``outstanding``
  misses in flight, responses in request order; private (three per RTC) or shared (three for
  the chip, each behind a bus that adds a register each way and takes one access a cycle);
* bus and memory: one grant a cycle for the whole chip (a calendar of cycles, so accesses
  booked ahead by the list and intersection units do not block earlier ones), the SDRAM
  chips of ``tb/harness/memory.py`` (XOR address hashing, a start on an SDRAM clock edge, the data
  bus busy ``burst`` cycles per word, the response ``latency + burst`` after the start, one
  response a cycle).

Not modelled: the SDRAM controller's per-chip queues (head-of-line blocking at the port),
the round-robin orders (arbitration is first come, first served), the result stream's
back-pressure (none by default), cache queue limits. ``docs/ladder.md`` measures the error
against the RTL in Verilator.
"""
from __future__ import annotations

import time

import numba
import numpy as np

from .cache import CacheGeometry, cache_geometry
from .config import Config
from .events import EV_DONE, EV_INT, EV_NODE, EV_TRI

__all__ = ["Estimate", "ChipTiming", "chip_timing", "work_of", "record_work", "estimate_events",
           "estimate_frame", "fps_error"]

# fixed latencies of the RTL units (binary32 FP latencies: add 3, mul 3, div 8)
STEP_LAT = 11            # traversal sub-unit: verdict a + STEP_LAT cycles after the step starts
INT_LAT = 36             # intersection: test issue -> LaneResult out (34 store + 1 + 1)
INT_LAT_PROJECTION = 40  # the same with Config.int_test = "projection" (its datapath: 37)
CACHE_HIT = 3            # cache hit latency
EYE_LAT = 30             # master + RGS slave pipeline: tile handed out -> first ray at the RTC

H_BITS = 16              # calendars: bookings at most 2^16 cycles ahead
H = 1 << H_BITS


class ChipTiming:
    """The parameters :func:`estimate_events` needs, from a :class:`Config`."""

    def __init__(self, cfg: Config):
        geoms = chip_geometries(cfg)
        self.cfg = cfg
        self.geoms = geoms
        g = [geoms[k] for k in ("trav", "list", "int")]
        self.sets = np.array([x.sets for x in g], np.int64)
        self.ways = np.array([x.ways for x in g], np.int64)
        self.offset_bits = np.array([x.offset_bits for x in g], np.int64)
        self.line_words = np.array([x.line_words for x in g], np.int64)
        self.outstanding = geoms["trav"].outstanding
        self.burst = 64 // cfg.mem_chip_bits * cfg.mem_clock_ratio
        self.params = np.array([
            cfg.rtcs, cfg.threads, cfg.trav_subunits, int(cfg.trav_sync),
            cfg.int_tri_slots, cfg.list_outstanding, cfg.mem_chips, cfg.mem_clock_ratio,
            self.burst, cfg.mem_latency, self.outstanding, cfg.rays_per_subunit,
            STEP_LAT, INT_LAT if cfg.int_test == "watertight" else INT_LAT_PROJECTION,
            CACHE_HIT, EYE_LAT, int(cfg.cache_topology == "shared")],
            np.int64)


def chip_geometries(cfg: Config) -> dict[str, CacheGeometry]:
    """The RTC-MI's cache geometries (``rtl.rtcmi.rtcmi_geometries``, computed here without
    importing the RTL): trav and list caches of 64-bit words, the int-cache of triangles."""
    served = cfg.rtcs // cfg.rtcmis                  # RTCs per RTC-MI cache
    def words(kb):
        size = 1 << ((kb * 1024).bit_length() - 1)
        return CacheGeometry(size_bytes=size, line_items=cfg.cache_line_words, item_bits=64,
                             item_span=64, ways=cfg.cache_ways,
                             outstanding=served * cfg.cache_outstanding,
                             queue=served * cfg.cache_queue)
    per_set = cfg.cache_ways * cfg.cache_line_words * cfg.int_item_bits
    sets = (cfg.int_cache_kb * 1024 * 8) // per_set
    sets = 1 << (sets.bit_length() - 1)
    return {"trav": words(cfg.trav_cache_kb), "list": words(cfg.list_cache_kb),
            "int": cache_geometry(cfg, "int", served, size_bytes=sets * per_set // 8)}


def chip_timing(cfg: Config) -> ChipTiming:
    return ChipTiming(cfg)


# --- the work of a frame, from the event log ----------------------------------------------------

def work_of(events: np.ndarray, image, n_packets: int, lanes: np.ndarray) -> dict:
    """The arrays :func:`estimate_events` replays: the event log (decoded, ``model.events``)
    without the per-lane ``EV_INT`` rows, and where each packet's events start. ``lanes``:
    rays per packet."""
    ev = events[events["kind"] != EV_INT]
    cols = {"kind": ev["kind"], "packet": ev["packet"],
            "addr": np.where(ev["kind"] == EV_TRI, ev["tri"], ev["node"]),
            "mask": ev["mask"], "first": ev["first"], "count": ev["count"], "sp": ev["sp"],
            "octant": ev["octant"], "near": ev["near"], "far": ev["far"]}
    return _work(cols, image, n_packets, lanes)


def _work(cols: dict, image, n_packets: int, lanes) -> dict:
    start = np.searchsorted(cols["packet"], np.arange(n_packets + 1)).astype(np.int64)
    out = {k: np.ascontiguousarray(cols[k], np.uint64 if k in ("mask", "near", "far")
                                   else np.int64)
           for k in ("kind", "addr", "mask", "first", "count", "sp", "octant", "near", "far")}
    out.update(start=start, lanes=np.asarray(lanes, np.int64),
               bases=np.array([image.node_base, image.list_base, image.tri_base], np.int64))
    return out


def record_work(image, rays, cfg: Config) -> dict:
    """:func:`work_of` straight from the golden model's raw event rows (``model.rtc``'s
    recording tracer, without decoding every row into ``EVENT_DTYPE``): the same arrays,
    faster; ``work["hits"]``: the trace's hits (``model.rtc.Hits``)."""
    from . import rtc
    from .events import _COLUMNS
    hits, ctrs, raw = rtc.trace_rows(image, rays, cfg)
    raw = raw[raw[:, 0] != EV_INT]
    kind = raw[:, 0]
    cols = {"kind": kind, "packet": raw[:, 1]}
    for name in ("node", "tri", "mask", "first", "count", "sp", "octant", "near", "far"):
        v = np.zeros(len(raw), np.int64)
        for k, columns in _COLUMNS.items():
            if name in columns and k != EV_INT:
                sel = kind == k
                v[sel] = raw[sel, columns[name]]
        cols[name] = v
    cols["addr"] = np.where(kind == EV_TRI, cols["tri"], cols["node"])
    for k in ("mask", "near", "far"):
        cols[k] = cols[k].view(np.uint64)
    work = _work(cols, image, rays.n_packets, np.diff(rays.pk_start))
    work["totals"] = rtc.counter_totals(ctrs)
    work["hits"] = hits
    return work


# --- the discrete-event model ---------------------------------------------------------------------

@numba.njit(cache=True)
def _popc(x):
    x = np.uint64(x)
    n = 0
    while x:
        x &= x - np.uint64(1)
        n += 1
    return n


@numba.njit(cache=True)
def _book(cal, t):
    """First cycle >= t free in calendar ``cal`` (stamps: absolute cycle), booked."""
    while cal[t & (H - 1)] == t:
        t += 1
    cal[t & (H - 1)] = t
    return t


@numba.njit(cache=True)
def _chip_of(a, chips):
    bits = 0
    c = chips
    while c > 1:
        c >>= 1
        bits += 1
    if bits == 0:
        return 0
    out = 0
    m = chips - 1
    sh = 0
    while sh < 64:
        out ^= (a >> sh) & m
        sh += bits
    return out


@numba.njit(cache=True)
def _mem_word(addr, t, bus_cal, chip_cal, resp_cal, P):
    """A word request leaving a cache at cycle t: bus grant, SDRAM chip, response; the cycle
    the word is back at the cache."""
    chips, ratio, burst, lat = P[6], P[7], P[8], P[9]
    tb = _book(bus_cal, t)                     # one grant a cycle, chip-wide
    c = _chip_of(addr, chips)
    # the chip starts on an SDRAM clock edge when its data bus is free (burst cycles a word)
    slot = (tb + 2 + ratio - 1) // ratio
    need = burst // ratio
    while True:
        ok = True
        for k in range(need):
            s = slot + k
            if chip_cal[c, s & (H - 1)] == s:
                ok = False
                slot = s + 1
                break
        if ok:
            break
    for k in range(need):
        s = slot + k
        chip_cal[c, s & (H - 1)] = s
    due = slot * ratio + lat + burst
    tr = _book(resp_cal, due)                  # one response a cycle from the memory
    return tr + 1                              # the bus's response register


@numba.njit(cache=True)
def _cache(ci, item, word, t, tags, fill, rr, acc_free, last_resp, mshr, n_miss, hits,
           misses, sets, ways, obits, lwords, bus_cal, chip_cal, resp_cal, P):
    """One access of RTC ``ci // 3`` to its cache ``ci % 3`` (item index ``item``, first memory
    word ``word``) leaving the unit at cycle t; returns the cycle its response leaves the cache
    (responses in order). Shared caches (``P[16]``): the RTCs' accesses go to one cache each,
    through the bus's request and response registers (a cycle each)."""
    u = ci % 3
    shared = P[16]
    if shared:
        ci = u
        t += 1
    outst = P[10]
    ta = max(t, acc_free[ci])
    line = item >> obits[u]
    s = line & (sets[u] - 1)
    tag = line // sets[u]
    w_hit = -1
    for w in range(ways[u]):
        if tags[ci, s, w] == tag:
            w_hit = w
            break
    if w_hit >= 0:
        hits[ci] += 1
        acc_free[ci] = ta + 1
        ready = max(ta + P[14], fill[ci, s, w_hit] + 1)
    else:
        misses[ci] += 1
        k = 0                                  # the MSHR that frees first
        for j in range(1, outst):
            if mshr[ci, j] < mshr[ci, k]:
                k = j
        tm = max(ta + 1, mshr[ci, k])          # a free MSHR (the lookup stalls meanwhile)
        acc_free[ci] = tm
        lw = lwords[u]
        base = word - (item - (line << obits[u])) * (lw // (1 << obits[u]))
        done = 0
        for j in range(lw):
            done = max(done, _mem_word(base + j, tm + 1 + j, bus_cal, chip_cal, resp_cal, P))
        w = rr[ci, s]
        rr[ci, s] = (w + 1) % ways[u]
        tags[ci, s, w] = tag
        fill[ci, s, w] = done
        mshr[ci, k] = done
        n_miss[ci] += 1
        ready = done + 2
    resp = max(ready, last_resp[ci] + 1)
    last_resp[ci] = resp
    return resp + shared


@numba.njit(cache=True)
def _pops(kind, sp, octant, i, base):
    """Control-engine cycles of the pops after event ``i`` (``EV_RESULT``: sp before the
    pops), ``base`` cycles before the first POP: two per popped stack entry down to the next
    visit's sp in the same pass; else the stack runs out (POP at sp 0, then PASS, PASS2 and the
    next pass's fetch, or DONE). Returns (cycles, next action, next event)."""
    j = i + 1
    if kind[j] != EV_DONE and octant[j] == octant[i]:
        return base + 2 * (sp[i] - sp[j]), 1, j
    if kind[j] == EV_DONE:
        return base + 2 * sp[i] + 2, 3, j
    return base + 2 * sp[i] + 3, 1, j


@numba.njit(cache=True)
def _simulate(P, kind, addr, mask, first, count, sp, octant, near, far, start, lanes, order,
              bases, sets, ways, obits, lwords, out):
    """Replay packets ``order`` (tile order) on the chip; returns the frame's cycles.
    ``out``: per RTC counters (packets, trav busy cycles, int tests)."""
    R, T, K, sync = P[0], P[1], P[2], P[3]
    slots, lout = P[4], P[5]
    rps = P[11]
    step_lat, int_lat, eye_lat = P[12], P[13], P[15]
    NT = R * T
    n_tiles = order.shape[0]
    maxw = max(ways[0], max(ways[1], ways[2]))
    maxs = max(sets[0], max(sets[1], sets[2]))
    tags = np.full((3 * R, maxs, maxw), -1, np.int64)
    fill = np.zeros((3 * R, maxs, maxw), np.int64)
    rr = np.zeros((3 * R, maxs), np.int64)
    acc_free = np.zeros(3 * R, np.int64)
    last_resp = np.zeros(3 * R, np.int64)
    mshr = np.zeros((3 * R, P[10]), np.int64)
    n_miss = np.zeros(3 * R, np.int64)
    hits = np.zeros(3 * R, np.int64)
    misses = np.zeros(3 * R, np.int64)
    bus_cal = np.full(H, -1, np.int64)
    resp_cal = np.full(H, -1, np.int64)
    chip_cal = np.full((P[6], H), -1, np.int64)
    out_cal = np.full(H, -1, np.int64)
    # per RTC resources
    fetch_free = np.zeros(R, np.int64)
    ctl_free = np.zeros(R, np.int64)
    sub_free = np.zeros((R, K), np.int64)
    qstart = np.zeros((R, 4), np.int64)          # start cycles of the last 4 steps (room)
    nsteps = np.zeros(R, np.int64)
    dec_free = np.zeros(R, np.int64)
    leaf_reg = np.zeros(R, np.int64)
    list_free = np.zeros(R, np.int64)
    list_emit = np.zeros(R, np.int64)
    lresp = np.zeros((R, 64), np.int64)          # list words in flight (ring of responses)
    nlw = np.zeros(R, np.int64)
    int_free = np.zeros(R, np.int64)
    slot_free = np.zeros((R, 64), np.int64)      # ring: cycle each triangle slot frees
    ntri = np.zeros(R, np.int64)
    readout_free = np.zeros(R, np.int64)
    loader_free = np.zeros(R, np.int64)
    # tiles: each RTC holds two ahead; the next one goes to the RTC whose loader takes one
    held = np.full((R, 2), -1, np.int64)
    nheld = np.zeros(R, np.int64)
    nxt = 0
    for k in range(2):
        for r in range(R):
            if nxt < n_tiles:
                held[r, nheld[r]] = nxt
                nheld[r] += 1
                nxt += 1
    # threads
    wake = np.zeros(NT, np.int64)
    act = np.zeros(NT, np.int64)                 # 0 load, 1 fetch, 2 control, 3 done, 9 retired
    ev = np.zeros(NT, np.int64)                  # current event of the thread
    pend = np.zeros(NT, np.int64)                # control work: 0 node/leaf, 1 pop, 2 pass
    pkt = np.full(NT, -1, np.int64)
    for i in range(NT):
        wake[i] = eye_lat
    end = 0
    alive = NT
    while alive > 0:
        # the thread with the earliest action (ties: lowest id)
        th = -1
        tm = 1 << 62
        for i in range(NT):
            if act[i] != 9 and wake[i] < tm:
                tm = wake[i]
                th = i
        r = th // T
        t = tm
        a = act[th]
        if a == 0:                                   # load a packet
            if loader_free[r] > t:                   # the loader is busy: wait for it
                wake[th] = loader_free[r]
                continue
            if nheld[r] == 0:
                act[th] = 9
                alive -= 1
                continue
            tile = held[r, 0]
            held[r, 0] = held[r, 1]
            nheld[r] -= 1
            if nxt < n_tiles:
                held[r, nheld[r]] = nxt
                nheld[r] += 1
                nxt += 1
            p = order[tile]
            tl = max(t, loader_free[r])
            loader_free[r] = tl + lanes[p] + 1
            pkt[th] = p
            ev[th] = start[p]
            out[r, 0] += 1
            act[th] = 2
            pend[th] = 2                             # NEXTPASS: the first pass
            wake[th] = tl + lanes[p] + 1
        elif a == 1:                                 # node fetch of event ev
            i = ev[th]
            tf = max(t, fetch_free[r])
            fetch_free[r] = tf + 1
            ci = 3 * r
            resp = _cache(ci, bases[0] + addr[i], bases[0] + addr[i], tf + 1, tags, fill, rr,
                          acc_free, last_resp, mshr, n_miss, hits, misses, sets, ways, obits,
                          lwords, bus_cal, chip_cal, resp_cal, P)
            act[th] = 2
            pend[th] = 0
            wake[th] = resp + 1
        elif a == 2:                                 # the control engine
            i = ev[th]
            tc = max(t, ctl_free[r])
            if pend[th] == 2:                        # PASS, PASS2 (a pass starts or the packet ends)
                ctl_free[r] = tc + 4
                if kind[i] == EV_DONE:
                    act[th] = 3
                    wake[th] = tc + 3
                else:
                    act[th] = 1
                    wake[th] = tc + 4
                continue
            if pend[th] == 1:                        # IDLE, DISPATCH, POP entries
                cost, na, ne = _pops(kind, sp, octant, i, 2)
                ctl_free[r] = tc + cost
                act[th] = na
                ev[th] = ne
                wake[th] = tc + cost
                continue
            if kind[i] == EV_NODE:
                # DISPATCH when every step queue has room
                q = nsteps[r]
                td = tc + 1
                if q >= 4:
                    td = max(td, qstart[r, q % 4])
                ctl_free[r] = td + 1
                m = mask[i]
                verdict = 0
                s0 = td + 1
                if sync:
                    occ = 1
                    amax = 0
                    for k in range(K):
                        s0 = max(s0, sub_free[r, k])
                    for k in range(K):
                        ak = _popc((m >> np.uint64(k * rps)) &
                                   ((np.uint64(1) << np.uint64(rps)) - np.uint64(1))
                                   if rps < 64 else m)
                        occ = max(occ, ak)
                        amax = max(amax, ak)
                    for k in range(K):
                        sub_free[r, k] = s0 + occ
                        out[r, 1] += occ
                    verdict = s0 + amax + step_lat - 1
                else:
                    for k in range(K):
                        ak = _popc((m >> np.uint64(k * rps)) &
                                   ((np.uint64(1) << np.uint64(rps)) - np.uint64(1))
                                   if rps < 64 else m)
                        sk = max(td + 1, sub_free[r, k])
                        sub_free[r, k] = sk + max(ak, 1)
                        out[r, 1] += max(ak, 1)
                        verdict = max(verdict, sk + ak + step_lat - 1)
                        s0 = min(s0, sk)
                qstart[r, q % 4] = s0
                nsteps[r] = q + 1
                tdec = max(verdict, dec_free[r])
                dec_free[r] = tdec + 1
                if near[i] == 0 and far[i] == 0:     # neither child: the pass ends
                    ev[th] = i + 1
                    act[th] = 2
                    pend[th] = 2
                    wake[th] = tdec + 1
                else:
                    ev[th] = i + 1
                    act[th] = 1
                    wake[th] = tdec + 1
                continue
            # a leaf
            if count[i] == 0:                        # empty: DISPATCH goes straight to POP
                cost, na, ne = _pops(kind, sp, octant, i + 1, 2)
                ctl_free[r] = tc + cost
                act[th] = na
                ev[th] = ne
                wake[th] = tc + cost
                continue
            tl = max(tc + 2, leaf_reg[r])           # LEAF: into the leaf output register
            ctl_free[r] = tl + 1
            tacc = max(tl + 1, list_free[r])         # the list unit takes it
            leaf_reg[r] = tacc
            w0 = first[i] >> 1
            w1 = (first[i] + count[i] - 1) >> 1
            nw = w1 - w0 + 1
            tq = tacc - 1
            wresp = np.empty(nw, np.int64)
            for k in range(nw):
                tq = max(tq + 1, lresp[r, nlw[r] % lout] if nlw[r] >= lout else tq + 1)
                ci = 3 * r + 1
                wa = bases[1] + w0 + k
                rsp = _cache(ci, wa, wa, tq, tags, fill, rr, acc_free, last_resp, mshr,
                             n_miss, hits, misses, sets, ways, obits, lwords, bus_cal,
                             chip_cal, resp_cal, P)
                wresp[k] = rsp
                lresp[r, nlw[r] % lout] = rsp
                nlw[r] += 1
            list_free[r] = tq
            # triangles: one address a cycle, in order, into the intersection unit's slots
            te = list_emit[r]
            last_issue = 0
            for j in range(count[i]):
                ti = i + 1 + j                       # the EV_TRI row
                wk = ((first[i] + j) >> 1) - w0
                te = max(te + 1, wresp[wk] + 1)
                n = ntri[r]
                if n >= slots:
                    te = max(te, slot_free[r, n % slots])
                ci = 3 * r + 2
                tri = addr[ti]
                dat = _cache(ci, tri, bases[2] + 5 * tri, te + 1, tags, fill, rr, acc_free,
                             last_resp, mshr, n_miss, hits, misses, sets, ways, obits, lwords,
                             bus_cal, chip_cal, resp_cal, P)
                pc = _popc(mask[ti])
                tis = max(dat + 1, int_free[r])
                int_free[r] = tis + pc
                slot_free[r, n % slots] = tis + pc
                ntri[r] = n + 1
                out[r, 2] += pc
                last_issue = tis + pc - 1
            list_emit[r] = te
            ev[th] = i + 1 + count[i]                # the EV_RESULT row
            pend[th] = 1
            act[th] = 2
            wake[th] = last_issue + int_lat + 2
        elif a == 3:                                 # PacketDone, read-out, release
            p = pkt[th]
            td = max(t + 1, readout_free[r])
            last = td
            for k in range(lanes[p]):
                last = _book(out_cal, max(last + 1, td + 1 + k))
            readout_free[r] = last
            end = max(end, last + 1)
            act[th] = 0
            wake[th] = last + 2
    for ci in range(3 * R):
        out[ci // 3, 3 + 2 * (ci % 3)] = hits[ci]
        out[ci // 3, 4 + 2 * (ci % 3)] = misses[ci]
    return end


class Estimate(dict):
    """The estimate of a frame: ``cycles``, ``fps`` (estimates), hit rates, per-RTC packets,
    the time the estimate took."""


def estimate_events(cfg: Config, work: dict, order: np.ndarray | None = None) -> Estimate:
    """Estimated cycles of the packets ``order`` (default: all, tile order) of ``work``
    (:func:`work_of`) on the chip ``cfg``, starting with cold caches."""
    ct = ChipTiming(cfg)
    n = len(work["start"]) - 1
    order = np.arange(n, dtype=np.int64) if order is None else np.asarray(order, np.int64)
    out = np.zeros((cfg.rtcs, 9), np.int64)
    t0 = time.perf_counter()
    cycles = int(_simulate(ct.params, work["kind"], work["addr"], work["mask"], work["first"],
                           work["count"], work["sp"], work["octant"], work["near"],
                           work["far"], work["start"], work["lanes"], order, work["bases"],
                           ct.sets, ct.ways, ct.offset_bits, ct.line_words, out))
    sec = time.perf_counter() - t0
    cache = {}
    for u, name in enumerate(("trav", "list", "int")):
        h, m = int(out[:, 3 + 2 * u].sum()), int(out[:, 4 + 2 * u].sum())
        cache[name] = {"hits": h, "misses": m, "hit_rate": h / max(1, h + m)}
    return Estimate(cycles=cycles, fps=cfg.clock_mhz * 1e6 / max(1, cycles),
                    packets_per_rtc=[int(x) for x in out[:, 0]], cache=cache,
                    int_ops=int(out[:, 2].sum()), seconds=sec, estimate=True)


def estimate_frame(cfg: Config, image, rays, *, events=None) -> Estimate:
    """The estimate for a frame of ``rays`` (``model.raygen.Rays``, packet = tile index):
    the golden model's event log (traced here unless ``events`` is given), then
    :func:`estimate_events`. ``seconds_trace`` / ``seconds_model`` split the run time."""
    t0 = time.perf_counter()
    if events is None:
        work = record_work(image, rays, cfg)
    else:
        work = work_of(events, image, rays.n_packets, np.diff(rays.pk_start))
    t1 = time.perf_counter()
    est = estimate_events(cfg, work)
    est["seconds_trace"] = t1 - t0
    est["seconds_model"] = est.pop("seconds")
    est["seconds"] = est["seconds_trace"] + est["seconds_model"]
    return est


def fps_error(estimated_cycles: float, exact_cycles: float) -> float:
    """Relative error of an estimated frame rate against the exact one (fps ~ 1 / cycles):
    ``exact / estimated - 1`` (positive: the estimate is too fast)."""
    if estimated_cycles <= 0 or exact_cycles <= 0:
        raise ValueError("cycle counts must be positive")
    return exact_cycles / estimated_cycles - 1.0
