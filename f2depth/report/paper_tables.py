"""The paper's tables with our numbers beside the published ones.

Each builder returns a :class:`Table` (rows and columns for ``f2depth.report.tables.write_table``). Our
cells are per-seed lists (rendered ``mean ± std``, with the seed count in the ``n`` column); given the
bootstrap intervals (``f2depth.report.intervals``), the cells without PP of Tables 5, 6 and the overview
show the mean with its interval instead (``mean [lo, hi]``), and :func:`gap_table` lists every ablation gap
as a paired difference (:func:`claims`: the ones whose interval excludes 0, as sentences). The paper's rows
(``f2depth.report.published``) carry ``quoted: True`` and get the † marker. Tables 1, 5 and 6 are NYU's; the
other test sets of ``f2depth.protocols.registry`` bring their per-scene table (``f2depth.report.layouts``) and
their columns of the variants overview.

Variant roles: ``full`` = F²Depth, ``baseline`` = our P²Net (no flow losses), ``no_feature`` = + L_rigid
only, ``flow_pretrained`` / ``flow_full_ft`` = flow network not fine-tuned / fine-tuned on all pixels.
A builder leaves out the rows of variants that were not evaluated.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from f2depth.io import write_text
from f2depth.numbers import format_number
from f2depth.protocols import registry
from f2depth.protocols.metrics import METRIC_NAMES
from f2depth.protocols.protocol import Protocol
from f2depth.report import published
from f2depth.report.intervals import Interval, Intervals, SetIntervals
from f2depth.report.layouts import layout
from f2depth.report.results import HEADLINE_METRICS, HEADLINE_SETS, VariantResults
from f2depth.report.tables import RULE, Column, MeanInterval, metric_columns, to_markdown, write_table

PAPER_NYU = ("abs_rel", "rmse", "log10", "a1", "a2", "a3")
OURS, P2NET = "full", "baseline"
N_COLUMN = Column("n", "n", align="r")


@dataclass
class Table:
    stem: str
    rows: list[dict[str, Any]]
    columns: list[Column]
    title: str
    caption: str
    label: str
    notes: list[str] = field(default_factory=list)

    def markdown(self) -> str:
        text = to_markdown(self.rows, self.columns, title=self.title)
        return text + ("".join(f"\n{n}  " for n in self.notes) + "\n" if self.notes else "")

    def write(self, out_dir: str | Path) -> list[Path]:
        stem = Path(out_dir) / self.stem
        write_table(stem, self.rows, self.columns, title=self.title, caption=self.caption, label=self.label)
        if self.notes:  # write_table's Markdown has the quoted/seed notes; add ours
            write_text(stem.with_suffix(".md"), self.markdown())
        return [stem.with_suffix(s) for s in (".md", ".csv", ".tex")]


def _cell(r: VariantResults, group: str, metric: str, intervals: Intervals | None) -> Any:
    """Per-seed values of ``group.metric``, as a :class:`MeanInterval` where ``intervals`` has its interval
    (the groups without PP)."""
    values = r.values(group, metric)
    found = intervals.sets.get(group) if intervals is not None and values is not None else None
    iv = found.variants.get(r.name, {}).get(metric) if found is not None else None
    return values if iv is None else MeanInterval(tuple(values), iv.lo, iv.hi, intervals.confidence)


def _ours(r: VariantResults, group: str, names: Sequence[str], intervals: Intervals | None = None
          ) -> dict[str, Any]:
    return {m: _cell(r, group, m, intervals) for m in names} | {"n": r.n_seeds}


def table1(results: Mapping[str, VariantResults]) -> Table:
    """NYU Depth V2 (tab:tab1): every published row, then ours (full and baseline, ± PP)."""
    rows: list[dict[str, Any]] = [
        {k: v for k, v in row.items() if k != "transformer"} for row in published.table1()
    ]
    rows.append(RULE)
    for name, label in ((P2NET, "P²Net (ours: baseline)"), (OURS, "F²Depth (ours: full)")):
        if name not in results:
            continue
        for pp in (False, True):
            rows.append({"method": label, "supervised": False, "post_process": pp,
                         **_ours(results[name], "nyu_pp" if pp else "nyu", PAPER_NYU)})
    cols = [Column("method", "Method"), Column("supervised", "Supervised", align="c"),
            Column("post_process", "PP", align="c"), *metric_columns(PAPER_NYU), N_COLUMN]
    return Table("table1_nyu", rows, cols, "Table 1: NYU Depth V2 test set",
                 "Depth on the NYU Depth V2 test split, per-image median scaling (PP: flip post-processing)",
                 "tab:nyu")


TABLE5_VARIANTS = ("baseline", "no_feature", "full")


def loss_marks(r: VariantResults) -> tuple[bool | None, bool | None]:
    """(L_rigid on, L_feature on) from the loss weights the variant's model was trained with, as the
    evaluate stage recorded them (``trained_with.weights``, term → weight); None where the metrics do not
    say."""
    weights = (r.metrics.get("trained_with") or {}).get("weights") or {}

    def on(term: str) -> bool | None:
        return None if weights.get(term) is None else float(weights[term]) != 0.0

    return on("rigid"), on("feature")


def table5(results: Mapping[str, VariantResults], intervals: Intervals | None = None) -> Table:
    """Losses on/off (tab:tab5): baseline, + L_rigid (no_feature), + L_feature (full), × PP. The ✓/×
    marks are the weights each run was trained with (so ``dvc exp run -S lambda3=0`` shows
    L_feature × for ``full``), not the variants' intended roles."""
    rows: list[dict[str, Any]] = []
    paper = published.table5()
    for pp in (False, True):
        if rows:
            rows.append(RULE)
        for name in TABLE5_VARIANTS:
            if name in results:
                rigid, feature = loss_marks(results[name])
                rows.append({"variant": name, "rigid": rigid, "feature": feature, "post_process": pp,
                             **_ours(results[name], "nyu_pp" if pp else "nyu", PAPER_NYU, intervals)})
        rows.extend(r for r in paper if r["post_process"] == pp)
    cols = [Column("variant", "Variant"), Column("rigid", "L_rigid", align="c"),
            Column("feature", "L_feature", align="c"), Column("post_process", "PP", align="c"),
            *metric_columns(PAPER_NYU), N_COLUMN]
    return Table("table5_losses", rows, cols, "Table 5: loss ablation on NYU Depth V2",
                 "Ablation of the optical-flow consistency (L_rigid) and feature-map synthesis (L_feature) "
                 "losses on NYU Depth V2", "tab:losses")


EPE = Mapping[str, Mapping[str, float | None] | None]
"""variant → EPE of its flow network (``f2depth.report.results.flow_epe``), None without one."""


def table6(results: Mapping[str, VariantResults], epe: EPE, intervals: Intervals | None = None) -> Table:
    """Flow weights (tab:tab6, no PP): which frozen flow network supervises depth; with that network's
    EPE on the held-out synthetic pairs (all pixels and low-texture pixels)."""
    labels = {row["variant"]: row["weights"] for row in published.table6()}
    rows: list[dict[str, Any]] = []
    for name, label in labels.items():
        if name in results:
            e = epe.get(name) or {}
            rows.append({"weights": label, "variant": name,
                         **_ours(results[name], "nyu", PAPER_NYU, intervals),
                         "epe_all": e.get("epe_all"), "epe_low_texture": e.get("epe_low_texture")})
    rows.append(RULE)
    rows.extend({**r, "n": None} for r in published.table6())
    cols = [Column("weights", "Flow network"), Column("variant", "Variant"), *metric_columns(PAPER_NYU),
            Column("epe_all", "EPE all↓", 2), Column("epe_low_texture", "EPE low-tex.↓", 2), N_COLUMN]
    notes = ["EPE: end-point error (px) of the frozen flow network on the held-out synthetic pairs of the "
             "prepared set (flow_finetune's test pairs); the paper had no flow ground truth on NYU."]
    return Table("table6_flow", rows, cols, "Table 6: flow network weights (NYU Depth V2, no PP)",
                 "Depth trained with different frozen flow networks, and their flow end-point error",
                 "tab:flow", notes)


def _pair_columns(names: Sequence[str], first: str, second: str, count: str) -> list[Column]:
    heads = {c.key: c.header for c in metric_columns(names)}
    return ([Column("scene", "Scene"), Column(count, count.capitalize())]
            + [Column(f"a_{m}", f"{first} {heads[m]}") for m in names]
            + [Column(f"b_{m}", f"{second} {heads[m]}") for m in names] + [N_COLUMN])


def scene_table(results: Mapping[str, VariantResults], protocol: Protocol) -> Table | None:
    """A test set's per-scene table (its layout's ``table``; the paper's 7-Scenes table, Campus Tables 3
    and 4): ours (full) beside our P²Net (baseline) per scene, the summary rows, then the paper's rows."""
    spec, a, b = layout(protocol.name).table, results.get(OURS), results.get(P2NET)
    if spec is None or a is None or not a.scenes(spec.group):
        return None
    count, group = protocol.scene_rows.count, spec.group

    def pair(values) -> dict[str, Any]:
        out = {f"a_{m}": values(a, m) for m in spec.metrics}
        out |= {f"b_{m}": values(b, m) if b is not None else None for m in spec.metrics}
        return out | {"n": a.n_seeds}

    rows: list[dict[str, Any]] = [
        {"scene": spec.scene_titles.get(scene, scene), count: a.scene_count(group, scene),
         **pair(lambda r, m, s=scene: r.scene_values(group, s, m))} for scene in a.scenes(group)]  # fmt: skip
    total = sum(a.scene_count(group, s) or 0 for s in a.scenes(group))
    summaries = {"headline": lambda r, m: r.values(group, m),
                 "scene_mean": lambda r, m: r.scene_mean_values(group, m)}
    rows += [{"scene": label, count: total, **pair(summaries[kind])} for label, kind in spec.summaries]
    rows.append(RULE)
    rows += [{"scene": label, count: n, **{f"a_{m}": ra[m] for m in spec.metrics},
              **{f"b_{m}": rb[m] for m in spec.metrics}, "n": None, "quoted": True}
             for label, n, ra, rb in spec.published()]  # fmt: skip
    return Table(spec.stem, rows, _pair_columns(spec.metrics, "F²Depth", "P²Net", count), spec.title,
                 spec.caption, spec.label, list(spec.notes))


def inference_table(results: Mapping[str, VariantResults]) -> Table:
    """Inference time per image (batch 1) without and with PP, beside the paper's RTX 3090 numbers."""
    rows: list[dict[str, Any]] = []
    for name, r in results.items():
        t = r.timing("ms")
        where = f"{t.get('device', '?')}, {t.get('threads', '?')} threads" if t else None
        size = f"{t['height']}×{t['width']}" if t else None
        rows.append({"variant": name, "device": where, "size": size, "ms": r.values("ms"),
                     "ms_pp": r.values("ms_pp"), "n": r.n_seeds})
    p = published.inference_ms()
    rows.append({"variant": "F²Depth", "device": p["device"], "size": f"{p['height']}×{p['width']}",
                 "ms": p["no_pp"], "ms_pp": p["pp"], "n": None, "quoted": True})
    cols = [Column("variant", "Model"), Column("device", "Device"), Column("size", "Input"),
            Column("ms", "ms / image", 1), Column("ms_pp", "ms / image (PP)", 1), N_COLUMN]
    return Table("inference_time", rows, cols, "Inference time (batch 1, median after warm-up)",
                 "Inference time per image", "tab:time")


NUMBERS = ("no", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine")


def overview_table(results: Mapping[str, VariantResults], intervals: Intervals | None = None) -> Table:
    """Every variant: all eight NYU metrics ± PP, and δ1 / AbsRel on every other registered test set."""
    others = [p for p in registry.protocols() if p.name != "nyu"]
    rows: list[dict[str, Any]] = []
    for name, r in results.items():
        for pp in (False, True):
            s = "_pp" if pp else ""
            rows.append({"variant": name, "post_process": pp, **_ours(r, f"nyu{s}", METRIC_NAMES, intervals),
                         **{f"{layout(p.name).column}_{m}": _cell(r, f"{p.name}{s}", m, intervals)
                            for p in others for m in ("abs_rel", "a1")}})  # fmt: skip
    cols = [Column("variant", "Variant"), Column("post_process", "PP", align="c"), *metric_columns()]
    for p in others:
        column = layout(p.name).column
        cols += [Column(f"{column}_abs_rel", f"{p.title} AbsRel↓"),
                 Column(f"{column}_a1", f"{p.title} δ<1.25↑")]
    titles = [p.title for p in others]
    names = ", ".join(titles[:-1]) + f" and {titles[-1]}" if len(titles) > 1 else "".join(titles)
    return Table("variants_overview", rows, [*cols, N_COLUMN], f"All variants: NYU (8 metrics), {names}",
                 f"Every ablation variant on the {NUMBERS[len(others) + 1]} test sets", "tab:variants",
                 ["; ".join(f"{p.title}: {layout(p.name).note}" for p in others) + "."])


METRIC_TITLES = {"a1": "δ1", "abs_rel": "AbsRel"}


def mark(iv: Interval) -> str:
    """✓ significant (the interval excludes 0), tie (it does not) or no interval (nothing to resample)."""
    return "no interval" if math.isnan(iv.lo) else "✓ significant" if iv.significant else "tie"


def _gaps(intervals: Intervals) -> list[tuple[str, str, str, SetIntervals]]:
    """(a, b, test set title, its SetIntervals) of every gap (params order) and headline set that has it."""
    return [(a, b, registry.protocol(group).title, found) for a, b in intervals.gaps
            for group, found in ((g, intervals.sets.get(g)) for g in HEADLINE_SETS)
            if found is not None and (a, b) in found.gaps]  # fmt: skip


def _basis(intervals: Intervals) -> str:
    seeds = sorted({s.n_seeds for s in intervals.sets.values()})
    text = (f"paired differences a − b of the means over {', '.join(map(str, seeds))} seed(s) on the same "
            f"test images; [lo, hi]: the {100 * intervals.confidence:g} % percentile bootstrap interval "
            f"({intervals.resamples} resamples of the seeds and of the test images, the same draws for a and "
            "b; Campus: the images within each scene; 7-Scenes: whole test sequences, whose frames are not "
            "independent)")
    one = "; with one seed the intervals cover the test images only, not the spread between training runs"
    return text + (one if 1 in seeds else "")


def gap_table(intervals: Intervals, floors: Mapping[str, Mapping[str, float | None]] | None = None) -> Table:
    """The ablation gaps (``tables.gaps``): one row per gap and test set, the paired difference of δ1 and of
    AbsRel with its interval and mark (✓ significant: the interval excludes 0; tie: it does not), the seeds,
    test images and resampling units; ``floors`` (``f2depth.report.results.floors``) go into the note."""
    rows: list[dict[str, Any]] = []
    for a, b, title, found in _gaps(intervals):
        row: dict[str, Any] = {"gap": f"{a} − {b}", "set": title}
        for m, iv in found.gaps[(a, b)].items():
            if m in HEADLINE_METRICS:
                row |= {m: iv, f"{m}_mark": mark(iv)}
        rows.append(row | {"seeds": found.n_seeds, "images": found.n_images, "units": found.n_units})
    cols = [Column("gap", "Gap (a − b)"), Column("set", "Test set")]
    for m in HEADLINE_METRICS:
        cols += [Column(m, f"Δ {METRIC_TITLES[m]}"), Column(f"{m}_mark", METRIC_TITLES[m], align="l")]
    cols += [Column("seeds", "Seeds"), Column("images", "Images"), Column("units", "Units")]
    notes = [f"Δ: {_basis(intervals)}.",
             "✓ significant: the interval excludes 0; tie: it does not (no claim either way; no interval: "
             "one seed and one image or sequence per stratum, nothing to resample). δ1 (δ<1.25): "
             "higher is better, Δ > 0 favours a; AbsRel: lower is better, Δ < 0 favours a. Units: the "
             "images or sequences a resample draws from."]
    named = {"untrained": "untrained network", "constant_depth": "constant depth"}
    given = [f"{named.get(k, k)} δ1 {format_number(f['nyu_a1'])}, AbsRel "
             f"{format_number(f.get('nyu_abs_rel'))}" for k, f in (floors or {}).items()
             if f.get("nyu_a1") is not None]
    if given:
        notes.append(f"Floors on NYU (train_depth's validation images): {'; '.join(given)}.")
    return Table("ablation_gaps", rows, cols, "Ablation gaps: paired differences with intervals",
                 "Ablation gaps as paired differences a − b (same seeds, same test images) with bootstrap "
                 "intervals", "tab:gaps", notes)


def _sentences(intervals: Intervals, significant: bool) -> list[str]:
    out = []
    for a, b, title, found in _gaps(intervals):
        for m in HEADLINE_METRICS:
            iv = found.gaps[(a, b)].get(m)
            if iv is None or iv.significant != significant:
                continue
            numbers = f"{iv.estimate:+.3f} [{format_number(iv.lo)}, {format_number(iv.hi)}]"
            if not significant:
                out.append(f"`{a}` vs `{b}` on {title} {METRIC_TITLES[m]} ({numbers})")
                continue
            better = a if (iv.estimate > 0) == (m == "a1") else b
            out.append(f"`{a}` {'>' if iv.estimate > 0 else '<'} `{b}` on {title} {METRIC_TITLES[m]} "
                       f"({numbers}; `{better}` better)")
    return out


def claims(intervals: Intervals) -> list[str]:
    """The gaps whose interval excludes 0, one short sentence each:
    "`no_feature` > `baseline` on NYU δ1 (+0.042 [0.020, 0.061]; `no_feature` better)"."""
    return _sentences(intervals, significant=True)


def claims_markdown(intervals: Intervals) -> str:
    """reports/tables/claims.md: what the ablation marks support (:func:`claims`), then the ties."""
    lines = ["# Ablation claims the intervals support", "",
             "Written by the `tables` stage (reports/tables/ablation_gaps.md has every gap): "
             f"{_basis(intervals)}. A claim is listed only where its interval excludes 0.", "",
             "## Significant", ""]
    lines += [f"- {c}" for c in claims(intervals)] or ["- none: no gap's interval excludes 0"]
    lines += ["", "## Ties (no claim either way)", ""]
    lines += [f"- {t}" for t in _sentences(intervals, significant=False)] or ["- none"]
    return "\n".join(lines) + "\n"


def build_tables(results: Mapping[str, VariantResults], epe: EPE, intervals: Intervals | None = None,
                 floors: Mapping[str, Mapping[str, float | None]] | None = None) -> list[Table]:
    """Every table the evaluated variants allow, in the order of the README; with ``intervals`` Tables 5, 6
    and the overview show them, and the ablation gaps table (:func:`gap_table`) comes last."""
    tables = [table1(results), table5(results, intervals), table6(results, epe, intervals),
              *(scene_table(results, p) for p in registry.protocols()), inference_table(results),
              overview_table(results, intervals), gap_table(intervals, floors) if intervals else None]
    return [t for t in tables if t is not None]
