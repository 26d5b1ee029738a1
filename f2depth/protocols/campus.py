"""Campus Indoor test set: sparse laser-measured points (the paper §4.1, §4.2.3; Tables 3 and 4).

The full image resized to the network size (a portrait image runs at 384×288, so it is not squashed),
the disparity read bilinearly at the points (``f2depth.protocols.scoring.sample_at_points``) after the PP
blend at the network resolution, valid points gt > 0, median scaling over the points of each image, clip
to [0.1, 10] m, the metrics over the points. Headline: the mean of the scene rows (the paper's Table 3
"average results of 18 scenes" equals the mean of its Table 4 scene rows). details.json also has the
mean over images and the metrics pooled over all points, which differ with ~15 points per image.
Images run one at a time (their sizes differ).
"""

from __future__ import annotations

from f2depth.formats.campus import CampusSet
from f2depth.protocols.protocol import Protocol, SceneRows
from f2depth.protocols.scoring import Settings

PROTOCOL = Protocol(
    name="campus",
    title="Campus",
    open=lambda get: CampusSet(get("data.campus")),
    defaults=Settings(keep_orientation=True),
    records=("height", "width", "keep_orientation", "interpolation", "post_process", "median_scaling",
             "min_depth", "max_depth", "max_gt_depth"),
    columns=("scene", "image"),
    ground_truth="points",
    headline="scenes",
    scene_rows=SceneRows("images", "image_mean"),
    max_batch=1,
)
