"""Scene files of other 3DGS tools: one registry that recognizes a file by its content and reads
it into a :class:`~spcodec.cloud.GaussianCloud`.

Each format is a module of this package with

* ``NAME`` - what the format is called in messages ("SPZ", "antimatter15 .splat", ...);
* ``sniff(head: bytes, size: int | None) -> bool`` - whether a file whose first bytes are
  ``head`` (up to :data:`HEAD_BYTES`) and whose size is ``size`` is of this format;
* ``read(path) -> GaussianCloud``;
* optionally ``write(path, cloud)`` and ``describe(path) -> str`` (a line for ``spcodec info``).

:func:`read_scene` asks the formats in registration order and reads the file with the first that
claims it; formats without magic (antimatter15 ``.splat``) come last. Names never decide: a
``.splat`` renamed ``.ply`` is still read as a ``.splat``. A file that no format claims gets one
line that says what it looks like instead (an image, text, a gzip or zip archive...).

Like Pillow's plugins, a new format is a module plus one :func:`register` call at the bottom of
this file. Everything here is numpy and the standard library; SPZ v4 needs ``zstandard`` and SOG
needs Pillow (extra ``formats``), imported only when such a file is read.

Why these readers are written here rather than taken from PyPI: ``gaussforge`` (0.6.0, compiled)
reads all of these formats, but by a format name the caller gives, and on the fixtures that the
formats' own tools wrote (tests/data/formats) it refused the ``.splat``, put the positions of
compressed ``.ksplat`` files units away from the source and returned SPZ in SPZ's own axes;
``gsply`` (0.4.6) reads PLY, SPZ and SOG only and brings numba. The modules here follow each
format's published source, are checked against those tools' files, and keep the format layer on
numpy.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Callable

from ..cloud import GaussianCloud
from ..errors import FormatError, UsageError

HEAD_BYTES = 64 * 1024
"""How much of a file the sniffers see."""


@dataclass(frozen=True)
class Format:
    """One registered format."""

    key: str
    name: str
    sniff: Callable[[bytes, int | None], bool]
    read: Callable[[str], GaussianCloud] | None
    write: Callable[[str, GaussianCloud], None] | None = None
    describe: Callable[[str], str] | None = None


FORMATS: list[Format] = []
"""The registered formats, in the order they are asked."""


def register(key: str, module: ModuleType) -> None:
    """Add a format module (see the package docstring) to the registry, after those before it."""
    FORMATS.append(Format(key, module.NAME, module.sniff, getattr(module, "read", None),
                          getattr(module, "write", None), getattr(module, "describe", None)))


def get(key: str) -> Format:
    for fmt in FORMATS:
        if fmt.key == key:
            return fmt
    raise KeyError(key)


def resolve(path: str | os.PathLike) -> Path:
    """The file to sniff for ``path``: a folder stands for the ``meta.json`` inside it (an
    unbundled SOG)."""
    path = Path(path)
    if path.is_dir() and (path / "meta.json").is_file():
        return path / "meta.json"
    return path


def read_head(path: str | os.PathLike) -> tuple[bytes, int | None]:
    """The first :data:`HEAD_BYTES` of a file and its size (None for a pipe or device)."""
    with open(path, "rb") as fh:
        head = fh.read(HEAD_BYTES)
        size = os.fstat(fh.fileno()).st_size if os.path.isfile(path) else None
    return head, size


def detect(path: str | os.PathLike) -> Format | None:
    """The registered format that claims ``path`` by content, or None."""
    head, size = read_head(resolve(path))
    return detect_bytes(head, size)


def detect_bytes(head: bytes, size: int | None) -> Format | None:
    for fmt in FORMATS:
        if fmt.sniff(head, size):
            return fmt
    return None


def read_scene(path: str | os.PathLike) -> GaussianCloud:
    """Read any supported 3DGS scene file, whatever its name; a FormatError of one line for a
    file that is none of them or is damaged."""
    target = resolve(path)
    if Path(path).is_dir() and target == Path(path):
        raise FormatError(f"{path}: is a folder without a meta.json (an unbundled SOG has one)",
                          "ply-invalid")
    fmt = detect(target)
    if fmt is None:
        head, size = read_head(target)
        raise FormatError(f"{path}: not a 3DGS scene file spcodec reads ({looks_like(head, size)}"
                          f"); it reads {readable_list()}", "ply-invalid")
    if fmt.read is None:
        raise FormatError(f"{path}: {_not_readable_hint(fmt)}", "ply-invalid")
    return fmt.read(str(target))


def write_scene(path: str | os.PathLike, cloud: GaussianCloud, key: str) -> None:
    """Write ``cloud`` in the registered format ``key`` (one that has a writer)."""
    fmt = get(key)
    if fmt.write is None:
        raise UsageError(f"spcodec cannot write {fmt.name} files")
    fmt.write(str(path), cloud)


def describe(path: str | os.PathLike) -> str | None:
    """One line on a scene file of a registered format (for ``spcodec info``), or None when no
    format with a description claims it."""
    fmt = detect(path)
    if fmt is None or fmt.describe is None:
        return None
    return fmt.describe(str(resolve(path)))


def readable_list() -> str:
    return ", ".join(f.name for f in FORMATS if f.read is not None)


def _not_readable_hint(fmt: Format) -> str:
    if fmt.key == "spc":
        return ("this is an .spc file, not a PLY or another scene file; decode it first with "
                "'spcodec decode' (or give the original scene)")
    return f"this is {fmt.name}, not a 3DGS scene; spcodec reads {readable_list()}"


_SIGNATURES = [
    (b"\x89PNG\r\n\x1a\n", "a PNG image"), (b"\xff\xd8\xff", "a JPEG image"),
    (b"GIF8", "a GIF image"), (b"%PDF", "a PDF document"), (b"PK\x03\x04", "a zip archive"),
    (b"\x1f\x8b", "gzip data"), (b"\x28\xb5\x2f\xfd", "zstd data"), (b"BZh", "bzip2 data"),
    (b"\xfd7zXZ\x00", "xz data"), (b"\x7fELF", "an executable"), (b"glTF", "a binary glTF"),
    (b"ply", "a PLY file without 3DGS properties"),
]


def looks_like(head: bytes, size: int | None) -> str:
    """What a file that no format claims looks like, in a few words."""
    if not head:
        return "it is empty"
    if head[:4] == b"RIFF" and head[8:12] == b"WEBP":
        return "it looks like a WebP image"
    for magic, kind in _SIGNATURES:
        if head.startswith(magic):
            return f"it looks like {kind}"
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError:
        text = None
    if text is not None:
        stripped = text.lstrip()
        if stripped.startswith(("{", "[")):
            return "it looks like JSON text"
        return "it looks like text"
    what = f"{size:,} bytes of unknown binary data" if size is not None else \
        "unknown binary data"
    return f"it looks like {what}"


# ---------------------------------------------------------------------------- the registry
from . import ksplat, ply, sog, spc, splat, spz  # noqa: E402

register("spc", spc)
register("ply", ply)
register("spz", spz)
register("sog", sog)
register("ksplat", ksplat)
register("splat", splat)  # no magic at all: the last resort
