"""Monodepth2's pose decoder on the separate 6-channel ResNet encoder (PoseCNN on frame pairs)."""

from __future__ import annotations

import torch
from torch import nn

#: Output scaling of the pose decoder (Monodepth2): keeps initial motions small.
POSE_SCALE = 0.01


class PoseDecoder(nn.Module):
    """Encoder's last feature (B,512,h,w) → axis-angle (B,k,3) and translation (B,k,3).

    squeeze 1×1 512→256 + ReLU, 3×3 256→256 + ReLU, 3×3 256→256 + ReLU, 1×1 256→6k, spatial mean, ×0.01.
    ``k = num_frames_to_predict_for`` (2 as in Monodepth2/P²Net; only index 0 is used for a pair).
    """

    def __init__(self, num_ch_in: int = 512, num_frames_to_predict_for: int = 2) -> None:
        super().__init__()
        self.num_frames = num_frames_to_predict_for
        self.squeeze = nn.Conv2d(num_ch_in, 256, 1)
        self.pose_0 = nn.Conv2d(256, 256, 3, stride=1, padding=1)
        self.pose_1 = nn.Conv2d(256, 256, 3, stride=1, padding=1)
        self.pose_2 = nn.Conv2d(256, 6 * num_frames_to_predict_for, 1)
        self.relu = nn.ReLU()

    def forward(self, features: list[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
        x = self.relu(self.squeeze(features[-1]))
        x = self.relu(self.pose_0(x))
        x = self.relu(self.pose_1(x))
        x = self.pose_2(x).mean(dim=(2, 3))
        x = POSE_SCALE * x.reshape(-1, self.num_frames, 6)
        return x[..., :3], x[..., 3:]
