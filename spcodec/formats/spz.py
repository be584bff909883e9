"""Niantic's SPZ (versions 1-4), read and written following nianticlabs/spz ``src/cc/load-spz.cc``
and ``splat-utils.h``.

Versions 1-3 are one gzip stream holding a 16-byte header (``NGSP`` magic, version, count, SH
degree, fractional bits, flags, reserved) and then the attributes one after the other:
positions (24-bit signed fixed point; float16 in version 1), alphas (sigmoid * 255), colours
(SH DC * 0.15 * 255 + 127.5), log-scales ((s + 10) * 16), rotations (version 2: x, y, z bytes of the
w >= 0 unit quaternion; version 3+: "smallest three" in 32 bits), SH (coefficient-major, RGB inner,
(b - 128) / 128). Version 4 keeps the attributes but stores them as separate zstd streams after a
plain 32-byte header and a table of (compressed, uncompressed) sizes.

SPZ stores its scenes in the RUB axes (x right, y up, z back); the PLY convention, and so
:class:`GaussianCloud`, is RDF: reading flips y and z of positions, the matching quaternion
components and the odd SH coefficients, as the spz library does when asked for RDF; writing
flips back. SH of degree 4 (SPZ v3+) are dropped to degree 3, with a warning.
"""

from __future__ import annotations

import gzip
import struct
import warnings
import zlib

import numpy as np

from ..cloud import GaussianCloud
from ..errors import FormatError, UnsupportedError
from ..fileio import atomic_write
from .common import check_count, logit, sigmoid, to_u8, unit_quats

NAME = "SPZ"
MAGIC = b"NGSP"
LEGACY_HEADER = struct.Struct("<4sIIBBBB")  # magic, version, count, sh degree, bits, flags, -
NGSP_HEADER = struct.Struct("<4sIIBBBBI12x")  # ... flags, stream count, TOC offset, reserved
COLOR_SCALE = 0.15
SQRT1_2 = 0.7071067811865476
FLAG_ANTIALIASED, FLAG_EXTENSIONS = 0x1, 0x2
SH_DIMS = {0: 0, 1: 3, 2: 8, 3: 15, 4: 24}
RUB_TO_RDF_SH = np.array([-1, -1, 1, -1, 1, 1, -1, 1, -1, 1, -1, -1, 1, -1, 1, 1, 1, 1, 1, 1, 1,
                          1, 1, 1][:15], np.float32)
"""spz's ``flipSh`` for x = 1, y = z = -1 (degrees 1-3)."""
SH1_BITS, SH_REST_BITS = 5, 4  # the reference writer's defaults


def _gunzip_head(head: bytes, want: int) -> bytes:
    try:
        return zlib.decompressobj(16 + zlib.MAX_WBITS).decompress(head, want)
    except zlib.error:
        return b""


def sniff(head: bytes, size: int | None = None) -> bool:
    if head.startswith(MAGIC):
        return True
    return head.startswith(b"\x1f\x8b") and _gunzip_head(head, 4) == MAGIC


def _header(path: str) -> tuple[dict, bytes, bool]:
    """The header fields, the whole file and whether it is gzip-wrapped (versions 1-3)."""
    with open(path, "rb") as fh:
        data = fh.read()
    gz = data[:2] == b"\x1f\x8b"
    head = _gunzip_head(data, LEGACY_HEADER.size) if gz else data[:NGSP_HEADER.size]
    if len(head) < LEGACY_HEADER.size or not head.startswith(MAGIC):
        raise FormatError(f"{path}: truncated or corrupt SPZ header", "truncated")
    magic, version, count, degree, bits, flags, _ = LEGACY_HEADER.unpack_from(head)
    fields = {"version": version, "count": count, "sh_degree": degree, "fractional_bits": bits,
              "flags": flags}
    if not gz:
        if len(head) < NGSP_HEADER.size:
            raise FormatError(f"{path}: truncated SPZ header", "truncated")
        fields["streams"], fields["toc"] = NGSP_HEADER.unpack_from(head)[6:8]
    if not 1 <= version <= 4 or (not gz and version < 4):
        raise UnsupportedError(f"{path}: SPZ version {version} "
                               f"{'in a gzip stream ' if gz else ''}is not one spcodec reads "
                               "(1-3 gzip-wrapped, 4 with zstd streams)")
    if degree not in SH_DIMS:
        raise UnsupportedError(f"{path}: SPZ SH degree {degree} is not 0..4")
    if count == 0:
        raise FormatError(f"{path}: SPZ declares no Gaussians", "bad-value")
    check_count(path, count, len(data))
    return fields, data, gz


def _sizes(fields: dict) -> list[int]:
    """Byte sizes of positions, alphas, colours, scales, rotations and SH."""
    n, version = fields["count"], fields["version"]
    return [n * (6 if version == 1 else 9), n, 3 * n, 3 * n, n * (4 if version >= 3 else 3),
            n * SH_DIMS[fields["sh_degree"]] * 3]


def _streams(path: str, fields: dict, data: bytes, gz: bool) -> list[bytes]:
    sizes = _sizes(fields)
    if gz:
        total = LEGACY_HEADER.size + sum(sizes)
        try:
            inflated = zlib.decompressobj(16 + zlib.MAX_WBITS).decompress(data, total)
        except zlib.error as exc:
            raise FormatError(f"{path}: corrupt gzip stream in SPZ ({exc})", "bad-gzip") from None
        if len(inflated) < total:
            raise FormatError(f"{path}: SPZ data ends after {len(inflated)} of the {total} "
                              "inflated bytes its header declares", "truncated")
        out, at = [], LEGACY_HEADER.size
        for size in sizes:
            out.append(inflated[at:at + size])
            at += size
        return out
    return _zstd_streams(path, fields, data, sizes)


def _zstd_streams(path: str, fields: dict, data: bytes, sizes: list[int]) -> list[bytes]:
    wanted = [s for s in sizes if s]  # zero-size streams (no SH) are not stored
    count, toc = fields["streams"], fields["toc"]
    if count != len(wanted):
        raise FormatError(f"{path}: SPZ v4 has {count} streams, its header implies "
                          f"{len(wanted)}", "bad-layout")
    if toc < NGSP_HEADER.size or toc + 16 * count > len(data):
        raise FormatError(f"{path}: SPZ v4 table of streams lies outside the file", "truncated")
    try:
        import zstandard
    except ModuleNotFoundError:
        raise FormatError(f"{path}: SPZ v4 needs the zstandard module: pip install "
                          "'spcodec[formats]'", "codec-unavailable") from None
    at = toc + 16 * count
    raw = []
    for i, size in enumerate(wanted):
        packed, unpacked = struct.unpack_from("<QQ", data, toc + 16 * i)
        if unpacked != size or at + packed > len(data):
            raise FormatError(f"{path}: SPZ v4 stream {i} is {unpacked} bytes in {packed} "
                              f"stored, expected {size} bytes within the file", "truncated")
        try:
            block = zstandard.ZstdDecompressor().decompress(data[at:at + packed],
                                                            max_output_size=size)
        except zstandard.ZstdError as exc:
            raise FormatError(f"{path}: SPZ v4 stream {i} does not decompress ({exc})",
                              "decompression-failed") from None
        if len(block) != size:
            raise FormatError(f"{path}: SPZ v4 stream {i} inflates to {len(block)} bytes, not "
                              f"{size}", "length-mismatch")
        raw.append(block)
        at += packed
    it = iter(raw)
    return [next(it) if s else b"" for s in sizes]


def read(path: str) -> GaussianCloud:
    fields, data, gz = _header(path)
    positions, alphas, colors, scales, rotations, sh = _streams(path, fields, data, gz)
    n, version = fields["count"], fields["version"]
    if version == 1:
        means = np.frombuffer(positions, "<f2").reshape(n, 3).astype(np.float32)
    else:
        b = np.frombuffer(positions, np.uint8).reshape(n, 3, 3).astype(np.int32)
        fixed = b[..., 0] | (b[..., 1] << 8) | (b[..., 2] << 16)
        fixed = (fixed ^ 0x800000) - 0x800000  # sign extension of 24 bits
        means = fixed.astype(np.float32) / np.float32(1 << fields["fractional_bits"])
    rot = np.frombuffer(rotations, np.uint8)
    xyzw = _smallest_three(rot.reshape(n, 4)) if version >= 3 else _first_three(rot.reshape(n, 3))
    dim = SH_DIMS[fields["sh_degree"]]
    sh_rest = (np.frombuffer(sh, np.uint8).reshape(n, dim, 3).astype(np.float32) - 128) / 128
    if dim == 24:
        warnings.warn(f"{path}: SPZ holds SH degree 4; spcodec keeps degrees 0-3 and drops "
                      "the rest", stacklevel=2)
        sh_rest = sh_rest[:, :15]
    # RUB (SPZ) -> RDF (PLY): flip y and z
    means = means * np.array([1, -1, -1], np.float32)
    quats = np.concatenate([xyzw[:, 3:], xyzw[:, :3] * np.array([1, -1, -1])], axis=1)
    sh_rest = sh_rest * RUB_TO_RDF_SH[:sh_rest.shape[1], None]
    return GaussianCloud(
        means=means,
        scales=np.frombuffer(scales, np.uint8).reshape(n, 3).astype(np.float32) / 16 - 10,
        quats=quats,
        opacities=logit(np.frombuffer(alphas, np.uint8) / 255.0),
        sh_dc=(np.frombuffer(colors, np.uint8).reshape(n, 3) / 255.0 - 0.5) / COLOR_SCALE,
        sh_rest=sh_rest,
    )


def _first_three(r: np.ndarray) -> np.ndarray:
    xyz = r.astype(np.float32) / 127.5 - 1
    w = np.sqrt(np.maximum(0.0, 1.0 - (xyz ** 2).sum(axis=1, keepdims=True)))
    return np.concatenate([xyz, w], axis=1)


def _smallest_three(r: np.ndarray) -> np.ndarray:
    comp = r.astype(np.uint32) @ np.array([1, 1 << 8, 1 << 16, 1 << 24], np.uint32)
    largest = (comp >> 30).astype(np.int64)
    out = np.zeros((len(r), 4), np.float32)
    rows = np.arange(len(r))
    squares = np.zeros(len(r), np.float32)
    # the reference walks the components from 3 down to 0, skipping the largest
    for i in range(3, -1, -1):
        skip = largest == i
        mag = (comp & 511).astype(np.float32)
        neg = (comp >> 9) & 1
        value = np.float32(SQRT1_2) * mag / np.float32(511)
        value = np.where(neg == 1, -value, value)
        out[:, i] = np.where(skip, 0.0, value)
        squares += np.where(skip, 0.0, value * value)
        comp = np.where(skip, comp, comp >> 10)
    out[rows, largest] = np.sqrt(np.maximum(0.0, 1.0 - squares))
    return out


def describe(path: str) -> str:
    fields, data, gz = _header(path)
    flags = fields["flags"]
    notes = [f"{fields['fractional_bits']} fractional position bits"]
    if flags & FLAG_ANTIALIASED:
        notes.append("trained antialiased")
    if flags & FLAG_EXTENSIONS:
        notes.append("with extensions")
    return (f"SPZ v{fields['version']} ({'gzip' if gz else 'zstd streams'}), "
            f"{fields['count']:,} Gaussians, SH degree {fields['sh_degree']}, "
            f"{len(data):,} bytes; {', '.join(notes)}")


# -------------------------------------------------------------------------------- writing
def spz_bytes(cloud: GaussianCloud, version: int = 3) -> bytes:
    """The SPZ file for ``cloud``: version 2 or 3 (gzip; readable everywhere) or 4 (zstd)."""
    if version not in (2, 3, 4):
        raise ValueError(f"SPZ version {version}: spcodec writes 2, 3 or 4")
    n = len(cloud)
    if n == 0:
        raise FormatError("SPZ cannot hold an empty scene (its readers refuse 0 Gaussians)",
                          "bad-value")
    flip = np.array([1, -1, -1], np.float64)
    means = cloud.means.astype(np.float64) * flip
    extent = float(np.abs(means).max()) if n else 0.0
    bits = 12  # the reference's ~0.25 mm; fewer where the scene would overflow 24 bits
    while bits > 0 and extent * (1 << bits) >= (1 << 23) - 1:
        bits -= 1
    if extent * (1 << bits) >= (1 << 23) - 1:
        raise FormatError(f"positions up to {extent:g} do not fit SPZ's 24-bit fixed point",
                          "bad-value")
    fixed = np.round(means * (1 << bits)).astype(np.int64) & 0xFFFFFF
    positions = np.stack([fixed & 0xFF, (fixed >> 8) & 0xFF, fixed >> 16], axis=-1)
    q = unit_quats(cloud.quats)
    xyzw = np.concatenate([q[:, 1:] * flip, q[:, :1]], axis=1)
    rotations = _pack_smallest_three(xyzw) if version >= 3 else _pack_first_three(xyzw)
    alphas = to_u8(sigmoid(cloud.opacities).astype(np.float64) * 255)
    colors = to_u8(cloud.sh_dc.astype(np.float64) * (COLOR_SCALE * 255) + 127.5)
    scales = to_u8((cloud.scales.astype(np.float64) + 10) * 16)
    k = cloud.sh_rest.shape[1]
    rest = cloud.sh_rest.astype(np.float64) * RUB_TO_RDF_SH[:k, None]
    bucket = np.where(np.arange(k) < 3, 1 << (8 - SH1_BITS), 1 << (8 - SH_REST_BITS))[None, :, None]
    quant = np.round(rest * 128) + 128
    quant = (quant + bucket // 2) // bucket * bucket
    sh = np.clip(quant, 0, 255).astype(np.uint8)
    streams = [positions.astype(np.uint8).tobytes(), alphas.tobytes(), colors.tobytes(),
               scales.tobytes(), rotations.tobytes(), sh.tobytes()]
    flags = 0
    if version < 4:
        header = LEGACY_HEADER.pack(MAGIC, version, n, cloud.sh_degree, bits, flags, 0)
        return gzip.compress(header + b"".join(streams), compresslevel=9, mtime=0)
    import zstandard

    chunks = [(zstandard.ZstdCompressor(level=12).compress(s), len(s)) for s in streams if s]
    header = NGSP_HEADER.pack(MAGIC, version, n, cloud.sh_degree, bits, flags, len(chunks),
                              NGSP_HEADER.size)
    toc = b"".join(struct.pack("<QQ", len(c), size) for c, size in chunks)
    return header + toc + b"".join(c for c, _ in chunks)


def _pack_first_three(xyzw: np.ndarray) -> np.ndarray:
    sign = np.where(xyzw[:, 3:] < 0, -127.5, 127.5)
    return to_u8(xyzw[:, :3] * sign + 127.5)


def _pack_smallest_three(xyzw: np.ndarray) -> np.ndarray:
    largest = np.argmax(np.abs(xyzw), axis=1)
    rows = np.arange(len(xyzw))
    negate = xyzw[rows, largest] < 0
    comp = largest.astype(np.uint64)
    for i in range(4):
        keep = largest != i
        negbit = ((xyzw[:, i] < 0) ^ negate).astype(np.uint64)
        mag = np.floor(511 * (np.abs(xyzw[:, i]) / SQRT1_2) + 0.5).astype(np.uint64)
        mag = np.minimum(mag, 511)
        comp = np.where(keep, (comp << np.uint64(10)) | (negbit << np.uint64(9)) | mag, comp)
    comp = comp.astype(np.uint32)
    return np.stack([(comp >> s) & 0xFF for s in (0, 8, 16, 24)], axis=1).astype(np.uint8)


def write(path: str, cloud: GaussianCloud, version: int = 3) -> None:
    """Write ``cloud`` as an SPZ file, atomically (version 3 by default: gzip, which every SPZ
    reader opens; 4 needs zstandard)."""
    atomic_write(path, spz_bytes(cloud, version))
