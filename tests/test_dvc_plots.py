"""dvc.yaml's plots (issue 52 item 4): every file and column a plot reads is one a writer writes, every plot
colours by run, and `dvc plots show` writes a page that draws offline (.dvc/plots/offline.html)."""

from __future__ import annotations

import configparser
import re
from pathlib import Path

import yaml
from dvc_render import VegaRenderer, render_html

from f2depth.flow import bootstrap
from f2depth.flow.finetune import HISTORY_COLUMNS as FINETUNE_COLUMNS
from f2depth.train.loop import HISTORY_FILES

ROOT = Path(__file__).resolve().parents[1]
PLOTS = ROOT / ".dvc" / "plots"
#: The columns each plotted file is written with (f2depth.epochs.write_history); flow_pretrain's default route
#: is `source: chairs` (f2depth.flow.bootstrap).
WRITERS = {
    r"metrics/train_depth/[^/]+/history\.csv": HISTORY_FILES["history.csv"],
    r"metrics/train_depth/[^/]+/validation\.csv": HISTORY_FILES["validation.csv"],
    r"metrics/flow_finetune/[^/]+/history\.csv": FINETUNE_COLUMNS,
    r"metrics/flow_pretrain/history\.csv": bootstrap.HISTORY_COLUMNS,
    r"metrics/flow_pretrain/phase_b\.csv": bootstrap.PHASE_B_COLUMNS,
}


def _columns(path: str) -> tuple[str, ...]:
    found = [columns for pattern, columns in WRITERS.items() if re.fullmatch(pattern, path)]
    assert len(found) == 1, f"{path}: no writer known for this plotted file"
    return tuple(found[0])


def _fields(y: str | list[str]) -> list[str]:
    return [y] if isinstance(y, str) else list(y)


def _plots() -> tuple[list[tuple[str, dict]], list[tuple[str, dict]]]:
    """(the top-level plots, the stages' plot outputs with ``${key}`` / ``${item}`` filled in), each as
    ``(name or file, properties)``."""
    dvc = yaml.safe_load((ROOT / "dvc.yaml").read_text())
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    top = [next(iter(p.items())) for p in dvc["plots"]]
    stages = []
    for stage in dvc["stages"].values():
        items = stage.get("foreach", {None: None})
        keys = params["flow_finetune"]["losses"] if isinstance(items, str) else list(items)
        for key in keys:
            for entry in stage.get("do", stage).get("plots", []):
                path, props = next(iter(entry.items()))
                if key is not None:
                    path = path.replace("${key}", key).replace("${item}", key)
                stages.append((path, props))
    return top, stages


def test_every_plot_reads_columns_its_file_is_written_with():
    top, stages = _plots()
    assert len(top) >= 6 and len(stages) == 1 + 1 + 2 + 2 * 5  # flow_pretrain 2, flow_finetune 2, depth 2 × 5
    declared = {path for path, _ in stages}
    for name, props in top:
        assert props.get("template") == "runs", name
        for path, y in props["y"].items():
            assert path in declared, f"{name}: {path} is no stage's plot output"
            assert {props["x"], *_fields(y)} <= set(_columns(path)), (name, path)
    for path, props in stages:
        assert props.get("template") == "runs" and props.get("cache") is False, path
        assert {props["x"], *_fields(props["y"])} <= set(_columns(path)), path


def test_sparse_measurements_are_plotted_from_the_files_of_measured_rows():
    top, _ = _plots()
    sparse = {"val_a1", "val_abs_rel", "train_a1", "pose_rot_err"}  # measured every val_every epochs
    files = {Path(path).name for name, props in top for path, y in props["y"].items()
             if path.startswith("metrics/train_depth/") and sparse & set(_fields(y))}
    assert files == {"validation.csv"}
    assert not set(HISTORY_FILES["history.csv"]) & set(HISTORY_FILES["validation.csv"]) - {"epoch"}


def _dvc_config() -> configparser.ConfigParser:
    config = configparser.ConfigParser()
    config.read_string((ROOT / ".dvc" / "config").read_text())
    return config


def _markup(html: str) -> str:
    """``html`` without the bodies of its inline scripts (library code, which names URLs it never loads)."""
    return re.sub(r"(<script[^>]*>).*?(</script>)", r"\1\2", html, flags=re.S | re.I)


def test_html_template_is_offline_and_names_its_vendored_libraries():
    template = ROOT / ".dvc" / _dvc_config()["plots"]["html_template"]
    assert template == PLOTS / "offline.html"
    html = template.read_text(encoding="utf-8")
    assert "{plot_divs}" in html and "{scripts}" not in html  # DVC's {scripts}: links to a CDN
    assert template.stat().st_size < 2_000_000
    markup = _markup(html)
    assert not re.search(r"https?://", markup), "the page must load nothing from the network"
    assert not re.search(r"<script[^>]*\bsrc\s*=|<link\b", markup, flags=re.I)
    vendored = dict(re.findall(r"<!-- (vega(?:-lite|-embed)?) (\d+\.\d+\.\d+) \(BSD-3-Clause\)", html))
    assert list(vendored) == ["vega", "vega-lite", "vega-embed"]  # the order they must load in
    readme = (PLOTS / "README.md").read_text()
    for name, version in vendored.items():
        assert re.search(rf"^\| {name} \| {re.escape(version)} \|", readme, flags=re.M), name
    assert "BSD-3-Clause" in readme and "Redistribution and use in source and binary forms" in readme
    for global_name in ("vega", "vegaLite", "vegaEmbed"):
        assert f".{global_name}=" in html or f".{global_name} =" in html, global_name


def test_dvc_renders_a_page_without_network_links_with_one_colour_per_run(tmp_path):
    """What `dvc plots show` does with a top-level plot: dvc_render fills the `runs` template and the page."""
    rows = [{"epoch": str(e), "val_a1": str(0.3 + 0.01 * e), "rev": "workspace", "field": "val_a1",
             "filename": f"{run}/validation.csv"} for run in ("full", "baseline") for e in (0, 5, 10)]
    renderer = VegaRenderer(rows, "depth_validation_a1", template="runs", template_dir=str(PLOTS),
                            x="epoch", y="val_a1", title="validation δ1")
    out = render_html([renderer], tmp_path / "dvc_plots" / "index.html",
                      html_template=str(PLOTS / "offline.html"))
    page = Path(out).read_text(encoding="utf-8")
    assert "cdn.jsdelivr" not in page and not re.search(r"https?://", _markup(page))
    spec = renderer.get_filled_template()
    assert spec["encoding"]["color"]["field"] == "run" and spec["data"]["values"] == rows
    calc = {t.get("as"): t.get("calculate") for t in spec["transform"]}
    assert calc["y_value"] == "toNumber(datum['val_a1'])" and calc["x_value"] == "toNumber(datum['epoch'])"
    assert any("isValid(datum.y_value)" in t.get("filter", "") for t in spec["transform"])  # blanks left out
    assert "var spec = " in page and '"run"' in page
