"""PlayCanvas SOG, version 2 ("spatially ordered Gaussians"): a ``meta.json`` and lossless WebP
images, either side by side in a folder or bundled in one zip (``.sog``). Read following
splat-transform's ``src/lib/readers/read-sog.ts`` (v2.7):

* ``means_l``/``means_u``: 16-bit (low byte, high byte) per axis, lerped between ``mins`` and
  ``maxs`` of a log transform ``sign(x) * log(|x| + 1)``, which is undone;
* ``quats``: smallest three in RGB (each ``b / 255 * 2 - 1``, over sqrt 2), alpha 252 + the index
  of the largest component, order w x y z;
* ``scales`` and ``sh0`` RGB: indices into 256-entry codebooks (log-scales, SH DC); ``sh0`` alpha
  is sigmoid(opacity) * 255;
* ``shN`` (optional): a 16-bit palette label per Gaussian (``shN_labels``) and the palette in
  ``shN_centroids`` (64 entries per row, one pixel per coefficient, RGB indices into a codebook).

Positions are already in the PLY axes. WebP decoding needs Pillow (extra ``formats``). The legacy
version 1 layout (no ``version`` field) is recognized and refused by name.
"""

from __future__ import annotations

import io
import json
import os
import zipfile
from pathlib import Path

import numpy as np

from ..cloud import GaussianCloud
from ..errors import FormatError, UnsupportedError
from .common import check_count, logit

NAME = "PlayCanvas SOG"
_MAX_META = 64 * 1024 * 1024


def sniff(head: bytes, size: int | None = None) -> bool:
    if head.startswith(b"PK\x03\x04") and len(head) >= 30:
        length = int.from_bytes(head[26:28], "little")
        first = head[30:30 + length]
        return first == b"meta.json" or first.endswith(b".webp")
    text = head.lstrip()
    return text.startswith(b"{") and b'"means"' in head and b'"quats"' in head and \
        b'"files"' in head


class _Files:
    """The named files of a SOG: members of a zip, or siblings of its meta.json."""

    def __init__(self, path: str) -> None:
        self.path = path
        self.zip = None
        with open(path, "rb") as fh:
            if fh.read(4) == b"PK\x03\x04":
                try:
                    self.zip = zipfile.ZipFile(path)
                except zipfile.BadZipFile as exc:
                    raise FormatError(f"{path}: corrupt SOG zip ({exc})", "truncated") from None

    def read(self, name: str) -> bytes:
        if not isinstance(name, str) or not name or "/" in name or "\\" in name or \
                name in (".", ".."):
            raise FormatError(f"{self.path}: SOG names a file {name!r} that is no plain file "
                              "name", "bad-value")
        if self.zip is not None:
            try:
                info = self.zip.getinfo(name)
                if info.file_size > _MAX_META * 16:
                    raise FormatError(f"{self.path}: SOG member {name} is too large", "limit-exceeded")
                return self.zip.read(info)
            except KeyError:
                raise FormatError(f"{self.path}: the SOG lacks {name}", "truncated") from None
            except (zipfile.BadZipFile, OSError, EOFError) as exc:
                raise FormatError(f"{self.path}: SOG member {name} is corrupt ({exc})",
                                  "decompression-failed") from None
        sibling = Path(self.path).parent / name
        try:
            return sibling.read_bytes()
        except FileNotFoundError:
            raise FormatError(f"{self.path}: the SOG file {name} is missing next to it",
                              "truncated") from None

    def meta(self) -> dict:
        data = self.read("meta.json") if self.zip is not None else Path(self.path).read_bytes()
        if len(data) > _MAX_META:
            raise FormatError(f"{self.path}: SOG meta.json is too large", "limit-exceeded")
        try:
            meta = json.loads(data)
        except (UnicodeDecodeError, ValueError) as exc:
            raise FormatError(f"{self.path}: SOG meta.json is not JSON ({exc})",
                              "bad-metadata") from None
        if not isinstance(meta, dict):
            raise FormatError(f"{self.path}: SOG meta.json is not a JSON object", "bad-metadata")
        return meta


def _image(files: _Files, name: str, count: int) -> np.ndarray:
    """The first ``count`` RGBA pixels of a WebP, as (count, 4) uint8, in row-major order."""
    try:
        from PIL import Image
    except ModuleNotFoundError:
        raise FormatError(f"{files.path}: reading SOG needs Pillow: pip install "
                          "'spcodec[formats]'", "codec-unavailable") from None
    data = files.read(name)
    try:
        with Image.open(io.BytesIO(data)) as img:
            if img.format != "WEBP":
                raise FormatError(f"{files.path}: SOG image {name} is {img.format}, not WebP",
                                  "bad-value")
            if img.width * img.height < count:
                raise FormatError(f"{files.path}: SOG image {name} has {img.width}x{img.height}"
                                  f" pixels, fewer than its {count} Gaussians", "truncated")
            pixels = np.asarray(img.convert("RGBA"), np.uint8)
    except FormatError:
        raise
    except (OSError, ValueError, SyntaxError) as exc:  # PIL's errors for damaged images
        raise FormatError(f"{files.path}: SOG image {name} does not decode ({exc})",
                          "decompression-failed") from None
    return pixels.reshape(-1, 4)[:count] if count else pixels.reshape(-1, 4)


def _field(meta: dict, path: str, key: str) -> dict:
    part = meta.get(key)
    if not isinstance(part, dict):
        raise FormatError(f"{path}: SOG meta.json lacks '{key}'", "bad-metadata")
    return part


def _codebook(path: str, part: dict, key: str) -> np.ndarray:
    try:
        book = np.asarray(part["codebook"], np.float32)
    except (KeyError, TypeError, ValueError):
        raise FormatError(f"{path}: SOG '{key}' has no numeric codebook", "bad-metadata") from None
    if book.ndim != 1 or len(book) == 0 or len(book) > 65536 or not np.isfinite(book).all():
        raise FormatError(f"{path}: SOG '{key}' codebook is malformed", "bad-metadata")
    return np.concatenate([book, np.zeros(256 - len(book) % 256 if len(book) < 256 else 0,
                                          np.float32)])


def _files(path: str, part: dict, key: str, n: int) -> list[str]:
    names = part.get("files")
    if not isinstance(names, list) or len(names) < n:
        raise FormatError(f"{path}: SOG '{key}' names {names!r}, not {n} files", "bad-metadata")
    return names


def read(path: str) -> GaussianCloud:
    files = _Files(path)
    meta = files.meta()
    version = meta.get("version")
    if version is None:
        raise UnsupportedError(f"{path}: a version 1 SOG (no 'version' in meta.json); spcodec "
                               "reads version 2: convert it with 'splat-transform in.json out.sog'")
    if version != 2:
        raise UnsupportedError(f"{path}: SOG version {version!r}; spcodec reads version 2")
    count = meta.get("count")
    if not isinstance(count, int) or isinstance(count, bool) or count <= 0:
        raise FormatError(f"{path}: SOG count {count!r} is not a positive integer",
                          "bad-metadata")
    check_count(path, count, os.path.getsize(path))

    means = _field(meta, path, "means")
    try:
        lo_b, hi_b = np.asarray(means["mins"], np.float64), np.asarray(means["maxs"], np.float64)
        assert lo_b.shape == (3,) and hi_b.shape == (3,) and np.isfinite([lo_b, hi_b]).all()
    except (KeyError, TypeError, ValueError, AssertionError):
        raise FormatError(f"{path}: SOG means lack 3 finite mins and maxs", "bad-metadata") \
            from None
    names = _files(path, means, "means", 2)
    lo = _image(files, names[0], count)[:, :3].astype(np.uint32)
    hi = _image(files, names[1], count)[:, :3].astype(np.uint32)
    span = np.where(hi_b - lo_b != 0, hi_b - lo_b, 1.0)
    logged = lo_b + span * ((lo | (hi << 8)) / 65535.0)
    xyz = np.sign(logged) * np.expm1(np.abs(logged))

    quats = _image(files, _files(path, _field(meta, path, "quats"), "quats", 1)[0], count)
    wxyz = _unpack_quats(quats)

    scales_part = _field(meta, path, "scales")
    scale_book = _codebook(path, scales_part, "scales")
    scales = scale_book[_image(files, _files(path, scales_part, "scales", 1)[0], count)[:, :3]]

    sh0_part = _field(meta, path, "sh0")
    sh0_book = _codebook(path, sh0_part, "sh0")
    sh0 = _image(files, _files(path, sh0_part, "sh0", 1)[0], count)
    sh_dc = sh0_book[sh0[:, :3]]
    opacities = logit(sh0[:, 3] / 255.0)

    sh_rest = np.zeros((count, 0, 3), np.float32)
    if isinstance(meta.get("shN"), dict):
        sh_rest = _read_shn(path, files, meta["shN"], count)
    return GaussianCloud(means=xyz, scales=scales, quats=wxyz, opacities=opacities,
                         sh_dc=sh_dc, sh_rest=sh_rest)


def _unpack_quats(px: np.ndarray) -> np.ndarray:
    tag = px[:, 3].astype(np.int64)
    valid = (tag >= 252) & (tag <= 255)
    largest = np.where(valid, tag - 252, 0)
    abc = (px[:, :3].astype(np.float64) / 255 * 2 - 1) / np.sqrt(2)
    others = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])[largest]
    out = np.zeros((len(px), 4))
    rows = np.arange(len(px))[:, None]
    out[rows, others] = abc
    out[rows[:, 0], largest] = np.sqrt(np.maximum(0.0, 1 - (abc ** 2).sum(axis=1)))
    out[~valid] = [1.0, 0.0, 0.0, 0.0]  # as the reference: an invalid tag is the identity
    return out


def _read_shn(path: str, files: _Files, part: dict, count: int) -> np.ndarray:
    bands = part.get("bands")
    if bands not in (1, 2, 3):
        raise FormatError(f"{path}: SOG shN bands {bands!r} is not 1..3", "bad-metadata")
    k = [0, 3, 8, 15][bands]
    palette = part.get("count")
    if not isinstance(palette, int) or palette <= 0 or palette > 65536:
        raise FormatError(f"{path}: SOG shN count {palette!r} is not 1..65536", "bad-metadata")
    book = _codebook(path, part, "shN")
    names = _files(path, part, "shN", 2)
    centroids = _image(files, names[0], 0)
    width = 64 * k
    if len(centroids) % width:
        raise FormatError(f"{path}: SOG shN centroids are not {width} pixels wide", "bad-value")
    labels = _image(files, names[1], count)
    label = labels[:, 0].astype(np.int64) | (labels[:, 1].astype(np.int64) << 8)
    # centroid c, coefficient j sits at pixel (c % 64) * k + j of row c // 64
    pixel = (label // 64)[:, None] * width + (label % 64)[:, None] * k + np.arange(k)[None, :]
    ok = (label < palette)[:, None] & (pixel < len(centroids))
    rgb = centroids[np.where(ok, pixel, 0), :3]  # (count, k, 3)
    return np.where(ok[..., None], book[rgb], 0.0).astype(np.float32)


def describe(path: str) -> str:
    files = _Files(path)
    meta = files.meta()
    shn = meta.get("shN") if isinstance(meta.get("shN"), dict) else {}
    where = "bundled .sog" if files.zip is not None else "unbundled meta.json"
    count = meta.get("count")
    count = f"{count:,}" if isinstance(count, int) else repr(count)
    return (f"PlayCanvas SOG v{meta.get('version', 1)} ({where}), {count} Gaussians, "
            f"SH degree {shn.get('bands', 0)}")
