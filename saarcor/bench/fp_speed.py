"""Amaranth simulation speed of the FP unit testbenches (``tb/units/fp.py``): a Markdown table of
cycles per second per unit, random operands with 25 % bubbles and 25 % stalls, and with
``--exhaustive`` the E4M3 exhaustive runs.

    saarcor bench fp-speed [--fmt E8M23] [--ops 3000] [--units add,mul,...] [--exhaustive]
"""
from __future__ import annotations

import argparse

from model.config import ConfigError
from model.fp import FPFormat
from saarcor.args import parse_fmt
from tb.units.fp import UNITS, make_unit, run_exhaustive, run_random

DEFAULT_UNITS = "add,mul,div,sqrt,cmp,min,conv"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="saarcor bench fp-speed",
                                 description="Amaranth simulation speed of the FP unit "
                                             "testbenches (tb/units/fp.py): cycles per second "
                                             "per unit, a Markdown table.")
    ap.add_argument("--fmt", default="E8M23", help="FP format E<exp>M<frac> (default E8M23)")
    ap.add_argument("--ops", type=int, default=3000, metavar="N",
                    help="about this many operations per unit (default 3000)")
    ap.add_argument("--units", default=DEFAULT_UNITS,
                    help=f"comma-separated, of {', '.join(UNITS)} (default {DEFAULT_UNITS})")
    ap.add_argument("--exhaustive", action="store_true", help="also the E4M3 exhaustive runs")
    args = ap.parse_args(argv)
    try:
        fmt = parse_fmt(args.fmt)
    except (ConfigError, ValueError) as e:
        ap.error(str(e))
    kinds = args.units.split(",")
    bad = [k for k in kinds if k not in UNITS]
    if bad:
        ap.error(f"--units: unknown unit(s) {bad}; choose from {', '.join(UNITS)}")
    print("| unit | format | latency | ops | cycles | s | cycles/s |\n|---|---|---|---|---|---|---|")
    for kind in kinds:
        r = run_random(kind, fmt, args.ops)
        lat = make_unit(kind, fmt).latency
        print(f"| {kind} (25 % bubbles, 25 % stalls) | {fmt} | {lat} | {r.ops} | {r.cycles} | "
              f"{r.seconds:.1f} | {r.cycles_per_s:.0f} |", flush=True)
    if args.exhaustive:
        e4m3 = FPFormat(4, 3)
        for kind in ("add", "mul", "div"):
            n = len(make_unit(kind, e4m3).BOUNDARIES)
            regs = (0,) + (1,) * (n - 1)
            r = run_exhaustive(kind, e4m3, latency=None, regs=regs)
            print(f"| {kind} exhaustive (no bubbles) | E4M3 | {sum(regs)} | {r.ops} | "
                  f"{r.cycles} | {r.seconds:.1f} | {r.cycles_per_s:.0f} |", flush=True)


if __name__ == "__main__":
    main()
