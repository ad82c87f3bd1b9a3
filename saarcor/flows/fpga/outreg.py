"""Block-RAM output registers: move the flip-flop after each ECP5 block-RAM read into the
DP16KD's own output register (``REGMODE OUTREG``), on Yosys's netlist before nextpnr.

Yosys's ``synth_ecp5`` does not use the DP16KD's output register: a read whose data go
straight into a register stays a RAM output (5.8 ns clock-to-out in nextpnr's speed-6 timing)
and a wire to a flip-flop in the fabric. The RTL registers every block-RAM read before any
logic (``rtl.common.BlockRAM`` with ``cfg.fast_clock``), so each used output bit drives one
flip-flop's D input and nothing else. This pass takes those flip-flops into the RAM: the
output register captures the read latch on the port's clock when its clock enable ``OCE``
is high, exactly as the flip-flop captured the RAM's output when its ``CE`` was. The cycle
behaviour is unchanged; the RAM's outputs now leave a register in the block (nextpnr times
the ``OUTREG`` mode from its own table).

A RAM's read port is taken only as a whole, and only when every used output bit drives
exactly one flip-flop's D input, on the port's clock (neither inverted), with one clock
enable (a net or always on, not inverted) shared by all of them, and no set/reset (``LSR``
tied low: the RTL's registers after the RAMs are ``reset_less``), and the RAM's own reset is
tied low. In the 36-bit (pseudo dual port) mode the read port is B and its data leave on both
halves (``DOA``, ``DOB``); both output registers are enabled (``REGMODE_A``, ``REGMODE_B``)
and both clock enables driven. A RAM whose output register is in use already (a netlist the
pass has rewritten) and anything else is left as it is and counted in the result.
"""
from __future__ import annotations

import re
from collections import defaultdict

__all__ = ["absorb_output_registers"]

_ONE = ("1 ", "1")          # a TRELLIS_FF CEMUX that means "always enabled"


def _width(c: dict, port: str) -> int:
    v = c["parameters"].get(f"DATA_WIDTH_{port}", "00000000000000000000000000010010")
    return int(v, 2) if isinstance(v, str) else int(v)


def _read_ports(c: dict) -> list[tuple[str, list[str]]]:
    """The DP16KD's output groups: (the port whose clock and enable read, its output pins)."""
    if _width(c, "A") == 36 or _width(c, "B") == 36:       # pseudo dual port: read on B
        return [("B", [f"DO{p}{i}" for p in "AB" for i in range(18)])]
    return [(p, [f"DO{p}{i}" for i in range(18)]) for p in "AB"]


def absorb_output_registers(netlist: dict, top: str | None = None,
                            only: str | None = None) -> dict:
    """Rewrite ``netlist`` (Yosys JSON, flattened) in place; returns counts: ``ports`` (read
    ports given an output register), ``bits`` (flip-flops removed), ``skipped`` (read ports
    with used outputs left as they were, by reason). ``only``: a regular expression; only the
    RAMs whose cell name it matches (``re.search``) are rewritten, the others are counted as
    skipped ("not selected")."""
    sel = re.compile(only) if only else None
    mods = netlist["modules"]
    mod = mods[top] if top else next(m for m in mods.values()
                                     if m.get("attributes", {}).get("top"))
    cells = mod["cells"]
    sinks: dict[int, list[tuple[str, str]]] = defaultdict(list)
    for name, c in cells.items():
        dirs = c.get("port_directions", {})
        for pin, bits in c["connections"].items():
            if dirs.get(pin) == "input":
                for b in bits:
                    if isinstance(b, int):
                        sinks[b].append((name, pin))
    for pname, p in mod["ports"].items():
        if p["direction"] != "input":
            for b in p["bits"]:
                if isinstance(b, int):
                    sinks[b].append(("", pname))
    res = {"ports": 0, "bits": 0, "skipped": defaultdict(int)}
    rename: dict[int, int] = {}
    for name, c in list(cells.items()):
        if c["type"] != "DP16KD":
            continue
        conn, par = c["connections"], c["parameters"]
        for port, pins in _read_ports(c):
            used = [(pin, conn[pin][0]) for pin in pins
                    if pin in conn and isinstance(conn[pin][0], int) and sinks.get(conn[pin][0])]
            if not used:
                continue
            why, oce = ("not selected", None) if sel and not sel.search(name) else \
                _check(cells, c, port, used, sinks)
            if why:
                res["skipped"][why] += 1
                continue
            for pin, b in used:
                ff = sinks[b][0][0]
                q = cells[ff]["connections"]["Q"][0]
                conn[pin] = [q]                   # the RAM's output drives the register's net
                rename[b] = q
                del cells[ff]
            for p in ("AB" if len(pins) == 36 else port):
                par[f"REGMODE_{p}"] = "OUTREG"
                conn[f"OCE{p}"] = [oce]
            res["ports"] += 1
            res["bits"] += len(used)
    for n in mod["netnames"].values():             # the old output nets join the register's
        n["bits"] = [rename.get(b, b) if isinstance(b, int) else b for b in n["bits"]]
    res["skipped"] = dict(res["skipped"])
    return res


def _check(cells: dict, ram: dict, port: str, used: list,
           sinks: dict) -> tuple[str | None, str | int | None]:
    """(why the read port's flip-flops cannot move into the RAM, ``None`` if they can; their
    shared clock enable: a net, or ``"1"``)."""
    conn, par = ram["connections"], ram["parameters"]
    clk = conn.get(f"CLK{port}")
    if par.get(f"CLK{port}MUX", f"CLK{port}") != f"CLK{port}":
        return "inverted RAM clock", None
    if any(par.get(f"REGMODE_{p}", "NOREG") != "NOREG" for p in "AB"):
        return "output register in use", None     # (a second pass would take one more)
    if any(conn.get(f"RST{p}", ["0"]) != ["0"] for p in "AB"):
        return "RAM reset used", None
    ces = set()
    for _, b in used:
        s = sinks[b]
        if len(s) != 1 or not s[0][0] or cells[s[0][0]]["type"] != "TRELLIS_FF" \
                or s[0][1] != "DI":
            return "output not only a flip-flop's D", None
        f = cells[s[0][0]]
        fp, fc = f["parameters"], f["connections"]
        if fc["CLK"] != clk or fp.get("CLKMUX", "CLK") != "CLK":
            return "flip-flop on another clock", None
        if fc.get("LSR", ["0"]) != ["0"] or fp.get("LSRMUX", "LSR") != "LSR":
            return "flip-flop with set/reset", None
        if fp.get("CEMUX", "1 ") in _ONE:
            ces.add("1")
        elif fp["CEMUX"] == "CE":
            ces.add(fc["CE"][0])
        else:
            return "inverted clock enable", None
    if len(ces) != 1:
        return "flip-flops with different enables", None
    return None, ces.pop()
