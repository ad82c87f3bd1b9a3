"""The command line's shared parts, one definition each: the configuration options (one per
:class:`~model.config.Config` field, plus ``--fmt``), the resolution ``--res WxH`` and the FP
format ``--fmt EeMm``. Every ``saarcor`` command builds its parser from these."""
from __future__ import annotations

import argparse
import dataclasses
import re

from model.config import Config, ConfigError, field_help
from model.fp import FPFormat

__all__ = ["parse_res", "parse_fmt", "add_config_args", "config_from_args", "config_and_res"]


def parse_res(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--res {text!r}: expected WIDTHxHEIGHT, e.g. 256x192")
    if w < 1 or h < 1 or w * h > 16384 * 16384:
        raise argparse.ArgumentTypeError(f"--res {text!r}: width and height must be >= 1")
    return w, h


def parse_fmt(text: str) -> FPFormat:
    m = re.fullmatch(r"E(\d+)M(\d+)", text)
    if not m:
        raise ConfigError(f"--fmt {text!r}: write the format as E<exp>M<frac>, e.g. E8M23")
    return FPFormat(int(m[1]), int(m[2]))


def add_config_args(ap: argparse.ArgumentParser) -> None:
    """One option per :class:`Config` field (``--trav-cache-kb``), plus ``--fmt``."""
    g = ap.add_argument_group("configuration (model/config.py Config; defaults are Config's)")
    g.add_argument("--fmt", help="FP format E<exp>M<frac> (default E8M23, binary32)")
    text = field_help()
    for f in dataclasses.fields(Config):
        if f.name == "fmt":
            continue
        default = getattr(Config(), f.name)
        typ = {bool: lambda s: s.lower() in ("1", "true", "yes", "on")}.get(type(default),
                                                                            type(default))
        g.add_argument("--" + f.name.replace("_", "-"), dest=f.name, type=typ, default=None,
                       metavar=type(default).__name__.upper(),
                       help=(text[f.name] + f" (default {default})" if f.name in text
                             else f"default {default}").replace("%", "%%"))


def config_from_args(args: argparse.Namespace) -> Config:
    changes = {f.name: getattr(args, f.name) for f in dataclasses.fields(Config)
               if f.name != "fmt" and getattr(args, f.name, None) is not None}
    if args.fmt:
        changes["fmt"] = parse_fmt(args.fmt)
    return Config(**changes)


def config_and_res(args: argparse.Namespace, prog: str) -> tuple[Config, int, int]:
    """The :class:`Config` (:func:`config_from_args`) and the ``--res`` width and height of a
    command line; a bad value exits naming it (``prog: ...``)."""
    try:
        return (config_from_args(args), *parse_res(args.res))
    except (ConfigError, argparse.ArgumentTypeError) as e:
        raise SystemExit(f"{prog}: {e}")
