"""The paper's tables with our numbers beside the published ones.

Each builder returns a :class:`Table` (rows and columns for ``f2depth.report.tables.write_table``). Our
cells are per-seed lists (rendered ``mean ± std``, with the seed count in the ``n`` column); the
paper's rows (``f2depth.report.published``) carry ``quoted: True`` and get the † marker. Tables 1, 5 and 6
are NYU's; the other test sets of ``f2depth.eval.registry`` bring their per-scene table
(``f2depth.report.layouts``) and their columns of the variants overview.

Variant roles: ``full`` = F²Depth, ``baseline`` = our P²Net (no flow losses), ``no_feature`` = + L_rigid
only, ``flow_pretrained`` / ``flow_full_ft`` = flow network not fine-tuned / fine-tuned on all pixels.
A builder leaves out the rows of variants that were not evaluated.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from f2depth.eval import registry
from f2depth.eval.metrics import METRIC_NAMES
from f2depth.eval.protocol import Protocol
from f2depth.io import write_text
from f2depth.report import published
from f2depth.report.layouts import layout
from f2depth.report.results import VariantResults
from f2depth.report.tables import RULE, Column, metric_columns, to_markdown, write_table

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


def _ours(r: VariantResults, group: str, names: Sequence[str]) -> dict[str, Any]:
    return {m: r.values(group, m) for m in names} | {"n": r.n_seeds}


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


def table5(results: Mapping[str, VariantResults]) -> Table:
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
                             **_ours(results[name], "nyu_pp" if pp else "nyu", PAPER_NYU)})
        rows.extend(r for r in paper if r["post_process"] == pp)
    cols = [Column("variant", "Variant"), Column("rigid", "L_rigid", align="c"),
            Column("feature", "L_feature", align="c"), Column("post_process", "PP", align="c"),
            *metric_columns(PAPER_NYU), N_COLUMN]
    return Table("table5_losses", rows, cols, "Table 5: loss ablation on NYU Depth V2",
                 "Ablation of the optical-flow consistency (L_rigid) and feature-map synthesis (L_feature) "
                 "losses on NYU Depth V2", "tab:losses")


EPE = Mapping[str, Mapping[str, float | None] | None]
"""variant → EPE of its flow network (``f2depth.report.results.flow_epe``), None without one."""


def table6(results: Mapping[str, VariantResults], epe: EPE) -> Table:
    """Flow weights (tab:tab6, no PP): which frozen flow network supervises depth; with that network's
    EPE on the held-out synthetic pairs (all pixels and low-texture pixels)."""
    labels = {row["variant"]: row["weights"] for row in published.table6()}
    rows: list[dict[str, Any]] = []
    for name, label in labels.items():
        if name in results:
            e = epe.get(name) or {}
            rows.append({"weights": label, "variant": name, **_ours(results[name], "nyu", PAPER_NYU),
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


def overview_table(results: Mapping[str, VariantResults]) -> Table:
    """Every variant: all eight NYU metrics ± PP, and δ1 / AbsRel on every other registered test set."""
    others = [p for p in registry.protocols() if p.name != "nyu"]
    rows: list[dict[str, Any]] = []
    for name, r in results.items():
        for pp in (False, True):
            s = "_pp" if pp else ""
            rows.append({"variant": name, "post_process": pp, **_ours(r, f"nyu{s}", METRIC_NAMES),
                         **{f"{layout(p.name).column}_{m}": r.values(f"{p.name}{s}", m) for p in others
                            for m in ("abs_rel", "a1")}})  # fmt: skip
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


def build_tables(results: Mapping[str, VariantResults], epe: EPE) -> list[Table]:
    """Every table the evaluated variants allow, in the order of the README."""
    tables = [table1(results), table5(results), table6(results, epe),
              *(scene_table(results, p) for p in registry.protocols()), inference_table(results),
              overview_table(results)]
    return [t for t in tables if t is not None]
