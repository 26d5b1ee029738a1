"""Colour jitter and flips of the flow fine-tuning (f2depth.flow.augment)."""

from __future__ import annotations

import pytest
import torch
from test_flow_patch_loss import patch_cfg

from f2depth.colour import AugmentConfig
from f2depth.flow.augment import (
    augment_batch,
    color_jitter,
    flip_and_swap,
    hflip_keypoints,
)
from f2depth.flow.patch_loss import finetune_loss, pad_keypoints
from f2depth.geometry import warp


def rand_img(b=2, h=12, w=16, seed=0):
    return torch.rand(b, 3, h, w, generator=torch.Generator().manual_seed(seed))


def test_flip_and_swap_is_arflows_per_sample_draw_from_the_generator():
    a, b = rand_img(64, seed=1), rand_img(64, seed=2)
    x, y = flip_and_swap(a, b, torch.Generator().manual_seed(3))
    again = flip_and_swap(a, b, torch.Generator().manual_seed(3))
    assert torch.equal(x, again[0]) and torch.equal(y, again[1])
    kinds = []
    for i in range(64):
        for flip in (False, True):
            p, q = (a[i].flip(-1), b[i].flip(-1)) if flip else (a[i], b[i])
            for swap in (False, True):
                if torch.equal(x[i], q if swap else p) and torch.equal(y[i], p if swap else q):
                    kinds.append((flip, swap))
    assert len(kinds) == 64  # every sample is one of the four, both frames treated alike
    assert len(set(kinds)) == 4 and 8 < sum(f for f, _ in kinds) < 56 and 8 < sum(s for _, s in kinds) < 56


def test_jitter_shares_parameters_between_frames_and_is_seeded():
    img = rand_img(4)
    a1, a2 = color_jitter([img, img.clone()], torch.Generator().manual_seed(3), AugmentConfig(jitter_p=1.0))
    assert torch.equal(a1, a2) and not torch.allclose(a1, img)
    b1, _ = color_jitter([img, img], torch.Generator().manual_seed(3), AugmentConfig(jitter_p=1.0))
    assert torch.equal(a1, b1)
    assert a1.min() >= 0 and a1.max() <= 1
    same, _ = color_jitter([img, img], torch.Generator().manual_seed(3), AugmentConfig(jitter_p=0.0))
    assert torch.equal(same, img)


def hflip_flow(flow: torch.Tensor) -> torch.Tensor:
    """Flow ``(B,2,H,W)`` of a pair → the flow of the mirrored pair: mirrored, u negated."""
    out = flow.flip(-1).clone()
    out[:, 0] = -out[:, 0]
    return out


def test_flip_keeps_the_loss_of_a_consistent_pair():
    """Mirroring frames, keypoints and flow (u negated) describes the same motion: same loss."""
    h, w = 20, 28
    img2 = torch.nn.functional.avg_pool2d(rand_img(1, h + 2, w + 2, 5), 3, 1)
    flow = torch.zeros(1, 2, h, w)
    flow[:, 0] = 1.5
    flow[:, 1] = -0.5
    flow[:, 0, :, 10:] = 2.5
    img1 = warp(img2, flow)
    kp, mask = pad_keypoints([torch.tensor([[5, 5], [14, 9], [20, 12]])])
    cfg = patch_cfg()
    loss, _ = finetune_loss(flow, -flow, img1, img2, kp, mask, cfg)
    fflow = hflip_flow(flow)
    assert torch.equal(fflow[0, 0, :, w - 1], -flow[0, 0, :, 0])
    loss_f, _ = finetune_loss(fflow, -fflow, img1.flip(-1), img2.flip(-1), hflip_keypoints(kp, w), mask, cfg)
    assert loss_f == pytest.approx(float(loss), rel=1e-4)


def test_augment_batch_flips_images_and_keypoints_together():
    img1, img2 = rand_img(8, seed=1), rand_img(8, seed=2)
    kp, mask = pad_keypoints([torch.tensor([[1, 2], [15, 11]])] * 8)
    batch = {"img1": img1, "img2": img2, "keypoints": kp, "keypoint_mask": mask}
    out = augment_batch(batch, torch.Generator().manual_seed(0))
    flipped = out["flipped"]
    assert flipped.any() and not flipped.all()
    for i in range(8):
        ref1 = img1[i].flip(-1) if flipped[i] else img1[i]
        assert torch.equal(out["img1"][i], ref1)
        x, y = kp[i, 1].tolist()
        assert out["keypoints"][i, 1].tolist() == ([16 - 1 - x, y] if flipped[i] else [x, y])
        x2, y2 = out["keypoints"][i, 1].tolist()
        assert torch.equal(out["img1"][i][:, y2, x2], img1[i][:, y, x])  # the keypoint stays on its pixel
    assert out["net1"].shape == img1.shape and torch.equal(batch["img1"], img1)  # input left untouched
    again = augment_batch(batch, torch.Generator().manual_seed(0))
    assert torch.equal(again["net2"], out["net2"])
