"""What the RGS kernels share (``eye.py``, ``secondary.py``, ``texture.py``, ``slave.py``): the
drivers' task size and the float32 constants of the scalar kernels."""
from __future__ import annotations

import numpy as np

CHUNK = 4096           # rows per parallel task of the drivers (scratch arrays made once per task)

_ONE = np.float32(1.0)
_ZERO = np.float32(0.0)
_INF = np.float32(np.inf)
