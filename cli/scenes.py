"""The scene files commands read: an .spc (or the one a .glb carries) for the decoder, any scene
file for ``eval`` and ``render``, and the up axis an .spc records for the views sampled around it.
"""

from __future__ import annotations

import os
from pathlib import Path

from spcodec.errors import FormatError, UsageError
from spcodec.limits import DEFAULT_LIMITS

from .options import UP_AXES


def spc_source(path: str) -> str | bytes:
    """What to decode for ``path``: the path itself, or for a binary glTF the .spc that
    ``spcodec embed`` put inside it (a glTF without one is named as such, not "bad magic")."""
    from spcodec.gltf import GLB_MAGIC, embedded_spc

    if not os.path.isfile(path):  # a pipe or device is read once, by the decoder alone
        return path
    with open(path, "rb") as fh:
        if fh.read(len(GLB_MAGIC)) != GLB_MAGIC:
            return path
    DEFAULT_LIMITS.check("input file size", os.path.getsize(path), DEFAULT_LIMITS.max_file_bytes)
    return embedded_spc(Path(path).read_bytes(), path)


def load_model(path: str, max_layer: int | None = None):
    """A scene from an .spc (by its magic, gzip-wrapped or not) or from any scene file the
    formats registry reads (PLY, SPZ, .splat, SOG, .ksplat; by content)."""
    from spcodec.decoder import decode
    from spcodec.formats import read_scene

    if is_spc(path):
        return decode(path, max_layer=max_layer)
    if max_layer is not None:
        raise UsageError(f"--max-layer needs an .spc input; {path} is not one")
    cloud = read_scene(path)
    try:
        cloud.check_finite()  # what encode refuses, render and eval refuse too
    except FormatError as exc:
        raise FormatError(f"{path}: {exc.args[0]}", exc.code) from None
    return cloud


def is_spc(path: str) -> bool:
    """An .spc by its magic, gzip-wrapped or not (whatever its name; a gzip-wrapped SPZ is none)."""
    from spcodec.formats import HEAD_BYTES, spc

    if os.path.isdir(path):  # an unbundled SOG
        return False
    with open(path, "rb") as fh:
        head = fh.read(HEAD_BYTES)
    return spc.sniff(head)


def view_up(given: str | None, *paths: str | None) -> str:
    """The up axis of sampled views: ``--up`` when given, else the one the first .spc among
    ``paths`` stores (encode --up records it, as viewers and .glb use it), else -y. Without
    this a z-up scene tumbled sideways unless --up was repeated."""
    from spcodec.decoder import inspect

    if given is not None:
        return given
    for path in paths:
        if path is not None and is_spc(path):
            stored = (inspect(path).metadata or {}).get("up")
            if stored in UP_AXES:  # metadata is untrusted: anything else is ignored
                return stored
    return "-y"
