"""Reading what the evaluate, flow_finetune and train_depth stages wrote, for tables and figures.

- ``metrics/evaluate/<variant>.json`` (``f2depth.eval.suite.metrics_document``): headline groups
  averaged over seeds, and ``per_seed``;
- ``reports/eval/<variant>/details.json``: per seed, per-scene rows of 7-Scenes and Campus, counts;
- ``reports/eval/<variant>/figures.npz``: the first seed's predictions on a few test images;
- ``metrics/flow_finetune/<loss>.json``: EPE of the pretrained and fine-tuned flow on held-out pairs;
- ``metrics/train_depth/<variant>/history.csv`` and ``metrics/flow_finetune/<loss>/history.csv``.
"""

from __future__ import annotations

import csv
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

EPE_KEYS = ("epe_all", "epe_noc", "epe_low_texture")


def read_json(path: str | os.PathLike, fix: str) -> dict[str, Any]:
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{p}: not found; {fix}")
    try:
        return json.loads(p.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{p}: not valid JSON ({exc}); {fix}") from exc


@dataclass
class VariantResults:
    """One variant's evaluation: ``metrics`` (the metrics document), ``details`` (details.json or {})
    and ``kept`` (figures.npz arrays or {})."""

    name: str
    metrics: dict[str, Any]
    details: dict[str, Any] = field(default_factory=dict)
    kept: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def seed_keys(self) -> list[str]:
        return list(self.metrics.get("per_seed", {}))

    @property
    def n_seeds(self) -> int:
        return len(self.seed_keys)

    def _group(self, seed: str, group: str) -> dict[str, Any]:
        """details.json's ``group`` (or ``timing``) of one seed; {} when absent."""
        return self.details.get("seeds", {}).get(seed, {}).get(group) or {}

    @staticmethod
    def _every(values: list[Any]) -> list[float] | None:
        return None if any(v is None for v in values) else [float(v) for v in values]

    def values(self, group: str, metric: str | None = None) -> list[float] | None:
        """Per-seed values of ``group.metric`` (or of the scalar ``group``, e.g. ``ms``); None if absent."""
        nodes = [self.metrics["per_seed"][key].get(group) for key in self.seed_keys]
        if metric is not None:
            nodes = [node.get(metric) if isinstance(node, dict) else None for node in nodes]
        return self._every(nodes)

    def scene_values(self, group: str, scene: str, metric: str) -> list[float] | None:
        """Per-seed values of one scene row of ``group`` (``sevenscenes_pp``, ``campus`` …) from details."""
        rows = [self._group(key, group).get("scenes", {}).get(scene, {}) for key in self.seed_keys]
        return self._every([row.get("mean", {}).get(metric) for row in rows])

    def scene_mean_values(self, group: str, metric: str) -> list[float] | None:
        """Per-seed unweighted mean of the scene rows (the ``average`` of 7-Scenes / Campus results)."""
        return self._every([self._group(key, group).get("average", {}).get(metric) for key in self.seed_keys])

    def scenes(self, group: str) -> list[str]:
        """Scene names of ``group`` in the first seed's order."""
        return list(self._group(self.seed_keys[0], group).get("scenes", {})) if self.seed_keys else []

    def scene_count(self, group: str, scene: str) -> int | None:
        row = self._group(self.seed_keys[0], group).get("scenes", {}).get(scene) if self.seed_keys else None
        return int(row["count"]) if row else None

    def timing(self, key: str = "ms") -> dict[str, Any]:
        """The first seed's timing record (device, threads, size) for ``ms`` or ``ms_pp``."""
        return self._group(self.seed_keys[0], "timing").get(key, {}) if self.seed_keys else {}


def load_variant(name: str, metrics_dir: str | os.PathLike, eval_dir: str | os.PathLike) -> VariantResults:
    fix = f"run `dvc repro evaluate@{name}`"
    metrics = read_json(Path(metrics_dir) / f"{name}.json", fix)
    if "per_seed" not in metrics:
        raise ValueError(f"{Path(metrics_dir) / f'{name}.json'}: no 'per_seed' section; {fix}")
    details_file = Path(eval_dir) / name / "details.json"
    details = read_json(details_file, fix) if details_file.is_file() else {}
    kept_file = Path(eval_dir) / name / "figures.npz"
    kept: dict[str, np.ndarray] = {}
    if kept_file.is_file():
        with np.load(kept_file) as z:
            kept = {k: z[k] for k in z.files}
    return VariantResults(name, metrics, details, kept)


def load_variants(names: list[str], metrics_dir: str | os.PathLike,
                  eval_dir: str | os.PathLike) -> dict[str, VariantResults]:
    return {n: load_variant(n, metrics_dir, eval_dir) for n in names}


def flow_epe(flow_model: str | None, flow_metrics: dict[str, dict[str, Any]], pretrained: str,
             model_template: str) -> dict[str, float | None] | None:
    """EPE (all / noc / low-texture) on the held-out test pairs of the flow network a variant used.

    flow_metrics: loss → ``metrics/flow_finetune/<loss>.json``; ``pretrained``: the path of the
    pretrained model (``flow_finetune.pretrained``), whose EPE every fine-tune json reports under
    ``pretrained``; ``model_template``: ``flow_finetune.model`` with ``{loss}``. None when the variant
    uses no flow network or its model is none of those.
    """
    if not flow_model:
        return None
    norm = os.path.normpath
    for loss, m in flow_metrics.items():
        if norm(flow_model) == norm(model_template.format(loss=loss)):
            return {k: m.get("finetuned", {}).get("test", {}).get(k) for k in EPE_KEYS}
    if norm(flow_model) == norm(pretrained) and flow_metrics:
        m = next(iter(flow_metrics.values()))
        return {k: m.get("pretrained", {}).get("test", {}).get(k) for k in EPE_KEYS}
    return None


def headline(results: dict[str, VariantResults], train_metrics: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """One flat record per variant for ``dvc exp show`` (the ``tables`` stage's metrics file): NYU δ1 and
    AbsRel of the trained network (mean over seeds) with their sample standard deviation over the seeds
    (``*_std``, None for one seed) and the seed count ``n_seeds``, and beside them the floors from its
    training run — the untrained network and a constant depth on the same test images (``train_metrics``:
    variant → ``metrics/train_depth/<variant>.json``)."""
    out: dict[str, Any] = {}
    for name, r in results.items():
        nyu = r.metrics.get("nyu", {})
        train = train_metrics.get(name, {})
        out[name] = {
            "nyu_a1": nyu.get("a1"), "nyu_abs_rel": nyu.get("abs_rel"),
            "nyu_a1_std": _sample_std(r.values("nyu", "a1")),
            "nyu_abs_rel_std": _sample_std(r.values("nyu", "abs_rel")), "n_seeds": r.n_seeds,
            "untrained_a1": train.get("val_untrained", {}).get("a1"),
            "untrained_abs_rel": train.get("val_untrained", {}).get("abs_rel"),
            "constant_depth_a1": train.get("val_constant_depth", {}).get("a1"),
            "constant_depth_abs_rel": train.get("val_constant_depth", {}).get("abs_rel"),
        }  # fmt: skip
    return out


def _sample_std(values: list[float] | None) -> float | None:
    """Sample standard deviation (ddof 1, as the tables' ``mean ± std``); None for fewer than two values."""
    return float(np.std(values, ddof=1)) if values is not None and len(values) > 1 else None


def read_history(path: str | os.PathLike) -> dict[str, list[float]]:
    """A history.csv → ``{column: values}`` (blank cells become NaN); {} when the file does not exist."""
    p = Path(path)
    if not p.is_file():
        return {}
    with p.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    if not rows:
        return {}
    out: dict[str, list[float]] = {}
    for col in rows[0]:
        vals = []
        for r in rows:
            try:
                vals.append(float(r[col]) if r[col] not in ("", None) else math.nan)
            except ValueError:
                vals.append(math.nan)
        out[col] = vals
    return out
