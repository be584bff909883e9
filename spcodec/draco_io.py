"""Decoding Draco point-cloud blobs with the checks the spec requires ([R-47], [R-49], [R-58]).

The blob's fixed header is checked *before* the Draco decoder runs: a hostile blob declaring a huge
point count would otherwise make the decoder allocate for it (a 74-byte blob claiming 50 million
points took 1.4 GB). DracoPy is a core dependency, but it is imported on first use so that reading
PLY files or inspecting headers never loads the compiled library.
"""

from __future__ import annotations

import struct

import numpy as np

from .errors import FormatError

DRACO_MAGIC = b"DRACO"
DRACO_HEADER_SIZE = 15
"""Magic (5), version major and minor (2), encoder type (1), method (1), flags (2), point count (4)."""


def check_header(blob: bytes | memoryview, count: int, what: str) -> None:
    """Validate a Draco point-cloud blob's fixed header against the declared point count ([R-49])."""
    head = bytes(blob[:DRACO_HEADER_SIZE])
    if len(head) < DRACO_HEADER_SIZE or head[:5] != DRACO_MAGIC:
        raise FormatError(f"{what}: not a Draco blob", "draco-failed")
    if head[5] != 2:
        raise FormatError(f"{what}: Draco major version {head[5]} is not 2", "draco-failed")
    if head[7] != 0:
        raise FormatError(f"{what}: Draco blob is not a point cloud (encoder type {head[7]})",
                          "draco-failed")
    if struct.unpack_from("<H", head, 9)[0] != 0:
        raise FormatError(f"{what}: Draco blob carries metadata or flags", "draco-failed")
    declared = struct.unpack_from("<i", head, 11)[0]
    if declared != count:
        raise FormatError(f"{what}: Draco blob declares {declared} points, expected {count}",
                          "draco-failed")


def decode_points(blob: bytes | memoryview, count: int, what: str) -> np.ndarray:
    """Decode a Draco point cloud that must hold exactly ``count`` finite points, in decode order.

    ``what`` names the blob in error messages (e.g. "sketch blob 3", "patch positions").
    """
    check_header(blob, count, what)
    import DracoPy

    try:
        decoded = DracoPy.decode(bytes(blob))
        points = np.asarray(decoded.points, dtype=np.float32).reshape(-1, 3)
    except Exception as exc:  # DracoPy raises assorted types on corrupt input
        raise FormatError(f"{what}: Draco blob cannot be decoded ({exc})", "draco-failed") from None
    faces = getattr(decoded, "faces", None)
    if faces is not None and len(faces):
        raise FormatError(f"{what}: Draco blob is a mesh, not a point cloud", "draco-failed")
    if len(getattr(decoded, "attributes", None) or [None]) != 1:
        raise FormatError(f"{what}: Draco blob carries attributes besides positions",
                          "draco-failed")
    if points.shape[0] != count:
        raise FormatError(f"{what}: Draco blob holds {points.shape[0]} points, expected {count}",
                          "draco-failed")
    if not np.isfinite(points).all():
        raise FormatError(f"{what}: Draco positions are not finite", "draco-failed")
    return np.ascontiguousarray(points)
