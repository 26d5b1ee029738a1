"""Multi-view geometry as pure, differentiable torch functions.

Conventions (docs/formats.md): pixel (u, v) = (column, row) with centres at integer coordinates; camera
axes x right, y down, z forward; depth is z-depth in metres; a transform named ``b_T_a`` maps points of
camera frame ``a`` into camera frame ``b`` (``X_b = b_T_a · X_a``); poses are ``world_T_cam``. Flow is
``(B,2,H,W)`` in pixels, x (u) first: ``flow[:, :, v, u]`` is the displacement from target pixel (u, v)
to its position in the source image.

Every function works for any batch size and for float32 or float64 inputs (all tensors of one call on
the same dtype and device); nothing here breaks the autograd graph except ``occlusion_by_depth`` and
``in_view_mask``, which return masks.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

#: The depth range in metres, defined once: DepthCNN's sigmoid maps to it (Monodepth2's and P²Net's
#: ``disp_to_depth``), the losses and the evaluation clip to it (P²Net's NYU evaluation: [0.1, 10] m).
MIN_DEPTH = 0.1
MAX_DEPTH = 10.0
#: Added to the projected z before the perspective division (as Monodepth2 / P²Net do).
PROJ_EPS = 1e-7
#: Below this squared angle (rad²) ``axis_angle_to_matrix`` uses Taylor series of sin θ/θ, (1−cos θ)/θ².
_SMALL_ANGLE2 = 1e-6


def patch_offsets(spacing: int = 2, dtype: torch.dtype = torch.int64, device=None) -> torch.Tensor:
    """The 3×3 patch ``{−s, 0, s}²`` of ``spacing`` s as ``(9,2)`` offsets ``(dx, dy)``, x first, row-major
    (dy outer: index 0 = (−s, −s), 1 = (0, −s), centre 4, 8 = (s, s)), P²Net's order. s = 2 is P²Net's
    photometric patch and the paper's eq. (1) patch P with N = 2."""
    r = (-spacing, 0, spacing)
    return torch.tensor([(dx, dy) for dy in r for dx in r], dtype=dtype, device=device)


def pixel_grid(height: int, width: int, dtype: torch.dtype = torch.float32, device=None) -> torch.Tensor:
    """Pixel coordinates ``(1,2,H,W)``, x (column) first, centres at integers."""
    v, u = torch.meshgrid(torch.arange(height, dtype=dtype, device=device),
                          torch.arange(width, dtype=dtype, device=device), indexing="ij")
    return torch.stack((u, v), dim=0).unsqueeze(0)


def backproject(depth: torch.Tensor, K_inv: torch.Tensor) -> torch.Tensor:
    """Lift every pixel to 3-D: ``X = D(p) · K⁻¹ · [u, v, 1]ᵀ``.

    depth (B,1,H,W) metres, K_inv (B,3,3) → points (B,3,H,W) in the camera frame (metres).
    """
    b, _, h, w = depth.shape
    grid = pixel_grid(h, w, depth.dtype, depth.device).reshape(1, 2, h * w)
    ones = torch.ones(1, 1, h * w, dtype=depth.dtype, device=depth.device)
    pix_h = torch.cat((grid, ones), dim=1)  # (1,3,HW)
    rays = torch.matmul(K_inv, pix_h)  # (B,3,HW)
    return (rays * depth.reshape(b, 1, h * w)).reshape(b, 3, h, w)


def transform_points(points: torch.Tensor, tgt_T_src: torch.Tensor) -> torch.Tensor:
    """Apply a rigid transform: points (B,3,H,W) in src → (B,3,H,W) in tgt; tgt_T_src (B,4,4)."""
    b, _, h, w = points.shape
    flat = points.reshape(b, 3, h * w)
    out = torch.matmul(tgt_T_src[:, :3, :3], flat) + tgt_T_src[:, :3, 3:4]
    return out.reshape(b, 3, h, w)


def project(points: torch.Tensor, K: torch.Tensor,
            tgt_T_src: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Project src-frame points into the tgt camera: ``p = K · tgt_T_src · X``.

    points (B,3,H,W) metres in the src frame, K (B,3,3), tgt_T_src (B,4,4) →
    (pix (B,2,H,W) pixels, x first, ``p_xy / (p_z + 1e-7)``; z (B,1,H,W) depth in the tgt frame).
    Points behind the camera (z ≤ 0) get meaningless pixels; callers mask them with ``z``.
    """
    cam = transform_points(points, tgt_T_src)
    b, _, h, w = cam.shape
    p = torch.matmul(K, cam.reshape(b, 3, h * w)).reshape(b, 3, h, w)
    z = p[:, 2:3]
    pix = p[:, :2] / (z + PROJ_EPS)
    return pix, cam[:, 2:3]


def rigid_flow(depth: torch.Tensor, K: torch.Tensor, src_T_tgt: torch.Tensor) -> torch.Tensor:
    """Rigid flow target → source: ``f(p_t) = π(K · src_T_tgt · D_t(p_t) · K⁻¹ · p_t) − p_t``.

    depth (B,1,H,W) target depth (metres), K (B,3,3) shared by both views, src_T_tgt (B,4,4) maps target
    camera points into the source camera → flow (B,2,H,W) pixels, x first. Sampling the source image at
    ``p_t + f`` (``warp``) synthesises the target.
    """
    points = backproject(depth, torch.linalg.inv(K))
    pix, _ = project(points, K, src_T_tgt)
    return pix - pixel_grid(depth.shape[2], depth.shape[3], depth.dtype, depth.device)


def _skew(v: torch.Tensor) -> torch.Tensor:
    """Cross-product matrix: v (B,3) → [v]× (B,3,3)."""
    zero = torch.zeros_like(v[:, 0])
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    rows = (torch.stack((zero, -z, y), dim=-1), torch.stack((z, zero, -x), dim=-1),
            torch.stack((-y, x, zero), dim=-1))
    return torch.stack(rows, dim=-2)


def axis_angle_to_matrix(aa: torch.Tensor) -> torch.Tensor:
    """Rodrigues: axis-angle aa (B,3) (direction = axis, norm = angle in rad, right-handed) → R (B,3,3).

    ``R = I + (sin θ/θ)·[a]× + ((1−cos θ)/θ²)·[a]×²`` with θ = |a|, the same matrix as Monodepth2's
    ``rot_from_axisangle``; Taylor series near θ = 0 keep it finite and differentiable at the identity.
    """
    theta2 = (aa * aa).sum(dim=-1)
    small = theta2 < _SMALL_ANGLE2
    safe2 = torch.where(small, torch.ones_like(theta2), theta2)
    safe = torch.sqrt(safe2)
    a_coef = torch.where(small, 1.0 - theta2 / 6.0 + theta2 * theta2 / 120.0, torch.sin(safe) / safe)
    b_coef = torch.where(small, 0.5 - theta2 / 24.0 + theta2 * theta2 / 720.0,
                         (1.0 - torch.cos(safe)) / safe2)
    k = _skew(aa)
    eye = torch.eye(3, dtype=aa.dtype, device=aa.device).expand_as(k)
    return eye + a_coef[:, None, None] * k + b_coef[:, None, None] * torch.matmul(k, k)


def make_transform(R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Homogeneous transform from R (B,3,3) and t (B,3) → T (B,4,4) = [[R, t], [0, 1]]."""
    b = R.shape[0]
    bottom = torch.zeros(b, 1, 4, dtype=R.dtype, device=R.device)
    bottom[:, 0, 3] = 1.0
    return torch.cat((torch.cat((R, t.reshape(b, 3, 1)), dim=2), bottom), dim=1)


def pose_from_params(axisangle: torch.Tensor, translation: torch.Tensor,
                     invert: bool = False) -> torch.Tensor:
    """Monodepth2's ``transformation_from_parameters``: axisangle (B,3), translation (B,3) → T (B,4,4).

    ``invert=False``: ``T = T(t)·R(aa)`` = [[R, t], [0, 1]] (rotate, then translate).
    ``invert=True``: the exact inverse, ``R(aa)ᵀ·T(−t)``.
    """
    R = axis_angle_to_matrix(axisangle)
    if not invert:
        return make_transform(R, translation)
    Rt = R.transpose(1, 2)
    return make_transform(Rt, -torch.matmul(Rt, translation.unsqueeze(-1)).squeeze(-1))


def invert_pose(T: torch.Tensor) -> torch.Tensor:
    """Inverse of rigid transforms T (..., 4, 4): [[Rᵀ, −Rᵀt], [0, 1]] (exact, no general matrix inverse)."""
    Rt = T[..., :3, :3].transpose(-1, -2)
    t = -torch.matmul(Rt, T[..., :3, 3:4])
    out = torch.zeros_like(T)
    out[..., :3, :3] = Rt
    out[..., :3, 3:4] = t
    out[..., 3, 3] = 1.0
    return out


def relative_pose(world_T_a: torch.Tensor, world_T_b: torch.Tensor) -> torch.Tensor:
    """b_T_a = (world_T_b)⁻¹ · world_T_a, for poses (..., 4, 4) (maps camera-a points into camera b)."""
    return torch.matmul(invert_pose(world_T_b), world_T_a)


def _normalised_grid(flow: torch.Tensor) -> torch.Tensor:
    """Sampling positions ``p + flow`` as a grid_sample grid (B,H,W,2), align_corners=True convention."""
    _, _, h, w = flow.shape
    pos = pixel_grid(h, w, flow.dtype, flow.device) + flow
    gx = 2.0 * pos[:, 0] / max(w - 1, 1) - 1.0
    gy = 2.0 * pos[:, 1] / max(h - 1, 1) - 1.0
    return torch.stack((gx, gy), dim=-1)


def warp(img: torch.Tensor, flow: torch.Tensor, padding: str = "border") -> torch.Tensor:
    """Backward warp (ARFlow's ``flow_warp``): ``out(p) = img(p + flow(p))``.

    img (B,C,H,W) source image or features, flow (B,2,H,W) pixels, x first, at the same H, W →
    (B,C,H,W). Bilinear, align_corners=True (grid = 2·(p + f)/(size − 1) − 1), ``padding`` "border"
    (ARFlow's images and features) or "zeros" (ARFlow's flow warp in its occlusion check).
    """
    if img.shape[-2:] != flow.shape[-2:] or flow.shape[1] != 2:
        raise ValueError(f"warp: img {tuple(img.shape)} and flow {tuple(flow.shape)} must share (H, W); "
                         "flow needs 2 channels")
    grid = _normalised_grid(flow)
    return F.grid_sample(img, grid, mode="bilinear", padding_mode=padding, align_corners=True)


def resize_flow(flow: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """ARFlow's ``resize_flow``: ``flow (B,2,H,W)`` pixels, x first → ``(B,2,h,w)`` for ``size = (h, w)``:
    bilinear (align_corners=True), u scaled by w/W and v by h/H so the flow is in pixels of the new grid.
    Returns ``flow`` itself when the size is unchanged."""
    h, w = size
    H, W = flow.shape[-2:]
    if (h, w) == (H, W):
        return flow
    out = F.interpolate(flow, size=(h, w), mode="bilinear", align_corners=True)
    scale = torch.tensor([w / W, h / H], dtype=flow.dtype, device=flow.device).reshape(1, 2, 1, 1)
    return out * scale


def in_view_mask(flow: torch.Tensor) -> torch.Tensor:
    """Where ``p + flow`` lies inside the image: 0 ≤ x ≤ W−1 and 0 ≤ y ≤ H−1.

    flow (B,2,H,W) → mask (B,1,H,W), float in {0, 1} of flow's dtype, no gradient.
    """
    _, _, h, w = flow.shape
    pos = pixel_grid(h, w, flow.dtype, flow.device) + flow.detach()
    inside = (pos[:, 0] >= 0) & (pos[:, 0] <= w - 1) & (pos[:, 1] >= 0) & (pos[:, 1] <= h - 1)
    return inside.unsqueeze(1).to(flow.dtype)


@torch.no_grad()
def occlusion_by_depth(depth_t: torch.Tensor, depth_s: torch.Tensor, K: torch.Tensor, src_T_tgt: torch.Tensor,
                       rel_tol: float = 0.02) -> torch.Tensor:
    """Target pixels hidden in the source view: projected depth z > (1 + rel_tol) · D_s(projection).

    depth_t, depth_s (B,1,H,W) metres (0 = invalid), K (B,3,3), src_T_tgt (B,4,4) → occluded (B,1,H,W)
    bool. The source depth is read with nearest-neighbour sampling (no mixing across depth edges).
    Pixels projecting outside the image, behind the camera, or onto an invalid source depth are *not*
    marked occluded: combine with ``in_view_mask`` for those.
    """
    points = backproject(depth_t, torch.linalg.inv(K))
    pix, z = project(points, K, src_T_tgt)
    _, _, h, w = depth_t.shape
    flow = pix - pixel_grid(h, w, depth_t.dtype, depth_t.device)
    sampled = F.grid_sample(depth_s, _normalised_grid(flow), mode="nearest", padding_mode="border",
                            align_corners=True)
    known = (sampled > 0) & (z > 0) & (depth_t > 0) & (in_view_mask(flow) > 0)
    return known & (z > sampled * (1.0 + rel_tol))


def endpoint_error(flow: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    """``flow, gt (B,2,H,W)`` pixels, x first → EPE ``(B,1,H,W)``."""
    return (flow - gt).norm(dim=1, keepdim=True)
