"""The ``torchhrc`` command: a thin layer over the API (parse, call, print).

Each sub-command lives in its own module under :mod:`torchhrc.commands` and exposes
``register(subparsers)``, which adds its parser and sets ``func`` (``args -> exit code``).
User errors (bad files, bad arguments, invalid models) print one line to stderr and exit
with status 2, without a traceback.

Example:
    >>> from torchhrc.cli import build_parser
    >>> build_parser().prog
    'torchhrc'
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from torchhrc.errors import TorchHRCError

__all__ = ["COMMANDS", "build_parser", "main"]

#: Sub-command modules under ``torchhrc.commands``, in the order ``--help`` lists them.
COMMANDS: tuple[str, ...] = (
    "simulate_demos",
    "cluster",
    "solve",
    "simulate",
    "evaluate",
    "graph",
    "convert",
    "reproduce",
    "sweep",
)

USER_ERRORS = (
    TorchHRCError,
    FileNotFoundError,
    IsADirectoryError,
    PermissionError,
    FileExistsError,
)


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    """Build the argument parser with every sub-command registered."""
    parser = _Parser(
        prog="torchhrc",
        description="Learn human types from demonstrations and plan robot policies (MOMDPs).",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log progress details")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name in COMMANDS:
        module = importlib.import_module(f"torchhrc.commands.{name}")
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; return the exit status (0 ok, 2 user error)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    try:
        return int(args.func(args) or 0)
    except USER_ERRORS as error:
        message = str(error).splitlines()[0] if str(error) else type(error).__name__
        if isinstance(error, OSError) and error.filename is not None:
            message = f"{error.strerror}: {error.filename}"
        print(f"torchhrc {args.command}: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"torchhrc {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
