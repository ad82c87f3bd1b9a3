from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_MESHES = (ROOT / ".." / "shared" / "meshes").resolve()
SCENES = sorted((ROOT / "scenes").glob("*.toml"))

needs_shared_meshes = pytest.mark.skipif(
    not SHARED_MESHES.exists(), reason=f"real meshes not present at {SHARED_MESHES}")


@pytest.fixture(scope="session")
def kd_cache(tmp_path_factory):
    """A kd-tree cache directory private to this test session."""
    return tmp_path_factory.mktemp("kdcache")
