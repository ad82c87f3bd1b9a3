"""``saarcor verilog``: write the Verilog of the one-RTC top or of one unit (``make verilog``).

Writes ``DIR/<top>.v`` (default ``build/verilog``); ``--list`` names the tops
(:data:`tb.harness.tops.TOPS`). Every field of :class:`model.config.Config` is an option
(``--threads 2 --trav-subunits 1 --trav-cache-kb 4``), ``--fmt E8M16`` sets the FP format,
``--fp-latency N`` the pipeline latency of an ``fp_*`` top.
"""
from __future__ import annotations

import argparse

from model.config import ConfigError
from saarcor.args import add_config_args, add_out_arg, config_from_args
from tb.harness.tops import TOPS, export


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="saarcor verilog",
                                 description="Write the Verilog of a unit or of the one-RTC top.")
    ap.add_argument("--top", default="rtc", help="what to export (default rtc; --list names all)")
    ap.add_argument("--list", action="store_true", help="list the tops and exit")
    add_out_arg(ap, "build/verilog")
    ap.add_argument("--name", help="Verilog module and file name (default: the top's name)")
    ap.add_argument("--fp-latency", type=int, metavar="N",
                    help="pipeline latency of an fp_* top (cycles; default the unit's own)")
    ap.add_argument("--ecp5", action="store_true",
                    help="for a Lattice ECP5 flow: the FP multipliers' partial products as "
                         "MULT18X18D instances using their own input and output registers "
                         "(at FP multiply latencies with those registers, e.g. 5); the "
                         "default is portable Verilog with the registers in logic")
    add_config_args(ap)
    args = ap.parse_args(argv)
    if args.list:
        for k, (_, desc) in TOPS.items():
            print(f"{k:15s} {desc}")
        return
    try:
        path = export(args.top, config_from_args(args), args.out, args.fp_latency, args.name,
                      ecp5=args.ecp5)
    except (ConfigError, ValueError) as e:
        raise SystemExit(f"saarcor verilog: {e}")
    print(f"saarcor verilog: wrote {path} ({path.stat().st_size // 1024} KB)")




if __name__ == "__main__":
    main()
