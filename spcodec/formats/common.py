"""Helpers the format modules share: activations, limits, small binary readers."""

from __future__ import annotations

import numpy as np

from ..errors import FormatError, LimitError
from ..limits import DEFAULT_LIMITS

OPACITY_EPS = 1e-6
"""Opacity bytes of 0 and 255 decode to the logits of this and 1 minus this (about -13.8 and
+13.8) instead of infinities: fully transparent and fully opaque in every renderer."""


def logit(p: np.ndarray) -> np.ndarray:
    p = np.clip(np.asarray(p, np.float64), OPACITY_EPS, 1.0 - OPACITY_EPS)
    return (np.log(p) - np.log1p(-p)).astype(np.float32)


def sigmoid(x: np.ndarray) -> np.ndarray:
    return (1.0 / (1.0 + np.exp(-np.asarray(x, np.float64)))).astype(np.float32)


def unit_quats(q: np.ndarray) -> np.ndarray:
    """Rows scaled to unit length (a zero row becomes the identity (1, 0, 0, 0))."""
    q = np.asarray(q, np.float64)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    out = np.where(norm > 0, q / np.where(norm > 0, norm, 1.0), [1.0, 0.0, 0.0, 0.0])
    return out


def to_u8(x: np.ndarray) -> np.ndarray:
    """Round and clamp to bytes (what the reference writers do)."""
    return np.clip(np.round(np.asarray(x, np.float64)), 0, 255).astype(np.uint8)


def check_count(name: str, count: int, stored_bytes: int | None = None) -> None:
    """Refuse a declared Gaussian count beyond the decoder's limit (one line, not a MemoryError)."""
    if count > DEFAULT_LIMITS.max_gaussians:
        raise LimitError(f"{name}: declares {count:,} Gaussians, more than the limit of "
                         f"{DEFAULT_LIMITS.max_gaussians:,}")
    if stored_bytes is not None:
        try:
            DEFAULT_LIMITS.check_gaussian_density(count, stored_bytes)
        except FormatError as exc:
            raise LimitError(f"{name}: {exc.args[0]}") from None
