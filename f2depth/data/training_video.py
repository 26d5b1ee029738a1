"""Which raw video the training set is made from: ``train_source`` of params.yaml.

``nyu_raw`` (the default, and the paper's): the NYU-raw folder ``data.nyu_raw`` (the embedded synthetic one,
or your copy of NYU Depth V2 raw with ``data_source: real``), its scenes not in the test set.
``video``: your own videos or image folders in ``data.video``, which the ``ingest`` stage turns into
``data.ingested`` (undistorted frames, camera.json, scenes.txt; docs/ingest.md); every ingested scene is a
training scene unless ``prepare.train_scenes_file`` says otherwise.

The test sets (``data_source``) are independent of it: the video route still validates and evaluates on
``data.nyu_labeled``, 7-Scenes and Campus, synthetic or real.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from f2depth import params as P

SCENES_FILE = "scenes.txt"  # of an ingested folder: its scenes, one a line


@dataclass(frozen=True)
class TrainingVideo:
    root: str  # the raw frame folder prepare, keypoints and poses read (<scene>/r-*.ppm|png)
    scenes_file: str | None  # the training scenes (null: prepare.train_scenes_file, else not-test scenes)


def training_video(params: dict) -> TrainingVideo:
    """The ``train_source`` route of ``params`` (module docstring)."""
    source = P.value(params, "train_source", Literal["nyu_raw", "video"])
    if source == "video":
        root = P.value(params, "data.ingested", str)
        return TrainingVideo(root, str(Path(root) / SCENES_FILE))
    return TrainingVideo(P.value(params, "data.nyu_raw", str), None)
