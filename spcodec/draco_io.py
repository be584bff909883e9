"""Decoding Draco point-cloud blobs with the checks the spec requires ([R-47], [R-49], [R-58]).

DracoPy is a core dependency, but it is imported on first use so that reading PLY files or
inspecting headers never loads the compiled library.

The Draco library sizes its buffers from its own header before it finds out that the data is
short: fuzzing showed a 300-byte blob whose point count field says 2^31 making it allocate
gigabytes (the process is killed, no exception), and older bitstream versions of the kd-tree
coder doing the same from other fields. So the blob's header is checked here first: a point
cloud, in the bitstream version current encoders write, without Draco metadata (whose decoder
allocates entry sizes read from the blob), declaring exactly the expected number of points.
"""

from __future__ import annotations

import numpy as np

from .errors import FormatError

DRACO_MAGIC = b"DRACO"
DRACO_POINT_CLOUD = 0
DRACO_VERSIONS = {(2, 3)}
"""Point-cloud bitstream versions accepted: what Draco 1.4 and later (and DracoPy) write."""
DRACO_METHODS = {0, 1}
"""Sequential and kd-tree encoding."""
DRACO_METADATA_FLAG = 0x8000
DRACO_POSITION = 0
"""Draco's attribute type POSITION."""
DRACO_FLOAT32 = 9
"""Draco's data type DT_FLOAT32."""
_DRACO_HEADER = 15
"""magic (5), version major and minor, encoder type, method, flags (u16), point count (i32)."""


def check_draco_header(blob: bytes | memoryview, count: int, what: str) -> None:
    """Refuse a blob before Draco allocates anything from it (see the module docstring)."""
    head = bytes(blob[:_DRACO_HEADER])
    if len(head) < _DRACO_HEADER or head[:5] != DRACO_MAGIC:
        raise FormatError(f"{what}: not a Draco blob", "draco-failed")
    version, kind, method = (head[5], head[6]), head[7], head[8]
    flags = int.from_bytes(head[9:11], "little")
    if kind != DRACO_POINT_CLOUD:
        raise FormatError(f"{what}: Draco blob is not a point cloud (type {kind})", "draco-failed")
    if version not in DRACO_VERSIONS or method not in DRACO_METHODS:
        raise FormatError(f"{what}: Draco bitstream {version[0]}.{version[1]}, method {method} "
                          f"is not supported", "draco-failed")
    if flags & DRACO_METADATA_FLAG:
        raise FormatError(f"{what}: Draco metadata is not supported", "draco-failed")
    declared = int.from_bytes(head[11:15], "little", signed=True)
    if declared != count:
        raise FormatError(f"{what}: Draco blob declares {declared} points, expected {count}",
                          "draco-failed")


def check_position_attribute(attributes: list[dict], what: str) -> None:
    """[R-49]: a decoded blob holds one attribute, POSITION with 3 float32 components.

    Draco decodes a blob whose attribute says GENERIC, or int8, without complaint (the kd-tree
    coder even returns points for an int8 position), so the attribute is checked, not assumed.
    """
    if len(attributes) != 1:
        raise FormatError(f"{what}: Draco blob carries {len(attributes)} attributes, expected "
                          f"only the positions", "draco-failed")
    att = attributes[0]
    found = (att.get("attribute_type"), att.get("num_components"), att.get("data_type"))
    if found != (DRACO_POSITION, 3, DRACO_FLOAT32):
        raise FormatError(f"{what}: Draco attribute is (type {found[0]}, {found[1]} components, "
                          f"data type {found[2]}), expected POSITION with 3 float32 components",
                          "draco-failed")


def decode_points(blob: bytes | memoryview, count: int, what: str) -> np.ndarray:
    """Decode a Draco point cloud that must hold exactly ``count`` finite points, in decode order.

    ``what`` names the blob in error messages (e.g. "sketch blob 3", "patch layer 2").
    """
    import DracoPy

    check_draco_header(blob, count, what)
    try:
        decoded = DracoPy.decode(bytes(blob))
    except Exception as exc:  # DracoPy raises assorted types on corrupt input
        raise FormatError(f"{what}: Draco blob cannot be decoded ({exc})", "draco-failed") from None
    faces = getattr(decoded, "faces", None)
    if faces is not None and len(faces):
        raise FormatError(f"{what}: Draco blob is a mesh, not a point cloud", "draco-failed")
    check_position_attribute(decoded.attributes, what)
    try:
        points = np.asarray(decoded.points, dtype=np.float32).reshape(-1, 3)
    except Exception as exc:  # noqa: BLE001 - as above: never another exception for a bad blob
        raise FormatError(f"{what}: Draco positions cannot be read ({exc})",
                          "draco-failed") from None
    if points.shape[0] != count:
        raise FormatError(f"{what}: Draco blob holds {points.shape[0]} points, expected {count}",
                          "draco-failed")
    if not np.isfinite(points).all():
        raise FormatError(f"{what}: Draco positions are not finite", "draco-failed")
    return np.ascontiguousarray(points)
