"""Every registered test set for one depth model, each without and with flip post-processing (PP), plus
the inference time; and the mean over the seeds of a variant.

The test sets are the protocols of ``f2depth.protocols.registry``; this module runs the ones of
``cfg.datasets`` with one set of settings (:class:`SuiteConfig`) and shapes their results into
- ``headline``: ``{<name>: {metric: value}, <name>_pp: …, "ms": …, "ms_pp": …}`` (each protocol's headline:
  ``nyu`` and ``sevenscenes`` the mean over the test images, which is how the paper's 7-Scenes "Average" row
  is computed, ``campus`` the mean of the scene rows as the paper's tab:tab3);
- ``details``: per-scene rows, std over images, counts, settings (JSON-ready);
- per-image rows (for CSV files) and a few kept predictions (for qualitative figures).

Predictions: ``predict_disp(img (B,3,h,w) in [0,1]) -> disp (B,1,h,w)`` with depth ∝ 1/disp; for a
``DepthModel`` use :func:`model_disparity` (Monodepth2's scaled disparity, not the raw sigmoid).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
import torch

from f2depth.depth.decoder import UPSAMPLE_MODES
from f2depth.depth.predict import PredictDisp
from f2depth.eval.timing import time_inference
from f2depth.formats.samples import SampleSet
from f2depth.io import csv_text
from f2depth.protocols import registry
from f2depth.protocols.protocol import Protocol
from f2depth.protocols.scoring import Kept, Settings

DATASETS = registry.NAMES
GROUPS = tuple(f"{d}{s}" for d in DATASETS for s in ("", "_pp"))
"""Headline metric groups: ``<name>`` and ``<name>_pp`` of every registered test set."""

TIMING_KEYS = ("ms", "ms_pp")


@dataclass(frozen=True)
class SuiteConfig:
    """How every protocol runs. ``height``/``width``: network input size for the test sets (the model's
    training size when None); timing always runs at ``timing_height`` × ``timing_width`` (the paper's
    288×384). ``nyu_crop``: the NYU protocol's crop. ``decoder_upsample``: the ×2 upsampling the evaluated
    depth decoder is rebuilt with (the caller loads the model with it; recorded here with the other
    settings). ``datasets``: which registered test sets to run. ``figure_images``: how many samples each
    test set with figures keeps (NYU: evenly spaced test images; 7-Scenes: the middle frame of every scene
    when not 0), downsized to ``figure_width``, from the run without PP."""

    height: int | None = None
    width: int | None = None
    nyu_crop: str = "eigen"
    interpolation: str = "lanczos"
    upsample: str = "nearest"
    decoder_upsample: str = "bilinear"  # the depth decoder's ×2 upsampling at test time (P²Net's evaluation)
    batch_size: int = field(default=4, metadata={"min": 1})
    device: str = "cpu"
    datasets: tuple[str, ...] = DATASETS
    timing_height: int = field(default=288, metadata={"min": 32})
    timing_width: int = field(default=384, metadata={"min": 32})
    timing_repeats: int = field(default=10, metadata={"min": 1})
    timing_warmup: int = field(default=2, metadata={"min": 0})
    figure_images: int = field(default=4, metadata={"min": 0})
    figure_width: int = field(default=320, metadata={"min": 1})
    progress: bool = False

    def __post_init__(self) -> None:
        unknown = sorted(set(self.datasets) - set(DATASETS))
        if unknown:
            raise ValueError(f"unknown test sets {unknown}; evaluate.datasets may hold {list(DATASETS)}")
        if (self.height is None) != (self.width is None):
            raise ValueError("give both evaluate.height and evaluate.width, or neither (model's size)")
        for name in self.datasets:  # fails early on a typo (e.g. an unknown NYU crop)
            settings(registry.protocol(name), self, (288, 384))
        if self.decoder_upsample not in UPSAMPLE_MODES:
            raise ValueError(f"evaluate.decoder_upsample is {self.decoder_upsample!r}; use one of "
                             f"{list(UPSAMPLE_MODES)}")


def settings(protocol: Protocol, cfg: SuiteConfig, hw: tuple[int, int]) -> dict[str, Any]:
    """The settings ``protocol`` runs with under ``cfg`` at network size ``hw``: the input size, resize and
    upsampling filters, and its own options (:attr:`Protocol.options`), as far as it reads them."""
    given = {"height": hw[0], "width": hw[1], "interpolation": cfg.interpolation, "upsample": cfg.upsample,
             **{name: getattr(cfg, option) for name, option in protocol.options.items()}}
    chosen = {k: v for k, v in given.items() if k in protocol.records}
    Settings(**chosen)  # checks them
    return chosen


def model_disparity(model: torch.nn.Module) -> PredictDisp:
    """``predict_disp`` of a ``DepthModel``: Monodepth2's scaled disparity (1/depth), not the sigmoid."""
    from f2depth.depth import disp_to_depth

    lo, hi = model.config.min_depth, model.config.max_depth
    return lambda x: disp_to_depth(model.predict_disp(x), lo, hi)[0]


# ---- one model ----------------------------------------------------------------------------------------


@dataclass
class ModelResult:
    """Everything one model scored. ``per_image``: test set → list of row dicts (with ``post_process``);
    ``kept``: arrays for figures (``nyu_rgb`` (K,h,w,3) uint8, ``nyu_gt``/``nyu_pred`` (K,h,w) float32,
    ``nyu_id`` (K,), and the same for every other test set with figures)."""

    headline: dict[str, Any]
    details: dict[str, Any]
    per_image: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    kept: dict[str, np.ndarray] = field(default_factory=dict)


def _small(img: np.ndarray, width: int, interp: int) -> np.ndarray:
    h, w = img.shape[:2]
    if w <= width:
        return img
    return cv2.resize(img, (width, max(1, round(h * width / w))), interpolation=interp)


def _keep_arrays(prefix: str, kept: Sequence[Kept], width: int) -> dict[str, np.ndarray]:
    if not kept:
        return {}

    def maps(arrays: list[np.ndarray]) -> np.ndarray:
        return np.stack([_small(a, width, cv2.INTER_NEAREST) for a in arrays]).astype(np.float32)

    return {f"{prefix}_id": np.array(["/".join(map(str, k.key)) for k in kept]),
            f"{prefix}_rgb": np.stack([_small(k.rgb, width, cv2.INTER_AREA) for k in kept]),
            f"{prefix}_gt": maps([k.gt for k in kept]), f"{prefix}_pred": maps([k.pred for k in kept])}


def evaluate_model(predict: PredictDisp, sets: Mapping[str, SampleSet], cfg: SuiteConfig,
                   net_hw: tuple[int, int], timing: Mapping[str, dict[str, Any]] | None = None
                   ) -> ModelResult:
    """Run the protocols of ``cfg.datasets`` on ``sets`` (name → loaded test set), each image and its mirror
    through the network once for the scores without and with flip post-processing, and time the predictor.
    ``net_hw``: the input size when ``cfg.height`` is None (the model's training size). ``timing``: the
    ``details["timing"]`` of an earlier result of a model of the same architecture, reused instead of timed
    again (the time depends on the architecture, not on the weights; the evaluate stage times each
    variant's first seed)."""
    hw = (cfg.height, cfg.width) if cfg.height is not None else tuple(net_hw)
    out = ModelResult(headline={}, details={"input_hw": list(hw)})
    for name in cfg.datasets:
        if name not in sets:
            raise ValueError(f"test set '{name}' is listed in evaluate.datasets but was not loaded")
        protocol, data = registry.protocol(name), sets[name]
        figure = protocol.figure
        keep = figure.pick(data, cfg.figure_images) if figure is not None and cfg.figure_images else []
        both = protocol.evaluate_with_and_without_pp(data, predict, batch_size=cfg.batch_size,
                                                     device=cfg.device, keep=keep, progress=cfg.progress,
                                                     **settings(protocol, cfg, hw))
        for pp, r in zip((False, True), both):
            group = f"{name}_pp" if pp else name
            out.headline[group] = r.metrics
            out.details[group] = protocol.details(r)
            out.per_image.setdefault(name, []).extend(protocol.image_rows(r, pp))
            if not pp:
                out.kept.update(_keep_arrays(name, r.kept, cfg.figure_width))
    if timing is None:
        timing = {key: time_inference(predict, height=cfg.timing_height, width=cfg.timing_width,
                                      post_process=pp, repeats=cfg.timing_repeats, warmup=cfg.timing_warmup,
                                      device=cfg.device)
                  for key, pp in zip(TIMING_KEYS, (False, True))}
    for key in TIMING_KEYS:
        out.headline[key] = timing[key]["ms_median"]
    out.details["timing"] = dict(timing)
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
    return {**mean_over_seeds(headlines), "n_seeds": len(seeds),
            "per_seed": {f"seed{s}": h for s, h in zip(seeds, headlines)}, "variant": variant}


def rows_csv(rows: Sequence[dict[str, Any]]) -> str:
    """Per-image rows (dicts, possibly with different keys) as CSV text; columns in first-seen order,
    floats written exactly (``repr``), missing cells empty."""
    fields = list(dict.fromkeys(k for r in rows for k in r))
    return csv_text(fields, ([repr(v) if isinstance(v, float) else v for v in (r.get(k, "") for k in fields)]
                             for r in rows))
