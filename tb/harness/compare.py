"""RTC results and counters against the golden model, whatever simulated the RTC.

The Amaranth-simulator testbenches (``tb/units/rtc.py``), the Verilator frame (``tb/harness/verilator.py``)
and any other simulation of an RTC hand their ``RayResult`` s here as arrays (packet, lane, tri,
t, u, v per result, in any order) and their counters as a dict:

* :func:`expected`: the model's :class:`model.rtc.Hits` as the RTC reports them (the triangle's
  index in the memory image, a miss as all ones; t, u, v as bit patterns of the configured FP
  format).
* :func:`hits_of`: the inverse of :func:`expected`: results by ray -> :class:`model.rtc.Hits`
  (scene-order triangle ids, float32 carriers), the golden model's own result format.
* :func:`results_by_ray`: result records -> one value per ray, by ray id
  (``rays.pk_start[packet] + lane``); a result that is not a ray of the input, a ray reported
  twice and a ray never reported raise :class:`ResultError`. :func:`results_by_id` does the
  same for the chip's records, whose id is (eye packet and lane, depth, sub).
* :func:`result_mismatches`: every (ray, field, rtl, model) that differs, bit for bit.
* :func:`counter_mismatches`: the RTC counters of :data:`COMPARED` against the model's totals.
* :func:`describe`: the first mismatches in words, for an assertion message.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from model.config import Config

__all__ = ["FIELDS", "MISS", "COMPARED", "ResultError", "expected", "hits_of", "results_by_ray",
           "record_fields", "results_by_id", "ray_ids", "result_mismatches", "counter_mismatches", "describe"]

FIELDS = ("tri", "t", "u", "v")
MISS = (1 << 32) - 1            # the RTC's triangle id of a ray that hit nothing

# RTC counter -> model counter (must be equal)
COMPARED = {"trav_ops": "trav_ops", "trav_steps": "trav_steps", "node_reads": "node_reads",
            "leaf_reqs": "leaf_visits", "passes": "passes", "pushes": "pushes",
            "list_ops": "list_ops", "list_reads": "list_reads", "int_ops": "int_ops",
            "int_tris": "int_steps"}


class ResultError(AssertionError):
    """The RTC reported a result for no ray of the input, a ray twice, or not every ray."""


def expected(hits, cfg: Config, image) -> dict[str, np.ndarray]:
    """The model's hits as the RTC reports them: ``{field: int64 array per ray}`` (the hit
    triangle by its index in ``image``)."""
    tri = image.tri_index(hits.tri)
    want = {"tri": np.where(tri < 0, MISS, tri)}
    for f in FIELDS[1:]:
        want[f] = cfg.fmt.to_bits(getattr(hits, f)).astype(np.int64)
    return want


def hits_of(got: Mapping[str, np.ndarray], cfg: Config, image):
    """The hardware's results by ray (:func:`results_by_ray`) as :class:`model.rtc.Hits`:
    triangle by scene-order id (-1 for a miss), t, u, v decoded from the format's bits."""
    from model.rtc import Hits
    tri = np.asarray(got["tri"], np.int64)
    tri = image.scene_ids(np.where(tri == MISS, -1, tri))
    return Hits(tri, *(cfg.fmt.from_bits(np.asarray(got[f], np.int64)) for f in FIELDS[1:]))


def results_by_ray(records: Mapping[str, np.ndarray], rays) -> dict[str, np.ndarray]:
    """Order result records by ray id. ``records`` holds equal-length integer arrays
    ``packet``, ``lane`` and each of :data:`FIELDS`; returns ``{field: array over rays}``."""
    n = len(rays)
    packet = np.asarray(records["packet"], np.int64)
    lane = np.asarray(records["lane"], np.int64)
    pk = np.asarray(rays.pk_start, np.int64)
    valid_pk = (packet >= 0) & (packet < rays.n_packets)
    p = np.where(valid_pk, packet, 0)
    ray = pk[p] + lane
    bad = ~valid_pk | (lane < 0) | (ray >= pk[p + 1])
    if bad.any():
        j = int(np.flatnonzero(bad)[0])
        raise ResultError(f"result {j}: packet {packet[j]} lane {lane[j]} is not a ray of the "
                          f"input ({rays.n_packets} packets)")
    return _place(records, ray, n)


def _place(records: Mapping[str, np.ndarray], ray: np.ndarray, n: int) -> dict:
    """``records`` (results for rays ``ray``) as one value per ray 0..n-1; each ray exactly
    once."""
    seen = np.bincount(ray, minlength=n)
    if (seen != 1).any():
        r = int(np.flatnonzero(seen != 1)[0])
        raise ResultError(f"ray {r} reported {seen[r]} times ({(seen == 0).sum()} rays missing, "
                          f"{(seen > 1).sum()} reported more than once)")
    got = {}
    for f in FIELDS:
        got[f] = np.empty(n, np.int64)
        got[f][ray] = np.asarray(records[f], np.int64)
    return got


def ray_ids(eye: np.ndarray, depth: np.ndarray, sub: np.ndarray, path=0) -> np.ndarray:
    """One integer per ray from its id: eye ray index, path (< 2**15: bit i, the ancestor of
    depth i + 1 is a refracted ray), depth (< 16), sub (< 16: 0 eye, reflection or refracted
    ray, 1 + l shadow ray of light l)."""
    e = np.asarray(eye, np.int64) << 15 | np.asarray(path, np.int64)
    return (e * 16 + np.asarray(depth, np.int64)) * 16 + np.asarray(sub, np.int64)


def record_fields(layout) -> list[tuple[str, int, int]]:
    """``(name, offset, width)`` of every field of a ``lib.data`` record layout, the elements of
    an array field as ``name0``, ``name1``, ... (each at most 32 bits: ``tb.harness.verilator._field``
    reads them)."""
    from amaranth.hdl import Shape
    from amaranth.lib import data
    out = []
    for name, fld in layout:
        if isinstance(fld.shape, data.ArrayLayout):
            ew = Shape.cast(fld.shape.elem_shape).width
            out += [(f"{name}{i}", fld.offset + i * ew, ew) for i in range(fld.shape.length)]
        else:
            out.append((name, fld.offset, fld.width))
    return out


def results_by_id(records: Mapping[str, np.ndarray], rays, eye_pk_start) -> dict:
    """Order the chip's result records by ray: ``records`` holds ``packet`` and ``lane`` (of
    the ray's eye ray), ``depth``, ``sub`` (and ``path``, with refraction) and each of
    :data:`FIELDS`; ``rays`` every ray of
    the frame with its id (``Rays.eye``, ``depth``, ``light``); ``eye_pk_start`` the eye
    rays' packet starts. Unknown, repeated and missing rays raise :class:`ResultError`."""
    pk = np.asarray(eye_pk_start, np.int64)
    packet = np.asarray(records["packet"], np.int64)
    lane = np.asarray(records["lane"], np.int64)
    ok = (packet >= 0) & (packet < len(pk) - 1)
    p = np.where(ok, packet, 0)
    eye = pk[p] + lane
    ok &= (lane >= 0) & (eye < pk[p + 1])
    got_id = ray_ids(eye, records["depth"], records["sub"], records.get("path", 0))
    want_id = ray_ids(rays.eye, rays.depth, np.asarray(rays.light, np.int64) + 1, rays.path)
    order = np.argsort(want_id, kind="stable")
    pos = np.searchsorted(want_id[order], got_id)
    pos = np.minimum(pos, len(order) - 1) if len(order) else pos
    found = ok & (len(order) > 0)
    if len(order):
        found &= want_id[order][pos] == got_id
    if not found.all():
        j = int(np.flatnonzero(~found)[0])
        raise ResultError(f"result {j}: eye packet {packet[j]} lane {lane[j]} depth "
                          f"{records['depth'][j]} sub {records['sub'][j]} is no ray of the "
                          f"frame ({len(rays)} rays)")
    return _place(records, order[pos], len(rays))


def result_mismatches(got: Mapping[str, np.ndarray],
                      want: Mapping[str, np.ndarray]) -> list[tuple[int, str, int, int]]:
    """``(ray, field, rtl, model)`` for every field of every ray whose bits differ, by ray."""
    out = []
    differ = np.any([np.asarray(got[f]) != np.asarray(want[f]) for f in FIELDS], axis=0)
    for r in np.flatnonzero(differ):
        for f in FIELDS:
            if got[f][r] != want[f][r]:
                out.append((int(r), f, int(got[f][r]), int(want[f][r])))
    return out


def counter_mismatches(counters: Mapping[str, int], model: Mapping[str, int]) -> dict:
    """``{rtc counter: (rtc, model)}`` for every counter of :data:`COMPARED` that differs."""
    return {k: (counters[k], model[v]) for k, v in COMPARED.items() if counters[k] != model[v]}


def describe(mismatches: list, counters: dict | None = None, first: int = 10,
             rays=None) -> str:
    """The first ``first`` result mismatches (and any counter mismatch) as text; with
    ``rays`` (:class:`model.raygen.Rays`) each ray's pixel, kind and packet too."""
    from model.raykind import RayKind
    lines = [f"{len(mismatches)} result mismatches"]
    for r, f, a, b in mismatches[:first]:
        if f == "colour":            # a pixel's colour sum: 3 x 24-bit channels, red lowest
            ch = lambda v: tuple((v >> (24 * c)) & 0xFFFFFF for c in range(3))  # noqa: E731
            lines.append(f"  pixel {r}: colour RTL {ch(a)}, model {ch(b)} (fixed point, "
                         "2**-16 units)")
            continue
        where = ""
        if rays is not None:
            pk = int(np.searchsorted(rays.pk_start, r, side="right") - 1)
            where = (f" (pixel {int(rays.pixel[r])}, {RayKind(int(rays.kind[r])).label}, "
                     f"packet {pk} lane {r - int(rays.pk_start[pk])})")
        lines.append(f"  ray {r}{where}: {f} RTL {a:#x}, model {b:#x}")
    if counters:
        lines.append(f"counters differ (rtc, model): {counters}")
    return "\n".join(lines)
