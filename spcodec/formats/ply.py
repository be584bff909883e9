"""PLY scenes (the INRIA layout and PlayCanvas ``compressed.ply``), through :mod:`spcodec.ply`."""

from __future__ import annotations

from ..cloud import GaussianCloud
from ..ply import read_ply, write_ply

NAME = "PLY (INRIA 3DGS or PlayCanvas compressed.ply)"


def sniff(head: bytes, size: int | None = None) -> bool:
    return head.startswith((b"ply\n", b"ply\r\n", b"ply\r"))


def read(path: str) -> GaussianCloud:
    return read_ply(path)


def write(path: str, cloud: GaussianCloud) -> None:
    write_ply(path, cloud)
