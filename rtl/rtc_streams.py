"""The streams between the RTC's units, defined once (``amaranth.lib.data`` layouts).

Every value field is a format word of ``fmt.width = 1 + E + M`` bits, encoded as
``model.fp.FPFormat.to_bits`` encodes it. ``lanes`` is the packet size (<= 64), ``threads``
the packets in flight. The golden model's event log (``model.rtc.trace(..., record=True)``,
``model/events.py``) records exactly these streams, so a unit testbench replays them:

========================  ==================  =========================================
stream                    producer -> consumer  model event
========================  ==================  =========================================
``RayIn``                 RGS -> RTC (all units keep their part of it, written once)
``LeafRequest``           traversal -> list    ``EV_LEAF`` (count > 0)
``TriRequest``            list -> intersection ``EV_TRI``
``IntResult`` (internal)  intersection datapath ``EV_INT``
``LaneResult``            intersection -> traversal  (per lane of the leaf's mask, after
                          the leaf's last triangle; traversal then terminates rays: ``EV_RESULT``)
``RayResult``             RTC -> RGS           the ray's final hit (``Hits``)
========================  ==================  =========================================
"""
from __future__ import annotations

from amaranth.lib import data

from model.config import Config

TRI_ID_BITS = 32
LIST_INDEX_BITS = 32          # index of a list entry (the leaf's ``first``)
COUNT_BITS = 30               # triangles in a leaf
TRI_INDEX_BITS = 32           # triangle index in memory (layout order)
PACKET_ID_BITS = 32           # the RGS's packet number, echoed in the results


def lane_bits(cfg: Config) -> int:
    return max(1, (cfg.packet_size - 1).bit_length())


def vec3(cfg: Config) -> data.ArrayLayout:
    return data.ArrayLayout(cfg.fmt.width, 3)


def RayIn(cfg: Config) -> data.StructLayout:
    """One ray of a packet as ray setup made it (``model.raygen.setup``), with its place.

    A packet is ``lanes`` transfers with ``lane`` 0..n-1 and ``last`` on the final one."""
    w = cfg.fmt.width
    return data.StructLayout({
        "packet": PACKET_ID_BITS,
        "lane": lane_bits(cfg),
        "last": 1,
        "org": vec3(cfg),
        "inv": vec3(cfg),          # 1 / dir per axis (traversal)
        "octant": 3,               # direction sign bits x | y<<1 | z<<2 (traversal)
        "tnear": w,                # interval clipped to the scene box (traversal)
        "tfar": w,
        "k": data.ArrayLayout(2, 3),   # kx, ky, kz (intersection; 0 for int_test="projection")
        "s": vec3(cfg),                # Sx, Sy, Sz (intersection; int_test="projection": the
                                       # direction, which that test reads instead)
        "tmax": w,                 # best t starts here (intersection)
        "anyhit": 1,               # shadow ray: any hit ends it
    })


def LeafRequest(cfg: Config) -> data.StructLayout:
    """A non-empty leaf to expand: its list entries [first, first + count) for ``mask``."""
    return data.StructLayout({
        "thread": cfg.thread_bits,
        "first": LIST_INDEX_BITS,
        "count": COUNT_BITS,
        "mask": cfg.packet_size,
    })


def TriRequest(cfg: Config) -> data.StructLayout:
    """One triangle address of a leaf for the rays in ``mask``; ``last``: the leaf's final one."""
    return data.StructLayout({
        "thread": cfg.thread_bits,
        "tri": TRI_INDEX_BITS,
        "mask": cfg.packet_size,
        "last": 1,
    })


def IntResult(cfg: Config) -> data.StructLayout:
    """One int-op out of the intersection datapath (before the closest-hit update)."""
    w = cfg.fmt.width
    return data.StructLayout({
        "thread": cfg.thread_bits,
        "lane": lane_bits(cfg),
        "hit": 1,                  # edge test passed and det != 0
        "t": w, "u": w, "v": w,
    })


def LaneResult(cfg: Config) -> data.StructLayout:
    """After a leaf: for each lane of its mask, whether the ray has a hit and its best t."""
    return data.StructLayout({
        "thread": cfg.thread_bits,
        "lane": lane_bits(cfg),
        "hit": 1,
        "t": cfg.fmt.width,
        "last": 1,                 # final lane of this leaf's results
    })


def RayResult(cfg: Config) -> data.StructLayout:
    """A finished ray: triangle id (all ones = miss), t, u, v (t = +inf on a miss)."""
    w = cfg.fmt.width
    return data.StructLayout({
        "packet": PACKET_ID_BITS,
        "lane": lane_bits(cfg),
        "last": 1,
        "tri": TRI_ID_BITS,
        "t": w, "u": w, "v": w,
    })


def PacketDone(cfg: Config) -> data.StructLayout:
    """Traversal -> intersection: thread ``thread`` (packet ``packet``) has finished all its
    passes; read the best hits of its lanes in ``mask`` (the lanes the packet has) out as
    ``RayResult`` s (model event ``EV_DONE``)."""
    return data.StructLayout({
        "thread": cfg.thread_bits,
        "packet": PACKET_ID_BITS,
        "mask": cfg.packet_size,
    })
