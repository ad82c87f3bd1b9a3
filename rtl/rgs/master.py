"""The RGS master: hands out a frame's packets (tiles) to the RGS slaves, one per RTC.

No golden-model counterpart (``model/rgs/``): the model makes the packets in the same order
(``model.rgs.eye.eye_packets``), and which slave takes which packet changes no result;
``model/timing.py`` models the hand-out's timing.
"""
from __future__ import annotations

from amaranth.hdl import Cat, Module, Mux, Signal
from amaranth.lib import stream, wiring
from amaranth.lib.fifo import SyncFIFO
from amaranth.lib.wiring import In, Out

from model.config import COORD_BITS, Config

from ..common import COUNTER_BITS, rr_pick
from .eye import EyeRequest

__all__ = ["RGSMaster"]


class RGSMaster(wiring.Component):
    """The RGS master: hands out the frame's packets (tiles, row-major, packet id = tile
    index) to whichever slave has room — dynamic load balancing.

    Each slave has a request queue of ``depth`` entries (``req[s]`` is its write side): in a
    cycle where some queues have room, the first of them at or after a round-robin pointer
    gets the next tile. ``start`` (one cycle) begins a frame of ``tiles_x`` × ``tiles_y``
    tiles; ``dispatched`` is high once every tile was handed out (and before the first start);
    ``queued`` while a queue holds a tile no slave has taken yet.
    Throughput: one packet a cycle. Counter: ``packets[s]`` (packets each slave got).
    """

    def __init__(self, cfg: Config, slaves: int, *, depth: int = 1):
        self.cfg, self.slaves, self.depth = cfg, slaves, depth
        super().__init__({
            "start": In(1), "tiles_x": In(COORD_BITS), "tiles_y": In(COORD_BITS),
            "req": Out(stream.Signature(EyeRequest(cfg))).array(slaves),
            "dispatched": Out(1), "queued": Out(1),
            "packets": Out(COUNTER_BITS).array(slaves),
        })

    def elaborate(self, platform):
        m = Module()
        n = self.slaves
        lay = EyeRequest(self.cfg)
        tx, ty = Signal.like(self.tiles_x), Signal.like(self.tiles_y)
        packet = Signal(32)
        active = Signal()
        m.d.comb += self.dispatched.eq(~active)
        room = Signal(n)
        fifos = []
        for s in range(n):
            f = SyncFIFO(width=lay.size, depth=self.depth)
            m.submodules[f"queue{s}"] = f
            fifos.append(f)
            m.d.comb += [room[s].eq(f.w_rdy), self.req[s].valid.eq(f.r_rdy),
                         self.req[s].payload.eq(f.r_data), f.r_en.eq(self.req[s].ready)]
        m.d.comb += self.queued.eq(Cat(*(f.r_rdy for f in fifos)).any())
        p2 = 1 << max(0, (n - 1).bit_length())
        ptr = Signal(range(p2))
        req_bits = Signal(p2)
        m.d.comb += req_bits.eq(Mux(active, room, 0))
        any_room, pick = rr_pick(m, req_bits, ptr, "rgs_master")
        give = Signal()
        m.d.comb += give.eq(active & any_room)
        entry = Signal(lay)
        m.d.comb += [entry.tile_x.eq(tx), entry.tile_y.eq(ty), entry.packet.eq(packet)]
        for s, f in enumerate(fifos):
            m.d.comb += [f.w_data.eq(entry), f.w_en.eq(give & (pick == s))]
            with m.If(give & (pick == s)):
                m.d.sync += self.packets[s].eq(self.packets[s] + 1)
        with m.If(give):
            end_x = tx == self.tiles_x - 1
            m.d.sync += [tx.eq(Mux(end_x, 0, tx + 1)), packet.eq(packet + 1),
                         ptr.eq(Mux(pick == n - 1, 0, pick + 1))]
            with m.If(end_x):
                m.d.sync += ty.eq(ty + 1)
                with m.If(ty == self.tiles_y - 1):
                    m.d.sync += active.eq(0)
        with m.If(self.start):
            m.d.sync += [active.eq((self.tiles_x != 0) & (self.tiles_y != 0)), tx.eq(0),
                         ty.eq(0), packet.eq(0)]
        return m
