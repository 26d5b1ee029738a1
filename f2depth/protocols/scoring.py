"""The one scoring recipe of every test set, and its result type.

P²Net's ``evaluation/nyuv2_eval_depth.py`` (Monodepth2's ``evaluate_depth.py``), on the
:class:`~f2depth.formats.samples.EvalSample` s of a loader, with a test set's :class:`Settings`:

- dense ground truth (``depth``): crop image and ground truth (``crop``; NYU's Eigen crop), resize the rgb
  to the network size, predict (with flip post-processing when ``post_process``), upsample the disparity
  to the ground truth (``upsample``) *before* the PP blend, depth = 1/disp;
- sparse ground truth (``points``): resize the full image (a portrait image runs at width×height when
  ``keep_orientation``), predict, read the disparity bilinearly at the points (:func:`sample_at_points`);
- valid where ``min_gt_depth < gt ≤ max_gt_depth``, per-image median scaling, clip to
  [``min_depth``, ``max_depth``], the eight metrics per image (``f2depth.protocols.metrics``); an image
  without a valid pixel is skipped (one warning line). Dataset numbers: the mean over images (``summary``),
  per scene (``scenes``) and the unweighted mean of the scene rows (``average``).
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from f2depth import threads
from f2depth.depth.predict import PredictDisp, depth_from_disparity
from f2depth.errors import DataError
from f2depth.formats.samples import EvalSample
from f2depth.geometry import MAX_DEPTH, MIN_DEPTH
from f2depth.protocols.inputs import (
    batched,
    report_skipped,
    run_batch,
    run_batch_with_and_without_pp,
    to_input,
)
from f2depth.protocols.metrics import (
    METRIC_NAMES,
    EmptyMaskError,
    Summary,
    aggregate,
    clip_depth,
    compute_errors,
    image_metrics,
    mean_of_rows,
    stack_per_image,
)

if TYPE_CHECKING:
    from f2depth.protocols.protocol import Protocol

log = logging.getLogger(__name__)

CROPS: dict[str, tuple[int, int, int, int] | None] = {
    "eigen": (44, 471, 40, 601),  # NYU toolbox mask(45:471, 41:601), 1-based inclusive → 427×561
    "eigen_sc": (45, 471, 41, 601),  # SC-Depth's eval_depth.py / ZoeDepth's compute_metrics, 426×560
    "none": None,
}
"""Named crops of 480×640 images as (top, bottom, left, right), 0-based, end exclusive."""


def resolve_crop(crop: str | tuple[int, int, int, int] | None) -> tuple[int, int, int, int] | None:
    """``"eigen"`` | ``"eigen_sc"`` | ``"none"`` | None | (top, bottom, left, right) → a tuple or None."""
    if crop is None:
        return None
    if isinstance(crop, str):
        if crop not in CROPS:
            raise ValueError(f"unknown NYU crop {crop!r}; use one of {sorted(CROPS)} or (top, bottom, left, "
                             "right)")
        return CROPS[crop]
    t, b, l, r = (int(v) for v in crop)
    if not (0 <= t < b and 0 <= l < r):
        raise ValueError(f"crop {crop} must be (top, bottom, left, right) with top < bottom, left < right")
    return t, b, l, r


@dataclass(frozen=True)
class Settings:
    """How a test set is scored (module docstring). ``crop`` may be given by name (:data:`CROPS`)."""

    height: int = 288
    width: int = 384
    crop: tuple[int, int, int, int] | None = None
    keep_orientation: bool = False
    interpolation: str = "area"
    upsample: str = "nearest"
    post_process: bool = False
    median_scaling: bool = True
    min_depth: float = MIN_DEPTH
    max_depth: float = MAX_DEPTH
    min_gt_depth: float = 0.0
    max_gt_depth: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "crop", resolve_crop(self.crop))

    def valid(self, gt: np.ndarray) -> np.ndarray:
        """gt (any shape) metres → bool mask of ``min_gt_depth < gt ≤ max_gt_depth``."""
        mask = gt > self.min_gt_depth
        return mask if self.max_gt_depth is None else mask & (gt <= self.max_gt_depth)

    def record(self, names: Sequence[str]) -> dict[str, Any]:
        """The settings ``names`` as JSON-ready values, in that order."""
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        return {n: list(values[n]) if isinstance(values[n], tuple) else values[n] for n in names}


SETTING_NAMES: tuple[str, ...] = tuple(f.name for f in fields(Settings))


@dataclass(frozen=True)
class Kept:
    """A sample kept for figures, as scored: ``rgb`` (H,W,3) uint8 and ``gt`` after the crop (dense: (H,W)
    metres; sparse: the points' depths); ``pred`` the scaled, clipped depth, float32 (dense: the ground
    truth's size; sparse: the network's)."""

    key: tuple[str | int, ...]
    rgb: np.ndarray
    gt: np.ndarray
    pred: np.ndarray


@dataclass
class ProtocolResult:
    """What every protocol returns. ``metrics``: its headline (``Protocol.headline``); ``summary``: mean and
    std over the N scored images; ``scenes``: the same per scene (numeric names in numeric order, then by
    name); ``average``: the unweighted mean of the scene rows; ``per_image``: metric, ``ratio`` (and
    ``points`` for sparse ground truth) → (N,) float64, for the N samples of ``keys`` / ``scene``;
    ``skipped``: keys without a valid ground-truth pixel; ``settings``: those its protocol records;
    ``kept``: the kept samples in the order asked; ``pooled``: sparse ground truth only, the metrics over
    all points of all images at once (after each image's own scaling)."""

    metrics: dict[str, float]
    summary: Summary
    scenes: dict[str, Summary]
    average: dict[str, float]
    per_image: dict[str, np.ndarray]
    keys: list[tuple[str | int, ...]]
    scene: list[str]
    skipped: list[tuple[str | int, ...]] = field(default_factory=list)
    settings: dict[str, Any] = field(default_factory=dict)
    kept: list[Kept] = field(default_factory=list)
    pooled: dict[str, float] | None = None


def sample_at_points(disp: Any, uv: np.ndarray, image_hw: tuple[int, int]) -> np.ndarray:
    """Bilinear sample of a low-resolution map at pixel positions of the full image.

    disp: (h,w) map (NumPy or torch) covering the same view as the image; uv: (K,2) pixel coordinates
    (u = column, v = row) in an image of ``image_hw = (H, W)``. A point (u, v) is read at
    x = (u + 0.5)·w/W − 0.5, y = (v + 0.5)·h/H − 0.5, clamped at the border: exactly the value the
    bilinearly upsampled map (``align_corners=False``) has at integer (u, v), without building it (camera
    photos can be 6240×4160). Returns (K,) float64.
    """
    d = torch.as_tensor(np.asarray(disp, dtype=np.float64) if not isinstance(disp, torch.Tensor) else disp)
    d = d.to(torch.float64).reshape(1, 1, *d.shape[-2:])
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    H, W = image_hw
    gx = (2.0 * uv[:, 0] + 1.0) / W - 1.0
    gy = (2.0 * uv[:, 1] + 1.0) / H - 1.0
    grid = torch.from_numpy(np.stack([gx, gy], -1)).reshape(1, 1, -1, 2)
    out = F.grid_sample(d, grid, mode="bilinear", padding_mode="border", align_corners=False)
    return out.reshape(-1).numpy()


def network_size(image_hw: tuple[int, int], height: int, width: int,
                 keep_orientation: bool) -> tuple[int, int]:
    """(height, width), swapped for a portrait image when ``keep_orientation`` and the size is landscape."""
    portrait = image_hw[0] > image_hw[1]
    if keep_orientation and portrait != (height > width) and height != width:
        return width, height
    return height, width


@dataclass
class _Item:
    """One sample ready for the network: its input, the ground truth as scored, where disparity is read."""

    position: int
    sample: EvalSample
    rgb: np.ndarray
    gt: np.ndarray  # dense: (H,W) map after the crop; sparse: (K,) point depths
    x: torch.Tensor
    out_hw: tuple[int, int] | None  # dense: the ground-truth size the disparity is upsampled to
    uv: np.ndarray | None  # sparse: (K,2) pixel positions of the points


def _prepare(p: Protocol, s: Settings, position: int, sample: EvalSample,
             nonfinite: list[tuple[int, str]]) -> _Item:
    what = f"{p.title} sample {sample.name}"
    sparse = p.ground_truth == "points"
    if (sample.points if sparse else sample.depth) is None:
        raise ValueError(f"{what}: the {p.title} protocol scores {p.ground_truth} ground truth")
    rgb, pts = sample.rgb, np.asarray(sample.points, dtype=np.float64) if sparse else None
    gt = pts[:, 2] if sparse else np.asarray(sample.depth, dtype=np.float32)
    bad = np.count_nonzero(~np.isfinite(gt))
    if bad and p.nonfinite == "error":
        raise DataError(what, f"ground truth has {bad} non-finite value(s) (NaN or inf) of {gt.size}",
                        "missing depth must be 0; check the test data")
    if bad:
        gt = np.where(np.isfinite(gt), gt, np.zeros((), gt.dtype))
        nonfinite.append((bad, sample.name))
    if sparse:
        hw = network_size(rgb.shape[:2], s.height, s.width, s.keep_orientation)
        return _Item(position, sample, rgb, gt, to_input(rgb, hw, s.interpolation), None, pts[:, :2])
    if s.crop is not None:
        t, b, l, r = s.crop
        if b > gt.shape[0] or r > gt.shape[1]:
            raise ValueError(f"{what}: crop {s.crop} does not fit an image of {gt.shape}")
        rgb, gt = rgb[t:b, l:r], gt[t:b, l:r]
    x = to_input(rgb, (s.height, s.width), s.interpolation)
    return _Item(position, sample, rgb, gt, x, gt.shape, None)


def _same_size(items: list[_Item]) -> list[list[_Item]]:
    """Split a batch where the input or ground-truth size changes."""
    groups: list[list[_Item]] = []
    for it in items:
        if groups and (groups[-1][0].x.shape, groups[-1][0].out_hw) == (it.x.shape, it.out_hw):
            groups[-1].append(it)
        else:
            groups.append([it])
    return groups


class _Tally:
    """What the scored images add up to."""

    def __init__(self) -> None:
        self.records: list[dict[str, float]] = []
        self.keys: list[tuple[str | int, ...]] = []
        self.scenes: list[str] = []
        self.skipped: list[tuple[str | int, ...]] = []
        self.kept: dict[int, Kept] = {}
        self.pooled: tuple[list[np.ndarray], list[np.ndarray]] = ([], [])
        self.nonfinite: list[tuple[int, str]] = []

    def add(self, s: Settings, it: _Item, disp: np.ndarray, keep: Sequence[int]) -> None:
        """Score one image: disp (H,W) at the ground truth's size (dense) or the network's (sparse)."""
        sparse = it.uv is not None
        pred = depth_from_disparity(sample_at_points(disp, it.uv, it.rgb.shape[:2]) if sparse else disp)
        mask = s.valid(it.gt)
        try:
            m, ratio = image_metrics(it.gt, pred, mask, median_scaling=s.median_scaling,
                                     min_depth=s.min_depth, max_depth=s.max_depth)
        except EmptyMaskError:
            self.skipped.append(it.sample.key)
            return
        self.records.append({**m, "ratio": ratio, **({"points": float(mask.sum())} if sparse else {})})
        self.keys.append(it.sample.key)
        self.scenes.append(it.sample.scene)
        if sparse:
            self.pooled[0].append(it.gt[mask])
            self.pooled[1].append(clip_depth(pred[mask] * ratio, s.min_depth, s.max_depth))
        if it.position in keep:
            depth = clip_depth(depth_from_disparity(disp) * ratio, s.min_depth, s.max_depth)
            self.kept[it.position] = Kept(it.sample.key, it.rgb, it.gt, depth.astype(np.float32))

    def result(self, p: Protocol, s: Settings, keep: Sequence[int]) -> ProtocolResult:
        if self.nonfinite:
            log.warning("%s: %d ground-truth pixels in %d image(s) are NaN or inf and count as missing depth "
                        "(first: %s)", p.title, sum(n for n, _ in self.nonfinite), len(self.nonfinite),
                        self.nonfinite[0][1])
        report_skipped(p.title, ["/".join(map(str, k)) for k in self.skipped], len(self.records))
        per_image = stack_per_image(self.records)
        scenes = {}
        for name in sorted(set(self.scenes), key=lambda s: (0, int(s)) if s.isdigit() else (1, s)):
            sel = np.array([n == name for n in self.scenes])
            scenes[name] = aggregate({m: per_image[m][sel] for m in METRIC_NAMES})
        summary, average = aggregate(per_image), mean_of_rows([v.mean for v in scenes.values()])
        pooled = None
        if p.ground_truth == "points":
            pooled = compute_errors(*map(np.concatenate, self.pooled)) if self.pooled[0] else {}
        return ProtocolResult(metrics=dict(summary.mean if p.headline == "images" else average),
                              summary=summary, scenes=scenes, average=average, per_image=per_image,
                              keys=self.keys, scene=self.scenes, skipped=self.skipped,
                              settings=s.record(p.records),
                              kept=[self.kept[i] for i in keep if i in self.kept], pooled=pooled)  # fmt: skip


def _groups(p: Protocol, s: Settings, samples: Iterable[EvalSample], nonfinite: list[tuple[int, str]],
            batch: int, progress: bool) -> Iterator[list[_Item]]:
    """The samples prepared for the network: groups of at most ``batch`` of one size."""
    for chunk in batched(enumerate(tqdm(samples, desc=p.title, disable=not progress)), batch):
        threads.adapt()
        yield from _same_size([_prepare(p, s, pos, sample, nonfinite) for pos, sample in chunk])


def score(p: Protocol, s: Settings, samples: Iterable[EvalSample], predict_disp: PredictDisp, *, batch: int,
          device: str, keep: Sequence[int], progress: bool) -> ProtocolResult:
    """Score ``predict_disp`` (``img (B,3,h,w) in [0,1] → disp (B,1,h,w)``, depth ∝ 1/disp) on ``samples``
    as protocol ``p`` with settings ``s``, ``batch`` images per forward pass (of one size)."""
    tally = _Tally()
    for group in _groups(p, s, samples, tally.nonfinite, batch, progress):
        disp = run_batch(predict_disp, [it.x for it in group], device=device, post_process=s.post_process,
                         out_hw=group[0].out_hw, upsample=s.upsample)
        for it, d in zip(group, disp):
            tally.add(s, it, d, keep)
    return tally.result(p, s, keep)


def score_with_and_without_pp(p: Protocol, s: Settings, samples: Iterable[EvalSample],
                              predict_disp: PredictDisp, *, batch: int, device: str, keep: Sequence[int],
                              progress: bool) -> tuple[ProtocolResult, ProtocolResult]:
    """:func:`score` without and with flip post-processing (whatever ``s.post_process`` says), each batch
    through the network once (:func:`~f2depth.protocols.inputs.run_batch_with_and_without_pp`) → (without,
    with). ``keep`` applies to both."""
    both = (replace(s, post_process=False), replace(s, post_process=True))
    tallies = (_Tally(), _Tally())
    for group in _groups(p, s, samples, tallies[0].nonfinite, batch, progress):
        disps = run_batch_with_and_without_pp(predict_disp, [it.x for it in group], device=device,
                                              out_hw=group[0].out_hw, upsample=s.upsample)
        for tally, settings, disp in zip(tallies, both, disps):
            for it, d in zip(group, disp):
                tally.add(settings, it, d, keep)
    tallies[1].nonfinite = tallies[0].nonfinite
    plain, pp = (t.result(p, settings, keep) for t, settings in zip(tallies, both))
    return plain, pp
