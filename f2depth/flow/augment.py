"""Training augmentation of frame pairs as F²Depth / P²Net do it (P²Net's code,
``datasets/nyu_dataset.py``): with probability 0.5 a colour jitter (brightness, contrast, saturation in
[0.8, 1.2], hue in [−0.1, 0.1], applied in a random order, one draw shared by both frames of a sample),
with probability 0.5 a horizontal flip of both frames and of the target's keypoints.

As in P²Net, the jittered images are only the *network input*; the loss compares the un-jittered
(but flipped) frames. A flip changes the sign of the horizontal flow component: flipping a pair and its
flow ``f`` gives the flow ``(−u, v)`` mirrored; frames are never swapped, so the
flow stays target → source. All randomness comes from the ``torch.Generator`` passed in.

The recipe is ``f2depth.colour.AugmentConfig`` and ``f2depth.colour.jitter``, as the depth training's;
here with MATLAB's grey weights (``GREY_MATLAB``). A sample's draws are float32 and made only when it is
jittered (the depth training draws float64 numbers for every sample): each stream is the one that trained
the committed models.
"""

from __future__ import annotations

import torch

from f2depth.colour import GREY_MATLAB, P2NET_AUGMENT, AugmentConfig, jitter


def _uniform(lo_hi: tuple[float, float], gen: torch.Generator) -> float:
    lo, hi = lo_hi
    return lo + (hi - lo) * float(torch.rand((), generator=gen))


def color_jitter(frames: list[torch.Tensor], gen: torch.Generator, cfg: AugmentConfig = P2NET_AUGMENT
                 ) -> list[torch.Tensor]:
    """Jitter frames ``(B,3,H,W)`` in [0,1]; per sample, with probability ``jitter_p``, one draw of the four
    factors and of their order, shared by all frames of that sample. Returns new tensors."""
    out = [f.clone() for f in frames]
    for i in range(frames[0].shape[0]):
        if float(torch.rand((), generator=gen)) >= cfg.jitter_p:
            continue
        factors = [_uniform(lo_hi, gen) for lo_hi in cfg.ranges()]
        order = torch.randperm(4, generator=gen).tolist()
        for frame in out:
            frame[i] = jitter(frame[i], factors, order, GREY_MATLAB)
    return out


def hflip_keypoints(keypoints: torch.Tensor, width: int) -> torch.Tensor:
    """``(...,2)`` integer pixels x first → mirrored: ``x ↦ W − 1 − x``."""
    out = keypoints.clone()
    out[..., 0] = width - 1 - out[..., 0]
    return out


def augment_batch(batch: dict[str, torch.Tensor], gen: torch.Generator, cfg: AugmentConfig = P2NET_AUGMENT
                  ) -> dict[str, torch.Tensor]:
    """Flip and jitter a batch ``{"img1", "img2" (B,3,H,W), "keypoints" (B,K,2), "keypoint_mask" (B,K)}``.

    Returns a new dict: ``img1``, ``img2``, ``keypoints`` flipped per sample (for the loss) and ``net1``,
    ``net2`` = the flipped frames colour-jittered (for the network); other entries are passed through.
    """
    out = dict(batch)
    img1, img2, kp = batch["img1"].clone(), batch["img2"].clone(), batch["keypoints"].clone()
    w = img1.shape[-1]
    flip = torch.rand(img1.shape[0], generator=gen) < cfg.flip_p
    if flip.any():
        img1[flip] = img1[flip].flip(-1)
        img2[flip] = img2[flip].flip(-1)
        kp[flip] = hflip_keypoints(kp[flip], w)
    out.update(img1=img1, img2=img2, keypoints=kp, flipped=flip)
    out["net1"], out["net2"] = color_jitter([img1, img2], gen, cfg)
    return out


def flip_and_swap(img1: torch.Tensor, img2: torch.Tensor, gen: torch.Generator, p: float = 0.5
                  ) -> tuple[torch.Tensor, torch.Tensor]:
    """ARFlow's pretraining augmentation (its ``transforms/co_transforms.py``): per sample of the frames
    ``(B,3,H,W)``, a horizontal flip of both frames with probability ``p``, then a swap of the frame order
    with probability ``p``, drawn from ``gen`` (flips for the batch first, then swaps)."""
    b = img1.shape[0]
    flip = (torch.rand(b, generator=gen) < p).reshape(b, 1, 1, 1)
    swap = (torch.rand(b, generator=gen) < p).reshape(b, 1, 1, 1)
    a, c = torch.where(flip, img1.flip(-1), img1), torch.where(flip, img2.flip(-1), img2)
    return torch.where(swap, c, a), torch.where(swap, a, c)
