"""Decoding Draco point-cloud blobs with the checks the spec requires ([R-47], [R-54]).

DracoPy is a core dependency, but it is imported on first use so that reading PLY files or
inspecting headers never loads the compiled library.
"""

from __future__ import annotations

import numpy as np

from .errors import FormatError


def decode_points(blob: bytes | memoryview, count: int, what: str) -> np.ndarray:
    """Decode a Draco point cloud that must hold exactly ``count`` finite points, in decode order.

    ``what`` names the blob in error messages (e.g. "sketch blob 3", "patch layer 2").
    """
    import DracoPy

    try:
        decoded = DracoPy.decode(bytes(blob))
        points = np.asarray(decoded.points, dtype=np.float32).reshape(-1, 3)
    except Exception as exc:  # DracoPy raises assorted types on corrupt input
        raise FormatError(f"{what}: Draco blob cannot be decoded ({exc})", "draco-failed") from None
    faces = getattr(decoded, "faces", None)
    if faces is not None and len(faces):
        raise FormatError(f"{what}: Draco blob is a mesh, not a point cloud", "draco-failed")
    if points.shape[0] != count:
        raise FormatError(f"{what}: Draco blob holds {points.shape[0]} points, expected {count}",
                          "draco-failed")
    if not np.isfinite(points).all():
        raise FormatError(f"{what}: Draco positions are not finite", "draco-failed")
    return np.ascontiguousarray(points)
