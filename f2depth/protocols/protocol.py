"""One interface for every test set: a :class:`Protocol` scores typed samples into a ``ProtocolResult``.

A test set is the ``PROTOCOL`` of its module, listed in ``f2depth.protocols.registry``: how its loader opens
from params, the ``Settings`` it is scored with (``f2depth.protocols.scoring``: one recipe for all), and how
the `evaluate` stage records it (details.json, per-image CSV, figures). How the `tables` stage shows it
(overview columns, per-scene table, the paper's rows) is ``f2depth.report.layouts``: editing the paper's
numbers re-runs the tables, never the evaluation or the training.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from f2depth.depth.predict import PredictDisp
from f2depth.formats.samples import EvalSample, SampleSet
from f2depth.protocols.metrics import METRIC_NAMES
from f2depth.protocols.scoring import (
    SETTING_NAMES,
    ProtocolResult,
    Settings,
    score,
    score_with_and_without_pp,
)


@dataclass(frozen=True)
class SceneRows:
    """details.json per scene: ``count`` names the image count (``frames``), ``overall`` the mean over all
    images (``frame_weighted``); ``all_images_row``: the label of a last row with that mean, if any."""

    count: str
    overall: str
    all_images_row: str | None = None


@dataclass(frozen=True)
class Figure:
    """Qualitative figures of a test set (the first seed, no PP): ``title``; ``pick(samples, n)``: the
    positions of the samples kept, ``n`` = ``evaluate.figure_images`` (> 0)."""

    title: str
    pick: Callable[[SampleSet, int], list[int]]


@dataclass(frozen=True)
class Protocol:
    """A test set, as the `evaluate` stage scores it (through ``f2depth.protocols.registry``).

    ``name``: registry name (``evaluate.datasets``, headline groups ``<name>`` and ``<name>_pp``,
    ``<name>.csv``); ``title``: display name; ``open(get)``: its loader (a ``SampleSet``), ``get(key)``
    reading a params key such as ``data.campus``; ``defaults``: its ``Settings``; ``records``: the settings
    it reads, recorded in that order; ``columns``: the names of a sample key's entries (per-image CSV);
    ``ground_truth``: ``depth`` (dense) or ``points`` (sparse); ``options``: setting → ``SuiteConfig``
    field a user sets (NYU: ``crop`` ← ``nyu_crop``); ``headline``: ``images`` (the mean over images) or
    ``scenes`` (the mean of the scene rows); ``scene_rows``: details.json per scene (None: per image only);
    ``nonfinite``: a NaN/inf ground-truth depth is an ``error`` (DataError: loaders mark missing depth with
    0) or ``missing`` (invalid, one warning line); ``max_batch``: images per forward pass at most;
    ``figure``: the qualitative figures `evaluate` keeps the predictions for (None: none).
    """

    name: str
    title: str
    open: Callable[[Callable[[str], Any]], SampleSet]
    defaults: Settings
    records: tuple[str, ...]
    columns: tuple[str, ...]
    ground_truth: str = "depth"
    options: Mapping[str, str] = field(default_factory=dict)
    headline: str = "images"
    scene_rows: SceneRows | None = None
    nonfinite: str = "error"
    max_batch: int | None = None
    figure: Figure | None = None

    def __post_init__(self) -> None:
        unknown = sorted(set(self.records) - set(SETTING_NAMES))
        if unknown:
            raise ValueError(f"protocol {self.name}: records {unknown} name no Settings field")
        choices = (("ground_truth", self.ground_truth, ("depth", "points")),
                   ("headline", self.headline, ("images", "scenes")),
                   ("nonfinite", self.nonfinite, ("error", "missing")))
        for what, value, allowed in choices:
            if value not in allowed:
                raise ValueError(f"protocol {self.name}: {what} is {value!r}; use one of {list(allowed)}")

    def evaluate(self, samples: Iterable[EvalSample], predict_disp: PredictDisp, *, batch_size: int = 1,
                 device: str = "cpu", keep: Collection[int] = (), progress: bool = False,
                 **settings: Any) -> ProtocolResult:
        """Score ``predict_disp`` (``img (B,3,h,w) in [0,1] → disp (B,1,h,w)``, depth ∝ 1/disp) on
        ``samples`` with :attr:`defaults` changed by ``settings`` (names of :attr:`records`); ``keep``:
        positions in ``samples`` whose scored maps the result keeps."""
        return score(self, self._settings(settings), samples, predict_disp, progress=progress,
                     batch=self._batch(batch_size), device=device, keep=list(keep))

    def evaluate_with_and_without_pp(self, samples: Iterable[EvalSample], predict_disp: PredictDisp, *,
                                     batch_size: int = 1, device: str = "cpu", keep: Collection[int] = (),
                                     progress: bool = False, **settings: Any
                                     ) -> tuple[ProtocolResult, ProtocolResult]:
        """:meth:`evaluate` without and with flip post-processing, from one forward pass a batch (the
        network sees each image and its mirror once) → (without, with); ``settings`` as in
        :meth:`evaluate`, but for ``post_process``."""
        if "post_process" in settings:
            raise TypeError("evaluate_with_and_without_pp scores both; do not give post_process")
        return score_with_and_without_pp(self, self._settings(settings), samples, predict_disp,
                                         progress=progress, batch=self._batch(batch_size), device=device,
                                         keep=list(keep))

    def _settings(self, settings: Mapping[str, Any]) -> Settings:
        unknown = sorted(set(settings) - set(self.records))
        if unknown:
            raise TypeError(f"the {self.title} protocol has no setting {unknown}; it takes "
                            f"{list(self.records)}")
        return replace(self.defaults, **settings)

    def _batch(self, batch_size: int) -> int:
        return min(batch_size, self.max_batch or batch_size)

    def details(self, r: ProtocolResult) -> dict[str, Any]:
        """One result in details.json: summaries, per-scene rows, skipped images, settings."""
        skipped = [k[0] if len(k) == 1 else [str(x) for x in k] for k in r.skipped]
        if self.scene_rows is None:
            ratio = r.per_image.get("ratio", np.zeros(0))
            return {"metrics": dict(r.summary.mean), "std": dict(r.summary.std), "count": r.summary.count,
                    "ratio_median": float(np.median(ratio)) if ratio.size else None,
                    "ratio_std": float(np.std(ratio)) if ratio.size else None,
                    "skipped": skipped, "settings": dict(r.settings)}  # fmt: skip
        out: dict[str, Any] = {"average": dict(r.average), self.scene_rows.overall: r.summary.as_dict()}
        if r.pooled is not None:
            points = r.per_image.get("points")
            out |= {"pooled": dict(r.pooled), "points": int(points.sum()) if points is not None else 0}
        return out | {"scenes": {s: v.as_dict() for s, v in r.scenes.items()}, "skipped": skipped,
                      "settings": dict(r.settings), "rows": self.rows(r)}

    def rows(self, r: ProtocolResult) -> list[dict[str, Any]]:
        """Per-scene table rows (sets with :attr:`scene_rows`): ``{"scene", <count>, <metrics>}`` per scene,
        ``Average`` (the mean of the scene rows), then the all-images row if there is one."""
        lay = self.scene_rows
        out = [{"scene": s, lay.count: v.count, **v.mean} for s, v in r.scenes.items()]
        out.append({"scene": "Average", lay.count: r.summary.count, **r.average})
        if lay.all_images_row:
            out.append({"scene": lay.all_images_row, lay.count: r.summary.count, **r.summary.mean})
        return out

    def image_rows(self, r: ProtocolResult, post_process: bool) -> list[dict[str, Any]]:
        """Per-image CSV rows: ``post_process``, the key's columns, ``scene``, the metrics, the extras."""
        names = sorted(r.per_image, key=lambda k: k not in METRIC_NAMES)  # stable: metrics first
        return [{"post_process": post_process, **dict(zip(self.columns, key)), "scene": scene,
                 **{m: float(r.per_image[m][i]) for m in names}}
                for i, (key, scene) in enumerate(zip(r.keys, r.scene))]  # fmt: skip
