"""The ``iap-mjx`` command line.

One ``argparse`` tree: :mod:`~iap_mjx.cli.commands` adds the commands over presets and run
directories (``presets``, ``show``, ``train``, ``eval``, ``video``, ``attended``, ``figures``,
``runs``), :mod:`~iap_mjx.cli.reproduce` adds ``reproduce`` with one subcommand per figure, each
command a small function. A new command is a function in one of them and its parser builder,
``_add_<command>``, called from that module's ``add_commands``: an ``add_parser`` call whose
defaults are ``func``, the function, and ``command_parser``, the parser itself, which refuses
unknown options with its own usage. JAX is imported only inside the commands, after :func:`main`
has split the CPU into devices and turned on the compilation cache.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys

from iap_mjx import runtime
from iap_mjx.cli import commands, reproduce


def build_parser() -> argparse.ArgumentParser:
    """The ``iap-mjx`` parser; each command's parser sets ``func`` to its command function and
    ``command_parser`` to itself."""
    parser = argparse.ArgumentParser(
        prog="iap-mjx", description="Implicit Attention for Pixels on MJX, trained with ES."
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    subparsers = parser.add_subparsers(dest="command", required=True)
    commands.add_commands(subparsers)
    reproduce.add_commands(subparsers)
    return parser


def is_override(word: str) -> bool:
    """Whether a command-line word is a ``key=value`` override (not an option, which starts with ``-``)."""
    return "=" in word and not word.startswith("-")


def parse(parser: argparse.ArgumentParser, argv: list[str] | None) -> tuple[argparse.Namespace, list[str]]:
    """``parser.parse_known_args(argv)``, with overrides taken wherever they stand among the
    options: argparse fills a command's trailing ``key=value ...`` list from its first run of
    words only (``eval RUN --episodes 20 env.distraction=none`` leaves the override over), so
    in a command that takes overrides the ``key=value`` words it leaves join that list, in the
    order typed. Returns the parsed arguments and the words still not understood (an unknown
    option, without the overrides around it)."""
    args, unknown = parser.parse_known_args(argv)
    overrides = getattr(args, "overrides", None)
    if overrides is not None:
        args.overrides = [*overrides, *(word for word in unknown if is_override(word))]
        unknown = [word for word in unknown if not is_override(word)]
    return args, unknown


def main(argv: list[str] | None = None) -> int:
    """Entry point: sets up devices and the compilation cache, then runs the command."""
    runtime.setup()
    parser = build_parser()
    args, unknown = parse(parser, argv)
    if unknown:  # refused by the command's own parser, whose usage lists the options it takes
        # an unknown option's value lands among the overrides: named with it, as the user typed it
        stray = [item for item in getattr(args, "overrides", None) or () if "=" not in item]
        getattr(args, "command_parser", parser).error(f"unrecognized arguments: {' '.join(unknown + stray)}")
    # Our own messages at INFO; JAX's, orbax's and absl's chatter only from WARNING (-v: all).
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.WARNING,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    logging.getLogger("iap_mjx").setLevel(logging.DEBUG if args.verbose else logging.INFO)
    try:
        return args.func(args)
    except BrokenPipeError:  # the reader left (``iap-mjx presets | head``): stop quietly
        # Python flushes stdout again at exit; pointing it at devnull keeps that flush silent
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1
