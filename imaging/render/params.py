"""Gaussian parameters as torch tensors, the form both renderers and the retraining loop use."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np
import torch

from spcodec.cloud import GaussianCloud

from .sh import sh_degree_for_coeff_count


@dataclass
class GaussianParams:
    """A GaussianCloud as tensors, in the same (INRIA, pre-activation) parametrization.

    * ``means`` (N, 3), ``scales`` (N, 3) log standard deviations, ``quats`` (N, 4) wxyz (need not
      be unit length), ``opacities`` (N,) logits;
    * ``sh`` (N, (d + 1) ** 2, 3): DC and higher coefficients in one tensor, coefficient-major,
      because renderers and optimizers treat them as one colour model.

    Keeping the raw parametrization means an optimizer steps in the same space the bitstream
    stores, and ``to_cloud`` is a copy, not a conversion.
    """

    means: torch.Tensor
    scales: torch.Tensor
    quats: torch.Tensor
    opacities: torch.Tensor
    sh: torch.Tensor

    def __post_init__(self) -> None:
        n = self.means.shape[0]
        expected = {"means": (n, 3), "scales": (n, 3), "quats": (n, 4), "opacities": (n,)}
        for name, shape in expected.items():
            if tuple(getattr(self, name).shape) != shape:
                raise ValueError(f"{name} has shape {tuple(getattr(self, name).shape)}, "
                                 f"expected {shape}")
        if self.sh.ndim != 3 or self.sh.shape[0] != n or self.sh.shape[2] != 3:
            raise ValueError(f"sh has shape {tuple(self.sh.shape)}, expected ({n}, K, 3)")
        sh_degree_for_coeff_count(self.sh.shape[1])
        devices = {t.device for t in self.tensors()}
        if len(devices) != 1:
            raise ValueError(f"parameters live on several devices: {sorted(map(str, devices))}")

    def __len__(self) -> int:
        return int(self.means.shape[0])

    @property
    def sh_degree(self) -> int:
        """SH degree 0..3 stored in ``sh``."""
        return sh_degree_for_coeff_count(self.sh.shape[1])

    @property
    def device(self) -> torch.device:
        return self.means.device

    def tensors(self) -> list[torch.Tensor]:
        """The five tensors, in field order (e.g. to hand to an optimizer)."""
        return [getattr(self, f.name) for f in fields(self)]

    def head(self, count: int) -> "GaussianParams":
        """The first ``count`` Gaussians (views of the same tensors, gradients flow through)."""
        return GaussianParams(*(t[:count] for t in self.tensors()))

    def detach(self) -> "GaussianParams":
        """The same values cut from the autograd graph."""
        return GaussianParams(*(t.detach() for t in self.tensors()))

    @classmethod
    def from_cloud(cls, cloud: GaussianCloud, device: torch.device | str = "cpu",
                   requires_grad: bool = False,
                   dtype: torch.dtype = torch.float32) -> "GaussianParams":
        """Copy a numpy cloud to ``device``; leaf tensors with gradients when ``requires_grad``."""
        sh = np.concatenate([cloud.sh_dc[:, None, :], cloud.sh_rest], axis=1)
        arrays = (cloud.means, cloud.scales, cloud.quats, cloud.opacities, sh)
        tensors = [torch.tensor(np.ascontiguousarray(a), dtype=dtype, device=device)
                   for a in arrays]
        for t in tensors:
            t.requires_grad_(requires_grad)
        return cls(*tensors)

    def to_cloud(self) -> GaussianCloud:
        """A float32 numpy copy (detached, on the CPU)."""
        arrays = [t.detach().to("cpu", torch.float32).numpy() for t in self.tensors()]
        means, scales, quats, opacities, sh = arrays
        return GaussianCloud(means=means, scales=scales, quats=quats, opacities=opacities,
                             sh_dc=sh[:, 0, :], sh_rest=sh[:, 1:, :])
