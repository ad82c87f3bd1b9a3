"""Cache geometry and the hit/miss model of the RTC's read-only caches (``rtl/cache.py``).

Addresses on a cache's unit side are *item indices* (node i, list entry i, triangle i); item i
spans ``item_span`` bits of memory starting at bit ``i * item_span`` of the section at word
``base`` (see ``model/layout.py``), and the cache keeps (and returns) its low ``item_bits`` bits.
A line holds ``line_items`` consecutive items = ``line_words`` memory words.

Hit/miss rule (the RTL counts exactly this): requests are classified one by one in the order the
cache accepts them. A request is a **hit** if its line's tag is in the set at that moment,
whether the line's data has arrived or is still being fetched by an earlier miss (a "secondary
access" / hit under miss counts as a hit: it causes no memory traffic). Otherwise it is a
**miss**: the line is allocated at once in way ``rr[set]`` of its set and ``rr[set]`` advances
(round-robin = FIFO replacement per set; hits do not change it). So the hit/miss sequence depends
only on the access sequence, never on memory timing.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from .config import Config

__all__ = ["CacheGeometry", "CacheModel", "cache_geometry", "item_values", "UNITS"]

UNITS = ("trav", "list", "int")


def _log2(x: int) -> int:
    return x.bit_length() - 1


@dataclass(frozen=True)
class CacheGeometry:
    """Shape of one cache; every size the RTL and the model need is derived here."""
    size_bytes: int          # data capacity (tags not counted), as the paper counts it
    ways: int                # 1 (direct-mapped), 2 or 4
    line_items: int          # items per line (power of two)
    item_bits: int           # bits kept and returned per item
    item_span: int           # bits an item occupies in memory (32, 64 or 64 * k)
    outstanding: int = 4     # line fetches in flight (MSHRs)
    queue: int = 16          # requests in flight inside the cache (in-order response queue)
    addr_width: int = 32     # item address bits on the unit port
    mem_addr_width: int = 32  # word address bits on the memory port

    def __post_init__(self):
        def bad(msg):
            raise ValueError(f"{self}: {msg}")
        if self.ways not in (1, 2, 4):
            bad("ways must be 1, 2 or 4")
        if self.line_items < 1 or self.line_items & (self.line_items - 1):
            bad("line_items must be a power of two")
        if not (0 < self.item_bits <= self.item_span):
            bad("need 0 < item_bits <= item_span")
        if (self.line_items * self.item_span) % 64:
            bad("a line must be a whole number of 64-bit words (line_items * item_span % 64)")
        if self.item_span > 64 and self.item_span % 64:
            bad("items wider than a word must span whole words")
        sets, rem = divmod(self.size_bytes * 8, self.ways * self.line_items * self.item_bits)
        if rem or sets < 1 or sets & (sets - 1):
            bad(f"size_bytes*8 / (ways*line_items*item_bits) = "
                f"{self.size_bytes * 8 / (self.ways * self.line_items * self.item_bits):g} sets; "
                "it must be a power of two: change the size, ways or line size")
        if self.outstanding < 1 or self.queue < 1:
            bad("outstanding and queue must be >= 1")
        if self.addr_width < self.offset_bits + self.set_bits:
            bad("addr_width too small for the set index")

    @property
    def sets(self) -> int:
        return self.size_bytes * 8 // (self.ways * self.line_items * self.item_bits)

    @property
    def line_words(self) -> int:
        return self.line_items * self.item_span // 64

    @property
    def offset_bits(self) -> int:
        return _log2(self.line_items)

    @property
    def set_bits(self) -> int:
        return _log2(self.sets)

    @property
    def tag_bits(self) -> int:
        return self.addr_width - self.offset_bits - self.set_bits

    @property
    def word_kept_bits(self) -> list[list[tuple[int, int]]]:
        """Per memory word of a line, the bit ranges ``(lo, hi)`` of it the cache keeps (each
        item's low ``item_bits``), in item order; empty for a word of padding only. The kept
        bits of the words, concatenated, are the line's items in order."""
        out = []
        for j in range(self.line_words):
            if self.item_span <= 64:            # whole items in a word
                out.append([(t * self.item_span, t * self.item_span + self.item_bits)
                            for t in range(64 // self.item_span)])
            else:                               # an item over several words
                hi = min(64, self.item_bits - (j % (self.item_span // 64)) * 64)
                out.append([(0, hi)] if hi > 0 else [])
        return out

    def line_word_addr(self, line: int, base: int = 0) -> int:
        """Memory word address of the first word of ``line``."""
        return base + line * self.line_words


def cache_geometry(cfg: Config, unit: str, served: int = 1, **overrides) -> CacheGeometry:
    """Geometry of the ``unit`` ('trav', 'list' or 'int') cache from the configuration.

    trav: 64-bit kd-nodes, ``cache_line_words`` nodes per line. list: 32-bit entries,
    ``2 * cache_line_words`` per line. int: triangles of 5 words, ``int_item_bits`` kept
    (288 = the 9 vertex floats; 320 keeps the scene-order id too), ``cache_line_words`` triangles
    per line. ``served``: the RTCs the cache serves (the shared RTC-MI's: ``cfg.rtcs``), each
    adding ``cache_outstanding`` misses in flight and ``cache_queue`` requests. ``overrides``
    replace fields (e.g. ``ways=2``, ``size_bytes=...``).
    """
    if unit == "trav":
        g = dict(size_bytes=cfg.trav_cache_kb * 1024, line_items=cfg.cache_line_words,
                 item_bits=64, item_span=64)
    elif unit == "list":
        g = dict(size_bytes=cfg.list_cache_kb * 1024, line_items=2 * cfg.cache_line_words,
                 item_bits=32, item_span=32)
    elif unit == "int":
        g = dict(size_bytes=cfg.int_cache_kb * 1024, line_items=cfg.cache_line_words,
                 item_bits=cfg.int_item_bits, item_span=5 * 64)
    else:
        raise ValueError(f"cache unit {unit!r}: must be one of {UNITS}")
    g.update(ways=cfg.cache_ways, outstanding=served * cfg.cache_outstanding,
             queue=served * cfg.cache_queue,
             addr_width=cfg.addr_bits, mem_addr_width=cfg.addr_bits)
    g.update(overrides)
    return CacheGeometry(**g)


@numba.njit(cache=True)
def _lookup(addrs, offset_bits, set_bits, ways, tags, valid, rr, hits):
    set_mask = (1 << set_bits) - 1
    n_hits = 0
    for i in range(addrs.shape[0]):
        line = addrs[i] >> offset_bits
        s = line & set_mask
        t = line >> set_bits
        hit = False
        for w in range(ways):
            if valid[s, w] and tags[s, w] == t:
                hit = True
                break
        if not hit:
            w = rr[s]
            tags[s, w] = t
            valid[s, w] = True
            rr[s] = (w + 1) % ways
        hits[i] = hit
        n_hits += hit
    return n_hits


class CacheModel:
    """Hit/miss sequence of a cache for a sequence of item addresses (numba, ~100 M/s).

    State persists across :meth:`access` calls, so a long stream can be fed in chunks.
    """

    def __init__(self, geom: CacheGeometry):
        self.geom = geom
        self.tags = np.zeros((geom.sets, geom.ways), np.int64)
        self.valid = np.zeros((geom.sets, geom.ways), np.bool_)
        self.rr = np.zeros(geom.sets, np.int64)
        self.hits = 0
        self.misses = 0

    def access(self, addrs) -> np.ndarray:
        """Classify ``addrs`` (item indices, in acceptance order); returns a bool array (hit)."""
        addrs = np.ascontiguousarray(addrs, dtype=np.int64)
        if addrs.size and addrs.min() < 0:
            raise ValueError("cache addresses must be >= 0 item indices")
        out = np.zeros(addrs.shape[0], np.bool_)
        g = self.geom
        h = _lookup(addrs, g.offset_bits, g.set_bits, g.ways, self.tags, self.valid, self.rr, out)
        self.hits += int(h)
        self.misses += addrs.shape[0] - int(h)
        return out

    @property
    def hit_rate(self) -> float:
        n = self.hits + self.misses
        return self.hits / n if n else 0.0

    @property
    def words_read(self) -> int:
        return self.misses * self.geom.line_words


def item_values(image: np.ndarray, geom: CacheGeometry, addrs, base: int = 0) -> list[int]:
    """The item the cache must return for each address: its low ``item_bits`` bits, from memory."""
    image = np.asarray(image, dtype=np.uint64)
    out = []
    mask = (1 << geom.item_bits) - 1
    for a in np.asarray(addrs, dtype=np.int64).tolist():
        bit = a * geom.item_span
        w0, sh = base + bit // 64, bit % 64
        nw = -(-(sh + geom.item_span) // 64)
        v = 0
        for k in range(nw):
            v |= int(image[w0 + k]) << (64 * k)
        out.append((v >> sh) & mask)
    return out


def synthetic_traces(n_packets: int, *, depth: int = 16, seed: int = 0,
                     coherence: float = 0.9) -> dict[str, np.ndarray]:
    """Kd-tree-like item-address streams for the three caches (until the golden model records
    real ones): each packet walks from the root of a complete binary tree of ``depth`` levels
    (BFS node numbering: hot top nodes) to a leaf near the previous packet's leaf (probability
    ``coherence``) or a random one, visiting a sibling subtree now and then (stack pops); each
    visited leaf reads its list entries (1-8, contiguous) and their triangles (neighbouring leaves
    share triangles). Returns ``{"trav", "list", "int"}`` int64 arrays.
    """
    rng = np.random.default_rng(seed)
    n_leaves = 1 << (depth - 1)
    first_leaf = n_leaves - 1
    trav, lst, tri = [], [], []
    leaf = int(rng.integers(n_leaves))
    for _ in range(n_packets):
        if rng.random() < coherence:
            leaf = int(np.clip(leaf + rng.integers(-8, 9), 0, n_leaves - 1))
        else:
            leaf = int(rng.integers(n_leaves))
        leaves = [leaf]
        if rng.random() < 0.5:                      # rays that also need the far subtree
            leaves.append(leaf ^ int(1 << rng.integers(0, 4)))
        for lf in leaves:
            path, node = [], first_leaf + lf
            while node > 0:
                path.append(node)
                node = (node - 1) // 2
            path.append(0)
            trav.extend(reversed(path))
            count = 1 + (lf * 7919) % 8
            first = lf * 5                           # ~5 list entries per leaf on average
            for e in range(first, first + count):
                lst.append(e)
                tri.append((lf * 3 + (e * 2654435761) % 7) % (n_leaves * 3))
    return {"trav": np.array(trav, np.int64), "list": np.array(lst, np.int64),
            "int": np.array(tri, np.int64)}
