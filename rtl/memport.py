"""The memory read port every unit uses: a tagged request stream and a tagged response stream.

Seen from the requester (a cache, a bus input, a unit reading through a cache)::

    req  : Out(stream)  payload {addr: addr_width, tag: tag_width}
    resp : In(stream)   payload {data: data_width, tag: tag_width}

The server (memory, bus output, cache input) uses ``MemReadPort(...).flip()``.

Protocol (see ``docs/memory-interface.md`` for the timing diagram):

* Both streams follow ``amaranth.lib.stream`` rules: a transfer happens in a cycle where
  ``valid & ready``; once ``valid`` is high, it and the payload stay unchanged until the transfer.
* Every accepted request gets exactly one response carrying the request's ``tag``, after at least
  one cycle. Responses may come back in any order; the tag says which request a response answers.
  A requester that needs to tell responses apart must not reuse a tag before its response arrived.
* ``addr`` counts items of the port's data width as seen by the server: 64-bit words on a memory
  port (word address = byte address // 8), items (node, list entry, triangle) on a cache's unit port.
"""
from __future__ import annotations

from amaranth.hdl import Module
from amaranth.lib import data, stream, wiring
from amaranth.lib.wiring import In, Out

__all__ = ["MemRequest", "MemResponse", "MemReadPort", "WORD_BITS", "connect_tags"]

WORD_BITS = 64  # one memory access: a 64-bit word


def MemRequest(addr_width: int, tag_width: int) -> data.StructLayout:
    """Layout of a read request: item address and the requester's tag."""
    return data.StructLayout({"addr": addr_width, "tag": tag_width})


def MemResponse(data_width: int, tag_width: int) -> data.StructLayout:
    """Layout of a read response: the item and the tag of the request it answers."""
    return data.StructLayout({"data": data_width, "tag": tag_width})


class MemReadPort(wiring.Signature):
    """Signature of a tagged read port, from the requester's side.

    Parameters
    ----------
    addr_width : int
        Address bits (items of ``data_width`` bits).
    data_width : int
        Bits per response: 64 for a memory word; a cache's unit port returns whole items.
    tag_width : int
        Bits of the tag a request carries back in its response (>= 1).
    """

    def __init__(self, *, addr_width: int, data_width: int, tag_width: int):
        for name, value in (("addr_width", addr_width), ("data_width", data_width),
                            ("tag_width", tag_width)):
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"MemReadPort: {name}={value!r} must be an int >= 1")
        self.addr_width = addr_width
        self.data_width = data_width
        self.tag_width = tag_width
        super().__init__({
            "req": Out(stream.Signature(MemRequest(addr_width, tag_width))),
            "resp": In(stream.Signature(MemResponse(data_width, tag_width))),
        })

    def __eq__(self, other):
        return (isinstance(other, MemReadPort) and self.addr_width == other.addr_width and
                self.data_width == other.data_width and self.tag_width == other.tag_width)

    def __repr__(self):
        return (f"MemReadPort(addr_width={self.addr_width}, data_width={self.data_width}, "
                f"tag_width={self.tag_width})")


def connect_tags(m: Module, requester, server) -> None:
    """Connect a requester's port to a server port whose tag is at least as wide (a bus input
    shared by requesters with different tags): the tag is zero-extended on the way in and
    truncated back on the way out. Address and data widths must match."""
    w = len(requester.req.payload.tag)
    if (len(server.req.payload.addr), len(server.resp.payload.data)) != (
            len(requester.req.payload.addr), len(requester.resp.payload.data)):
        raise ValueError("connect_tags: the ports' address or data widths differ")
    if len(server.req.payload.tag) < w:
        raise ValueError(f"connect_tags: the server's tag ({len(server.req.payload.tag)} bits) "
                         f"is narrower than the requester's ({w} bits)")
    m.d.comb += [
        server.req.valid.eq(requester.req.valid), requester.req.ready.eq(server.req.ready),
        server.req.payload.addr.eq(requester.req.payload.addr),
        server.req.payload.tag.eq(requester.req.payload.tag),
        requester.resp.valid.eq(server.resp.valid), server.resp.ready.eq(requester.resp.ready),
        requester.resp.payload.data.eq(server.resp.payload.data),
        requester.resp.payload.tag.eq(server.resp.payload.tag[:w]),
    ]
