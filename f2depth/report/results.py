"""Reading what the evaluate, flow_finetune and train_depth stages wrote, for tables and figures.

- ``metrics/evaluate/<variant>.json`` (``f2depth.eval.suite.metrics_document``): headline groups
  averaged over seeds, and ``per_seed``;
- ``reports/eval/<variant>/details.json``: per seed, per-scene rows of 7-Scenes and Campus, counts;
- ``reports/eval/<variant>/figures.npz``: the first seed's predictions on a few test images;
- ``metrics/flow_finetune/<loss>.json``: EPE of the pretrained and fine-tuned flow on held-out pairs;
- ``metrics/train_depth/<variant>/{history,validation}.csv`` (every epoch; the measured epochs) and
  ``metrics/flow_finetune/<loss>/history.csv``;
- ``reports/eval/<variant>/<set>.csv``: per-image metrics of every seed, for the bootstrap intervals
  (:func:`headline_intervals`, ``f2depth.report.intervals``).
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

from f2depth.io import json_values
from f2depth.protocols import registry
from f2depth.protocols.metrics import METRIC_NAMES
from f2depth.report.intervals import Interval, Intervals, Pair, load_set, point, summarize

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
#: The metrics of the headline, each with its interval and its gaps.
HEADLINE_METRICS = ("a1", "abs_rel")
#: What one bootstrap resample draws of a test set (``f2depth.report.intervals``): the per-image CSV columns
#: naming the unit, each with all its images (a set not listed: every image on its own). 7-Scenes: a test
#: sequence, whose consecutive frames are not independent test images.
RESAMPLING_UNITS = {"nyu": ("index",), "sevenscenes": ("scene", "seq"), "campus": ("scene", "image")}


def headline_intervals(results: dict[str, VariantResults], eval_dir: str | os.PathLike, gaps: list[Pair],
                       resamples: int, confidence: float, seed: int) -> Intervals:
    """Bootstrap intervals (``f2depth.report.intervals``) of every headline set the variants were evaluated
    on, from ``eval_dir/<variant>/<set>.csv``: NYU with every metric (Tables 5, 6 and the overview show them),
    the other sets with :data:`HEADLINE_METRICS`; ``gaps``: (a, b) pairs, a − b. A CSV whose seeds or point
    estimates are not those of the variant's metrics file (another evaluate run) → ValueError naming it."""
    sets = {}
    for group in HEADLINE_SETS:
        names = [v for v, r in results.items() if r.metrics.get(group)]
        if not names:
            continue
        files = {v: Path(eval_dir) / v / f"{group}.csv" for v in names}
        for v, f in files.items():
            if not f.is_file():
                raise FileNotFoundError(f"{f}: not found; run `dvc repro evaluate@{v}`")
        protocol = registry.protocol(group)
        scores = load_set(group, files, protocol.columns, RESAMPLING_UNITS.get(group, protocol.columns),
                          protocol.headline == "scenes", METRIC_NAMES if group == "nyu" else HEADLINE_METRICS)
        for v, estimates in point(scores).items():
            fix = f"the evaluate runs differ; run `dvc repro evaluate@{v}`"
            if sorted(results[v].seed_keys) != sorted(f"seed{s}" for s in scores.seeds):
                raise ValueError(f"{files[v]}: seeds {list(scores.seeds)}, but {v}.json has "
                                 f"{results[v].seed_keys}; {fix}")
            for m, value in estimates.items():
                stored = results[v].metrics[group].get(m)
                if stored is not None and not math.isclose(value, stored, rel_tol=1e-9, abs_tol=1e-12):
                    raise ValueError(f"{files[v]}: mean {m} {value!r}, but {v}.json has {group}.{m} "
                                     f"{stored!r}; {fix}")
        sets[group] = summarize(scores, gaps, resamples, confidence, seed)
    return Intervals(tuple(gaps), confidence, resamples, sets)


def _interval(intervals: Intervals | None, group: str, variant: str | Pair, metric: str) -> Interval | None:
    found = intervals.sets.get(group) if intervals is not None else None
    if found is None:
        return None
    return (found.gaps if isinstance(variant, tuple) else found.variants).get(variant, {}).get(metric)


def floors(results: dict[str, VariantResults], train_metrics: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """δ1 and AbsRel of the untrained network and of a constant depth on the NYU test images, from the first
    variant's training run (``train_metrics``: variant → ``metrics/train_depth/<variant>.json``; the untrained
    network is the same for every variant of a seed); None where it did not record them."""
    first = train_metrics.get(next(iter(results), ""), {})
    return {floor: {"nyu_a1": (first.get(f"val_{floor}") or {}).get("a1"),
                    "nyu_abs_rel": (first.get(f"val_{floor}") or {}).get("abs_rel")}
            for floor in ("untrained", "constant_depth")}


def headline(results: dict[str, VariantResults], train_metrics: dict[str, dict[str, Any]],
             teacher: dict[str, Any], intervals: Intervals | None = None) -> dict[str, Any]:
    """The declared DVC metrics (``metrics/tables.json``): the ablation table ``dvc exp show`` compares.

    One record per variant, under its name (short column names for ``dvc exp show``: ``full.nyu_a1``): δ1 and
    AbsRel on the NYU test split, 7-Scenes and Campus (mean over seeds), ``n_seeds``, then each one's interval
    (``nyu_a1_lo``, ``nyu_a1_hi``, … from ``intervals``, :func:`headline_intervals`); ``floors``: the
    untrained network and a constant depth on the NYU test images (:func:`floors`); ``teacher``: the flow
    networks' EPE and swap consistency (:func:`teacher_summary`); ``gaps``: per gap ``<a>-<b>`` the paired
    difference a − b of the means (``nyu_a1``), its interval (``nyu_a1_lo``, ``nyu_a1_hi``) and
    ``nyu_a1_significant`` (1: the interval excludes 0, else 0; null without an interval), the same for
    AbsRel and every set; ``confidence``: the intervals' level. Numbers only (DVC metrics); null where a set
    was not evaluated or without ``intervals``. Everything else (histories, timings, diagnostics) stays in the
    stages' own files, which are not DVC metrics."""
    variants: dict[str, Any] = {}
    for name, r in results.items():
        row: dict[str, Any] = {}
        for group, label in HEADLINE_SETS.items():
            scores = r.metrics.get(group) or {}
            row[f"{label}_a1"], row[f"{label}_abs_rel"] = scores.get("a1"), scores.get("abs_rel")
        row["n_seeds"] = r.n_seeds
        for group, label in HEADLINE_SETS.items():
            for m in HEADLINE_METRICS:
                iv = _interval(intervals, group, name, m)
                row[f"{label}_{m}_lo"] = json_values(iv.lo) if iv else None
                row[f"{label}_{m}_hi"] = json_values(iv.hi) if iv else None
        variants[name] = row
    gaps: dict[str, Any] = {}
    for pair in intervals.gaps if intervals is not None else ():
        record: dict[str, Any] = {}
        for group, label in HEADLINE_SETS.items():
            for m in HEADLINE_METRICS:
                iv = _interval(intervals, group, pair, m)
                record[f"{label}_{m}"] = json_values(iv.estimate) if iv else None
                record[f"{label}_{m}_lo"] = json_values(iv.lo) if iv else None
                record[f"{label}_{m}_hi"] = json_values(iv.hi) if iv else None
                known = iv is not None and math.isfinite(iv.lo) and math.isfinite(iv.hi)
                record[f"{label}_{m}_significant"] = int(iv.significant) if known else None
        gaps["-".join(pair)] = record
    clash = set(variants) & {"floors", "teacher", "gaps", "confidence"}
    if clash:
        raise ValueError(f"variants {sorted(clash)}: the headline's own sections have these names; "
                         "rename the variants")
    return {**variants, "floors": floors(results, train_metrics), "teacher": teacher, "gaps": gaps,
            "confidence": intervals.confidence if intervals is not None else None}


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
