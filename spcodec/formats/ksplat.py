"""mkkellogg GaussianSplats3D ``.ksplat`` (version 0.1), read following splat-transform's
``src/lib/readers/read-ksplat.ts``.

A 4096-byte main header (version 0.1, section counts, splat count, compression mode 0-2, SH
range), ``max sections`` 1024-byte section headers, then per section its bucket data (partial
bucket sizes, bucket centres) and its splats: mode 0 stores float32 centre, scale (linear),
rotation (w x y z) and SH; modes 1 and 2 store 16-bit bucket-relative positions and float16
scales and rotations, and SH as float16 (mode 1) or bytes over [min, max] (mode 2). Colour is
RGBA bytes as in ``.splat``. Axes are the PLY ones.

The header has no magic number; the sniffer checks the version bytes and that the declared
counts and mode are consistent with the file size.
"""

from __future__ import annotations

import struct

import numpy as np

from ..cloud import SH_C0, GaussianCloud
from ..errors import FormatError, UnsupportedError
from .common import check_count, logit

NAME = "GaussianSplats3D .ksplat"
MAIN_HEADER, SECTION_HEADER = 4096, 1024
# centre, scale, rotation, colour bytes; bytes per SH value; default position quantization range
_MODES = {0: (12, 12, 16, 4, 4, 1), 1: (6, 6, 8, 4, 2, 32767), 2: (6, 6, 8, 4, 1, 32767)}
_SH_VALUES = [0, 9, 24, 45]


def _main(head: bytes) -> tuple[int, int, int, int, int, float, float]:
    major, minor = head[0], head[1]
    max_sections, _sections, _max_splats, splats = struct.unpack_from("<4I", head, 4)
    mode = struct.unpack_from("<H", head, 20)[0]
    sh_min, sh_max = struct.unpack_from("<2f", head, 36)
    return major, minor, max_sections, splats, mode, sh_min, sh_max


def sniff(head: bytes, size: int | None = None) -> bool:
    if len(head) < MAIN_HEADER + SECTION_HEADER or size is None:
        return False
    major, minor, max_sections, splats, mode, _, _ = _main(head)
    if major != 0 or minor < 1 or mode not in _MODES or splats == 0 or \
            not 1 <= max_sections <= 1 << 16:
        return False
    if any(head[22:24]) or size < MAIN_HEADER + SECTION_HEADER:
        return False  # (a short file is claimed, and read() names it truncated)
    # the first section header: a count within its maximum and a known SH degree
    count, max_count = struct.unpack_from("<2I", head, MAIN_HEADER)
    degree = struct.unpack_from("<H", head, MAIN_HEADER + 40)[0]
    return count <= max_count and degree <= 3


def read(path: str) -> GaussianCloud:
    with open(path, "rb") as fh:
        data = fh.read()
    if len(data) < MAIN_HEADER:
        raise FormatError(f"{path}: too small for a .ksplat header", "truncated")
    major, minor, max_sections, total, mode, sh_min, sh_max = _main(data)
    if major != 0 or minor < 1:
        raise UnsupportedError(f"{path}: .ksplat version {major}.{minor}; spcodec reads 0.1")
    if mode not in _MODES:
        raise FormatError(f"{path}: .ksplat compression mode {mode} is not 0, 1 or 2",
                          "bad-value")
    check_count(path, total, len(data))
    if total == 0:
        raise FormatError(f"{path}: .ksplat declares no Gaussians", "bad-value")
    sh_min = sh_min or -1.5
    sh_max = sh_max or 1.5
    c_bytes, s_bytes, r_bytes, col_bytes, h_bytes, default_range = _MODES[mode]
    if MAIN_HEADER + max_sections * SECTION_HEADER > len(data):
        raise FormatError(f"{path}: .ksplat section headers run past the end", "truncated")
    headers = []
    degree = 0
    for s in range(max_sections):
        at = MAIN_HEADER + s * SECTION_HEADER
        count, max_count, capacity, buckets = struct.unpack_from("<4I", data, at)
        block = struct.unpack_from("<f", data, at + 16)[0]
        storage = struct.unpack_from("<H", data, at + 20)[0]
        qrange = struct.unpack_from("<I", data, at + 24)[0] or default_range
        full, partial = struct.unpack_from("<2I", data, at + 32)
        sec_degree = struct.unpack_from("<H", data, at + 40)[0]
        if count and sec_degree > 3:
            raise FormatError(f"{path}: .ksplat section {s} has SH degree {sec_degree}",
                              "bad-value")
        if count > max_count:
            raise FormatError(f"{path}: .ksplat section {s} holds {count} of at most "
                              f"{max_count} splats", "bad-layout")
        headers.append((count, max_count, capacity, buckets, block, storage, qrange, full,
                        partial, sec_degree))
        if count:
            degree = max(degree, sec_degree)
    k = _SH_VALUES[degree] // 3
    means = np.zeros((total, 3), np.float32)
    scales = np.zeros((total, 3), np.float32)
    quats = np.zeros((total, 4), np.float32)
    rgba = np.zeros((total, 4), np.uint8)
    rest = np.zeros((total, 3, k), np.float32)  # channel-major, as f_rest
    offset = MAIN_HEADER + max_sections * SECTION_HEADER
    done = 0
    for s, (count, max_count, capacity, buckets, block, storage, qrange, full, partial,
            sec_degree) in enumerate(headers):
        values = _SH_VALUES[sec_degree]
        per_splat = c_bytes + s_bytes + r_bytes + col_bytes + values * h_bytes
        bucket_bytes = storage * buckets + 4 * partial
        end = offset + bucket_bytes + per_splat * max_count
        if end > len(data):
            raise FormatError(f"{path}: .ksplat section {s} runs past the end of the file",
                              "truncated")
        if done + count > total:
            raise FormatError(f"{path}: .ksplat sections hold more than the {total} splats "
                              "declared", "bad-layout")
        if count:
            records = np.frombuffer(data, np.uint8, per_splat * count,
                                    offset + bucket_bytes).reshape(count, per_splat)
            rows = slice(done, done + count)
            if mode == 0:
                floats = records[:, :40].copy().view("<f4")
                means[rows], scales[rows], quats[rows] = floats[:, :3], floats[:, 3:6], \
                    floats[:, 6:10]
            else:
                halves = records[:, 6:20].copy().view("<f2").astype(np.float32)
                scales[rows], quats[rows] = halves[:, :3], halves[:, 3:7]
                if buckets > (len(data) - offset) // 12 or capacity == 0 and full:
                    raise FormatError(f"{path}: .ksplat section {s} bucket table is malformed",
                                      "bad-layout")
                sizes = np.frombuffer(data, "<u4", partial, offset).astype(np.int64)
                centres = np.frombuffer(data, "<f4", 3 * buckets, offset + 4 * partial)
                bucket = _bucket_of(count, capacity, full, sizes)
                if bucket.size and bucket.max() >= buckets:
                    raise FormatError(f"{path}: .ksplat section {s} names a bucket beyond its "
                                      f"{buckets}", "bad-layout")
                q = records[:, :6].copy().view("<u2").astype(np.float32)
                scale = block / 2.0 / qrange
                means[rows] = (q - qrange) * scale + centres.reshape(-1, 3)[bucket]
            col = c_bytes + s_bytes + r_bytes
            rgba[rows] = records[:, col:col + 4]
            if values:
                raw = records[:, col + 4:col + 4 + values * h_bytes]
                if mode == 0:
                    sh = raw.copy().view("<f4")
                elif mode == 1:
                    sh = raw.copy().view("<f2").astype(np.float32)
                else:
                    sh = sh_min + raw.astype(np.float32) / 255 * (sh_max - sh_min)
                # stored band by band, each channel-major (R coefficients, then G, then B)
                at = 0
                for band, width in ((0, 3), (3, 5), (8, 7)):
                    if at >= values:
                        break
                    part = sh[:, at:at + 3 * width].reshape(count, 3, width)
                    rest[rows, :, band:band + width] = part
                    at += 3 * width
            done += count
        offset = end
    if done != total:
        raise FormatError(f"{path}: .ksplat sections hold {done} splats, the header declares "
                          f"{total}", "bad-layout")
    with np.errstate(divide="ignore", invalid="ignore"):
        log_scales = np.where(scales > 0, np.log(np.where(scales > 0, scales, 1)), -10.0)
    rgba_f = rgba.astype(np.float64) / 255.0
    return GaussianCloud(means=means, scales=log_scales, quats=quats,
                         opacities=logit(rgba_f[:, 3]), sh_dc=(rgba_f[:, :3] - 0.5) / SH_C0,
                         sh_rest=rest.transpose(0, 2, 1))


def _bucket_of(count: int, capacity: int, full: int, partial_sizes: np.ndarray) -> np.ndarray:
    """Each splat's bucket: full buckets of ``capacity``, then partial ones of the given sizes."""
    index = np.arange(count, dtype=np.int64)
    full_splats = full * capacity
    bucket = np.empty(count, np.int64)
    head = index < full_splats
    bucket[head] = index[head] // max(capacity, 1)
    if (~head).any():
        bounds = full_splats + np.cumsum(partial_sizes)
        bucket[~head] = full + np.searchsorted(bounds, index[~head], side="right")
    return bucket


def describe(path: str) -> str:
    with open(path, "rb") as fh:
        head = fh.read(MAIN_HEADER)
    major, minor, _, splats, mode, _, _ = _main(head)
    return f"GaussianSplats3D .ksplat v{major}.{minor}, {splats:,} Gaussians, compression mode {mode}"
