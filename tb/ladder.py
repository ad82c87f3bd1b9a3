"""The simulation ladder: a frame's cycles from five models of the chip, fastest first.

* ``model``: the golden model alone (``model.rtc.trace``): op counts, no timing;
* ``estimate``: ``model.timing``: a discrete-event model of the chip's resources replaying the
  golden model's event log (an estimate);
* ``sampled``: the RTL in Verilator on a few bands of tile rows (:func:`run_band`: the same
  camera, a sub-image through the frame registers), extrapolated to the frame with the
  estimate as control variate (:func:`sampled_frame`; an estimate);
* ``rtl``: the whole frame in Verilator (``tb.chip.run_chip_frame``, exact);
* ``amaranth``: the whole frame in Amaranth's simulator (``tb.chip.run_chip``, exact, tiny
  frames only).

A band is rows ``[y0, y0 + rows)`` of the full image: the host writes the full frame's camera
with its corner moved down by ``y0`` pixel steps (float64, then quantized, as a driver
would), the full width and ``rows`` as the height. The chip needs no change; the band's rays
are the golden model's eye rays for those registers (bit for bit what the chip makes), which
may differ from the full frame's rays of the same pixels in the last bits of the direction.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from model.config import Config

__all__ = ["band_registers", "band_rays", "run_band", "choose_bands", "SampledRun",
           "sampled_frame"]


def _band_camera(cfg: Config, camera, width: int, height: int, y0: int):
    """The camera registers (pos, corner, dx, dy; format values) of a band starting at
    sample row ``y0`` of the full ``width x height`` frame."""
    from model.raygen import camera_basis
    n = cfg.oversampling
    pos, corner, dx, dy = camera_basis(camera.position, camera.look_at, camera.up,
                                       camera.fov_y, width * n, height * n)
    corner = corner + y0 * dy
    return tuple(cfg.fmt.quantize(v) for v in (pos, corner, dx, dy))


def band_registers(cfg: Config, image, camera, width: int, height: int, y0: int,
                   rows: int) -> dict:
    """The chip's host registers for sample rows ``[y0, y0 + rows)`` of the frame (as
    ``tb.chip.frame_registers`` makes them for a whole frame)."""
    fmt, n = cfg.fmt, cfg.oversampling
    if n != 1:
        raise ValueError("bands of oversampled frames are not supported (oversampling=1)")
    pos, corner, dx, dy = _band_camera(cfg, camera, width, height, y0)
    bits = lambda v: [int(b) for b in fmt.to_bits(np.asarray(v, np.float32))]  # noqa: E731
    return {
        "node_base": image.node_base, "list_base": image.list_base,
        "tri_base": image.tri_base, "root": image.root,
        "box_lo": bits(image.bounds[0]), "box_hi": bits(image.bounds[1]),
        "pos": bits(pos), "corner": bits(corner), "dx": bits(dx), "dy": bits(dy),
        "width": width, "height": rows,
        "tiles_x": -(-width // cfg.tile_w), "tiles_y": -(-rows // cfg.tile_h),
        "n_rays": width * rows,
    }


def band_rays(cfg: Config, camera, width: int, height: int, y0: int, rows: int):
    """The golden model's eye rays of a band (``model.raygen.Rays``), as the chip makes them
    from :func:`band_registers`."""
    from model.raygen import Rays
    from model.rgs import eye_packets, packet_count
    pos, corner, dx, dy = _band_camera(cfg, camera, width, height, y0)
    tw, th = cfg.tile_w, cfg.tile_h
    total = width * rows
    d = np.empty((total, 3), np.float32)
    pixel = np.empty(total, np.int32)
    pk = np.empty(packet_count(width, rows, tw, th) + 1, np.int64)
    eye_packets(width, rows, tw, th, 1, width, corner, dx, dy, d, pixel, pk, *cfg.fmt.em)
    org = np.broadcast_to(pos, d.shape).astype(np.float32)
    return Rays(org, d, np.full(total, np.inf, np.float32), np.zeros(total, np.uint8),
                pixel, pk)


def run_band(cfg: Config, image, camera, width: int, height: int, y0: int, rows: int, *,
             build_root=None, build=None, check: bool = True, log=None,
             max_cycles: int = 100_000_000):
    """Sample rows ``[y0, y0 + rows)`` of the frame through the whole chip in Verilator (the
    binary of ``tb.chip.chip_build``, or ``build``); every ray checked against the golden
    model when ``check``. Returns a ``tb.chip.ChipRun`` (``eye`` = the band's rays)."""
    import sys

    from model.rtc import trace
    from rtl.rtc_streams import RayResult

    from .chip import _finish, chip_blocks, chip_build, stuck
    from .chip_frame import chip_counter_names
    from .verilator import FrameError, _field, run_binary, write_blocks
    log = sys.stderr if log is None else log
    regs = band_registers(cfg, image, camera, width, height, y0, rows)
    rays = band_rays(cfg, camera, width, height, y0, rows)
    b = build or chip_build(cfg, len(image.data), build_root=build_root, log=log)
    names = chip_counter_names(cfg)
    golden = None
    if check:
        from concurrent.futures import ThreadPoolExecutor
        pool = ThreadPoolExecutor(max_workers=1)
        golden = pool.submit(trace, image, rays, cfg)
        pool.shutdown(wait=False)
    out = run_binary(b, lambda f: write_blocks(f, chip_blocks(cfg, image, regs)), cfg,
                     len(rays), max_cycles=max_cycles, progress=False, log=log,
                     desc="chip band (Verilator)", names=names, allow_limit=True)
    lay = RayResult(cfg)
    records = {name: _field(out.results, fld.offset, fld.width) for name, fld in lay}
    if out.status == 2:
        raise FrameError(stuck(cfg, rays, records, out.counters, max_cycles))
    if check:
        run = _finish(cfg, image, rays, records, out.cycles, out.seconds, out.counters,
                      golden=golden.result())
    else:
        from .chip import ChipRun
        run = ChipRun(out.cycles, out.seconds, len(rays), {}, {}, eye=rays)
    run.build = b
    return run


def choose_bands(cfg: Config, height: int, fraction: float, *, bands: int = 2) -> list:
    """``(y0, rows)`` of ``bands`` bands of whole tile rows, together about ``fraction`` of
    the frame's rows (at least one tile row each), spread evenly over the frame (the centre of
    band i at (i + 0.5) / bands of the height)."""
    th = cfg.tile_h
    tile_rows = -(-height // th)
    per = max(1, int(round(fraction * tile_rows / bands)))
    bands = max(1, min(bands, tile_rows // per))
    out = []
    for i in range(bands):
        c = (i + 0.5) * tile_rows / bands
        r0 = int(min(max(0, round(c - per / 2)), tile_rows - per))
        y0 = r0 * th
        out.append((y0, min(per * th, height - y0)))
    return out


@dataclass
class SampledRun:
    cycles: float                 # the estimate for the frame (an estimate)
    plain_cycles: float           # without the control variate: band cycles x work ratio
    estimate_cycles: int          # the discrete-event estimate of the whole frame
    bands: list                   # per band: y0, rows, rtl cycles, estimated cycles, seconds
    seconds: float                # wall time of the whole method
    rays_checked: int
    mismatches: int


def sampled_frame(cfg: Config, image, camera, width: int, height: int, *, fraction=0.08,
                  bands: int = 2, build_root=None, build=None, events=None, rays=None,
                  check: bool = True, log=None) -> SampledRun:
    """The frame's cycles from the RTL on a few bands (:func:`choose_bands`), extrapolated:
    ``estimate(frame) x sum(rtl(band)) / sum(estimate(band))`` — the discrete-event estimate
    (``model.timing``) corrected by its error on the bands, each band simulated from cold
    caches in both. ``plain_cycles``: the band cycles scaled by the frame's int-ops + trav-ops
    over the bands' (no estimator). ``events``/``rays``: the full frame's event log and eye
    rays if already at hand."""
    from model.raygen import eye_rays
    from model.rtc import trace
    from model.timing import estimate_events, work_of
    t0 = time.perf_counter()
    if rays is None:
        rays = eye_rays(camera, width, height, cfg)
    if events is None:
        _, _, events = trace(image, rays, cfg, record=True)
    full = estimate_events(cfg, work_of(events, image, rays.n_packets, np.diff(rays.pk_start)))
    work_full = _work(events)
    rows_out = []
    rtl_sum = est_sum = work_sum = 0.0
    n_checked = n_bad = 0
    for y0, rows in choose_bands(cfg, height, fraction, bands=bands):
        tb = time.perf_counter()
        run = run_band(cfg, image, camera, width, height, y0, rows, build_root=build_root,
                       build=build, check=check, log=log)
        build = run.build
        _, _, ev = trace(image, run.eye, cfg, record=True)
        est = estimate_events(cfg, work_of(ev, image, run.eye.n_packets,
                                           np.diff(run.eye.pk_start)))
        rtl_sum += run.cycles
        est_sum += est["cycles"]
        work_sum += _work(ev)
        n_checked += run.rays if check else 0
        n_bad += len(run.mismatches)
        rows_out.append({"y0": y0, "rows": rows, "rtl_cycles": run.cycles,
                         "estimate_cycles": est["cycles"],
                         "seconds": round(time.perf_counter() - tb, 3)})
    cycles = full["cycles"] * rtl_sum / max(1.0, est_sum)
    plain = rtl_sum * work_full / max(1.0, work_sum)
    return SampledRun(cycles, plain, full["cycles"], rows_out, time.perf_counter() - t0,
                      n_checked, n_bad)


def _work(events) -> float:
    """A frame's work for plain extrapolation: trav-ops + int-ops of the event log."""
    from model.events import EV_INT, EV_NODE
    from model.lanes import popcount_array
    node = events[events["kind"] == EV_NODE]
    return float(popcount_array(node["mask"]).sum() + (events["kind"] == EV_INT).sum())
