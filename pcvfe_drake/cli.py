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
    "world",
    "diagnose",
    "calibrate",
    "evaluate",
    "vehicle_bridge",
    "replay",
    "import_bag",
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


STDOUT_NAME = "<standard output>"

INTERNAL_ERROR_EXIT = 70
"""Exit status of a failure of the project's own code (a bug, not the user's input; BSD's
EX_SOFTWARE): the traceback goes to stderr, after one line saying so."""


class _NamedStdout:
    """stdout whose write errors (a full disk, a closed pipe) carry the name of the stream."""

    def __init__(self, stream) -> None:
        self._stream = stream

    def _guard(self, method, *args):
        try:
            return method(*args)
        except BrokenPipeError:
            raise
        except OSError as exc:
            raise OSError(exc.errno, exc.strerror, STDOUT_NAME) from exc

    def write(self, text: str) -> int:
        return self._guard(self._stream.write, text)

    def flush(self) -> None:
        self._guard(self._stream.flush)

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


def _silence_stdout() -> None:
    """Send what is left for stdout to /dev/null, so that the exit does not fail a second time."""
    try:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except (OSError, ValueError):  # no file descriptor (e.g. captured output): nothing to do
        pass


def _run(argv: list[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        code = int(args.func(args) or 0)
        sys.stdout.flush()  # a full or broken stdout fails here, inside the error handling
        return code
    except BrokenPipeError:
        # Output piped into a reader that stopped early (e.g. `| head`): not an error.
        _silence_stdout()
        return 0
    except OSError as exc:
        from pcvfe_drake.runs.output_paths import describe_os_error

        if exc.filename == STDOUT_NAME:
            _silence_stdout()
        print(f"pcvfe {args.command}: error: {describe_os_error(exc)}", file=sys.stderr)
        return 2
    except ValueError as exc:
        print(f"pcvfe {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # noqa: BLE001 - a bug: say so, with its traceback
        import traceback

        traceback.print_exc(file=sys.stderr)
        print(
            f"pcvfe {args.command}: internal error (a bug in pcvfe, not your input): "
            f"{type(exc).__name__}: {exc}",
            file=sys.stderr,
        )
        return INTERNAL_ERROR_EXIT


def main(argv: list[str] | None = None) -> int:
    """Run one ``pcvfe`` command; bad input and OS errors become one line on stderr (exit 2),
    any other exception is an internal error (its traceback, then one line; exit
    :data:`INTERNAL_ERROR_EXIT`), Ctrl-C at any moment (also while the command modules are being
    imported) exit 130."""
    stdout = sys.stdout
    sys.stdout = _NamedStdout(stdout)
    try:
        return _run(argv)
    except KeyboardInterrupt:
        print("pcvfe: interrupted", file=sys.stderr)
        return 130
    finally:
        sys.stdout = stdout


if __name__ == "__main__":
    sys.exit(main())
