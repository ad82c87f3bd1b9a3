"""SaarCOR golden model: the algorithm of the hardware in NumPy/numba, bit for bit.

numba's on-disk cache keys a compiled function on its own file only, but our kernels inline
functions from other modules (``fp``, ``traversal``, ``intersection``...): an edit there would
leave a stale kernel in the cache. So the cache directory is keyed on a hash of every source
file of this package and its subpackages (set before numba reads its configuration).
"""
import hashlib
import os
from pathlib import Path


def _numba_cache_dir() -> str:
    h = hashlib.sha256()
    root = Path(__file__).parent
    for p in sorted(root.rglob("*.py")):
        h.update(p.relative_to(root).as_posix().encode())
        h.update(p.read_bytes())
    base = Path(os.environ.get("SAARCOR_CACHE", Path.home() / ".cache" / "saarcor"))
    return str(base / "numba" / h.hexdigest()[:16])


if "SAARCOR_NUMBA_CACHE_FIXED" not in os.environ:
    os.environ["NUMBA_CACHE_DIR"] = _numba_cache_dir()
    import sys
    if "numba" in sys.modules:                     # imported earlier: make it re-read the dir
        from numba.core import config as _cfg
        _cfg.reload_config()
