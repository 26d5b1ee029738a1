"""NYU Depth V2 test set: the 654 test images of the labeled set, scored as P²Net's
``evaluation/nyuv2_eval_depth.py`` does (the paper's Tables 1, 5, 6).

The Eigen crop (rows 44:471, cols 40:601, 427×561; ``evaluate.nyu_crop``) of rgb and ground truth
(``evaluate.nyu_gt``: filled ``depths`` or ``rawDepths``), the crop resized to the network size, the
disparity upsampled to the crop (nearest, as P²Net; ``evaluate.upsample``) before the PP blend, valid
where gt > 0 (P²Net has no cap), median scaling, clip to [0.1, 10] m. Headline: the mean over images.
"""

from __future__ import annotations

from f2depth.formats.nyu_labeled import NYULabeledSet
from f2depth.formats.samples import spread
from f2depth.protocols.protocol import Figure, Protocol
from f2depth.protocols.scoring import Settings

PROTOCOL = Protocol(
    name="nyu",
    title="NYU",
    open=lambda get: NYULabeledSet(get("data.nyu_labeled"), get("data.nyu_splits"), split="test",
                                   gt=str(get("evaluate.nyu_gt"))),
    defaults=Settings(crop="eigen"),
    records=("height", "width", "crop", "interpolation", "upsample", "post_process", "median_scaling",
             "min_depth", "max_depth", "max_gt_depth"),
    columns=("index",),
    options={"crop": "nyu_crop"},
    figure=Figure("NYU Depth V2 test images", lambda samples, n: spread(len(samples), n)),
)

evaluate_nyu = PROTOCOL.evaluate  # the training stage's per-epoch validation scores with it
