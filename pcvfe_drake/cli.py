"""The ``pcvfe`` console script: one subcommand per module in ``pcvfe_drake.commands``."""

from __future__ import annotations

import argparse
import importlib
import os
import sys

# Subcommand modules under pcvfe_drake.commands, in the order --help lists them.
COMMANDS = [
    "demo",
    "simulate",
    "fit",
    "features",
    "export_clip",
    "terrain_map",
    "diagnose",
    "evaluate",
]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pcvfe",
        description="PC-VFE friction estimation in Drake, and a model-discrepancy workbench.",
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"pcvfe_drake.commands.{name}").register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except (ValueError, FileNotFoundError) as exc:
        print(f"pcvfe {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # Output piped into a reader that stopped early (e.g. `| head`): not an error.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0


if __name__ == "__main__":
    sys.exit(main())
