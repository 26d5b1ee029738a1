"""Render result rows as Markdown, CSV and LaTeX (booktabs).

A table is a list of rows (dicts) and a list of :class:`Column` s. Cell values may be
- a number (floats get ``digits`` decimals; ints are printed as they are),
- a sequence of numbers, one per seed: shown as ``mean ± std`` (sample std, ddof=1; a single value is
  shown alone); the CSV keeps the mean in the column and adds ``<key>_std`` and ``<key>_n``,
- a :class:`MeanInterval` (per-seed values and the bootstrap interval of their mean): shown as
  ``mean [lo, hi]``; the CSV adds ``<key>_std``, ``<key>_n``, ``<key>_lo`` and ``<key>_hi``,
- an :class:`~f2depth.report.intervals.Interval` (a paired difference): shown signed, ``+0.042 [0.020,
  0.061]``; the CSV keeps the difference in the column and adds ``<key>_lo`` and ``<key>_hi``,
- a bool (✓ / ×), a string, or None / NaN (shown as ``-``).
A row with ``"quoted": True`` holds published numbers: its first cell gets a marker (†) and a note
under the table says so; the CSV has a ``quoted`` column instead. A row ``RULE`` draws a horizontal
rule in LaTeX (ignored in Markdown and CSV).

CSV numbers are written with ``repr`` so they parse back to exactly the same floats.
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from f2depth.io import write_text
from f2depth.numbers import format_number
from f2depth.protocols.metrics import METRIC_NAMES
from f2depth.report.intervals import Interval

QUOTED = "quoted"
RULE: dict[str, Any] = {"_rule": True}
MARKER = "†"

METRIC_HEADERS: dict[str, str] = {"abs_rel": "AbsRel↓", "sq_rel": "SqRel↓", "rmse": "RMS↓",
                                  "rmse_log": "RMSlog↓", "log10": "log10↓", "a1": "δ<1.25↑", "a2": "δ<1.25²↑",
                                  "a3": "δ<1.25³↑"}

_LATEX_SPECIAL = {
    "\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_", "{": r"\{",
    "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}",
    "²": r"\textsuperscript{2}", "³": r"\textsuperscript{3}", "↓": r"$\downarrow$", "↑": r"$\uparrow$",
    "±": r"$\pm$", "δ": r"$\delta$", "×": r"$\times$", "✓": r"\checkmark{}", "†": r"$^\dagger$",
    "<": r"$<$", ">": r"$>$", "−": r"$-$", "Δ": r"$\Delta$",
}  # fmt: skip


@dataclass(frozen=True)
class Column:
    """One column: the row key, its header (plain text; LaTeX-escaped unless ``latex`` is given),
    decimals for floats and the LaTeX alignment."""

    key: str
    header: str
    digits: int = 3
    latex: str | None = None
    align: str = "r"


@dataclass(frozen=True)
class MeanInterval:
    """A cell: per-seed ``values`` (S,) and the ``confidence`` bootstrap interval [``lo``, ``hi``] of their
    mean (``f2depth.report.intervals``)."""

    values: tuple[float, ...]
    lo: float
    hi: float
    confidence: float


def metric_columns(names: Sequence[str] = METRIC_NAMES, digits: int = 3) -> list[Column]:
    """Columns for the given metric names with the paper's headers (AbsRel↓ … δ<1.25³↑)."""
    return [Column(n, METRIC_HEADERS[n], digits) for n in names]


def latex_escape(text: str) -> str:
    """Escape LaTeX specials and map the few Unicode symbols used in headers (², ↓, δ, ±, …); adjacent
    math snippets are merged (``$\\delta$$<$`` → ``$\\delta<$``)."""
    return re.sub(r"(?<!\\)\$\$", "", "".join(_LATEX_SPECIAL.get(ch, ch) for ch in text))


def _is_seq(value: Any) -> bool:
    return isinstance(value, (list, tuple, np.ndarray))


def seed_stats(values: Sequence[float]) -> tuple[float, float, int]:
    """(mean, sample std with ddof=1 (NaN for one value), n) of per-seed values."""
    v = np.asarray(values, dtype=np.float64).ravel()
    if v.size == 0:
        return float("nan"), float("nan"), 0
    return float(v.mean()), float(v.std(ddof=1)) if v.size > 1 else float("nan"), int(v.size)


def format_value(value: Any, digits: int = 3, latex: bool = False) -> str:
    """One cell as text (see the module docstring for the rules)."""
    if value is None:
        return "-"
    if isinstance(value, (bool, np.bool_)):
        return latex_escape("✓" if value else "×") if latex else ("✓" if value else "×")
    if isinstance(value, (MeanInterval, Interval)):
        mean = seed_stats(value.values)[0] if isinstance(value, MeanInterval) else value.estimate
        text = (f"{mean:+.{digits}f}" if isinstance(value, Interval) and math.isfinite(mean)
                else format_number(mean, digits))
        return f"{text} [{format_number(value.lo, digits)}, {format_number(value.hi, digits)}]"
    if _is_seq(value):
        mean, std, n = seed_stats(value)
        if n == 0:
            return "-"
        if n == 1:
            return format_value(mean, digits, latex)
        pm = r" $\pm$ " if latex else " ± "
        return f"{mean:.{digits}f}{pm}{std:.{digits}f}"
    if isinstance(value, (int, float, np.integer, np.floating)):
        return format_number(value, digits)
    return latex_escape(str(value)) if latex else str(value)


def _body_rows(rows: Sequence[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    return [r for r in rows if not r.get("_rule")]


def _seed_counts(rows: Sequence[Mapping[str, Any]], columns: Sequence[Column]) -> list[int]:
    counts = {len(r[c.key]) for r in _body_rows(rows) for c in columns if _is_seq(r.get(c.key))}
    return sorted(counts - {0, 1})


def _interval_cells(rows: Sequence[Mapping[str, Any]], columns: Sequence[Column]) -> list[MeanInterval]:
    return [r[c.key] for r in _body_rows(rows) for c in columns if isinstance(r.get(c.key), MeanInterval)]


def _notes(rows: Sequence[Mapping[str, Any]], columns: Sequence[Column], quoted_note: str) -> list[str]:
    notes = []
    if any(r.get(QUOTED) for r in _body_rows(rows)):
        notes.append(f"{MARKER} {quoted_note}")
    counts = _seed_counts(rows, columns)
    if counts:
        notes.append(f"a ± b: mean ± sample std over n = {', '.join(map(str, counts))} seeds")
    cells = _interval_cells(rows, columns)
    if cells:
        seeds = ", ".join(map(str, sorted({len(c.values) for c in cells})))
        levels = ", ".join(f"{100 * c:g}" for c in sorted({c.confidence for c in cells}))
        notes.append(f"a [lo, hi]: mean over n = {seeds} seeds and its {levels} % bootstrap interval (seeds "
                     "and test images resampled; with one seed the test images only)")
    return notes


def to_markdown(rows: Sequence[Mapping[str, Any]], columns: Sequence[Column], *, title: str | None = None,
                quoted_note: str = "quoted from the paper, not reproduced") -> str:
    """A GitHub-flavoured Markdown table (first column left-aligned), with notes under it."""

    def cell(text: str) -> str:
        return text.replace("|", r"\|")

    lines = [f"**{title}**", ""] if title else []
    lines.append("| " + " | ".join(cell(c.header) for c in columns) + " |")
    lines.append("|" + "|".join(":---" if i == 0 else "---:" for i in range(len(columns))) + "|")
    for r in _body_rows(rows):
        cells = [format_value(r.get(c.key), c.digits) for c in columns]
        if r.get(QUOTED):
            cells[0] += f" {MARKER}"
        lines.append("| " + " | ".join(cell(x) for x in cells) + " |")
    notes = _notes(rows, columns, quoted_note)
    if notes:
        lines.append("")
        lines.extend(f"{n}  " for n in notes)
    return "\n".join(lines) + "\n"


def to_csv(rows: Sequence[Mapping[str, Any]], columns: Sequence[Column]) -> str:
    """CSV with one column per :class:`Column` key (mean for per-seed lists, plus ``_std``/``_n``; intervals
    add ``_lo``/``_hi``) and a ``quoted`` column when any row is quoted. Floats are written exactly
    (``repr``)."""
    body = _body_rows(rows)
    seeded = {c.key for c in columns if any(_is_seq(r.get(c.key)) or isinstance(r.get(c.key), MeanInterval)
                                            for r in body)}
    ranged = {c.key for c in columns if any(isinstance(r.get(c.key), (MeanInterval, Interval)) for r in body)}
    fields: list[str] = []
    for c in columns:
        fields.append(c.key)
        if c.key in seeded:
            fields += [f"{c.key}_std", f"{c.key}_n"]
        if c.key in ranged:
            fields += [f"{c.key}_lo", f"{c.key}_hi"]
    quoted = any(r.get(QUOTED) for r in body)
    if quoted:
        fields.append(QUOTED)

    def plain(v: Any) -> str:
        if v is None:
            return ""
        if isinstance(v, (bool, np.bool_)):
            return "true" if v else "false"
        if isinstance(v, (int, np.integer)):
            return str(int(v))
        if isinstance(v, (float, np.floating)):
            return "" if math.isnan(v) else repr(float(v))
        return str(v)

    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=fields, lineterminator="\n")
    writer.writeheader()
    for r in body:
        out: dict[str, str] = {}
        for c in columns:
            v = r.get(c.key)
            if c.key in ranged:
                lo, hi = (v.lo, v.hi) if isinstance(v, (MeanInterval, Interval)) else (None, None)
                out[f"{c.key}_lo"], out[f"{c.key}_hi"] = plain(lo), plain(hi)
                v = v.values if isinstance(v, MeanInterval) else v.estimate if isinstance(v, Interval) else v
            if c.key in seeded:
                mean, std, n = seed_stats(v) if _is_seq(v) else (v, float("nan"), 1 if v is not None else 0)
                out[c.key], out[f"{c.key}_std"], out[f"{c.key}_n"] = plain(mean), plain(std), str(n)
            else:
                out[c.key] = plain(v)
        if quoted:
            out[QUOTED] = plain(bool(r.get(QUOTED)))
        writer.writerow(out)
    return buf.getvalue()


def to_latex(rows: Sequence[Mapping[str, Any]], columns: Sequence[Column], *, caption: str | None = None,
             label: str | None = None, quoted_note: str = "quoted from the paper, not reproduced") -> str:
    """A booktabs ``tabular`` (wrapped in a ``table`` with caption, label and notes when a caption or
    label is given). Needs ``\\usepackage{booktabs}`` (and ``amssymb`` for ✓)."""
    spec = "".join("l" if i == 0 else c.align for i, c in enumerate(columns))
    lines = [rf"\begin{{tabular}}{{{spec}}}", r"\toprule"]
    lines.append(" & ".join(c.latex if c.latex is not None else latex_escape(c.header) for c in columns)
                 + r" \\")
    lines.append(r"\midrule")
    for r in rows:
        if r.get("_rule"):
            lines.append(r"\midrule")
            continue
        cells = [format_value(r.get(c.key), c.digits, latex=True) for c in columns]
        if r.get(QUOTED):
            cells[0] += latex_escape(MARKER)
        lines.append(" & ".join(cells) + r" \\")
    lines += [r"\bottomrule", r"\end{tabular}"]
    if caption is None and label is None:
        return "\n".join(lines) + "\n"
    head = [r"\begin{table}[t]", r"\centering"]
    if caption is not None:
        head.append(rf"\caption{{{latex_escape(caption)}}}")
    if label is not None:
        head.append(rf"\label{{{label}}}")
    notes = [latex_escape(n) for n in _notes(rows, columns, quoted_note)]
    tail = [r"\par\smallskip{\footnotesize " + r" \\ ".join(notes) + "}"] if notes else []
    return "\n".join(head + lines + tail + [r"\end{table}"]) + "\n"


def write_table(stem: str | os.PathLike, rows: Sequence[Mapping[str, Any]], columns: Sequence[Column], *,
                title: str | None = None, caption: str | None = None, label: str | None = None,
                quoted_note: str = "quoted from the paper, not reproduced") -> None:
    """Write ``<stem>.md``, ``<stem>.csv`` and ``<stem>.tex`` atomically."""
    stem = os.fspath(stem)
    write_text(f"{stem}.md", to_markdown(rows, columns, title=title, quoted_note=quoted_note))
    write_text(f"{stem}.csv", to_csv(rows, columns))
    write_text(f"{stem}.tex", to_latex(rows, columns, caption=caption, label=label, quoted_note=quoted_note))
