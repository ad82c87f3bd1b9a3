"""Yosys ECP5 resources of the FP units at a given format, cached per format.

``fp_cost(fmt)`` runs :func:`saarcor.flows.synth.synth_unit` (``synth_ecp5``, default latencies) for
each unit and keeps the result in ``build/precision/synth/<fmt>.json``; later calls read the file.

    saarcor bench fp-cost [--formats E8M23,E8M16,E8M10] [--units add,mul,div]
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

from model.fp import FPFormat

ROOT = Path(__file__).resolve().parents[2]
CACHE = ROOT / "build" / "precision" / "synth"
UNITS = ("add", "mul", "div", "cmp", "minmax", "conv")


def fp_cost(fmt: FPFormat, units=UNITS, cache: Path = CACHE, run: bool = True) -> dict | None:
    """``{unit: {"LUT4", "CCU2C", "MUX", "FF", "DSP", "latency"}}`` at ``fmt``; ``None`` when
    not cached and ``run`` is False."""
    path = Path(cache) / f"{fmt}.json"
    have = json.loads(path.read_text()) if path.exists() else {}
    missing = [u for u in units if u not in have]
    if missing and not run:
        return None
    if missing:
        from saarcor.flows.synth import synth_unit
        with tempfile.TemporaryDirectory() as tmp:
            for u in missing:
                r = synth_unit(u, fmt, Path(tmp))
                e = r["ecp5"]
                have[u] = {"LUT4": e.get("LUT4", 0), "CCU2C": e.get("CCU2C", 0),
                           "MUX": e.get("PFUMX", 0) + e.get("L6MUX21", 0),
                           "FF": e.get("TRELLIS_FF", 0), "DSP": e.get("MULT18X18D", 0),
                           "latency": r["latency"]}
                print(f"fp_cost: {fmt} {u}: {have[u]}", file=sys.stderr, flush=True)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(have, indent=1))
    return {u: have[u] for u in units}


def main(argv=None) -> None:
    from saarcor.args import add_formats_arg, parse_formats
    ap = argparse.ArgumentParser(prog="saarcor bench fp-cost",
                                 description=__doc__.splitlines()[0] + " Prints one JSON line "
                                 "per format.")
    add_formats_arg(ap, "E8M23")
    ap.add_argument("--units", default=",".join(UNITS),
                    help="comma-separated units (default %(default)s)")
    args = ap.parse_args(argv)
    try:
        formats = parse_formats(args.formats)
    except ValueError as e:
        ap.error(str(e))
    units = tuple(args.units.split(","))
    bad = [u for u in units if u not in UNITS]
    if bad:
        ap.error(f"--units: unknown unit(s) {bad}; choose from {', '.join(UNITS)}")
    for f in formats:
        print(f, json.dumps(fp_cost(f, units)))


if __name__ == "__main__":
    main()
