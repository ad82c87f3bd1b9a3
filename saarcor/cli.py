"""``saarcor COMMAND [options]``: one command line for the golden model, the RTL and the benches.

Each command hands its arguments to an existing module's ``main(argv)``, so every option is
defined once, in that module, and ``saarcor COMMAND --help`` prints that module's full help.
Modules are imported only when their command runs (``saarcor --help`` imports none of them).
"""
from __future__ import annotations

import argparse
import importlib
import os
import signal
import sys
from dataclasses import dataclass


@dataclass(frozen=True)
class Command:
    """A command: ``module.func(argv)`` runs it; ``help`` is its line in the listing."""
    module: str
    help: str
    func: str = "main"


COMMANDS: dict[str, Command] = {
    "sim": Command("saarcor.sim", "render a scene on the simulated chip (RTL) and check it "
                                  "against the golden model"),
    "render": Command("saarcor.render", "render a scene with the golden model alone: image.png, "
                                        "stats.json, rays.npz, hits.npz"),
    "scene": Command("saarcor.scene", "a summary of each scene file: triangles, materials, "
                                      "lights, bounds; --prepare: kd-tree and image cost"),
    "verilog": Command("saarcor.verilog", "write the Verilog of the one-RTC top or of one unit"),
    "fpga": Command("saarcor.flows.fpga.flow", "synthesis, place and route on an ECP5-85k "
                                               "(YoWASP Yosys, nextpnr); resources and Fmax"),
    "synth": Command("saarcor.flows.synth", "Yosys synthesis of the FP units (generic and "
                                            "ECP5): no latches, a table of resources"),
    "formal": Command("saarcor.flows.formal.bus", "formal checks of the round-robin bus "
                                                  "(SMT-BMC): BMC, k-induction, cover"),
    "verilator": Command("saarcor.verilator", "trace a frame through one RTC in Verilator, "
                                              "every ray compared with the golden model"),
    "sweep": Command("saarcor.sweep", "a design-space sweep (configurations x scenes x "
                                      "resolutions) on Dask, cached per point, into one results "
                                      "table"),
    "results": Command("saarcor.results", "docs/results.md: the paper's Section 5 tables beside "
                                          "ours, from sweeps, with plots"),
}
"""Top-level commands; ``bench`` (below) is a group of its own."""

BENCHES: dict[str, Command] = {
    "chip": Command("saarcor.bench.chip", "a frame on the whole chip in Verilator: cycles, fps, "
                                          "relative performance"),
    "memory": Command("saarcor.bench.memory", "cache hit rates per unit and SDRAM bandwidth"),
    "threads": Command("saarcor.bench.threads", "RTC cycles against threads per RTC (the "
                                                "paper's speed-up)"),
    "model": Command("saarcor.bench.model", "golden-model rays per second (trace kernel and "
                                            "whole render) next to Embree, kd-tree build time"),
    "ladder": Command("saarcor.ladder", "the simulation ladder: golden model, cycle estimate, "
                                        "sampled RTL, Verilator, Amaranth: run time against fps "
                                        "error"),
    "stress": Command("saarcor.stress", "numerical stress cases of the golden model against the "
                                        "exact oracle"),
    "precision": Command("saarcor.precision", "image and ray error, FP-unit cost and run time "
                                              "against the FP format"),
    "fp-cost": Command("saarcor.bench.fp_cost", "Yosys ECP5 resources of the FP units per "
                                                "format, cached"),
    "resources": Command("saarcor.bench.resources", "the chip's FP units by kind, flip-flop and "
                                                    "memory bits, from its netlist"),
    "simspeed": Command("saarcor.bench.simspeed", "a chip frame's wall time step by step "
                                                  "(build, simulation, golden model, outputs) "
                                                  "and the simulation's cost by unit"),
    "fp-speed": Command("saarcor.bench.fp_speed", "Amaranth simulation speed of the FP unit "
                                                  "testbenches"),
    "cocotb": Command("saarcor.bench.cocotb_speed", "speed of the cocotb benches on each "
                                                    "simulator (Icarus, Verilator)"),
    "skipping": Command("saarcor.skipping", "what skipping work a scene doesn't need saves: "
                                            "run-time skips, the chip built for the scene, "
                                            "second runs"),
}

BENCH_HELP = "benchmarks (most write JSON to build/bench/): " + ", ".join(BENCHES)


def _parser(prog: str, description: str, commands: dict[str, str]) -> argparse.ArgumentParser:
    """A parser used for its help and its error messages; commands parse their own options."""
    ap = argparse.ArgumentParser(
        prog=prog, description=description,
        epilog=f"Run `{prog} COMMAND --help` for the options of a command.")
    sub = ap.add_subparsers(title="commands", metavar="COMMAND")
    for name, text in commands.items():
        sub.add_parser(name, help=text, add_help=False)
    return ap


def top_parser() -> argparse.ArgumentParser:
    listing = {name: c.help for name, c in COMMANDS.items()}
    listing["bench"] = BENCH_HELP
    return _parser("saarcor", "SaarCOR ray-tracing chip: golden model, RTL, simulation and "
                              "benchmarks.", listing)


def bench_parser() -> argparse.ArgumentParser:
    return _parser("saarcor bench", "Benchmarks; most write JSON to their --out directory "
                                    "(build/bench by default).",
                   {name: c.help for name, c in BENCHES.items()})


def _dispatch(ap: argparse.ArgumentParser, commands: dict, argv: list[str]):
    """The command named by ``argv[0]`` and the rest of ``argv``; help and errors for the rest."""
    if not argv:
        ap.print_usage(sys.stderr)
        ap.exit(2, f"{ap.prog}: error: name a command: {', '.join(commands)} "
                   f"(`{ap.prog} --help` explains each)\n")
    first = argv[0]
    if first in ("-h", "--help"):
        ap.print_help()
        ap.exit(0)
    if first.startswith("-"):
        named = next((a for a in argv if a in commands), "COMMAND")
        ap.error(f"unknown option {first!r}: options go after the command, "
                 f"e.g. `{ap.prog} {named} {first}`")
    if first not in commands:
        ap.error(f"unknown command {first!r}; choose one of: {', '.join(commands)}")
    return first, argv[1:]


def run(name: str, cmd: Command, argv: list[str]) -> int:
    """Import ``cmd.module`` and call its ``main`` with ``argv``; its exit status."""
    try:
        module = importlib.import_module(cmd.module)
    except ModuleNotFoundError as e:
        if e.name and (cmd.module + ".").startswith(e.name + "."):
            path = cmd.module.replace(".", "/") + ".py"
            raise SystemExit(f"{name}: {path} ({cmd.module}) is not in this checkout; update "
                             f"the checkout to a version that has it")
        raise SystemExit(f"{name}: needs the Python package {e.name!r}, which is not installed; "
                         f"run `make setup`")
    if os.environ.get("SAARCOR_TRACEBACK"):
        status = getattr(module, cmd.func)(_join_dash_values(argv))
        return status if isinstance(status, int) else 0
    import warnings
    from model.config import ConfigError
    from model.scene_data import SceneError
    with warnings.catch_warnings():
        warnings.showwarning = _warning_line(name)
        old = signal.signal(signal.SIGINT, _interrupted(name))
        try:
            status = getattr(module, cmd.func)(_join_dash_values(argv))
        except (ConfigError, SceneError) as e:
            print(f"{name}: {e}", file=sys.stderr)
            return 2
        except OSError as e:
            where = f" {e.filename}" if e.filename else ""
            print(f"{name}: cannot complete:{where}: {e.strerror or e} (the outputs of earlier "
                  f"runs are unchanged; SAARCOR_TRACEBACK=1 shows the traceback)",
                  file=sys.stderr)
            return 1
        finally:
            signal.signal(signal.SIGINT, old)
    return status if isinstance(status, int) else 0      # some mains return their results


def _interrupted(name: str):
    """The SIGINT (Ctrl-C) handler: one line and exit status 130, at once. Exiting from the
    handler, not by ``KeyboardInterrupt``, also stops a run whose main thread is inside
    compiled code (a numba compile swallows the exception and carries on). Outputs are
    staged (``saarcor.outputs.OutputDir``, which holds off SIGINT while it renames), so the
    previous run's files stay whole; simulator child processes get the same Ctrl-C."""
    def handler(signum, frame):
        print(f"\n{name}: interrupted (Ctrl-C); earlier outputs are kept whole", file=sys.stderr,
              flush=True)
        os._exit(130)
    return handler


VALUE_OPTIONS_WITH_DASH = ("--res",)
"""Options whose value may start with a dash (``--res -5x10``), which argparse would take for
an option: :func:`_join_dash_values` writes them ``--res=-5x10`` so the option's own check
reports the bad value."""


def _join_dash_values(argv: list[str]) -> list[str]:
    out, i = [], 0
    while i < len(argv):
        a = argv[i]
        if a in VALUE_OPTIONS_WITH_DASH and i + 1 < len(argv) and argv[i + 1].startswith("-") \
                and len(argv[i + 1]) > 1 and not argv[i + 1].startswith("--"):
            out.append(f"{a}={argv[i + 1]}")
            i += 2
            continue
        out.append(a)
        i += 1
    return out


def _warning_line(name: str):
    """``warnings.showwarning`` printing ``name: warning: message`` on one line."""
    def show(message, category, filename, lineno, file=None, line=None):
        print(f"{name}: warning: {message}", file=file or sys.stderr)
    return show


def main(argv: list[str] | None = None) -> int:
    """Run ``saarcor COMMAND [options]``; returns the exit status."""
    argv = list(sys.argv[1:] if argv is None else argv)
    listing = dict(COMMANDS, bench=None)
    name, rest = _dispatch(top_parser(), listing, argv)
    if name == "bench":
        sub, rest = _dispatch(bench_parser(), BENCHES, rest)
        return run(f"saarcor bench {sub}", BENCHES[sub], rest)
    return run(f"saarcor {name}", COMMANDS[name], rest)


if __name__ == "__main__":
    sys.exit(main())
