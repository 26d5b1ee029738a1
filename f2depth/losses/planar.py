"""P²Net's superpixel planar consistency loss L_spp (P²Net's ``trainer_geo.py``), vectorised.

Per superpixel m of the target (Felzenszwalb labels) the predicted depth is back-projected,
``X_i = D_i·K⁻¹·p_i``, and the plane ``nᵀX = 1`` is fitted by ridge least squares in closed form:
``n_m = (Σ X_i X_iᵀ + 0.01·I)⁻¹ Σ X_i``. The plane's depth at each pixel is
``D^plane_i = clamp(1 / (n_mᵀ K⁻¹ p_i + 1e-6), min_depth, max_depth)``. Superpixels of more than
``min_area`` pixels count: ``L_spp = mean over all pixels of |D − D^plane|·mask`` (not normalised by
the mask's size, as P²Net). Gradients flow through D and through the fit (no detach).
All superpixels of the batch are fitted at once with scatter sums and one batched 3×3 solve.
"""

from __future__ import annotations

import torch

from f2depth.geometry import MAX_DEPTH, MIN_DEPTH, backproject
from f2depth.superpixels import MIN_AREA

RIDGE = 0.01
PLANE_EPS = 1e-6


def _global_labels(segments: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, int]:
    """(B,H,W) labels (negative = ignored) → (compact ids (B·H·W,), valid (B·H·W,) bool, count M)."""
    b = segments.shape[0]
    seg = segments.reshape(b, -1).long()
    valid = seg >= 0
    span = int(seg.max().item()) + 1 if valid.any() else 1
    offsets = torch.arange(b, device=seg.device).unsqueeze(1) * span
    ids = torch.where(valid, seg + offsets, torch.zeros_like(seg)).reshape(-1)
    _, compact = torch.unique(ids, return_inverse=True)
    return compact, valid.reshape(-1), int(compact.max().item()) + 1


def fit_planes(
    depth: torch.Tensor, K_inv: torch.Tensor, segments: torch.Tensor, ridge: float = RIDGE
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Least-squares planes nᵀX = 1 of all superpixels.

    depth (B,1,H,W) metres, K_inv (B,3,3), segments (B,H,W) or (B,1,H,W) integer labels (negative =
    ignored) → (normals (M,3), pixel → plane id (B,H,W) int64, area per plane (M,) pixels).
    """
    b, _, h, w = depth.shape
    segments = segments.reshape(b, h, w)
    ids, valid, m = _global_labels(segments)
    X = backproject(depth, K_inv).permute(0, 2, 3, 1).reshape(-1, 3)  # (BHW,3)
    Xv = X * valid.unsqueeze(1).to(X.dtype)
    outer = (Xv.unsqueeze(2) * Xv.unsqueeze(1)).reshape(-1, 9)
    A = torch.zeros(m, 9, dtype=X.dtype, device=X.device).index_add(0, ids, outer).reshape(m, 3, 3)
    A = A + ridge * torch.eye(3, dtype=X.dtype, device=X.device)
    rhs = torch.zeros(m, 3, dtype=X.dtype, device=X.device).index_add(0, ids, Xv)
    normals = torch.linalg.solve(A, rhs.unsqueeze(-1)).squeeze(-1)
    area = torch.zeros(m, dtype=torch.long, device=X.device).index_add(0, ids, valid.long())
    return normals, ids.reshape(b, h, w), area


def planar_depth(
    depth: torch.Tensor,
    K_inv: torch.Tensor,
    segments: torch.Tensor,
    min_area: int = MIN_AREA,
    min_depth: float = MIN_DEPTH,
    max_depth: float = MAX_DEPTH,
    ridge: float = RIDGE,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Depth of each pixel's superpixel plane and the mask of pixels in superpixels > min_area pixels.

    depth (B,1,H,W), K_inv (B,3,3), segments (B,H,W) → (plane depth (B,1,H,W) metres, mask (B,1,H,W)
    float in {0, 1}).
    """
    b, _, h, w = depth.shape
    normals, ids, area = fit_planes(depth, K_inv, segments, ridge)
    rays = backproject(torch.ones_like(depth), K_inv)  # K⁻¹ p, (B,3,H,W)
    n_pix = normals[ids.reshape(-1)].reshape(b, h, w, 3).permute(0, 3, 1, 2)
    d_plane = 1.0 / ((n_pix * rays).sum(dim=1, keepdim=True) + PLANE_EPS)
    d_plane = d_plane.clamp(min_depth, max_depth)
    valid = segments.reshape(b, 1, h, w) >= 0
    mask = ((area[ids] > min_area).reshape(b, 1, h, w) & valid).to(depth.dtype)
    return d_plane, mask


def planar_loss(
    depth: torch.Tensor,
    K_inv: torch.Tensor,
    segments: torch.Tensor,
    min_area: int = MIN_AREA,
    min_depth: float = MIN_DEPTH,
    max_depth: float = MAX_DEPTH,
    ridge: float = RIDGE,
) -> torch.Tensor:
    """L_spp = mean_{B,H,W} |D − D^plane|·mask (shapes as ``planar_depth``) → scalar."""
    d_plane, mask = planar_depth(depth, K_inv, segments, min_area, min_depth, max_depth, ridge)
    return ((depth - d_plane).abs() * mask).mean()
