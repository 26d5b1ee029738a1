"""Reading what the evaluate, flow_finetune and train_depth stages wrote, for tables and figures.

- ``metrics/evaluate/<variant>.json`` (``f2depth.eval.suite.metrics_document``): headline groups
  averaged over seeds, and ``per_seed``;
- ``reports/eval/<variant>/details.json``: per seed, per-scene rows of 7-Scenes and Campus, counts;
- ``reports/eval/<variant>/figures.npz``: the first seed's predictions on a few test images;
- ``metrics/flow_finetune/<loss>.json``: EPE of the pretrained and fine-tuned flow on held-out pairs;
- ``metrics/train_depth/<variant>/{history,validation}.csv`` (every epoch; the measured epochs) and
  ``metrics/flow_finetune/<loss>/history.csv``.
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


#: The test sets of the headline, by their evaluate group and the name their columns carry.
HEADLINE_SETS = {"nyu": "nyu", "sevenscenes": "7scenes", "campus": "campus"}


def headline(results: dict[str, VariantResults], train_metrics: dict[str, dict[str, Any]],
             teacher: dict[str, Any]) -> dict[str, Any]:
    """The declared DVC metrics (``metrics/tables.json``): the ablation table ``dvc exp show`` compares.

    One record per variant, under its name (short column names for ``dvc exp show``: ``full.nyu_a1``): δ1 and
    AbsRel on the NYU test split, 7-Scenes and Campus (mean over seeds) and ``n_seeds``; ``floors``: the
    untrained network and a constant depth on the NYU test images (from the first variant's training run,
    ``train_metrics``: variant → ``metrics/train_depth/<variant>.json``; the untrained network is the same for
    every variant of a seed); ``teacher``: the flow networks' EPE and swap consistency
    (:func:`teacher_summary`). Everything else (histories, timings, diagnostics) stays in the stages' own
    files, which are not DVC metrics."""
    variants: dict[str, Any] = {}
    for name, r in results.items():
        row: dict[str, Any] = {}
        for group, label in HEADLINE_SETS.items():
            scores = r.metrics.get(group) or {}
            row[f"{label}_a1"], row[f"{label}_abs_rel"] = scores.get("a1"), scores.get("abs_rel")
        variants[name] = {**row, "n_seeds": r.n_seeds}
    first = train_metrics.get(next(iter(results), ""), {})
    floors = {floor: {"nyu_a1": (first.get(f"val_{floor}") or {}).get("a1"),
                      "nyu_abs_rel": (first.get(f"val_{floor}") or {}).get("abs_rel")}
              for floor in ("untrained", "constant_depth")}
    clash = set(variants) & {"floors", "teacher"}
    if clash:
        raise ValueError(f"variants {sorted(clash)}: the headline's own sections have these names; "
                         "rename the variants")
    return {**variants, "floors": floors, "teacher": teacher}


def teacher_summary(pretrain: dict[str, Any], finetune: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The flow teachers' EPE (px, all pixels) and swap consistency: the pretrained one on the prepared
    training pairs with ground truth (``metrics/flow_pretrain.json`` ``prepared``) beside zero flow, and
    every teacher on the held-out scene's pairs (``finetune``: loss → ``metrics/flow_finetune/<loss>.json``)
    beside zero flow. None where a run did not score it."""
    prepared = pretrain.get("prepared") or {}
    out: dict[str, Any] = {
        "prepared_epe": (prepared.get("model") or {}).get("epe_all"),
        "prepared_swap": (prepared.get("model") or {}).get("swap_consistency"),
        "prepared_zero_flow_epe": (prepared.get("zero_flow") or {}).get("epe_all"),
    }
    first = next(iter(finetune.values()), {})
    heldout = {"pretrained": (first.get("pretrained") or {}).get("test") or {}}
    heldout |= {loss: (m.get("finetuned") or {}).get("test") or {} for loss, m in finetune.items()}
    out["heldout_epe"] = {name: test.get("epe_all") for name, test in heldout.items()}
    out["heldout_swap"] = {name: test.get("swap_consistency") for name, test in heldout.items()}
    out["heldout_zero_flow_epe"] = ((first.get("zero_flow") or {}).get("test") or {}).get("epe_all")
    return out


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
