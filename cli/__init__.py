"""The ``spcodec`` command line: one module per command, assembled into one parser here.

Every failure ends with one line on stderr (``spcodec: error: ...``) and a non-zero exit code; no
traceback for a bad file or a bad argument (``--debug`` shows one), and no partial output file.
Commands that need the encoder's heavy dependencies import them only when they run, and say which
extra to install when they are missing. A command module holds ``NAME``, ``HELP``,
``configure(parser)`` (its options) and ``run(args) -> exit code``; what several share is in
:mod:`.options` (argument types, exit codes) and :mod:`.scenes` (the files they read).
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from typing import Callable, NoReturn, Sequence

from spcodec.allocator import keep_freed_memory
from spcodec.errors import FormatError, Interrupted, SpcodecError, TruncatedError, UsageError

from . import attach_preview, conformance, decode, demo, embed, encode, info, render, serve, tile
from . import eval as evaluate
from .options import EXIT_BROKEN_PIPE, EXIT_ERROR, EXIT_OK, EXIT_USAGE

Handler = Callable[[argparse.Namespace], int]
Configure = Callable[[argparse.ArgumentParser], None]
COMMANDS: dict[str, tuple[str, Configure, Handler]] = {
    module.NAME: (module.HELP, module.configure, module.run)
    for module in (decode, embed, info, attach_preview, serve, demo, conformance, encode,
                   evaluate, render, tile)
}
"""Sub-command -> (help text, what adds its options, what runs it), in --help's order."""

__all__ = ["COMMANDS", "build_parser", "describe_error", "main", "missing_extra_message"]


class _Parser(argparse.ArgumentParser):
    """argparse with the command line's one-line errors instead of a usage dump."""

    def error(self, message: str) -> NoReturn:
        _fail(f"{message} (see '{self.prog} --help')")
        raise SystemExit(EXIT_USAGE)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every sub-command of :data:`COMMANDS`."""
    from spcodec import __version__

    parser = _Parser(prog="spcodec", description="Sketch&Patch++ codec for 3D "
                     "Gaussian Splatting scenes")
    parser.add_argument("--version", action="version", version=f"spcodec {__version__}")
    parser.add_argument("--debug", action="store_true",
                        help="show tracebacks on errors (default: off)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, (help_text, configure, handler) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        configure(p)
        p.set_defaults(handler=handler)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``spcodec`` console script."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version, or a bad argument already reported
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    keep_freed_memory()  # this process renders: see spcodec.allocator
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _warn
            return int(args.handler(args) or EXIT_OK)
    except BrokenPipeError:  # e.g. `spcodec info X.spc | head -3`: the reader has all it wants
        _quiet_broken_pipe()
        return EXIT_BROKEN_PIPE
    except KeyboardInterrupt:
        _fail("interrupted")
        return 130
    except Interrupted as exc:
        _fail(str(exc), label="interrupted")
        return 130
    except Exception as exc:  # noqa: BLE001 - the one place that turns errors into one line
        if args.debug:
            raise
        _fail(describe_error(exc, args))
        return EXIT_USAGE if isinstance(exc, UsageError) else EXIT_ERROR


def describe_error(exc: BaseException, args: argparse.Namespace | None = None) -> str:
    """The one-line message for an exception reaching the command line."""
    source = getattr(args, "input", None)
    if isinstance(exc, FormatError):
        message = f"{source}: {exc}" if source and str(source) not in str(exc) else str(exc)
        if isinstance(exc, TruncatedError) and exc.complete_layers:
            last = exc.complete_layers - 1
            message += f"; decode layers 0..{last} with --max-layer {last}"
        return message
    if isinstance(exc, SpcodecError):
        return str(exc)
    if isinstance(exc, FileNotFoundError):
        return f"{exc.filename}: no such file"
    if isinstance(exc, IsADirectoryError):
        return f"{exc.filename}: is a directory"
    if isinstance(exc, PermissionError):
        return f"{exc.filename}: permission denied"
    if isinstance(exc, OSError):
        return f"{exc.filename or ''}: {exc.strerror or exc}".lstrip(": ")
    if isinstance(exc, MemoryError):
        return "out of memory"
    if isinstance(exc, ModuleNotFoundError):
        return missing_extra_message(exc.name or "")
    return f"internal error: {exc.__class__.__name__}: {exc} (run with --debug for a traceback)"


def missing_extra_message(module: str) -> str:
    """Which extra installs a missing module."""
    extra = {"torch": "encoder", "sklearn": "encoder", "scipy": "encoder", "tqdm": "encoder",
             "zstandard": "zstd", "gsplat": "gsplat", "dask": "tiling",
             "distributed": "tiling"}.get(module.split(".")[0])
    if extra:
        return f"this command needs '{module}': pip install 'spcodec[{extra}]'"
    return f"missing Python module '{module}'"


def _fail(message: str, label: str = "error") -> None:
    first = message.strip().splitlines()[0] if message.strip() else "failed"
    print(f"spcodec: {label}: {first}", file=sys.stderr)


def _quiet_broken_pipe() -> None:
    """After the reader of standard output went away: say nothing, and keep Python from
    complaining about the unflushable stream at exit."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):  # no real file descriptor (a test's captured stream)
        pass


def _warn(message, category, filename, lineno, file=None, line=None) -> None:
    """``warnings.showwarning`` for the command line: one line, no source location."""
    text = str(message).strip().splitlines()
    print(f"spcodec: warning: {text[0] if text else category.__name__}", file=sys.stderr)
