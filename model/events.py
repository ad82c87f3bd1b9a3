"""The golden model's event log: every unit's input and output, one row per event.

The compiled tracer appends raw rows ``(kind, packet, a, b, c, d, e, f)`` (int64, see
:func:`record`); :func:`decode` turns them into a structured array with a named field for every
quantity (``EVENT_DTYPE``), which is what ``model.rtc.trace(..., record=True)`` returns and
what the testbenches read. Fields an event kind does not have are 0.

====================  ================================================================
kind                  fields
====================  ================================================================
``EV_NODE`` (0)       traversal at an inner node: octant, node, mask (in), near, far, sp
``EV_LEAF`` (1)       leaf reached (list unit input): octant, node, mask, first, count, sp
``EV_TRI`` (2)        list output / intersection input: octant, tri (index), mask (lanes
                      tested), id (scene-order triangle id)
``EV_INT`` (3)        one int-op: lane, tri, flags (1 edge/det test passed, 2 accepted),
                      t, u, v (binary32 bits)
``EV_RESULT`` (4)     results back in traversal: octant, node (the leaf), mask, terminated, sp
``EV_DONE`` (5)       packet finished: live (mask at start), terminated
====================  ================================================================

Masks are 64-bit lane masks (``uint64``).
"""
from __future__ import annotations

import numba
import numpy as np

EV_NODE, EV_LEAF, EV_TRI, EV_INT, EV_RESULT, EV_DONE = range(6)
RAW_COLUMNS = 8

_MASKS = ("mask", "near", "far", "terminated", "live")
EVENT_DTYPE = np.dtype(
    [("kind", np.int8), ("packet", np.int64), ("octant", np.int8), ("lane", np.int8),
     ("node", np.int64), ("tri", np.int64), ("id", np.int64), ("first", np.int64),
     ("count", np.int64), ("sp", np.int16), ("flags", np.int8),
     ("t", np.uint32), ("u", np.uint32), ("v", np.uint32)]
    + [(name, np.uint64) for name in _MASKS])

# raw column (2..7 = a..f) of each field, per event kind
_COLUMNS = {
    EV_NODE: {"octant": 2, "node": 3, "mask": 4, "near": 5, "far": 6, "sp": 7},
    EV_LEAF: {"octant": 2, "node": 3, "mask": 4, "first": 5, "count": 6, "sp": 7},
    EV_TRI: {"octant": 2, "tri": 3, "mask": 4, "id": 5},
    EV_INT: {"lane": 2, "tri": 3, "flags": 4, "t": 5, "u": 6, "v": 7},
    EV_RESULT: {"octant": 2, "node": 3, "mask": 4, "terminated": 5, "sp": 7},
    EV_DONE: {"live": 4, "terminated": 5},
}


@numba.njit(cache=True)
def record(rec, rec_n, kind, pid, a, b, c, d, e, f):
    """Append a raw event row at ``rec_n[0]`` (counted even when ``rec`` is full)."""
    i = rec_n[0]
    rec_n[0] = i + 1
    if i < rec.shape[0]:
        rec[i, 0] = kind
        rec[i, 1] = pid
        rec[i, 2] = np.int64(a)
        rec[i, 3] = np.int64(b)
        rec[i, 4] = np.int64(c)
        rec[i, 5] = np.int64(d)
        rec[i, 6] = np.int64(e)
        rec[i, 7] = np.int64(f)


def decode(raw: np.ndarray) -> np.ndarray:
    """Raw ``(K, 8)`` int64 rows -> structured array of ``EVENT_DTYPE`` (vectorized)."""
    raw = np.asarray(raw, np.int64).reshape(-1, RAW_COLUMNS)
    out = np.zeros(len(raw), EVENT_DTYPE)
    kind = raw[:, 0]
    out["kind"] = kind
    out["packet"] = raw[:, 1]
    for k, columns in _COLUMNS.items():
        sel = kind == k
        if not sel.any():
            continue
        for name, col in columns.items():
            out[name][sel] = raw[sel, col].astype(EVENT_DTYPE[name], casting="unsafe")
    return out

