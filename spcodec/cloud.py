"""The scene model shared by every part of spcodec: a set of 3D Gaussians as numpy arrays.

Parametrization (that of the INRIA 3DGS code and its PLY files):

* ``means``      (N, 3) float32 - centres in world units.
* ``scales``     (N, 3) float32 - *log* standard deviations along the local axes.
* ``quats``      (N, 4) float32 - rotation quaternions, order (w, x, y, z); need not be unit length.
* ``opacities``  (N,)   float32 - opacity *logits* (the rendered opacity is ``sigmoid(opacities)``).
* ``sh_dc``      (N, 3) float32 - degree-0 spherical-harmonic coefficient per RGB channel.
* ``sh_rest``    (N, K, 3) float32 - higher SH coefficients, coefficient-major then channel, with
  ``K = (degree + 1) ** 2 - 1`` in {0, 3, 8, 15} for SH degree 0..3.

Structure-of-arrays keeps every operation vectorized, and the same object flows through the PLY
reader, the encoder, the decoder and the renderers.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Iterable, Sequence

import numpy as np

from .errors import FormatError

SH_REST_COUNTS = {0: 0, 1: 3, 2: 8, 3: 15}
"""Number of non-DC SH coefficients per channel for each SH degree."""

SH_C0 = 0.28209479177387814
"""Value of the degree-0 real spherical harmonic; colour = SH_C0 * sh_dc + 0.5."""


def sh_degree_for_rest_count(k: int) -> int:
    """SH degree whose non-DC coefficient count per channel is ``k``; FormatError otherwise."""
    for degree, count in SH_REST_COUNTS.items():
        if count == k:
            return degree
    raise FormatError(f"{k} higher-order SH coefficients per channel match no SH degree 0..3",
                      "bad-value")


@dataclass(eq=False)
class GaussianCloud:
    """A set of 3D Gaussians in the INRIA parametrization (see the module docstring)."""

    means: np.ndarray
    scales: np.ndarray
    quats: np.ndarray
    opacities: np.ndarray
    sh_dc: np.ndarray
    sh_rest: np.ndarray

    def __post_init__(self) -> None:
        self.means = _as_f32(self.means, "means")
        self.scales = _as_f32(self.scales, "scales")
        self.quats = _as_f32(self.quats, "quats")
        self.opacities = _as_f32(self.opacities, "opacities")
        self.sh_dc = _as_f32(self.sh_dc, "sh_dc")
        self.sh_rest = _as_f32(self.sh_rest, "sh_rest")
        n = self.means.shape[0] if self.means.ndim == 2 else -1
        expected = {
            "means": (n, 3), "scales": (n, 3), "quats": (n, 4), "opacities": (n,), "sh_dc": (n, 3),
        }
        for name, shape in expected.items():
            if getattr(self, name).shape != shape:
                raise ValueError(f"{name} has shape {getattr(self, name).shape}, expected {shape}")
        rest = self.sh_rest
        if rest.ndim != 3 or rest.shape[0] != n or rest.shape[2] != 3:
            raise ValueError(f"sh_rest has shape {rest.shape}, expected ({n}, K, 3)")
        sh_degree_for_rest_count(rest.shape[1])

    # ----------------------------------------------------------------------------------- basics
    def __len__(self) -> int:
        return int(self.means.shape[0])

    @property
    def sh_degree(self) -> int:
        """Spherical-harmonic degree 0..3."""
        return sh_degree_for_rest_count(self.sh_rest.shape[1])

    @classmethod
    def empty(cls, sh_degree: int = 0) -> "GaussianCloud":
        """A cloud with no Gaussians."""
        return cls.zeros(0, sh_degree)

    @classmethod
    def zeros(cls, n: int, sh_degree: int = 0) -> "GaussianCloud":
        """``n`` Gaussians with zero parameters and identity rotations (useful for building)."""
        quats = np.zeros((n, 4), np.float32)
        quats[:, 0] = 1.0
        return cls(
            means=np.zeros((n, 3), np.float32),
            scales=np.zeros((n, 3), np.float32),
            quats=quats,
            opacities=np.zeros(n, np.float32),
            sh_dc=np.zeros((n, 3), np.float32),
            sh_rest=np.zeros((n, SH_REST_COUNTS[sh_degree], 3), np.float32),
        )

    def arrays(self) -> dict[str, np.ndarray]:
        """The parameter arrays by field name."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def subset(self, index: np.ndarray | slice | Sequence[int]) -> "GaussianCloud":
        """The Gaussians selected by a boolean mask, an index array or a slice (copies)."""
        return GaussianCloud(**{k: np.array(v[index]) for k, v in self.arrays().items()})

    def view(self, start: int, stop: int) -> "GaussianCloud":
        """Gaussians ``start..stop`` as views sharing memory with this cloud (no copy)."""
        out = object.__new__(GaussianCloud)
        for name, array in self.arrays().items():
            setattr(out, name, array[start:stop])
        return out

    def with_sh_degree(self, degree: int) -> "GaussianCloud":
        """A copy truncated or zero-padded to SH ``degree``."""
        k = SH_REST_COUNTS[degree]
        rest = np.zeros((len(self), k, 3), np.float32)
        keep = min(k, self.sh_rest.shape[1])
        rest[:, :keep] = self.sh_rest[:, :keep]
        arrays = self.arrays()
        arrays["sh_rest"] = rest
        return GaussianCloud(**{n: np.array(a) for n, a in arrays.items()})

    @staticmethod
    def concat(clouds: Iterable["GaussianCloud"], sh_degree: int | None = None) -> "GaussianCloud":
        """Concatenate clouds, padding SH to the highest degree present (or ``sh_degree``)."""
        clouds = list(clouds)
        if not clouds:
            return GaussianCloud.empty(sh_degree or 0)
        degree = max(c.sh_degree for c in clouds) if sh_degree is None else sh_degree
        clouds = [c if c.sh_degree == degree else c.with_sh_degree(degree) for c in clouds]
        return GaussianCloud(**{
            name: np.concatenate([getattr(c, name) for c in clouds], axis=0)
            for name in clouds[0].arrays()
        })

    # ------------------------------------------------------------------------- derived values
    def activated_opacity(self) -> np.ndarray:
        """Opacity in [0, 1] (sigmoid of the logits)."""
        return (1.0 / (1.0 + np.exp(-self.opacities.astype(np.float64)))).astype(np.float32)

    def rgb(self) -> np.ndarray:
        """View-independent colour from the DC term, ``SH_C0 * dc + 0.5`` (not clamped)."""
        return (SH_C0 * self.sh_dc + 0.5).astype(np.float32)

    def is_finite(self) -> bool:
        """True when no parameter is NaN or infinite."""
        return all(np.isfinite(a).all() for a in self.arrays().values())

    def check_finite(self) -> None:
        """Refuse NaN or infinite parameters with one line (``ply-invalid``).

        The one check that ``encode``, ``render`` and ``eval`` share: the encoder cannot code
        such values and a renderer would draw garbage (or nothing) without a word, so a scene
        holding them is refused everywhere rather than judged in one place and coded in none.
        The line names every kind of bad value by its PLY property ("NaN in x; infinite value
        in opacity"): naming only the first array sent the user to fix one column and run again
        to meet the next.
        """
        bad = [(field, array) for field, array in self.arrays().items()
               if not np.isfinite(array).all()]
        if not bad:
            return
        found: dict[str, list[str]] = {"NaN": [], "infinite value": []}
        counts = []
        for field, array in bad:
            names, columns = _property_columns(field, array)
            for kind, test in (("NaN", np.isnan), ("infinite value", np.isinf)):
                found[kind] += [n for n, hit in zip(names, test(columns).any(axis=0)) if hit]
            rows = np.unique(np.nonzero(~np.isfinite(columns))[0])
            counts.append(f"{len(rows)} Gaussians have NaN or infinite {field} (first: #{rows[0]})")
        kinds = [f"{kind} in {_name_list(names)}" for kind, names in found.items() if names]
        raise FormatError(f"{'; '.join(kinds)}: {', '.join(counts)}; remove them from the scene "
                          "first", "ply-invalid")

    def equals(self, other: "GaussianCloud") -> bool:
        """Bit-exact equality of every array (NaNs compare by bit pattern)."""
        if len(self) != len(other) or self.sh_degree != other.sh_degree:
            return False
        return all(
            a.shape == b.shape and a.tobytes() == b.tobytes()
            for a, b in zip(self.arrays().values(), other.arrays().values())
        )

    def nbytes(self) -> int:
        """Bytes the parameters take as float32 (the size of an uncompressed PLY body)."""
        return sum(a.nbytes for a in self.arrays().values())

    def __repr__(self) -> str:
        return f"GaussianCloud(n={len(self)}, sh_degree={self.sh_degree})"


def _as_f32(a: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(a)
    if arr.dtype != np.float32:
        arr = arr.astype(np.float32)
    return np.ascontiguousarray(arr)


def _property_columns(field: str, array: np.ndarray) -> tuple[list[str], np.ndarray]:
    """One of a cloud's arrays as (PLY property names, an (n, len(names)) array of columns)."""
    n = len(array)
    if field == "sh_rest":  # (n, k, 3), written channel-major as f_rest_0..3k-1
        columns = array.transpose(0, 2, 1).reshape(n, -1)
        return [f"f_rest_{i}" for i in range(columns.shape[1])], columns
    columns = array.reshape(n, -1)
    fixed = {"means": ["x", "y", "z"], "opacities": ["opacity"]}
    prefix = {"scales": "scale_", "quats": "rot_", "sh_dc": "f_dc_"}.get(field, f"{field}_")
    return fixed.get(field, [f"{prefix}{i}" for i in range(columns.shape[1])]), columns


def _name_list(names: list[str], shown: int = 4) -> str:
    """``x, y`` or, for many properties, the first few and how many more."""
    if len(names) <= shown:
        return ", ".join(names)
    return f"{', '.join(names[:shown])} and {len(names) - shown} more"
