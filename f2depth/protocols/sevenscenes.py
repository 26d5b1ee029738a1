"""7-Scenes zero-shot test set (the paper §4.1 and §4.2.2; Shotton et al., CVPR 2013).

Every ``evaluate.sevenscenes_stride``-th frame of the official test sequences, the full 480×640 frame
resized to the network size, the disparity upsampled to the ground truth (nearest, as P²Net's ScanNet
evaluation) before the PP blend, valid where 0 < gt ≤ 10 m (0 and the 65535 mm code are invalid; NaN or
inf metres count as missing too, logged in one warning line), median scaling, clip to [0.1, 10] m.

Headline: the mean over all test frames. The paper's "Average" row (Table 2) is the *frame-weighted*
mean of its scene rows with the official test counts (17,000 frames in all, the paper §4.1), not the
unweighted one (see tests/test_eval_published.py); details.json has both (``frame_weighted``, ``average``).
"""

from __future__ import annotations

from f2depth.formats.samples import middle_frames
from f2depth.formats.sevenscenes import SevenScenesSet
from f2depth.protocols.protocol import Figure, Protocol, SceneRows
from f2depth.protocols.scoring import Settings

PROTOCOL = Protocol(
    name="sevenscenes",
    title="7-Scenes",
    open=lambda get: SevenScenesSet(get("data.sevenscenes"), split="test",
                                    stride=int(get("evaluate.sevenscenes_stride"))),
    defaults=Settings(max_gt_depth=10.0),
    records=("height", "width", "interpolation", "upsample", "post_process", "median_scaling", "min_depth",
             "max_depth", "min_gt_depth", "max_gt_depth"),
    columns=("scene", "seq", "frame"),
    scene_rows=SceneRows("frames", "frame_weighted", all_images_row="All frames"),
    nonfinite="missing",
    figure=Figure("7-Scenes test frames (one per scene)", lambda samples, n: middle_frames(samples)),
)
