"""Where a placed design congests: router2's congestion per tile beside the unit placed there.

nextpnr's router2 writes, with ``--router2-heatmap PREFIX``, four CSVs per routing iteration N.
Two are read here: ``PREFIX_congestion_by_coordinate_N.csv`` (one row per tile column x, one
value per tile row y: the sum, over the tile's wires used by more than one net, of the nets on
each) and ``PREFIX_congestion_by_net_N.csv`` (``net,excess``: over the net's overused wires, the
nets beyond the first). A placed design (``placed.json``, ``saarcor fpga --place-only``)
names each cell's site in its ``NEXTPNR_BEL`` attribute (``X12/Y34/SLICEA``); cell and net names
carry the path of the unit they came from (``dut.rtcmi.cache_int.queue.q_wait_TRELLIS_FF_Q``).
:func:`unit_of` maps a name to its unit, :func:`tile_units` counts each unit's cells per tile,
:func:`attribute` splits the congestion of every tile between the units in proportion to their
cells there, :func:`net_units` sums the nets' excess by unit, and :func:`plot` draws the two maps
side by side (``saarcor fpga --congestion LABEL``).
"""
from __future__ import annotations

import json
import re
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

__all__ = ["unit_of", "read_heatmap", "heatmaps", "tile_units", "attribute", "net_units", "plot",
           "report"]

# units split one level deeper than the default depth (the intersection unit's FP datapath is
# most of the RTC: it is shown apart from the unit's control)
SPLIT = ("rtc.int.pipe",)
_BEL = re.compile(r"^X(\d+)/Y(\d+)/")
# the site types of a placed ECP5 design that hold logic, flip-flops, RAM and DSPs (nextpnr packs
# LUT4s and carry cells into TRELLIS_COMB)
KINDS = ("TRELLIS_COMB", "TRELLIS_FF", "TRELLIS_RAMW", "MULT18X18D", "DP16KD")
MAP_UNITS = 9            # units in colour on the unit map (the largest by cells; the rest grey)


def _unit() -> dict:
    """A unit's entry before any of its cells or nets is counted."""
    return {"cells": 0, "tiles": 0, "overuse": 0.0, "share": 0.0, "cell_share": 0.0}


def unit_of(cell: str, depth: int = 2, split: tuple[str, ...] = SPLIT) -> str:
    """The unit of a flattened cell name: the module path below the wrapped design (``dut``)
    cut to ``depth`` modules (``dut.rtcmi.cache_int.queue.q_wait_TRELLIS_FF_Q`` ->
    ``rtcmi.cache_int``), one module deeper where that path starts with one of ``split``.
    A name's last component is a signal, and a component with ``$`` starts Yosys' own
    suffixes, so neither counts as a module. Cells outside ``dut`` (the pin wrapper, nets
    Yosys named itself) are ``other``; cells of the design's own top are ``top``."""
    parts = cell.lstrip("\\").split(".")
    if parts[0] != "dut":
        return "other"
    mods = []
    for p in parts[1:-1]:
        if "$" in p:
            break
        mods.append(p)
    if not mods:
        return "top"
    if ".".join(mods[:depth + 1]) in split:
        return ".".join(mods[:depth + 1])
    return ".".join(mods[:depth])


def read_heatmap(path: Path) -> np.ndarray:
    """One ``congestion_by_coordinate`` CSV (a row per tile column x, trailing commas) as an
    array indexed [y, x]."""
    rows = [[int(v) for v in line.strip().rstrip(",").split(",") if v.strip() != ""]
            for line in Path(path).read_text().splitlines() if line.strip()]
    if not rows:
        raise ValueError(f"{path}: empty heatmap")
    height = max(map(len, rows))
    return np.array([r + [0] * (height - len(r)) for r in rows], dtype=np.int64).T


def heatmaps(wd: Path, kind: str = "coordinate") -> dict[int, Path]:
    """The router2 heatmap CSVs of ``kind`` (``coordinate`` or ``net``) in run directory
    ``wd``, by iteration (``*congestion_by_<kind>_N.csv``)."""
    found = {}
    for f in Path(wd).glob(f"*congestion_by_{kind}_*.csv"):
        m = re.search(rf"congestion_by_{kind}_(\d+)\.csv$", f.name)
        if m:
            found[int(m.group(1))] = f
    return dict(sorted(found.items()))


def net_units(path: Path, depth: int = 2) -> Counter:
    """A ``congestion_by_net`` CSV summed by the unit of each net's name."""
    out = Counter()
    for line in Path(path).read_text().splitlines():
        name, _, value = line.rpartition(",")
        if name and value.strip().lstrip("-").isdigit():
            out[unit_of(name, depth)] += int(value)
    return out


def tile_units(placed: dict, depth: int = 2) -> dict[tuple[int, int], Counter]:
    """Cells per tile and unit of a placed nextpnr design: {(x, y): Counter(unit -> cells)},
    cells of the site types ``KINDS`` only. nextpnr writes the placed design as one module."""
    (mod,) = placed["modules"].values()
    tiles: dict[tuple[int, int], Counter] = defaultdict(Counter)
    for name, cell in mod["cells"].items():
        if cell.get("type") not in KINDS:
            continue
        bel = cell.get("attributes", {}).get("NEXTPNR_BEL", "")
        m = _BEL.match(bel)
        if m:
            tiles[(int(m.group(1)), int(m.group(2)))][unit_of(name, depth)] += 1
    return dict(tiles)


def attribute(heat: np.ndarray, tiles: dict[tuple[int, int], Counter]) -> dict[str, dict]:
    """Each unit's share of the congestion: every tile's congestion split between the units by
    their cells in that tile. Returns {unit: {"cells", "tiles", "overuse", "share",
    "cell_share"}} (share: of the congestion in tiles with cells; cell_share: of the cells, so
    share / cell_share above 1 marks a unit placed where the routing is more crowded than
    average), largest first."""
    out: dict[str, dict] = defaultdict(_unit)
    total = 0.0
    for (x, y), units in tiles.items():
        n = sum(units.values())
        over = float(heat[y, x]) if y < heat.shape[0] and x < heat.shape[1] else 0.0
        total += over
        for u, k in units.items():
            out[u]["cells"] += k
            out[u]["tiles"] += 1
            out[u]["overuse"] += over * k / n
    cells = sum(u["cells"] for u in out.values())
    for u in out.values():
        u["share"] = u["overuse"] / total if total else 0.0
        u["cell_share"] = u["cells"] / cells if cells else 0.0
    return dict(sorted(out.items(), key=lambda kv: -kv[1]["overuse"]))


def plot(heat: np.ndarray, tiles: dict[tuple[int, int], Counter], names: list[str],
         title: str, png: Path) -> None:
    """Two maps of the die side by side, written to ``png``: router2's congestion per tile
    and the unit with most cells in each tile (each of ``names`` in its colour, other units
    grey)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap, LogNorm

    grid = np.full(heat.shape, np.nan)
    for (x, y), units in tiles.items():
        if y < grid.shape[0] and x < grid.shape[1]:
            u = units.most_common(1)[0][0]
            grid[y, x] = names.index(u) if u in names else len(names)
    fig, (a, b) = plt.subplots(1, 2, figsize=(14, 6.5), constrained_layout=True)
    im = a.imshow(np.where(heat > 0, heat, np.nan), origin="upper", cmap="inferno_r",
                  norm=LogNorm(vmin=1, vmax=max(2, int(heat.max()))), interpolation="nearest")
    a.set_title(f"nets on overused wires, per tile ({int(heat.sum())} in all)")
    fig.colorbar(im, ax=a, shrink=0.8)
    colours = list(plt.get_cmap("tab10").colors[:len(names)]) + [(0.7, 0.7, 0.7)]
    b.imshow(grid, origin="upper", cmap=ListedColormap(colours), vmin=-0.5,
             vmax=len(colours) - 0.5, interpolation="nearest")
    b.set_title("unit with most cells in each tile")
    b.legend(handles=[plt.Rectangle((0, 0), 1, 1, color=c) for c in colours],
             labels=names + ["others"], loc="upper left", bbox_to_anchor=(1.0, 1.0),
             fontsize=8)
    for ax in (a, b):
        ax.set_xlabel("tile x")
        ax.set_ylabel("tile y")
    fig.suptitle(title)
    fig.savefig(png, dpi=110)
    plt.close(fig)


def report(wd: Path, iteration: int | None = None) -> dict:
    """Congestion of run directory ``wd`` (a ``--place-only`` run's ``placed.json`` and the
    heatmaps of a router2 ``--route-only`` run of it copied or written there): the iteration
    with the least congestion (the coordinate map's sum) unless ``iteration`` is given.
    Writes ``congestion.png`` and ``congestion.json`` in ``wd`` and returns the JSON's
    content."""
    wd = Path(wd)
    maps = heatmaps(wd)
    if not maps:
        raise SystemExit(f"saarcor.flows.fpga: no router2 heatmaps (*congestion_by_coordinate_N.csv) in "
                         f"{wd}; route with --router router2 --pnr-arg=--router2-heatmap "
                         "--pnr-arg=heatmap")
    placed = wd / "placed.json"
    if not placed.exists():
        raise SystemExit(f"saarcor.flows.fpga: {placed} does not exist; place with --place-only first")
    heats = {i: read_heatmap(f) for i, f in maps.items()}
    if iteration is None:
        iteration = min(heats, key=lambda i: (heats[i].sum(), i))
    elif iteration not in heats:
        raise SystemExit(f"saarcor.flows.fpga: no heatmap of iteration {iteration} in {wd} "
                         f"(iterations {min(heats)}..{max(heats)})")
    heat = heats[iteration]
    tiles = tile_units(json.loads(placed.read_text()))
    units = attribute(heat, tiles)
    by_net = heatmaps(wd, "net")
    if iteration in by_net:
        nets = net_units(by_net[iteration])
        total = sum(nets.values())
        for u, v in nets.items():
            units.setdefault(u, _unit()).update(net_excess=v, net_share=v / total if total else 0.0)
    res = {"iteration": iteration,
           "overuse_by_iteration": {i: int(h.sum()) for i, h in heats.items()},
           "overused_tiles": int((heat > 0).sum()), "placed_tiles": len(tiles),
           "units": units}
    (wd / "congestion.json").write_text(json.dumps(res, indent=1) + "\n")
    by_cells = sorted(units, key=lambda u: -units[u]["cells"])[:MAP_UNITS]
    plot(heat, tiles, by_cells, f"{wd.name}: router2 iteration {iteration}",
         wd / "congestion.png")
    return res
