"""P²Net's training augmentation in plain torch (P²Net's `datasets/nyu_dataset.py`): horizontal flip and
colour jitter.

* Flip (p = 0.5): every frame of a sample, the superpixel labels and the keypoints are mirrored
  (x → W−1−x) and so is the principal point, ``cx' = W−1−cx`` (pixel centres at integers). P²Net and
  Monodepth2 leave K unchanged on a flip, which is only right when cx = (W−1)/2; we mirror it so the
  mirrored frames are an exact pinhole view of the mirrored world.
* Colour jitter (p = 0.5): brightness, contrast, saturation factors in (0.8, 1.2) and a hue shift in
  (−0.1, 0.1) turns, applied in a random order (as torchvision's ``ColorJitter``), one draw for all the
  frames of a sample. Definitions as torchvision's functional ops: brightness ``f·x``; contrast
  ``f·x + (1−f)·mean(gray(x))``; saturation ``f·x + (1−f)·gray(x)`` with ITU-R 601 luma weights; hue: a
  rotation of the HSV hue; each step clamped to [0, 1].

Every random number comes from a ``torch.Generator`` the caller seeds, so a sample's augmentation is a
function of that seed alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from f2depth.colour import GREY_PIL, AugmentConfig, jitter


@dataclass(frozen=True)
class AugmentDraw:
    """One sample's random choices. ``order``: indices into JITTER_OPS, the order of application."""

    flip: bool
    jitter: bool
    brightness: float
    contrast: float
    saturation: float
    hue: float
    order: tuple[int, ...]


def draw(config: AugmentConfig, generator: torch.Generator) -> AugmentDraw:
    """Draw a sample's augmentation. Always consumes the same amount of the stream (9 numbers + a
    permutation), whatever the outcome."""
    u = torch.rand(2, generator=generator, dtype=torch.float64)

    def uniform(lo_hi: tuple[float, float]) -> float:
        lo, hi = lo_hi
        return float(lo + (hi - lo) * torch.rand(1, generator=generator, dtype=torch.float64))

    b, c, s, h = (uniform(config.brightness), uniform(config.contrast), uniform(config.saturation),
                  uniform(config.hue))
    order = tuple(int(i) for i in torch.randperm(4, generator=generator))
    return AugmentDraw(bool(u[0] < config.flip_p), bool(u[1] < config.jitter_p), b, c, s, h, order)


# ---- flip ------------------------------------------------------------------------------------------

def flip_image(img: torch.Tensor) -> torch.Tensor:
    """Mirror left-right: (..., H, W) → (..., H, W)."""
    return torch.flip(img, dims=(-1,))


def flip_points(points: torch.Tensor, width: int) -> torch.Tensor:
    """Keypoints (N, ≥2) x first (integer or float pixels) → x' = W−1−x, other columns unchanged."""
    out = points.clone()
    out[:, 0] = (width - 1) - out[:, 0]
    return out


def flip_intrinsics(K: torch.Tensor, width: int) -> torch.Tensor:
    """K (3,3) of the mirrored image: cx' = W−1−cx (fx, fy, cy unchanged; zero skew assumed)."""
    if float(K[0, 1]) != 0.0:
        raise ValueError("flip_intrinsics: K has a skew term; a mirrored camera would need K[0,1] → −K[0,1]")
    out = K.clone()
    out[0, 2] = (width - 1) - K[0, 2]
    return out


def flip_pose(T: torch.Tensor) -> torch.Tensor:
    """A relative pose ``tgt_T_src`` (..., 4, 4) between mirrored images: F·T·F with F = diag(−1, 1, 1, 1)
    (the mirrored image is the camera's view of the world reflected in its x axis)."""
    F = torch.diag(torch.tensor([-1.0, 1.0, 1.0, 1.0], dtype=T.dtype, device=T.device))
    return F @ T @ F


# ---- colour ----------------------------------------------------------------------------------------

def color_jitter(img: torch.Tensor, d: AugmentDraw) -> torch.Tensor:
    """Apply the drawn jitter (if ``d.jitter``) to RGB (..., 3, H, W) in [0, 1]; contrast uses each
    image's own mean (leading dimensions are separate images)."""
    if not d.jitter:
        return img
    return jitter(img, (d.brightness, d.contrast, d.saturation, d.hue), d.order, GREY_PIL)
