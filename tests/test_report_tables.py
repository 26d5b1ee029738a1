"""Tests for f2depth.report.tables: Markdown, CSV round trip, LaTeX structure, seeds and quoted rows."""

from __future__ import annotations

import csv
import io
import math
import re

import numpy as np
import pytest

from f2depth.report import published
from f2depth.report import tables as T

COLUMNS = [T.Column("method", "Method"), T.Column("pp", "PP"), *T.metric_columns(("abs_rel", "rmse", "a1"))]
ROWS = [
    {"method": "P²Net", "pp": False, "abs_rel": 0.159, "rmse": 0.599, "a1": 0.772, "quoted": True},
    T.RULE,
    {"method": "ours_full", "pp": True, "abs_rel": [0.1581, 0.1602, 0.1553], "rmse": 0.5831234567891,
     "a1": np.float64(0.78)},
    {"method": "a|b & c", "pp": False, "abs_rel": None, "rmse": float("nan"), "a1": 0.5},
]  # fmt: skip


def unescaped_ampersands(line: str) -> int:
    return len(re.findall(r"(?<!\\)&", line))


def test_csv_round_trip():
    text = T.to_csv(ROWS, COLUMNS)
    rows = list(csv.DictReader(io.StringIO(text)))
    assert len(rows) == 3  # the rule is not a row
    assert list(rows[0]) == ["method", "pp", "abs_rel", "abs_rel_std", "abs_rel_n", "rmse", "a1", "quoted"]
    assert float(rows[0]["abs_rel"]) == 0.159 and rows[0]["quoted"] == "true"
    assert rows[0]["abs_rel_n"] == "1" and rows[0]["abs_rel_std"] == ""
    seeds = [0.1581, 0.1602, 0.1553]
    assert float(rows[1]["abs_rel"]) == float(np.mean(seeds))
    assert float(rows[1]["abs_rel_std"]) == float(np.std(seeds, ddof=1))
    assert rows[1]["abs_rel_n"] == "3"
    assert float(rows[1]["rmse"]) == 0.5831234567891  # exact, not rounded to 3 decimals
    assert float(rows[1]["a1"]) == 0.78 and rows[1]["pp"] == "true" and rows[1]["quoted"] == "false"
    assert rows[2]["method"] == "a|b & c" and rows[2]["abs_rel"] == "" and rows[2]["rmse"] == ""


def test_markdown_layout_marker_and_seeds():
    md = T.to_markdown(ROWS, COLUMNS, title="Table 1")
    lines = md.splitlines()
    table = [ln for ln in lines if ln.startswith("|")]
    assert len(table) == 2 + 3
    assert table[0] == "| Method | PP | AbsRel↓ | RMS↓ | δ<1.25↑ |"
    assert table[1] == "|:---|---:|---:|---:|---:|"
    assert "P²Net †" in table[2] and "0.159" in table[2] and "×" in table[2]
    mean, std = np.mean([0.1581, 0.1602, 0.1553]), np.std([0.1581, 0.1602, 0.1553], ddof=1)
    assert f"{mean:.3f} ± {std:.3f}" in table[3] and "0.583" in table[3] and "✓" in table[3]
    assert r"a\|b & c" in table[4] and "| - | - |" in table[4]
    assert all(ln.count("|") - ln.count(r"\|") == len(COLUMNS) + 1 for ln in table)
    assert any("† quoted from the paper" in ln for ln in lines)
    assert any("n = 3 seeds" in ln for ln in lines)


def test_latex_structure():
    tex = T.to_latex(ROWS, COLUMNS)
    lines = tex.strip().splitlines()
    assert lines[0] == r"\begin{tabular}{lrrrr}" and lines[-1] == r"\end{tabular}"
    assert lines[1] == r"\toprule" and lines[-2] == r"\bottomrule"
    assert tex.count(r"\midrule") == 2  # under the header and the RULE row
    rows = [ln for ln in lines if ln.endswith(r"\\")]
    assert len(rows) == 1 + 3
    assert all(unescaped_ampersands(ln) == len(COLUMNS) - 1 for ln in rows)
    assert r"P\textsuperscript{2}Net$^\dagger$" in rows[1]
    assert r"$\pm$" in rows[2] and r"a|b \& c" in rows[3] and r"ours\_full" in rows[2]
    assert r"AbsRel$\downarrow$" in rows[0] and r"$\delta<$1.25$\uparrow$" in rows[0]
    assert tex.count("{") == tex.count("}")


def test_latex_table_environment_with_caption_and_notes():
    tex = T.to_latex(ROWS, COLUMNS, caption="NYU, 654 images", label="tab:nyu")
    assert tex.startswith(r"\begin{table}") and tex.rstrip().endswith(r"\end{table}")
    assert r"\caption{NYU, 654 images}" in tex and r"\label{tab:nyu}" in tex
    assert tex.index(r"\end{tabular}") < tex.index("quoted from the paper") < tex.index(r"\end{table}")
    assert tex.count(r"\begin{") == tex.count(r"\end{")


def test_format_value_rules():
    assert T.format_value(0.15349) == "0.153"
    assert T.format_value(0.15349, digits=4) == "0.1535"
    assert T.format_value(17000) == "17000"
    assert T.format_value(None) == "-" and T.format_value(float("nan")) == "-"
    assert T.format_value([0.2]) == "0.200"  # one seed: no ±
    assert T.format_value([0.1, 0.3]) == f"0.200 ± {math.sqrt(0.02):.3f}"
    assert T.format_value(True) == "✓" and T.format_value(False, latex=True) == r"$\times$"


def test_log_lines_and_cells_share_one_number_format():
    from f2depth.numbers import format_number

    for value in (0.15349, 17000, np.int64(7), np.float32(0.5), None, float("nan")):
        assert format_number(value) == T.format_value(value)
    assert format_number(0.15349, 2) == "0.15"
    mean, std, n = T.seed_stats([1.0, 2.0, 3.0])
    assert (mean, std, n) == (2.0, 1.0, 3)


def test_published_rows_render(tmp_path):
    rows = published.table1()[-4:]
    cols = [T.Column("method", "Method"), T.Column("post_process", "PP"), *T.metric_columns(
        ("abs_rel", "rmse", "log10", "a1", "a2", "a3"))]  # fmt: skip
    T.write_table(tmp_path / "table1", rows, cols, title="Table 1", caption="NYU", label="tab:t1")
    back = list(csv.DictReader((tmp_path / "table1.csv").open()))
    assert [float(r["rmse"]) for r in back] == [0.599, 0.583, 0.592, 0.569]
    assert all(r["quoted"] == "true" for r in back)
    assert (tmp_path / "table1.md").read_text().count("†") == 5  # 4 rows + the note
    assert (tmp_path / "table1.tex").read_text().count(r"\\") >= 5


@pytest.mark.parametrize("bad", [[], [T.RULE]])
def test_empty_tables(bad):
    assert T.to_csv(bad, COLUMNS).splitlines() == ["method,pp,abs_rel,rmse,a1"]
    assert T.to_latex(bad, COLUMNS).count(r"\\") == 1
