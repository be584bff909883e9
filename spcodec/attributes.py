"""Gaussian attributes as the bitstream codes them (spec section 5, [R-30]..[R-34]).

Sketch models and patch codebooks code the same quantities in the same *coded domain*:

===========  ======================================================================================
attribute    coded value -> GaussianCloud parameter
===========  ======================================================================================
scale        log standard deviations, stored as is
rotation     quaternion (w, x, y, z); the decoder divides by its norm (identity if the norm < 1e-8)
opacity      opacity in [0, 1] (after the sigmoid); the decoder clamps it to [1e-4, 1 - 1e-4] and
             stores the logit
colour DC    degree-0 SH coefficient per channel, stored as is
SH rest      higher SH coefficients, coefficient-major then channel, stored as is
===========  ======================================================================================

Opacity is coded after activation because that is the quantity that reaches the image: a model or
codebook error of 0.01 means the same everywhere, while the same error on a logit does not.
"""

from __future__ import annotations

import enum

import numpy as np

from .cloud import SH_REST_COUNTS

OPACITY_MIN = 1e-4
"""Decoded opacity is clamped to [OPACITY_MIN, 1 - OPACITY_MIN] before taking the logit ([R-32])."""

QUAT_MIN_NORM = 1e-8
"""A coded quaternion shorter than this decodes to the identity rotation ([R-31])."""


class SketchAttribute(enum.IntEnum):
    """Attributes modelled per sketch cluster, in the order of the cluster record's degrees."""

    SCALE = 0
    ROTATION = 1
    OPACITY = 2
    COLOR_DC = 3
    SH_REST = 4

    def outputs(self, sh_degree: int) -> int:
        """Number of model outputs (columns of the coefficient matrix)."""
        if self is SketchAttribute.SH_REST:
            return 3 * SH_REST_COUNTS[sh_degree]
        return _BASE_WIDTH[self.name]


class PatchAttribute(enum.IntEnum):
    """Attributes coded with codebooks in patch layers; ids as stored in the codebook section."""

    SCALE = 0
    ROTATION = 1
    OPACITY = 2
    COLOR_DC = 3
    SH_BAND_1 = 4
    SH_BAND_2 = 5
    SH_BAND_3 = 6

    @property
    def width(self) -> int:
        """Number of scalar components of the attribute per Gaussian."""
        return _PATCH_WIDTH[self]

    @property
    def sh_slice(self) -> slice:
        """For an SH band: which rows of ``GaussianCloud.sh_rest`` it covers."""
        band = int(self) - 3
        start = band * band - 1
        return slice(start, (band + 1) * (band + 1) - 1)

    @staticmethod
    def for_sh_degree(sh_degree: int) -> list["PatchAttribute"]:
        """The attributes a patch layer carries for a scene of the given SH degree, in id order."""
        return [a for a in PatchAttribute if a <= 3 + sh_degree]


_BASE_WIDTH = {"SCALE": 3, "ROTATION": 4, "OPACITY": 1, "COLOR_DC": 3}
_PATCH_WIDTH = {
    PatchAttribute.SCALE: 3, PatchAttribute.ROTATION: 4, PatchAttribute.OPACITY: 1,
    PatchAttribute.COLOR_DC: 3, PatchAttribute.SH_BAND_1: 9, PatchAttribute.SH_BAND_2: 15,
    PatchAttribute.SH_BAND_3: 21,
}


def decode_opacity(coded: np.ndarray) -> np.ndarray:
    """Coded opacity (activated) -> logit, with the normative clamp."""
    a = np.clip(np.asarray(coded, dtype=np.float64), OPACITY_MIN, 1.0 - OPACITY_MIN)
    return np.log(a / (1.0 - a)).astype(np.float32)


def encode_opacity(logits: np.ndarray) -> np.ndarray:
    """Logit -> coded opacity (activated), float64."""
    return 1.0 / (1.0 + np.exp(-np.asarray(logits, dtype=np.float64)))


def decode_rotation(coded: np.ndarray) -> np.ndarray:
    """Coded quaternion -> unit quaternion (identity where the norm is below QUAT_MIN_NORM)."""
    q = np.asarray(coded, dtype=np.float64)
    with np.errstate(over="ignore"):
        norm = np.linalg.norm(q, axis=1, keepdims=True)
    small = norm[:, 0] < QUAT_MIN_NORM
    out = q / np.where(norm < QUAT_MIN_NORM, 1.0, norm)
    out[small] = (1.0, 0.0, 0.0, 0.0)
    huge = np.isinf(norm[:, 0]) & np.isfinite(q).all(axis=1)
    if huge.any():  # finite components whose squares overflow: scale first, the ratio is exact
        scaled = q[huge] / np.abs(q[huge]).max(axis=1, keepdims=True)
        out[huge] = scaled / np.linalg.norm(scaled, axis=1, keepdims=True)
    return out.astype(np.float32)


def canonical_rotation(quats: np.ndarray) -> np.ndarray:
    """Unit quaternions with w >= 0 (q and -q are the same rotation), float64; used by encoders."""
    q = decode_rotation(quats).astype(np.float64)
    return np.where(q[:, :1] < 0, -q, q)
