"""Quick path estimate of a synthesized ECP5 netlist (Yosys JSON), before placement.

nextpnr reports one critical path per clock, after an hour of place and route for the RTC.
This estimate lists *every* register-to-register path class longer than the clock period from
the netlist alone, in seconds: arrival times through the mapped cells with fixed delays (the
LFE5U-85 speed grade 6 figures nextpnr reports for its cells: flip-flop clock-to-out 0.52 ns,
block-RAM clock-to-out 5.8 ns, 0.9 ns from its output register (``REGMODE OUTREG``,
``saarcor/flows/fpga/outreg.py``), LUT4 0.24 ns, a carry cell 0.07 ns along its chain; a
MULT18X18D 4.5 ns through, or, with its own registers on, 0.74 ns clock-to-out and an endpoint
at its inputs) and a guess
for each net's routing (``route`` ns, more with fanout; 0 inside a slice: LUT -> PFUMX ->
L6MUX21, carry chain). It is a ranking of where the long paths are, not a timing sign-off:
routed delays depend on placement (nextpnr's routed nets ranged from 0.2 to 3.6 ns).

Run: ``saarcor fpga --estimate LABEL`` (a run with a netlist in
``build/fpga/LABEL``, e.g. from ``--synth-only``).

After a route with ``--pnr-arg=--detailed-timing-report``, nextpnr's report holds every
endpoint's routed arrival time (its "detailed net timings": per net into an endpoint, the
earliest and latest arrival at each endpoint). ``--estimate LABEL --routed`` lists the
endpoints by those routed times instead (:func:`routed_arrivals`), each named by the start of
its estimated worst path: every path class over the period after routing, where nextpnr
prints only the one critical path.
"""
from __future__ import annotations

import json
import math
import re
from collections import defaultdict
from pathlib import Path

__all__ = ["estimate", "report", "routed_arrivals"]

FF_CQ, BRAM_CQ, LUTRAM_RD, DSP, DSP_CQ = 0.52, 5.8, 0.5, 4.5, 0.74
BRAM_OUTREG_CQ = 0.9
LUT, MUX, CARRY_IN, CARRY, CARRY_OUT = 0.24, 0.26, 0.45, 0.07, 0.44
SETUP = 0.1


def base_name(cell: str) -> str:
    """A signal-like name for a mapped cell: the Yosys-derived suffix and bit indices cut."""
    cut = re.search(r"_(LUT4|PFUMX|L6MUX21|CCU2C|TRELLIS|DPR16X4|MULT18X18D|DP16KD|DI|DO[AB]?\d)",
                    cell)
    name = cell[:cut.start()] if cut else cell
    return re.sub(r"(\.\d+)+$", "", name)


def routed_arrivals(report: Path) -> dict[str, float]:
    """The latest routed arrival time (ns, setup included) at each endpoint cell, from a
    nextpnr ``--report`` written with ``--detailed-timing-report``."""
    rep = json.loads(Path(report).read_text())
    nets = rep.get("detailed_net_timings")
    if nets is None:
        raise ValueError(f"{report} has no detailed_net_timings: route with "
                         "--pnr-arg=--detailed-timing-report")
    out: dict[str, float] = {}
    for n in nets:
        for e in n["endpoints"]:
            out[e["cell"]] = max(out.get(e["cell"], 0.0), float(e["delay"][1]))
    return out


def estimate(netlist: Path, top: str = "fpga_top", route: float = 0.9,
             routed: dict[str, float] | None = None) -> list[dict]:
    """Per endpoint (a flip-flop or block-RAM/LUT-RAM input): the estimated arrival time (ns)
    and the cells of its worst path, for every endpoint; sorted, longest first. ``routed``
    (:func:`routed_arrivals`): each endpoint's time is its routed one (``est``: the
    estimate), endpoints it does not list are left out."""
    mod = json.loads(Path(netlist).read_text())["modules"][top]
    cells = mod["cells"]
    driver: dict[int, tuple[str, str]] = {}
    fanout: dict[int, int] = defaultdict(int)
    for name, c in cells.items():
        for port, bits in c["connections"].items():
            d = c["port_directions"].get(port)
            for b in bits:
                if not isinstance(b, int):
                    continue
                if d == "output":
                    driver[b] = (name, port)
                else:
                    fanout[b] += 1

    def net_delay(bit, sink_type, sink_port):
        src = driver.get(bit)
        if src is None:
            return 0.0
        st = cells[src[0]]["type"]
        if (st == "LUT4" and sink_type in ("PFUMX", "L6MUX21") and sink_port != "C0"
                and sink_port != "SD") or (st in ("PFUMX",) and sink_type == "L6MUX21"
                                           and sink_port != "SD") or \
                (st == "CCU2C" and src[1] == "COUT" and sink_port == "CIN"):
            return 0.0
        return route + 0.25 * math.log2(max(1, fanout[bit]))

    memo: dict[int, tuple[float, int | None]] = {}

    def arrival(bit):
        """(arrival at the driver's output, the input bit on the worst path)."""
        if bit in memo:
            return memo[bit]
        stack = [bit]
        while stack:
            b = stack[-1]
            if b in memo:
                stack.pop()
                continue
            src = driver.get(b)
            if src is None:
                memo[b] = (0.0, None)
                stack.pop()
                continue
            name, port = src
            c = cells[name]
            t = c["type"]
            if t == "TRELLIS_FF":
                memo[b] = (FF_CQ, None); stack.pop(); continue
            if t == "DP16KD":
                reg = c["parameters"].get(f"REGMODE_{port[2]}", "NOREG") == "OUTREG"
                memo[b] = (BRAM_OUTREG_CQ if reg else BRAM_CQ, None); stack.pop(); continue
            if t == "MULT18X18D" and _dsp_reg(c, "OUTPUT"):
                memo[b] = (DSP_CQ, None); stack.pop(); continue
            ins = _comb_inputs(c, port)
            pending = [i for i, _ in ins if i not in memo and driver.get(i) is not None]
            if pending:
                stack.extend(pending)
                continue
            best, via = 0.0, None
            for i, cell_delay in ins:
                a = memo.get(i, (0.0, None))[0] + net_delay(i, t, _port_of(c, i)) + cell_delay
                if a > best:
                    best, via = a, i
            memo[b] = (best, via)
            stack.pop()
        return memo[bit]

    out = []
    for name, c in cells.items():
        t = c["type"]
        if t == "TRELLIS_FF":
            ports = ("DI", "CE", "LSR", "M")
        elif t == "DP16KD":
            ports = tuple(p for p in c["connections"] if p.startswith(("AD", "DI", "CE", "WE",
                                                                       "OCE", "CS", "RST")))
        elif t == "TRELLIS_DPR16X4":
            ports = ("WAD", "DI", "WRE")
        elif t == "MULT18X18D" and (_dsp_reg(c, "INPUTA") or _dsp_reg(c, "INPUTB")):
            ports = tuple(f"{x}{i}" for x in "AB" for i in range(18)
                          if _dsp_reg(c, f"INPUT{x}")) + ("CE0",)
        else:
            continue
        worst, wbit = -1.0, None
        for p in ports:
            for b in c["connections"].get(p, []):
                if isinstance(b, int) and b in driver:
                    a = arrival(b)[0] + net_delay(b, t, p) + SETUP
                    if a > worst:
                        worst, wbit = a, b
        if wbit is None:
            continue
        path, b = [name], wbit
        while b is not None:
            path.append(driver[b][0])
            b = memo[b][1]
        e = {"end": name, "ns": round(worst, 2), "path": path[::-1]}
        if routed is not None:
            if name not in routed:
                continue
            e["est"], e["ns"] = e["ns"], round(routed[name], 2)
        out.append(e)
    out.sort(key=lambda e: -e["ns"])
    return out


def _dsp_reg(c: dict, which: str) -> bool:
    """A MULT18X18D's own register ``which`` (INPUTA, INPUTB, OUTPUT) is on."""
    return str(c.get("parameters", {}).get(f"REG_{which}_CLK", "NONE")) not in ("", "NONE")


def _comb_inputs(c: dict, out_port: str) -> list[tuple[int, float]]:
    """(input bit, cell delay to ``out_port``) of a combinational cell."""
    t, con = c["type"], c["connections"]
    bits = lambda *ps: [b for p in ps for b in con.get(p, []) if isinstance(b, int)]
    if t == "LUT4":
        return [(b, LUT) for b in bits("A", "B", "C", "D")]
    if t in ("PFUMX", "L6MUX21"):
        return [(b, MUX) for b in bits("ALUT", "BLUT", "C0", "D0", "D1", "SD")]
    if t == "CCU2C":
        data = bits("A0", "B0", "C0", "D0", "A1", "B1", "C1", "D1")
        if out_port == "COUT":
            return [(b, CARRY_IN) for b in data] + [(b, CARRY) for b in bits("CIN")]
        return [(b, CARRY_OUT) for b in data + bits("CIN")]
    if t == "TRELLIS_DPR16X4":
        return [(b, LUTRAM_RD) for b in bits("RAD")]
    if t == "MULT18X18D":
        return [(b, DSP) for b in bits(*(f"{x}{i}" for x in "AB" for i in range(18)))]
    return [(b, LUT) for p, d in c["port_directions"].items() if d == "input" for b in bits(p)]


def _port_of(c: dict, bit: int) -> str:
    for p, bs in c["connections"].items():
        if bit in bs:
            return p
    return "?"


def report(netlist: Path, period: float = 10.0, top_n: int = 25, **kw) -> str:
    """The path classes (start signal -> end signal) estimated longer than ``period`` ns:
    worst estimate, number of endpoints, and the worst path's cells (``routed=``: by the
    routed arrival times, each endpoint's start taken from its estimated worst path)."""
    ends = estimate(netlist, **kw)
    what = "routed" if kw.get("routed") is not None else "estimated"
    groups: dict[tuple[str, str], list] = {}
    for e in ends:
        if e["ns"] <= period:
            break
        key = (base_name(e["path"][0]), base_name(e["end"]))
        groups.setdefault(key, []).append(e)
    lines = [f"{sum(1 for e in ends if e['ns'] > period)} of {len(ends)} endpoints {what} "
             f"over {period} ns, in {len(groups)} classes (start -> end):"]
    for (a, b), es in sorted(groups.items(), key=lambda kv: -kv[1][0]["ns"])[:top_n]:
        w = es[0]
        mid = [base_name(x) for x in w["path"][1:-1]]
        mid = [x for i, x in enumerate(mid) if i == 0 or x != mid[i - 1]]
        lines.append(f"{w['ns']:6.2f} ns  {len(es):5d} ends  {a} -> {b}  ({len(w['path']) - 2} "
                     f"cells: {' > '.join(mid[:8])}{' ...' if len(mid) > 8 else ''})")
    return "\n".join(lines)
