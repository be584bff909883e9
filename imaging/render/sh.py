"""Real spherical harmonics up to degree 3, in the basis and sign convention of 3DGS.

The INRIA 3DGS code, gsplat and every 3DGS PLY file store colour as coefficients of a real SH
basis that equals the textbook real SH (no Condon-Shortley phase) times ``(-1)**m``; the
coefficient index is ``l*l + l + m`` with ``m`` running from ``-l`` to ``l``. The constants below
are the normalisation factors of that basis written out for Cartesian unit directions, so colour
evaluation is a handful of polynomial terms per Gaussian and stays differentiable w.r.t. both the
coefficients and the direction (hence the means).
"""

from __future__ import annotations

import torch

SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
         0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)

MAX_SH_DEGREE = 3


def sh_coeff_count(degree: int) -> int:
    """Coefficients per channel for SH ``degree`` (DC included): ``(degree + 1) ** 2``."""
    if not 0 <= degree <= MAX_SH_DEGREE:
        raise ValueError(f"SH degree {degree} is outside 0..{MAX_SH_DEGREE}")
    return (degree + 1) ** 2


def sh_degree_for_coeff_count(count: int) -> int:
    """SH degree whose per-channel coefficient count (DC included) is ``count``."""
    for degree in range(MAX_SH_DEGREE + 1):
        if sh_coeff_count(degree) == count:
            return degree
    raise ValueError(f"{count} SH coefficients per channel match no SH degree 0..{MAX_SH_DEGREE}")


def sh_basis(dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """The basis functions at unit directions ``dirs`` (N, 3): a tensor (N, (degree + 1) ** 2).

    ``dirs`` must already be normalised; the caller decides how (the renderer normalises
    ``mean - camera_centre``).
    """
    count = sh_coeff_count(degree)
    x, y, z = dirs[:, 0], dirs[:, 1], dirs[:, 2]
    terms = [torch.full_like(x, SH_C0)]
    if degree >= 1:
        terms += [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        xy, yz, xz = x * y, y * z, x * z
        terms += [
            SH_C2[0] * xy,
            SH_C2[1] * yz,
            SH_C2[2] * (2.0 * zz - xx - yy),
            SH_C2[3] * xz,
            SH_C2[4] * (xx - yy),
        ]
    if degree >= 3:
        terms += [
            SH_C3[0] * y * (3.0 * xx - yy),
            SH_C3[1] * xy * z,
            SH_C3[2] * y * (4.0 * zz - xx - yy),
            SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy),
            SH_C3[4] * x * (4.0 * zz - xx - yy),
            SH_C3[5] * z * (xx - yy),
            SH_C3[6] * x * (xx - 3.0 * yy),
        ]
    basis = torch.stack(terms, dim=1)
    assert basis.shape[1] == count
    return basis


def eval_sh(sh: torch.Tensor, dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """Raw SH value per channel, ``sum_k basis_k(dir) * sh[:, k, :]`` (N, 3), without the +0.5.

    Only the first ``(degree + 1) ** 2`` coefficients of ``sh`` (N, K, 3) are used, so a scene can
    be rendered at a lower degree than it stores (as training schedules do).
    """
    count = sh_coeff_count(degree)
    if sh.shape[1] < count:
        raise ValueError(f"SH degree {degree} needs {count} coefficients, "
                         f"the tensor has {sh.shape[1]}")
    if degree == 0:
        return SH_C0 * sh[:, 0, :]
    basis = sh_basis(dirs, degree)
    # broadcast-multiply and sum: batched (1 x K) @ (K x 3) products are 5x slower on the CPU
    return (basis[:, :, None] * sh[:, :count, :]).sum(dim=1)


def sh_to_rgb(sh: torch.Tensor, dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """Colour the rasterizer blends: SH value + 0.5, clamped at 0 below and not above (3DGS)."""
    return torch.clamp_min(eval_sh(sh, dirs, degree) + 0.5, 0.0)
