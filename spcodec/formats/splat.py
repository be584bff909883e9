"""antimatter15's ``.splat`` (the WebGL viewer's format, also written by many converters).

32 bytes per Gaussian, no header: position (3 float32), *linear* scales (3 float32), colour RGBA
(4 uint8: ``(0.5 + SH_C0 * dc) * 255`` and ``sigmoid(opacity) * 255``), rotation (4 uint8,
w x y z of the unit quaternion mapped from [-1, 1] by ``q * 128 + 128``). No SH beyond DC.

With no magic number it is recognized by plausibility alone: a size that is a multiple of 32 and
records whose floats are finite and of sane size, whose scales are not negative and whose
quaternion bytes have about unit length. It is the registry's last resort.
"""

from __future__ import annotations

import numpy as np

from ..cloud import SH_C0, GaussianCloud
from ..errors import FormatError
from ..fileio import atomic_write
from .common import check_count, logit, sigmoid, unit_quats

NAME = "antimatter15 .splat"
RECORD = np.dtype([("position", "<f4", 3), ("scale", "<f4", 3), ("rgba", "u1", 4),
                   ("rot", "u1", 4)])
assert RECORD.itemsize == 32
_SNIFF_RECORDS = 2048


def sniff(head: bytes, size: int | None = None) -> bool:
    if size is None or size == 0 or size % RECORD.itemsize:
        return False
    n = min(len(head) // RECORD.itemsize, _SNIFF_RECORDS)
    if n == 0:
        return False
    return plausible(np.frombuffer(head, RECORD, count=n))


def plausible(records: np.ndarray) -> bool:
    """Whether records look like Gaussians (used on the first ones only)."""
    with np.errstate(all="ignore"):
        floats = np.concatenate([records["position"], records["scale"]], axis=1)
        if not np.isfinite(floats).all() or np.abs(floats).max() > 1e7:
            return False
        if (records["scale"] < 0).any():
            return False
        q = records["rot"].astype(np.float64) - 128
        length = np.sqrt((q * q).sum(axis=1))  # 128 for a unit quaternion, up to rounding
    return bool(np.mean((length > 100) & (length < 160)) >= 0.99)


def read(path: str) -> GaussianCloud:
    with open(path, "rb") as fh:
        data = fh.read()
    if len(data) % RECORD.itemsize:
        raise FormatError(f"{path}: {len(data)} bytes is not a whole number of 32-byte .splat "
                          "records", "truncated")
    n = len(data) // RECORD.itemsize
    check_count(path, n)
    return cloud_from_records(np.frombuffer(data, RECORD))


def cloud_from_records(records: np.ndarray) -> GaussianCloud:
    """The Gaussians of ``RECORD`` records: apart from :func:`read` so that a chunked reader
    (``spcodec.tiling.source``) decodes a memory-mapped slice of the file the same way."""
    n = len(records)
    scales = records["scale"].astype(np.float64)
    with np.errstate(divide="ignore"):
        log_scales = np.log(np.maximum(scales, 1e-30))  # 0 (an underflowed tiny scale): -69
    rgba = records["rgba"].astype(np.float64) / 255.0
    quats = records["rot"].astype(np.float32) - 128
    quats[(quats == 0).all(axis=1), 0] = 1  # an all-128 record: the identity, not a NaN later
    return GaussianCloud(
        means=records["position"],
        scales=log_scales,
        quats=quats / 128,
        opacities=logit(rgba[:, 3]),
        sh_dc=(rgba[:, :3] - 0.5) / SH_C0,
        sh_rest=np.zeros((n, 0, 3), np.float32),
    )


def splat_bytes(cloud: GaussianCloud) -> bytes:
    """The ``.splat`` file for ``cloud`` in antimatter15's convert.py order (largest, most opaque
    first); SH beyond DC are dropped."""
    n = len(cloud)
    records = np.zeros(n, RECORD)
    records["position"] = cloud.means
    records["scale"] = np.exp(cloud.scales)  # float32, as convert.py
    colour = 0.5 + SH_C0 * cloud.sh_dc.astype(np.float64)
    alpha = sigmoid(cloud.opacities).astype(np.float64)
    # truncated, not rounded, as convert.py does
    records["rgba"] = np.clip(np.concatenate([colour, alpha[:, None]], axis=1) * 255, 0,
                              255).astype(np.uint8)
    records["rot"] = np.clip(unit_quats(cloud.quats) * 128 + 128, 0, 255).astype(np.uint8)
    order = np.argsort(-np.exp(cloud.scales.astype(np.float64).sum(axis=1)) * alpha,
                       kind="stable")
    return records[order].tobytes()


def write(path: str, cloud: GaussianCloud) -> None:
    atomic_write(path, splat_bytes(cloud))
