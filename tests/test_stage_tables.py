"""The `tables` stage on hand-written evaluation results: the paper's tables in three formats, with our
rows (mean ± std over seeds; without PP the mean with its bootstrap interval) beside the quoted ones, the
flow EPE of Table 6, the ablation gaps as paired differences, the figures and the index."""

from __future__ import annotations

import csv
import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from f2depth.protocols.metrics import METRIC_NAMES

ROOT = Path(__file__).resolve().parents[1]
VARIANTS = ("full", "no_feature", "baseline", "flow_pretrained", "flow_full_ft")
GROUPS = ("nyu", "nyu_pp", "sevenscenes", "sevenscenes_pp", "campus", "campus_pp")
PNG = b"\x89PNG\r\n\x1a\n"


def metrics(base: float) -> dict:
    """All eight metrics; AbsRel = base, δ1 = 1 − base, the rest derived."""
    return {m: (1.0 - base if m == "a1" else base + 0.01 * i) for i, m in enumerate(METRIC_NAMES)}


def headline(base: float) -> dict:
    groups = {g: metrics(base + 0.001 * i) for i, g in enumerate(GROUPS)}
    return {**groups, "ms": 100 + base, "ms_pp": 200 + base}


def seed_details(base: float) -> dict:
    def scenes(names):
        return {s: {"mean": metrics(base + 0.01 * k), "std": metrics(0.0), "count": 3 + k}
                for k, s in enumerate(names)}

    return {
        "input_hw": [64, 96],
        "sevenscenes_pp": {"scenes": scenes(["chess", "fire"]), "average": metrics(base + 0.005),
                           "frame_weighted": {"mean": metrics(base), "count": 7}},
        "campus": {"scenes": scenes(["1", "2"]), "average": metrics(base + 0.005)},
        "timing": {"ms": {"device": "cpu", "threads": 1, "height": 288, "width": 384},
                   "ms_pp": {"device": "cpu", "threads": 1, "height": 288, "width": 384}},
    }  # fmt: skip


#: Per-image CSV of each test set (the evaluate stage's reports/eval/<variant>/<set>.csv): its key columns and
#: test images, and its headline group in ``headline()`` (GROUPS index: the base offset 0.001·index).
IMAGE_KEYS = {
    "nyu": (("index", "scene"), [(str(k), f"room_{k // 2}") for k in range(6)]),
    "sevenscenes": (("scene", "seq", "frame"), [(sc, sq, str(f)) for sc in ("chess", "fire")
                                                for sq in ("seq-01", "seq-02") for f in range(3)]),
    "campus": (("scene", "image"), [(sc, f"img_{k}.jpg") for sc in ("lab_01", "hall_02", "room_03")
                                    for k in (1, 2)]),
}  # fmt: skip
GAPS = [["full", "no_feature"], ["full", "baseline"], ["no_feature", "baseline"], ["full", "flow_pretrained"],
        ["full", "flow_full_ft"]]


def write_per_image(out: Path, bases: dict[int, float], rng: np.random.Generator) -> None:
    """``out/<set>.csv`` as the evaluate stage writes them, for seeds ``bases`` (seed → base): each image's
    metrics are its seed's headline ± noise that sums to 0 in every scene, so the mean over images (NYU,
    7-Scenes) and the mean of the scene means (Campus) are the headline of metrics/evaluate."""
    for name, (columns, images) in IMAGE_KEYS.items():
        lines = [",".join(["seed", "post_process", *columns, *([] if "scene" in columns else ["scene"]),
                           *METRIC_NAMES, "ratio"])]
        scenes = [dict(zip(columns, key)).get("scene") for key in images]
        for seed, base in bases.items():
            for pp in (False, True):
                group = GROUPS.index(f"{name}_pp" if pp else name)
                values = metrics(base + 0.001 * group)
                noise = rng.normal(0, 0.01, (len(images), len(METRIC_NAMES)))
                for scene in set(scenes):
                    rows = [i for i, s in enumerate(scenes) if s == scene]
                    noise[rows] -= noise[rows].mean(axis=0)
                for key, scene, n in zip(images, scenes, noise):
                    cells = [str(seed), str(pp), *key, *([] if "scene" in columns else [scene])]
                    cells += [repr(float(values[m] + d)) for m, d in zip(METRIC_NAMES, n)] + ["1.0"]
                    lines.append(",".join(cells))
        (out / f"{name}.csv").write_text("\n".join(lines) + "\n")


#: The loss weights each variant's model was trained with (what evaluate records as ``trained_with``).
WEIGHTS = {
    "full": {"smooth": 0.001, "planar": 0.05, "rigid": 1.0, "feature": 3.0},
    "no_feature": {"smooth": 0.001, "planar": 0.05, "rigid": 1.0, "feature": 0.0},
    "baseline": {"smooth": 0.001, "planar": 0.05, "rigid": 0.0, "feature": 0.0},
    "flow_pretrained": {"smooth": 0.001, "planar": 0.05, "rigid": 1.0, "feature": 3.0},
    "flow_full_ft": {"smooth": 0.001, "planar": 0.05, "rigid": 1.0, "feature": 3.0},
}


def write_inputs(root: Path, weights: dict[str, dict[str, float]] = WEIGHTS) -> Path:
    """metrics/evaluate, reports/eval (with the per-image CSVs), flow metrics and histories for every
    variant, two seeds each: variant i, seed s has base AbsRel 0.1 + 0.01·i + 0.002·s; trained with
    ``weights[variant]``."""
    rng = np.random.default_rng(0)
    for i, v in enumerate(VARIANTS):
        bases = {s: 0.1 + 0.01 * i + 0.002 * s for s in (0, 1)}
        per_seed = {f"seed{s}": headline(b) for s, b in bases.items()}
        doc = {**headline(0.1 + 0.01 * i + 0.001), "n_seeds": 2, "per_seed": per_seed, "variant": v,
               "decoder_upsample": "bilinear", "trained_with": {"flow_model": None, "weights": weights[v]}}
        (root / "metrics" / "evaluate").mkdir(parents=True, exist_ok=True)
        (root / "metrics" / "evaluate" / f"{v}.json").write_text(json.dumps(doc))
        out = root / "reports" / "eval" / v
        out.mkdir(parents=True)
        (out / "details.json").write_text(json.dumps(
            {"variant": v, "seeds": {f"seed{s}": seed_details(b) for s, b in bases.items()}}))
        gt = rng.uniform(1, 5, (2, 24, 32)).astype(np.float32)
        gt[:, :3, :3] = 0.0
        kept = {}
        for prefix in ("nyu", "sevenscenes"):
            kept |= {f"{prefix}_id": np.array(["1", "7"]),
                     f"{prefix}_rgb": rng.integers(0, 256, (2, 24, 32, 3), dtype=np.uint8),
                     f"{prefix}_gt": gt, f"{prefix}_pred": gt * (1.0 + 0.05 * i)}
        np.savez(out / "figures.npz", **kept)
        write_per_image(out, bases, rng)
        hist = root / "metrics" / "train_depth" / v
        hist.mkdir(parents=True)
        (hist / "history.csv").write_text("epoch,total\n1,0.9\n2,0.8\n")
        (hist / "validation.csv").write_text("epoch,val_abs_rel,val_a1\n0,0.3,0.5\n1,0.25,0.6\n2,0.2,0.65\n")
        (hist.parent / f"{v}.json").write_text(json.dumps({
            "val_untrained": {"a1": 0.36, "abs_rel": 0.39}, "val_trained": {"a1": 0.5 + 0.01 * i},
            "val_constant_depth": {"a1": 0.357, "abs_rel": 0.390}}))
    flow = root / "metrics" / "flow_finetune"
    for loss, ft in (("patch", 1.5), ("full", 2.5)):
        (flow / loss).mkdir(parents=True)
        (flow / f"{loss}.json").write_text(json.dumps({
            "pretrained": {"test": {"epe_all": 4.0, "epe_noc": 3.5, "epe_low_texture": 6.0,
                                    "swap_consistency": 0.7}},
            "finetuned": {"test": {"epe_all": ft, "epe_noc": ft - 0.2, "epe_low_texture": ft + 1,
                                   "swap_consistency": 1.1 - ft / 5}},
            "zero_flow": {"test": {"epe_all": 5.0}}}))
        (flow / loss / "history.csv").write_text(
            f"epoch,loss,epe_all,epe_low_texture\n0,,4.0,6.0\n1,0.5,{ft},{ft + 1}\n")
    (root / "metrics" / "flow_pretrain.json").write_text(json.dumps({"prepared": {
        "model": {"epe_all": 2.25, "swap_consistency": 0.77}, "zero_flow": {"epe_all": 4.14}}}))
    params = {
        "variants": {
            "full": {"flow": "models/flow_patch.pt", "without": []},
            "no_feature": {"flow": "models/flow_patch.pt", "without": ["feature"]},
            "baseline": {"flow": None, "without": ["rigid", "feature"]},
            "flow_pretrained": {"flow": "models/flow_pretrained.pt", "without": []},
            "flow_full_ft": {"flow": "models/flow_full.pt", "without": []}},
        "flow_finetune": {"losses": ["patch", "full"], "out_dir": str(flow),
                          "pretrained": "models/flow_pretrained.pt", "model": "models/flow_{loss}.pt"},
        "evaluate": {"nyu_gt": "depths"},
        "tables": {"gaps": GAPS, "bootstrap": 200, "confidence": 0.95, "bootstrap_seed": 0},
    }  # fmt: skip
    path = root / "params.yaml"
    path.write_text(yaml.safe_dump(params, sort_keys=False))
    return path


def run(root: Path) -> Path:
    spec = importlib.util.spec_from_file_location("tables_stage", ROOT / "stages" / "tables.py")
    stage = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(stage)
    stage.main(["tables.py", "--params", str(root / "params.yaml"),
                "--metrics", str(root / "metrics" / "evaluate"), "--eval", str(root / "reports" / "eval"),
                "--train-metrics", str(root / "metrics" / "train_depth"), "--out", str(root / "reports"),
                "--pretrain-metrics", str(root / "metrics" / "flow_pretrain.json"),
                "--headline", str(root / "metrics" / "tables.json")])
    return root / "reports"


def read_csv(path: Path) -> list[dict]:
    with path.open(newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def reports(tmp_path_factory):
    """One stage run shared by the read-only checks below."""
    root = tmp_path_factory.mktemp("tables")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("F2DEPTH_MLFLOW", "0")
        write_inputs(root)
        return run(root)


def test_headline_metrics_file_is_the_ablation_table_with_floors_and_teachers(reports):
    doc = json.loads((reports.parent / "metrics" / "tables.json").read_text())
    assert list(doc) == [*VARIANTS, "floors", "teacher", "gaps", "confidence"]
    labels = (("nyu", "nyu"), ("sevenscenes", "7scenes"), ("campus", "campus"))
    for v in VARIANTS:
        row = doc[v]
        evaluated = json.loads((reports.parent / "metrics" / "evaluate" / f"{v}.json").read_text())
        assert list(row)[:7] == ["nyu_a1", "nyu_abs_rel", "7scenes_a1", "7scenes_abs_rel", "campus_a1",
                                 "campus_abs_rel", "n_seeds"]  # the keys before the intervals, unchanged
        assert list(row)[7:] == [f"{label}_{m}_{end}" for _, label in labels for m in ("a1", "abs_rel")
                                 for end in ("lo", "hi")]
        for group, label in labels:
            for m in ("a1", "abs_rel"):
                assert row[f"{label}_{m}"] == evaluated[group][m]
                assert row[f"{label}_{m}_lo"] < row[f"{label}_{m}"] < row[f"{label}_{m}_hi"]
        assert row["n_seeds"] == 2
    assert doc["confidence"] == 0.95 and list(doc["gaps"]) == ["-".join(g) for g in GAPS]
    for (a, b), gap in zip(GAPS, doc["gaps"].values()):
        for _, label in labels:
            for m in ("a1", "abs_rel"):
                assert gap[f"{label}_{m}"] == pytest.approx(doc[a][f"{label}_{m}"] - doc[b][f"{label}_{m}"])
                assert gap[f"{label}_{m}_lo"] <= gap[f"{label}_{m}"] <= gap[f"{label}_{m}_hi"]
                excludes = gap[f"{label}_{m}_lo"] > 0 or gap[f"{label}_{m}_hi"] < 0
                assert gap[f"{label}_{m}_significant"] == int(excludes)
    assert doc["floors"] == {"untrained": {"nyu_a1": 0.36, "nyu_abs_rel": 0.39},
                             "constant_depth": {"nyu_a1": 0.357, "nyu_abs_rel": 0.390}}
    assert doc["teacher"] == {
        "prepared_epe": 2.25, "prepared_swap": 0.77, "prepared_zero_flow_epe": 4.14,
        "heldout_epe": {"pretrained": 4.0, "patch": 1.5, "full": 2.5},
        "heldout_swap": {"pretrained": 0.7, "patch": pytest.approx(0.8), "full": pytest.approx(0.6)},
        "heldout_zero_flow_epe": 5.0}
    leaves = sum(len(doc[v]) for v in VARIANTS) + 4 + 3 + 6 + 1 + sum(map(len, doc["gaps"].values())) + 1
    assert leaves == 5 * 19 + 14 + 5 * 24 + 1  # a summary (means, intervals, gaps), not the stages' results


def test_ablation_gaps_table_and_claims(reports):
    """Every gap of `tables.gaps` on every set, as the paired difference with its interval and mark; the
    claims are exactly the marked ones, in words; the NYU floors are in the note."""
    doc = json.loads((reports.parent / "metrics" / "tables.json").read_text())
    rows = read_csv(reports / "tables" / "ablation_gaps.csv")
    assert [(r["gap"], r["set"]) for r in rows] == [(f"{a} − {b}", s) for a, b in GAPS
                                                    for s in ("NYU", "7-Scenes", "Campus")]
    assert list(rows[0]) == ["gap", "set", "a1", "a1_lo", "a1_hi", "a1_mark", "abs_rel", "abs_rel_lo",
                             "abs_rel_hi", "abs_rel_mark", "seeds", "images", "units"]
    assert [(r["seeds"], r["images"], r["units"]) for r in rows[:3]] == [("2", "6", "6"), ("2", "12", "4"),
                                                                         ("2", "6", "6")]
    gap = doc["gaps"]["full-baseline"]
    full_baseline = rows[3]
    assert float(full_baseline["abs_rel"]) == gap["nyu_abs_rel"]
    assert float(full_baseline["abs_rel_lo"]) == gap["nyu_abs_rel_lo"]
    marks = {"✓ significant": 1, "tie": 0}
    assert all(marks[r[f"{m}_mark"]] in (0, 1) for r in rows for m in ("a1", "abs_rel"))
    assert gap["nyu_abs_rel_significant"] == marks[full_baseline["abs_rel_mark"]] == 1  # −0.02 on every image
    md = (reports / "tables" / "ablation_gaps.md").read_text()
    assert md.startswith("**Ablation gaps: paired differences with intervals**\n\n| Gap (a − b) | Test set |")
    d, lo, hi = gap["nyu_abs_rel"], gap["nyu_abs_rel_lo"], gap["nyu_abs_rel_hi"]
    assert "| full − baseline | NYU |" in md and f"| {d:+.3f} [{lo:.3f}, {hi:.3f}] | ✓ significant |" in md
    assert "95 % percentile bootstrap interval (200 resamples" in md
    assert "untrained network δ1 0.360, AbsRel 0.390; constant depth δ1 0.357, AbsRel 0.390" in md
    claims = (reports / "tables" / "claims.md").read_text()
    listed = claims.split("## Significant")[1].split("## Ties")[0]
    significant = sum(v for g in doc["gaps"].values() for k, v in g.items() if k.endswith("_significant"))
    assert listed.count("\n- ") == significant
    assert f"- `full` < `baseline` on NYU AbsRel ({d:+.3f} [{lo:.3f}, {hi:.3f}]; `full` better)" in claims
    ties = claims.split("## Ties (no claim either way)")[1]
    assert significant + ties.count("\n- `") == 5 * 3 * 2  # every gap, set and metric: a claim or a tie


def test_every_table_in_three_formats(reports):
    stems = ("table1_nyu", "table5_losses", "table6_flow", "sevenscenes_scenes", "campus_scenes",
             "inference_time", "variants_overview", "ablation_gaps")
    for stem in stems:
        for suffix in (".md", ".csv", ".tex"):
            assert (reports / "tables" / f"{stem}{suffix}").stat().st_size > 100, stem + suffix
    tex = (reports / "tables" / "table1_nyu.tex").read_text()
    assert r"\begin{tabular}" in tex and r"\toprule" in tex and r"$^\dagger$" in tex and r"$\pm$" in tex


def test_table1_our_rows_beside_quoted_rows(reports):
    rows = read_csv(reports / "tables" / "table1_nyu.csv")
    quoted = [r for r in rows if r["quoted"] == "true"]
    ours = [r for r in rows if r["quoted"] == "false"]
    assert len(quoted) == 25 and [r["method"] for r in ours] == ["P²Net (ours: baseline)"] * 2 + [
        "F²Depth (ours: full)"] * 2
    assert [r["post_process"] for r in ours] == ["false", "true", "false", "true"]
    full = ours[2]  # full is variant 0: seeds 0.1 and 0.102
    assert float(full["abs_rel"]) == pytest.approx(0.101)
    assert float(full["abs_rel_std"]) == pytest.approx(np.std([0.1, 0.102], ddof=1))
    assert full["abs_rel_n"] == "2" and full["n"] == "2"
    md = (reports / "tables" / "table1_nyu.md").read_text()
    assert "| F²Depth † |" in md and "| F²Depth (ours: full) |" in md and "0.101 ± 0.001" in md
    assert "† quoted from the paper" in md and "n = 2 seeds" in md


def test_table5_losses_ablation(reports):
    rows = read_csv(reports / "tables" / "table5_losses.csv")
    ours = [(r["variant"], r["rigid"], r["feature"], r["post_process"])
            for r in rows if r["quoted"] == "false"]
    assert ours == [("baseline", "false", "false", "false"), ("no_feature", "true", "false", "false"),
                    ("full", "true", "true", "false"), ("baseline", "false", "false", "true"),
                    ("no_feature", "true", "false", "true"), ("full", "true", "true", "true")]
    assert sum(r["quoted"] == "true" for r in rows) == 6
    doc = json.loads((reports.parent / "metrics" / "tables.json").read_text())
    ours = [r for r in rows if r["quoted"] == "false"]
    full = next(r for r in ours if r["variant"] == "full" and r["post_process"] == "false")
    assert float(full["a1_lo"]) == doc["full"]["nyu_a1_lo"]
    assert float(full["a1_hi"]) == doc["full"]["nyu_a1_hi"]
    assert full["a1_n"] == "2" and float(full["a1"]) == pytest.approx(doc["full"]["nyu_a1"])
    pp = next(r for r in ours if r["variant"] == "full" and r["post_process"] == "true")
    assert pp["a1_lo"] == pp["a1_hi"] == ""  # with PP: mean ± std only
    md = (reports / "tables" / "table5_losses.md").read_text()
    lo, hi = doc["full"]["nyu_a1_lo"], doc["full"]["nyu_a1_hi"]
    assert f"{doc['full']['nyu_a1']:.3f} [{lo:.3f}, {hi:.3f}]" in md
    assert "a [lo, hi]: mean over n = 2 seeds and its 95 % bootstrap interval" in md


def test_table5_marks_come_from_the_weights_each_run_recorded(tmp_path, monkeypatch):
    """What `dvc exp run -S lambda3=0` produces: `full` retrained with λ3 = 0 must be marked
    L_feature × (the marks are not the variants' intended roles); a run whose metrics carry no weights gets
    no mark."""
    monkeypatch.setenv("F2DEPTH_MLFLOW", "0")
    weights = {**WEIGHTS, "full": {**WEIGHTS["full"], "feature": 0.0},
               "baseline": {}}  # metrics written before the weights were recorded
    write_inputs(tmp_path, weights)
    rows = read_csv(run(tmp_path) / "tables" / "table5_losses.csv")
    marks = {(r["variant"], r["post_process"]): (r["rigid"], r["feature"])
             for r in rows if r["quoted"] == "false"}
    for pp in ("false", "true"):
        assert marks[("full", pp)] == ("true", "false")
        assert marks[("no_feature", pp)] == ("true", "false")
        assert marks[("baseline", pp)] == ("", "")
    md = (tmp_path / "reports" / "tables" / "table5_losses.md").read_text()
    full_rows = [line for line in md.splitlines() if line.startswith("| full |")]
    assert len(full_rows) == 2 and all("| ✓ | × |" in line for line in full_rows)


def test_table6_flow_epe_comes_from_the_flow_network_each_variant_used(reports):
    table = read_csv(reports / "tables" / "table6_flow.csv")
    rows = {r["variant"]: r for r in table if r["quoted"] == "false"}
    assert list(rows) == ["flow_pretrained", "flow_full_ft", "full"]
    assert float(rows["flow_pretrained"]["epe_all"]) == 4.0
    assert float(rows["flow_pretrained"]["epe_low_texture"]) == 6.0
    assert float(rows["flow_full_ft"]["epe_all"]) == 2.5 and float(rows["full"]["epe_all"]) == 1.5
    assert float(rows["full"]["epe_low_texture"]) == 2.5


def test_sevenscenes_and_campus_per_scene(reports):
    rows = read_csv(reports / "tables" / "sevenscenes_scenes.csv")
    ours = [r for r in rows if r["quoted"] == "false"]
    assert [r["scene"] for r in ours] == ["Chess", "Fire", "Average (frame-weighted, as the paper)",
                                          "Mean of scene rows"]
    assert float(ours[0]["a_abs_rel"]) == pytest.approx(0.101)  # full, chess, mean of two seeds
    assert float(ours[0]["b_abs_rel"]) == pytest.approx(0.121)  # baseline (variant 2)
    assert ours[2]["frames"] == "7" and float(ours[3]["a_abs_rel"]) == pytest.approx(0.106)
    quoted = [r["scene"] for r in rows if r["quoted"] == "true"]
    assert quoted[0] == "Chess" and quoted[-1] == "Average" and len(quoted) == 8
    campus = read_csv(reports / "tables" / "campus_scenes.csv")
    assert [r["scene"] for r in campus if r["quoted"] == "false"] == ["1", "2", "Average of scenes"]
    assert sum(r["quoted"] == "true" for r in campus) == 19


def test_inference_table_and_overview(reports):
    rows = read_csv(reports / "tables" / "inference_time.csv")
    assert rows[-1]["quoted"] == "true" and float(rows[-1]["ms"]) == 9.4 and float(rows[-1]["ms_pp"]) == 13.5
    assert rows[0]["variant"] == "full" and rows[0]["device"] == "cpu, 1 threads"
    overview = read_csv(reports / "tables" / "variants_overview.csv")
    assert len(overview) == 10 and set(METRIC_NAMES) <= set(overview[0])


def test_figures_and_index(reports):
    figs = reports / "figures" / "depth"
    names = sorted(p.name for p in figs.iterdir())
    assert names == ["nyu_error_maps.png", "nyu_qualitative.png", "sevenscenes_error_maps.png",
                     "sevenscenes_qualitative.png", "training_curves.png"]
    for name in names:
        data = (figs / name).read_bytes()
        assert data.startswith(PNG) and len(data) > 5000, name
    index = (reports / "README.md").read_text()
    assert "tables/table1_nyu.csv" in index and "figures/depth/nyu_qualitative.png" in index
    assert "| F²Depth (ours: full) |" in index


def test_missing_evaluation_names_the_fix(tmp_path, monkeypatch):
    monkeypatch.setenv("F2DEPTH_MLFLOW", "0")
    write_inputs(tmp_path)
    (tmp_path / "metrics" / "evaluate" / "baseline.json").unlink()
    fix = r"baseline\.json: not found; run `dvc repro evaluate@baseline`"
    with pytest.raises(FileNotFoundError, match=fix):
        run(tmp_path)


def test_repository_dvc_stage_outputs_do_not_overlap_other_stages():
    dvc = yaml.safe_load((ROOT / "dvc.yaml").read_text())
    stage = dvc["stages"]["tables"]
    outs = [next(iter(o)) if isinstance(o, dict) else o for o in stage["outs"]]
    assert outs == ["reports/tables", "reports/figures/depth", "reports/README.md"]
    for dep in ("metrics/evaluate", "reports/eval", "metrics/train_depth", "${flow_finetune.out_dir}",
                "f2depth/report/", "stages/tables.py"):
        assert dep in stage["deps"], dep
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    others = [params["keypoints"]["overlay_dir"], params["flow_figure"]["out"]]
    assert not any(o.startswith(("reports/tables", "reports/figures/depth")) for o in others)
    plots = {next(iter(p)) for p in dvc["plots"]}
    assert {"depth_validation_a1", "flow_finetune_epe"} <= plots
