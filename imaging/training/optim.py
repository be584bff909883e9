"""The optimizer of every training loop: the standard 3DGS parameter groups, rates and schedule.

Rates are those of the INRIA 3DGS code and gsplat's default strategy, which trained almost every
model people compress: Adam (eps 1e-15) with one group per attribute, the position rate decaying
exponentially from 1.6e-4 to 1.6e-6 times the scene extent over the run, and constant rates for
the rest (colour 2.5e-3, higher SH bands 20 times less, opacity 2.5e-2, log-scale 5e-3, rotation
1e-3). Positions are scaled by the extent so a 0.3-unit object and a 300-unit room move alike.

Free Gaussians are held as six leaf tensors (:class:`FreeGaussians`) rather than the renderer's
:class:`~spcodec.imaging.render.GaussianParams`, because the DC colour and the higher SH bands take
different rates; :meth:`FreeGaussians.params` joins them for the renderer.
"""

from __future__ import annotations

import numpy as np
import torch

from spcodec.cloud import GaussianCloud

from ..render import GaussianParams
from .rates import LearningRates, position_rate

_ATTRIBUTES = ("means", "scales", "quats", "opacities", "sh_dc", "sh_rest")


class FreeGaussians:
    """Gaussians optimized freely (retraining, vanilla training): six leaf tensors and their Adam.

    ``sh_dc`` (N, 3) and ``sh_rest`` (N, K, 3) are separate leaves because they take different
    rates; :meth:`params` joins them. The position rate follows :func:`position_rate` over the run.
    """

    def __init__(self, cloud: GaussianCloud, device: torch.device | str,
                 rates: LearningRates = LearningRates(), extent: float = 1.0) -> None:
        arrays = (cloud.means, cloud.scales, cloud.quats, cloud.opacities, cloud.sh_dc,
                  cloud.sh_rest)
        self.tensors = {name: torch.tensor(np.ascontiguousarray(a), dtype=torch.float32,
                                           device=device).requires_grad_(True)
                        for name, a in zip(_ATTRIBUTES, arrays)}
        self.rates, self.extent = rates, float(extent)
        self.optimizer = make_optimizer(self.tensors, rates, self.extent)

    def __len__(self) -> int:
        return int(self.tensors["means"].shape[0])

    def params(self) -> GaussianParams:
        t = self.tensors
        return GaussianParams(t["means"], t["scales"], t["quats"], t["opacities"],
                              torch.cat([t["sh_dc"][:, None, :], t["sh_rest"]], dim=1))

    def before_step(self, step: int, total: int) -> None:
        set_position_rate(self.optimizer, position_rate(self.rates, self.extent, step, total))

    def state_dict(self) -> dict:
        return {"tensors": {k: v.detach().clone() for k, v in self.tensors.items()},
                "optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        with torch.no_grad():
            for name, value in state["tensors"].items():
                self.tensors[name].copy_(value)
        self.optimizer.load_state_dict(state["optimizer"])

    def to_cloud(self) -> GaussianCloud:
        """A float32 numpy copy, quaternions normalized (the renderer's and the coder's view)."""
        with torch.no_grad():
            t = self.tensors
            quats = t["quats"] / t["quats"].norm(dim=1, keepdim=True).clamp_min(1e-12)
            arrays = [a.detach().to("cpu", torch.float32).numpy() for a in
                      (t["means"], t["scales"], quats, t["opacities"], t["sh_dc"], t["sh_rest"])]
        means, scales, quats, opacities, sh_dc, sh_rest = arrays
        return GaussianCloud(means=means, scales=scales, quats=quats, opacities=opacities,
                             sh_dc=sh_dc, sh_rest=sh_rest)


def make_optimizer(tensors: dict[str, torch.Tensor], rates: LearningRates,
                   extent: float) -> torch.optim.Adam:
    """Adam (eps 1e-15) with one group per attribute, named like it; the position group's rate is
    set each step by :func:`set_position_rate`."""
    lr = {"means": rates.position_init * extent, "scales": rates.scale, "quats": rates.rotation,
          "opacities": rates.opacity, "sh_dc": rates.sh_dc,
          "sh_rest": rates.sh_dc / rates.sh_rest_divisor}
    groups = [{"params": [tensors[name]], "lr": lr[name], "name": name} for name in _ATTRIBUTES]
    return torch.optim.Adam(groups, lr=0.0, eps=1e-15)


def set_position_rate(optimizer: torch.optim.Optimizer, rate: float) -> None:
    for group in optimizer.param_groups:
        if group.get("name") == "means":
            group["lr"] = rate


def camera_extent(positions: np.ndarray) -> float:
    """1.1 times the largest distance of a camera centre from their mean (the 3DGS rule for the
    spatial rate scale); never zero."""
    positions = np.asarray(positions, np.float64).reshape(-1, 3)
    radius = float(np.linalg.norm(positions - positions.mean(axis=0), axis=1).max())
    return 1.1 * radius if radius > 0 else 1.0
