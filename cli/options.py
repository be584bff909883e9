"""What several commands share on their command lines: exit codes, checked argument types, the
view options of ``eval`` and ``render``, the --device rule and where a report is printed.

Importing this module loads neither the encoder nor torch: ``spcodec decode`` starts without them.
"""

from __future__ import annotations

import argparse
import math
import os
import sys

from spcodec.errors import UsageError

EXIT_OK, EXIT_ERROR, EXIT_USAGE = 0, 1, 2
EXIT_BROKEN_PIPE = 141
"""What a shell reports for a program ended by SIGPIPE (128 + 13), as `cat big | head` does."""


class Bounded:
    """An argparse ``type``: a number within a range, checked while the command line is parsed
    (before any work starts) and shown by ``--help`` through ``%(type)s``."""

    def __init__(self, kind: type = int, low: float = 1, high: float | None = None,
                 exclusive: bool = False) -> None:
        self.kind, self.low, self.high, self.exclusive = kind, low, high, exclusive

    def __call__(self, text: str) -> int | float:
        try:
            value = self.kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {self}, got {text!r}") from None
        above = value > self.low if self.exclusive else value >= self.low
        if not (math.isfinite(value) and above and (self.high is None or value <= self.high)):
            raise argparse.ArgumentTypeError(f"must be {self}, got {text}")
        return value

    def __str__(self) -> str:
        noun = "an integer" if self.kind is int else "a number"
        if self.high is not None:
            return f"{noun} in {self.low}..{self.high}"
        return f"{noun} {'>' if self.exclusive else '>='} {self.low}"


def closeup_list(text: str) -> tuple[float, ...]:
    """An argparse ``type``: comma-separated distance factors in (0, 1), or ``none``."""
    if text.strip().lower() == "none":
        return ()
    try:
        values = tuple(float(part) for part in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected factors such as 0.5,0.25 or none, got "
                                         f"{text!r}") from None
    if not all(0 < v < 1 for v in values):
        raise argparse.ArgumentTypeError(f"each factor must lie strictly between 0 and 1, got "
                                         f"{text}")
    return values


SEED = Bounded(int, 0, 2**32 - 1)
"""Seeds of numpy and scikit-learn: non-negative and below 2**32."""
MAX_LAYER = Bounded(int, 0)
PORT = Bounded(int, 0, 65535)
THROTTLE = Bounded(float, 0, exclusive=True)
"""``serve --throttle`` in kbit/s: any positive speed."""
DEVICE_HELP = ("auto: CUDA when torch sees a GPU (rendered by gsplat when installed, else by the "
               "torch renderer), else the CPU (default: %(default)s)")
"""--device of encode and of the commands that render: one device rule (resolve_device)."""
UP_AXES = ("+x", "-x", "+y", "-y", "+z", "-z")
"""The values of --up, and the ones an .spc's metadata may store."""


DEFAULT_THREADS = 1
"""Torch threads for the commands that render or train when --threads is not given: the CPU
renderer runs many small tensor operations that more threads barely speed up, while two threads
on this project's busy 2-core machine ran retraining 4-8x slower than one (docs/LOG.md, section
13) and ``eval`` 4x slower (section 21.5)."""
THREADS_HELP = (f"CPU threads for rendering (and training): %(type)s (default: {DEFAULT_THREADS}; "
                "the CPU renderer gains little from more and, on a busy 2-core machine, ran 4-8x "
                "slower with 2)")


def use_threads(threads: int | None) -> None:
    """Set torch's CPU threads to ``threads``, else :data:`DEFAULT_THREADS` (torch's own default,
    every core, is what made renders slower)."""
    import torch

    torch.set_num_threads(threads or DEFAULT_THREADS)


def add_view_options(p: argparse.ArgumentParser) -> None:
    """The options of ``eval`` and ``render`` that say how the sampled views are rendered."""
    p.add_argument("--resolution", type=Bounded(int, 8, 8192), default=400, metavar="PIXELS",
                   help="side of square sampled views: %(type)s (default: %(default)s)")
    p.add_argument("--max-layer", type=MAX_LAYER, default=None, metavar="K",
                   help="use layers 0..K of an .spc: %(type)s (default: every layer)")
    p.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"],
                   help=DEVICE_HELP)
    p.add_argument("--up", default=None, choices=UP_AXES,
                   metavar="AXIS", help="the scene's up axis for sampled views, one of "
                   "+x -x +y -y +z -z; -y suits COLMAP-derived scenes, +z z-up ones; write "
                   "a negative axis as --up=-y (default: the one an .spc stores, else -y)")
    p.add_argument("--antialiased", action="store_true",
                   help="render with Mip-Splatting's antialiased opacity (default: off)")
    p.add_argument("--threads", type=Bounded(int, 1, 1024), default=None, metavar="N",
                   help=THREADS_HELP)


def check_device(device: str) -> None:
    """Refuse a --device this machine lacks (``cuda`` without a GPU) with a one-line usage
    error, before any work: encode, eval and render share this check."""
    from spcodec.imaging.render import resolve_device

    try:
        resolve_device(device)  # before any work: a missing GPU is the user's to fix
    except RuntimeError as exc:
        raise UsageError(f"--device {device}: {exc}; use --device cpu or auto") from None


def report_stream(output: str):
    """Where a command's report goes: standard error when its output is standard output (``-``,
    or a name such as /dev/stdout for the same file), so the two never mix."""
    from spcodec.fileio import is_stdout

    if is_stdout(output):
        return sys.stderr
    try:
        same = os.path.samestat(os.stat(output), os.fstat(sys.stdout.fileno()))
    except (OSError, ValueError, AttributeError):  # no output yet, or stdout is no real file
        same = False
    return sys.stderr if same else sys.stdout
