"""What the command-line tools share: an argument error is one line (``PROG: error: ...
(see --help)``, exit 2, no usage block), ROS's own arguments (``--ros-args ...``, appended by
``ros2 run`` and launch) are left out, and an input error found after parsing
(:class:`InputError`) is one line with exit 2."""
from __future__ import annotations

import argparse
from contextlib import contextmanager
import sys
from typing import Callable, Optional, Sequence


class Parser(argparse.ArgumentParser):
    """argparse, with its errors on one line."""

    def error(self, message: str):
        print(f'{self.prog}: error: {message} (see --help)', file=sys.stderr)
        raise SystemExit(2)


class InputError(Exception):
    """Bad input found after the arguments parsed: one line on stderr, exit 2."""


@contextmanager
def input_errors(*types: type, prefix: str = ''):
    """An exception of `types` raised inside becomes an InputError (`prefix` + its text)."""
    try:
        yield
    except types as exc:
        raise InputError(f'{prefix}{exc}') from None


def own_args(argv: Optional[Sequence[str]]) -> list[str]:
    """The tool's arguments: `argv` (default sys.argv[1:]) up to ``--ros-args``."""
    argv = list(sys.argv[1:] if argv is None else argv)
    return argv[:argv.index('--ros-args')] if '--ros-args' in argv else argv


def run(prog: str, parser: argparse.ArgumentParser, body: Callable[[argparse.Namespace], int],
        argv: Optional[Sequence[str]] = None) -> int:
    """Parse `argv` with `parser` and return body(args); an InputError is one line, exit 2."""
    args = parser.parse_args(own_args(argv))
    try:
        return body(args)
    except InputError as exc:
        print(f'{prog}: error: {exc}', file=sys.stderr)
        return 2
