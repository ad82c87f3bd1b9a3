"""One Verilog module for the identical units of a simulation top (Verilator builds only).

The chip holds ``rtcs`` copies of each large unit (RTC, RTC-MI, RGS slave, shading and texel
caches), all elaborated from the same configuration. Exporting the chip as it stands writes
every copy out in full: Amaranth's netlist builder and Yosys then handle each bit four times,
and Verilator translates and compiles it four times. :func:`deduplicate` exports such a unit
once, as a module of its own, and puts a :class:`Blackbox` (an ``Instance`` of that module with
the unit's signature) in place of every copy, so the chip's ports and wiring stay as they are.

The exported module is the unit's own elaboration: Amaranth writes its ports from the
signature (``"__".join(path)``, as :class:`Blackbox` names them) and adds ``clk`` and ``rst``
for the ``sync`` domain. A ``ResetInserter`` around the chip (the frame tops hold the chip in
reset until ``start``) does not reach into an ``Instance``, so :class:`Blackbox` takes that
extra reset as ``hold`` and drives the module's ``rst`` with ``rst | hold``: the registers
reset exactly when the inserted reset would have reset them, and the frame runs cycle for cycle
as the flat export does (``tests/test_chip.py`` checks the same cycles against pysim).
"""
from __future__ import annotations

import re
import time
import types

from amaranth.hdl import ClockSignal, Instance, Module, ResetSignal, Value
from amaranth.lib import wiring

__all__ = ["Blackbox", "deduplicate", "export_units", "module_ports", "port_names"]


def port_names(component: wiring.Component) -> dict[str, tuple[str, Value]]:
    """``{verilog port name: ("i" | "o", value)}`` of ``component``'s signature, named as
    ``amaranth.back.verilog.convert`` names a component's ports."""
    ports = {}
    for path, member, value in component.signature.flatten(component):
        value = Value.cast(value)
        if len(value) == 0:
            continue
        ports["__".join(map(str, path))] = ("i" if member.flow == wiring.In else "o", value)
    return ports


class Blackbox(wiring.Component):
    """Stands in for ``like`` (same signature, same methods) and elaborates to an
    ``Instance`` of the Verilog module ``module``, which :func:`deduplicate` exports from one
    copy of the unit. ``hold``: a 1-bit signal ORed into the module's ``rst`` (the reset a
    ``ResetInserter`` around the stand-in would have added). No logic of its own: latency and
    throughput are the unit's."""

    def __init__(self, like: wiring.Component, module: str, hold: Value | None = None):
        self._like, self._module, self._hold = like, module, hold
        self._module_ports = None        # the exported module's ports (export_units sets it)
        self._ready = False              # no delegation while the ports are being made
        super().__init__(like.signature)
        self._ready = True

    def __getattr__(self, name):
        # methods of the unit's class (``RTCMI.mem``) act on the stand-in's ports; other
        # attributes (``cfg``, geometries) are the unit's
        if name.startswith("_") or not self.__dict__.get("_ready"):
            raise AttributeError(name)
        attr = getattr(type(self._like), name, None)
        if isinstance(attr, types.FunctionType):
            return types.MethodType(attr, self)
        return getattr(self._like, name)

    def elaborate(self, platform):
        m = Module()
        names = port_names(self)
        have = self._module_ports
        if have is not None and set(names) - have:
            raise ValueError(f"Blackbox {self._module!r}: the exported module lacks the ports "
                             f"{sorted(set(names) - have)}")
        ports = {f"{d}_{name}": v for name, (d, v) in names.items()}
        rst = ResetSignal("sync")
        if self._hold is not None:
            rst = rst | self._hold
        if have is None or "clk" in have:
            ports["i_clk"] = ClockSignal("sync")
        if have is None or "rst" in have:
            ports["i_rst"] = rst
        m.submodules.unit = Instance(self._module, **ports)
        return m


def deduplicate(slots, module: str, hold: Value | None = None) -> wiring.Component | None:
    """Replace every unit in the list ``slots`` by a :class:`Blackbox` of ``module`` (in
    place); return the first original unit, which the caller exports as ``module`` (``None``
    for an empty list)."""
    if not slots:
        return None
    first = slots[0]
    sig = first.signature
    for u in slots[1:]:
        if u.signature != sig or type(u) is not type(first):
            raise ValueError(f"deduplicate {module!r}: the units differ "
                             f"({type(first).__name__} and {type(u).__name__})")
    for u in slots[1:]:
        _silence(u)
    slots[:] = [Blackbox(u, module, hold) for u in slots]
    return first


def _silence(obj, seen=None) -> None:
    """Mark ``obj`` and the elaboratables it holds as used: a replaced copy is never
    elaborated, which Amaranth would otherwise report as ``UnusedElaboratable``."""
    from amaranth.hdl import Elaboratable
    seen = set() if seen is None else seen
    if id(obj) in seen:
        return
    seen.add(id(obj))
    if isinstance(obj, Elaboratable):
        obj._MustUse__used = True
        items = vars(obj).values()
    elif isinstance(obj, (list, tuple)):
        items = obj
    elif isinstance(obj, dict):
        items = obj.values()
    else:
        return
    for v in items:
        if isinstance(v, (Elaboratable, list, tuple, dict)):
            _silence(v, seen)


def module_ports(verilog_text: str, module: str) -> set[str]:
    """The port names of ``module`` in Yosys's Verilog ``verilog_text``."""
    m = re.search(rf"^module {re.escape(module)}\((.*?)\);", verilog_text, re.M | re.S)
    if m is None:
        raise ValueError(f"no module {module!r} in the exported Verilog")
    return {p.strip() for p in m.group(1).split(",") if p.strip()}


_UNITS: list = []                 # the units a forked export worker reads (export_units)


def _export_one(i: int) -> tuple[int, str, float]:
    from amaranth.back import verilog
    t0 = time.perf_counter()
    module, unit, _ = _UNITS[i]
    return i, verilog.convert(unit, name=module), time.perf_counter() - t0


def export_units(units, jobs: int = 1):
    """Export each ``(module, unit, stand_ins)`` of ``units`` to Verilog once and tell its
    stand-ins (the :class:`Blackbox` objects) the module's ports; yields ``(module, Verilog
    text, seconds)`` as each is done. ``jobs`` > 1: that many forked processes export the
    units side by side (Amaranth's export is single-threaded Python); inside a daemonic process
    (a Dask or multiprocessing worker, which may not have children) they are exported in turn."""
    import multiprocessing
    global _UNITS
    _UNITS = list(units)
    try:
        if jobs > 1 and len(_UNITS) > 1 and not multiprocessing.current_process().daemon:
            pool = multiprocessing.get_context("fork").Pool(min(jobs, len(_UNITS)))
            with pool:
                done = list(pool.imap_unordered(_export_one, range(len(_UNITS))))
        else:
            done = map(_export_one, range(len(_UNITS)))
        for i, text, secs in done:
            module, unit, stand_ins = _UNITS[i]
            _silence(unit)                 # elaborated in a worker process, not in this one
            have = module_ports(text, module)
            for bb in stand_ins:
                bb._module_ports = have
            yield module, text, secs
    finally:
        _UNITS = []
