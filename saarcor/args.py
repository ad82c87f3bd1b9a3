"""The command line's shared parts, one definition each: the configuration options (one per
:class:`~model.config.Config` field, plus ``--fmt``), ``--scene``, ``--res``, ``--backend``,
``--out``, the FP format parsers. Every ``saarcor`` command builds its parser from these.

One spelling per concept, in every command:

* ``--scene PATH``: a scene, a ``.toml`` file (docs/scenes.md) or a bare mesh; a command that
  takes several repeats the option (``--scene a.toml --scene b.obj``).
* ``--res WxH``: the image in pixels.
* ``--backend verilator|amaranth``: the simulator (the cocotb bench's are icarus|verilator).
* ``--mem-latency N``: memory latency in cycles (the Config field); ``--fp-latency N``: the
  pipeline latency of an ``fp_*`` top.
* ``--trace FILE``: a waveform (an address stream is ``--addr-trace``).
* ``--fmt EeMm``: one FP format (``E8M23``); ``--formats`` a comma list of them.
* ``--out DIR``: the output directory; a single file is named by what it holds (``--json
  FILE``, ``--table FILE``); ``--keep DIR`` keeps a tool's intermediate files; ``--kd-cache
  DIR`` the kd-tree cache, ``--build-dir DIR`` the Verilator binaries.

Several values: a path option repeats (paths may hold commas), a list of short tokens is one
comma list (``--formats E8M23,E8M16``, ``--thread-counts 1,2,4``).

Default resolutions, one per purpose; a command's help names the constant it uses, and a
command with another default says why:

* :data:`RES_QUICK` 128x96: a quick check, a frame through the simulated chip in a minute or so
  (``saarcor sim``, ``make sim``, ``bench simspeed``, ``bench skipping``, the ladder's small
  configurations);
* :data:`RES_BENCH` 256x192: benchmarks and golden-model images (``saarcor render``, ``bench
  chip``, ``bench memory``, the ladder's standard chip);
* :data:`RES_PAPER` 1024x768: the paper's operating point (``bench model``).
"""
from __future__ import annotations

import argparse
import dataclasses
import re

from model.config import Config, ConfigError, field_help
from model.fp import FPFormat

__all__ = ["resolve_scene", "parse_bool", "RES_QUICK", "RES_BENCH", "RES_PAPER", "SCENE", "parse_res", "parse_fmt",
           "parse_formats", "add_config_args", "config_from_args", "config_and_res",
           "res_from_args", "add_scene_arg", "add_res_arg", "add_out_arg", "add_kd_cache_arg",
           "add_backend_arg", "add_formats_arg"]

RES_QUICK = "128x96"
"""Quick checks: a frame through the simulated chip in a minute or so."""
RES_BENCH = "256x192"
"""Benchmarks and golden-model images."""
RES_PAPER = "1024x768"
"""The paper's operating point (its frame rates are for 1024x768)."""
_RES_NAMES = {RES_QUICK: "RES_QUICK, quick checks",
              RES_BENCH: "RES_BENCH, benchmarks and golden-model images",
              RES_PAPER: "RES_PAPER, the paper's operating point"}

MAX_RES = (1 << 16) - 1
"""The widest and tallest image: the RGS counts samples in 16 bits (``model.config.COORD_BITS``;
with ``oversampling`` n, the image is at most ``MAX_RES // n`` pixels a side)."""

MAX_PIXELS = 16384 * 16384
"""The most pixels a frame may have: the host keeps every ray and hit in memory."""

SCENE = "scenes/cornell.toml"
"""The default scene of the commands that render one frame for a quick look."""

SCENE_HELP = ("a scene: a .toml file (docs/scenes.md) or a bare mesh (.obj .ply .stl .glb .off; "
              "the camera frames it, one light)")


def resolve_scene(path: str, prog: str) -> str:
    """``path`` as given when it exists; a relative path that does not exist here but does in
    the repository (the default ``scenes/cornell.toml`` run from another folder) resolves
    there; otherwise raises ``SceneError`` naming the path and the shipped scenes (``saarcor``
    prints it on one line, exit status 2)."""
    from pathlib import Path
    p = Path(path)
    if p.exists():
        return str(path)
    repo = Path(__file__).resolve().parents[1]
    if not p.is_absolute() and (repo / p).exists():
        return str(repo / p)
    shipped = sorted(x.name for x in (repo / "scenes").glob("*.toml"))
    from model.scene_data import SceneError
    raise SceneError(f"scene {path!r} not found (shipped scenes in the repository's "
                     f"scenes/: {', '.join(shipped)})")


def summary(doc: str) -> str:
    """A module docstring's first paragraph on one line: a command's ``--help`` description."""
    return " ".join(doc.strip().split("\n\n")[0].split())


def parse_res(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in str(text).lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--res {text!r}: expected WIDTHxHEIGHT, e.g. 256x192")
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"--res {text!r}: width and height must be >= 1")
    if w > MAX_RES or h > MAX_RES:
        raise argparse.ArgumentTypeError(
            f"--res {text!r}: at most {MAX_RES}x{MAX_RES} pixels (the RGS counts pixels and "
            f"samples in 16 bits; with oversampling n, at most {MAX_RES}/n pixels a side)")
    if w * h > MAX_PIXELS:
        raise argparse.ArgumentTypeError(
            f"--res {text!r}: {w * h:,} pixels; at most {MAX_PIXELS:,} (16384x16384): a ray "
            "takes about 60 bytes on the host, so a frame beyond that needs more than 16 GB")
    return w, h


_TRUE, _FALSE = ("1", "true", "yes", "on"), ("0", "false", "no", "off")


def parse_bool(text: str) -> bool:
    """A boolean option's value, strictly: true/yes/on/1 or false/no/off/0 (any case)."""
    t = str(text).strip().lower()
    if t in _TRUE or t in _FALSE:
        return t in _TRUE
    raise argparse.ArgumentTypeError(f"{text!r} is not a boolean: write true or false "
                                     "(also yes/no, on/off, 1/0)")


def parse_fmt(text: str) -> FPFormat:
    """``E8M16`` -> ``FPFormat(8, 16)``; a value out of range raises ``ValueError``."""
    m = re.fullmatch(r"E(\d+)M(\d+)", str(text).strip())
    if not m:
        raise ConfigError(f"--fmt {text!r}: write the format as E<exp>M<frac>, e.g. E8M23")
    return FPFormat(int(m[1]), int(m[2]))


def parse_formats(text: str) -> list[FPFormat]:
    """A comma list of formats, ``E8M23,E8M16``."""
    try:
        return [parse_fmt(f) for f in str(text).split(",")]
    except ConfigError:
        raise ConfigError(f"--formats {text!r}: write each format as E<exp>M<frac>, "
                          "comma-separated, e.g. E8M23,E8M16") from None
    except ValueError as e:
        raise ConfigError(f"--formats {text!r}: {e}") from None


def add_config_args(ap: argparse.ArgumentParser) -> None:
    """One option per :class:`Config` field (``--trav-cache-kb``), plus ``--fmt``."""
    from model.config import PRESETS
    g = ap.add_argument_group("configuration (model/config.py Config; defaults are Config's)")
    g.add_argument("--preset", choices=list(PRESETS), default=None,
                   help="start from a named configuration, then apply the options below: "
                        "standard (Config's defaults) or paper (the standard chip at the "
                        "paper's cost: the projection triangle test, every RGS slave datapath "
                        "on one pool of 3 adders and 4 multipliers; "
                        "model/config.py PRESETS)")
    g.add_argument("--fmt", help="FP format E<exp>M<frac> (default E8M23, binary32)")
    text = field_help()
    for f in dataclasses.fields(Config):
        if f.name == "fmt":
            continue
        default = getattr(Config(), f.name)
        typ = {bool: parse_bool}.get(type(default), type(default))
        g.add_argument("--" + f.name.replace("_", "-"), dest=f.name, type=typ, default=None,
                       metavar=type(default).__name__.upper(),
                       help=(text[f.name] + f" (default {default})" if f.name in text
                             else f"default {default}").replace("%", "%%"))


def config_from_args(args: argparse.Namespace) -> Config:
    changes = {f.name: getattr(args, f.name) for f in dataclasses.fields(Config)
               if f.name != "fmt" and getattr(args, f.name, None) is not None}
    if args.fmt:
        changes["fmt"] = parse_fmt(args.fmt)
    from model.config import preset
    return preset(getattr(args, "preset", None) or "standard", **changes)


def res_from_args(args: argparse.Namespace, prog: str) -> tuple[int, int]:
    """The ``--res`` width and height; a bad value exits naming it (``prog: ...``)."""
    try:
        return parse_res(args.res)
    except argparse.ArgumentTypeError as e:
        raise SystemExit(f"{prog}: {e}")


def config_and_res(args: argparse.Namespace, prog: str) -> tuple[Config, int, int]:
    """The :class:`Config` (:func:`config_from_args`) and the ``--res`` width and height of a
    command line; a bad value exits naming it (``prog: ...``)."""
    try:
        return (config_from_args(args), *parse_res(args.res))
    except (ConfigError, ValueError, argparse.ArgumentTypeError) as e:
        raise SystemExit(f"{prog}: {e}")


class _Repeat(argparse.Action):
    """``action="append"`` whose default is replaced (not extended) by the values given."""

    def __call__(self, parser, namespace, values, option_string=None):
        have = getattr(namespace, self.dest)
        setattr(namespace, self.dest, [*([] if have is self.default else have), values])


def add_scene_arg(ap: argparse.ArgumentParser, default: str | list[str] | None = SCENE, *,
                  repeat: bool = False, help: str | None = None) -> None:
    """``--scene PATH``; ``repeat``: the option repeats and ``args.scene`` is a list (``default``
    when none is given). ``help`` says what the command does with it; the default is named."""
    text = help or SCENE_HELP
    if repeat:
        default = list(default or [])
        text += ("; repeat for several" +
                 (f" (default {' '.join(default)})" if default else ""))
        ap.add_argument("--scene", action=_Repeat, default=default, metavar="PATH", help=text)
    else:
        ap.add_argument("--scene", default=default, metavar="PATH",
                        help=text + (f" (default {default})" if default else ""))


def add_res_arg(ap: argparse.ArgumentParser, default: str = RES_QUICK,
                why: str | None = None, what: str = "image") -> None:
    """``--res WxH`` (a string; :func:`res_from_args` / :func:`config_and_res` parse it). A
    default other than the three constants needs ``why``."""
    if default in _RES_NAMES:
        note = _RES_NAMES[default] + (f"; {why}" if why else "")
    elif why:
        note = why
    else:
        raise ValueError(f"--res default {default!r}: use RES_QUICK, RES_BENCH or RES_PAPER, "
                         "or say why it differs")
    ap.add_argument("--res", default=default, metavar="WxH",
                    help=f"{what} width x height in pixels (default {default}: {note})")


def add_out_arg(ap: argparse.ArgumentParser, default: str = "build/bench",
                what: str = "output directory") -> None:
    """``--out DIR``."""
    ap.add_argument("--out", default=default, metavar="DIR", help=f"{what} (default {default})")


def add_kd_cache_arg(ap: argparse.ArgumentParser) -> None:
    """``--kd-cache DIR``: where built kd-trees are kept (``default``: the model's cache)."""
    ap.add_argument("--kd-cache", default="default", metavar="DIR",
                    help="kd-tree cache directory (default: the model's, ~/.cache/saarcor/kdtree "
                         "or $SAARCOR_CACHE/kdtree)")


def add_backend_arg(ap: argparse.ArgumentParser, default: str = "verilator",
                    choices: tuple[str, ...] = ("verilator", "amaranth"),
                    help: str | None = None) -> None:
    """``--backend``: which simulator."""
    ap.add_argument("--backend", default=default, choices=choices,
                    help=(help or "simulator: verilator (compiled once per configuration, "
                                  "fast) or amaranth (Amaranth's Python simulator: tiny frames "
                                  "only)") + f"; default {default}")


def add_formats_arg(ap: argparse.ArgumentParser, default: str, what: str = "FP formats") -> None:
    """``--formats E8M23,E8M16``: several FP formats (:func:`parse_formats`)."""
    ap.add_argument("--formats", default=default, metavar="EeMm,...",
                    help=f"{what}, comma-separated E<exp>M<frac> (default {default})")
