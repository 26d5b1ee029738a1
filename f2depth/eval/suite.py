"""Every test protocol for one depth model: NYU, 7-Scenes and Campus, each without and with flip
post-processing (PP), plus the inference time; and the mean over the seeds of a variant.

The protocols themselves live in ``nyu``, ``sevenscenes``, ``campus`` and ``timing``; this module only
runs them with one set of settings (:class:`SuiteConfig`), and shapes the results into
- ``headline``: ``{group: {metric: value}, "ms": …, "ms_pp": …}`` with the groups of :data:`GROUPS`
  (``nyu`` = mean over the test images, ``sevenscenes`` = mean over all test frames, which is how the
  paper's 7-Scenes "Average" row is computed, ``campus`` = mean of the scene rows as the paper's tab:tab3);
- ``details``: per-scene rows, std over images, counts, settings (JSON-ready);
- per-image rows (for CSV files and figures) and a few kept predictions (for qualitative figures).

Predictions: ``predict_disp(img (B,3,h,w) in [0,1]) -> disp (B,1,h,w)`` with depth ∝ 1/disp; for a
``DepthModel`` use :func:`model_disparity` (Monodepth2's scaled disparity, not the raw sigmoid).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import torch

from f2depth.depth.decoder import UPSAMPLE_MODES
from f2depth.eval.campus import evaluate_campus
from f2depth.eval.metrics import METRIC_NAMES, PredictDisp
from f2depth.eval.nyu import evaluate_nyu, resolve_crop
from f2depth.eval.sevenscenes import evaluate_sevenscenes
from f2depth.eval.timing import time_inference

DATASETS = ("nyu", "sevenscenes", "campus")
GROUPS = tuple(f"{d}{s}" for d in DATASETS for s in ("", "_pp"))
"""Headline metric groups: ``nyu``, ``nyu_pp``, ``sevenscenes``, ``sevenscenes_pp``, ``campus``,
``campus_pp``."""

TIMING_KEYS = ("ms", "ms_pp")


@dataclass(frozen=True)
class SuiteConfig:
    """How every protocol runs. ``height``/``width``: network input size for the test sets (the model's
    training size when None); timing always runs at ``timing_height`` × ``timing_width`` (the paper's
    288×384). ``decoder_upsample``: the ×2 upsampling the evaluated depth decoder is rebuilt with (the
    caller loads the model with it; recorded here with the other settings). ``datasets``: which of
    :data:`DATASETS` to run. ``figure_images``: NYU test images (evenly
    spaced) whose predictions (PP off) are kept for figures, downsized to ``figure_width``; when it is
    not 0, the middle test frame of every 7-Scenes scene is kept too."""

    height: int | None = None
    width: int | None = None
    nyu_crop: str = "eigen"
    interpolation: str = "area"
    upsample: str = "nearest"
    decoder_upsample: str = "bilinear"  # the depth decoder's ×2 upsampling at test time (P²Net's evaluation)
    batch_size: int = 4
    device: str = "cpu"
    datasets: tuple[str, ...] = DATASETS
    timing_height: int = 288
    timing_width: int = 384
    timing_repeats: int = 20
    timing_warmup: int = 3
    figure_images: int = 4
    figure_width: int = 320
    progress: bool = False

    def __post_init__(self) -> None:
        unknown = sorted(set(self.datasets) - set(DATASETS))
        if unknown:
            raise ValueError(f"unknown test sets {unknown}; evaluate.datasets may hold {list(DATASETS)}")
        if (self.height is None) != (self.width is None):
            raise ValueError("give both evaluate.height and evaluate.width, or neither (model's size)")
        resolve_crop(self.nyu_crop)  # fails early on a typo
        if self.decoder_upsample not in UPSAMPLE_MODES:
            raise ValueError(f"evaluate.decoder_upsample is {self.decoder_upsample!r}; use one of "
                             f"{list(UPSAMPLE_MODES)}")


class Subset:
    """The samples at ``positions`` of an indexable dataset (``len`` and ``[i]``); iterable."""

    def __init__(self, dataset: Any, positions: Sequence[int]) -> None:
        self.dataset, self.positions = dataset, [int(p) for p in positions]

    def __len__(self) -> int:
        return len(self.positions)

    def __getitem__(self, i: int) -> Any:
        return self.dataset[self.positions[i]]

    def __iter__(self) -> Iterator[Any]:
        for p in self.positions:
            yield self.dataset[p]


def spread(n: int, k: int | None) -> list[int]:
    """``k`` evenly spaced positions out of ``n`` (all of them when ``k`` is None or ≥ n)."""
    if k is None or k >= n:
        return list(range(n))
    if k < 1:
        raise ValueError(f"need at least one image, got max_images={k}")
    return np.unique(np.linspace(0, n - 1, k).round().astype(int)).tolist()


def limit(dataset: Any, max_images: int | None) -> Any:
    """The dataset itself, or an evenly spaced :class:`Subset` of ``max_images`` samples."""
    if max_images is None or max_images >= len(dataset):
        return dataset
    return Subset(dataset, spread(len(dataset), max_images))


def model_disparity(model: torch.nn.Module) -> PredictDisp:
    """``predict_disp`` of a ``DepthModel``: Monodepth2's scaled disparity (1/depth), not the sigmoid."""
    from f2depth.depth import disp_to_depth

    lo, hi = model.config.min_depth, model.config.max_depth
    return lambda x: disp_to_depth(model.predict_disp(x), lo, hi)[0]


# ---- one model ----------------------------------------------------------------------------------------


@dataclass
class ModelResult:
    """Everything one model scored. ``per_image``: dataset → list of row dicts (with ``post_process``);
    ``kept``: arrays for figures (``nyu_rgb`` (K,h,w,3) uint8, ``nyu_gt``/``nyu_pred`` (K,h,w) float32,
    ``nyu_id`` (K,), and the same with prefix ``sevenscenes_``)."""

    headline: dict[str, Any]
    details: dict[str, Any]
    per_image: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    kept: dict[str, np.ndarray] = field(default_factory=dict)


def _small(img: np.ndarray, width: int, interp: int) -> np.ndarray:
    h, w = img.shape[:2]
    if w <= width:
        return img
    return cv2.resize(img, (width, max(1, round(h * width / w))), interpolation=interp)


def _keep_arrays(prefix: str, ids: list[str], rgbs: list[np.ndarray], gts: list[np.ndarray],
                 preds: list[np.ndarray], width: int) -> dict[str, np.ndarray]:
    if not ids:
        return {}
    return {
        f"{prefix}_id": np.array(ids),
        f"{prefix}_rgb": np.stack([_small(r, width, cv2.INTER_AREA) for r in rgbs]),
        f"{prefix}_gt": np.stack([_small(g, width, cv2.INTER_NEAREST) for g in gts]).astype(np.float32),
        f"{prefix}_pred": np.stack([_small(p, width, cv2.INTER_NEAREST) for p in preds]).astype(np.float32),
    }


def _rows(per_image: dict[str, np.ndarray], keys: dict[str, Sequence[Any]], pp: bool) -> list[dict[str, Any]]:
    n = len(next(iter(per_image.values()))) if per_image else 0
    names = [k for k in per_image if k in METRIC_NAMES] + [k for k in per_image if k not in METRIC_NAMES]
    return [{"post_process": pp, **{k: v[i] for k, v in keys.items()},
             **{m: float(per_image[m][i]) for m in names}} for i in range(n)]  # fmt: skip


def _run_nyu(predict: PredictDisp, data: Any, cfg: SuiteConfig, hw: tuple[int, int],
             out: ModelResult) -> None:
    keep_pos = spread(len(data), cfg.figure_images) if cfg.figure_images else []
    keep_samples = [data[p] for p in keep_pos]
    keep_ids = {int(s.index) for s in keep_samples}
    box = resolve_crop(cfg.nyu_crop)
    for pp in (False, True):
        r = evaluate_nyu(
            data, predict, height=hw[0], width=hw[1], crop=cfg.nyu_crop, interpolation=cfg.interpolation,
            upsample=cfg.upsample, post_process=pp, batch_size=cfg.batch_size, device=cfg.device,
            keep=() if pp else keep_ids, progress=cfg.progress,
        )  # fmt: skip
        group = "nyu_pp" if pp else "nyu"
        out.headline[group] = r.metrics
        out.details[group] = r.to_json()
        out.per_image.setdefault("nyu", []).extend(
            _rows(r.per_image, {"index": r.index.tolist(), "scene": r.scene}, pp))
        if not pp:
            kept = [s for s in keep_samples if int(s.index) in r.predictions]
            crop = (slice(box[0], box[1]), slice(box[2], box[3])) if box else (slice(None), slice(None))
            out.kept.update(_keep_arrays(
                "nyu", [str(s.index) for s in kept], [s.rgb[crop] for s in kept],
                [np.asarray(s.depth, np.float32)[crop] for s in kept],
                [r.predictions[int(s.index)] for s in kept], cfg.figure_width))  # fmt: skip


def middle_frames(data: Any) -> list[int]:
    """Position of the middle test frame of every scene (in first-appearance order of the scenes)."""
    by_scene: dict[str, list[int]] = {}
    for i in range(len(data)):
        scene = data.info(i)[0] if hasattr(data, "info") else data[i].scene
        by_scene.setdefault(str(scene), []).append(i)
    return [pos[len(pos) // 2] for pos in by_scene.values()]


def _run_sevenscenes(predict: PredictDisp, data: Any, cfg: SuiteConfig, hw: tuple[int, int],
                     out: ModelResult) -> None:
    keep_samples = [data[p] for p in middle_frames(data)] if cfg.figure_images else []
    keep_keys = {(str(s.scene), s.seq, s.frame) for s in keep_samples}
    for pp in (False, True):
        r = evaluate_sevenscenes(
            data, predict, height=hw[0], width=hw[1], interpolation=cfg.interpolation, upsample=cfg.upsample,
            post_process=pp, batch_size=cfg.batch_size, device=cfg.device, keep=() if pp else keep_keys,
            progress=cfg.progress,
        )  # fmt: skip
        group = "sevenscenes_pp" if pp else "sevenscenes"
        out.headline[group] = dict(r.frame_weighted.mean)
        out.details[group] = {**r.to_json(), "rows": r.rows()}
        out.per_image.setdefault("sevenscenes", []).extend(
            _rows(r.per_image, {"scene": r.scene, "seq": r.seq, "frame": r.frame}, pp))
        if not pp:
            kept = [s for s in keep_samples if (str(s.scene), s.seq, s.frame) in r.predictions]
            out.kept.update(_keep_arrays(
                "sevenscenes", [f"{s.scene}/{s.seq}/{s.frame}" for s in kept], [s.rgb for s in kept],
                [np.asarray(s.depth, np.float32) for s in kept],
                [r.predictions[(str(s.scene), s.seq, s.frame)] for s in kept], cfg.figure_width))  # fmt: skip


def _run_campus(predict: PredictDisp, data: Any, cfg: SuiteConfig, hw: tuple[int, int],
                out: ModelResult) -> None:
    for pp in (False, True):
        r = evaluate_campus(
            data, predict, height=hw[0], width=hw[1], interpolation=cfg.interpolation, post_process=pp,
            device=cfg.device, progress=cfg.progress,
        )  # fmt: skip
        group = "campus_pp" if pp else "campus"
        out.headline[group] = dict(r.average)
        out.details[group] = {**r.to_json(), "rows": r.rows()}
        out.per_image.setdefault("campus", []).extend(
            _rows(r.per_image, {"scene": r.scene, "image": r.image}, pp))


def evaluate_model(predict: PredictDisp, sets: dict[str, Any], cfg: SuiteConfig,
                   net_hw: tuple[int, int]) -> ModelResult:
    """Run the protocols of ``cfg.datasets`` on ``sets`` (name → dataset, see :data:`DATASETS`) and time
    the predictor. ``net_hw``: the input size when ``cfg.height`` is None (the model's training size)."""
    hw = (cfg.height, cfg.width) if cfg.height is not None else tuple(net_hw)
    out = ModelResult(headline={}, details={"input_hw": list(hw)})
    runners: dict[str, Callable[..., None]] = {"nyu": _run_nyu, "sevenscenes": _run_sevenscenes,
                                               "campus": _run_campus}
    for name in cfg.datasets:
        if name not in sets:
            raise ValueError(f"test set '{name}' is listed in evaluate.datasets but was not loaded")
        runners[name](predict, sets[name], cfg, hw, out)
    timing = {}
    for key, pp in zip(TIMING_KEYS, (False, True)):
        timing[key] = time_inference(
            predict, height=cfg.timing_height, width=cfg.timing_width, post_process=pp,
            repeats=cfg.timing_repeats, warmup=cfg.timing_warmup, device=cfg.device,
        )  # fmt: skip
        out.headline[key] = timing[key]["ms_median"]
    out.details["timing"] = timing
    return out


# ---- over seeds -----------------------------------------------------------------------------------------


def mean_over_seeds(headlines: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Per-seed headline dicts (same keys) → their mean, key by key (nested one level)."""
    if not headlines:
        raise ValueError("no per-seed results to average")
    out: dict[str, Any] = {}
    for key, value in headlines[0].items():
        if isinstance(value, dict):
            out[key] = {m: float(np.mean([h[key][m] for h in headlines])) for m in value}
        else:
            out[key] = float(np.mean([h[key] for h in headlines]))
    return out


def metrics_document(variant: str, seeds: Sequence[int],
                     headlines: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The ``metrics/evaluate/<variant>.json`` document: the mean over seeds flat at the top (what
    ``dvc metrics show`` / ``dvc exp show`` list), then ``n_seeds`` and ``per_seed`` (``seed<k>`` →
    that seed's headline)."""
    if len(seeds) != len(headlines):
        raise ValueError(f"{len(seeds)} seeds but {len(headlines)} results")
    return {
        **mean_over_seeds(headlines),
        "n_seeds": len(seeds),
        "per_seed": {f"seed{s}": h for s, h in zip(seeds, headlines)},
        "variant": variant,
    }


def rows_csv(rows: Sequence[dict[str, Any]]) -> str:
    """Per-image rows (dicts, possibly with different keys) as CSV text; columns in first-seen order,
    floats written exactly (``repr``), missing cells empty."""
    import csv
    import io

    fields: list[str] = []
    for r in rows:
        fields.extend(k for k in r if k not in fields)
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n", restval="")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: repr(v) if isinstance(v, float) else v for k, v in r.items()})
    return buf.getvalue()
