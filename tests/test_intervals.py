"""Seeds with intervals (f2depth.report.intervals, issue 54): a variant's mean over seeds and each ablation
gap as a paired difference with a bootstrap interval, on per-image CSVs written here in the evaluate stage's
format (``reports/eval/<variant>/<set>.csv``, f2depth.eval.suite.rows_csv); and the `tables` stage's params,
tables and MLflow run."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from f2depth import params as P
from f2depth.eval.suite import rows_csv
from f2depth.protocols.metrics import aggregate, mean_of_rows
from f2depth.report import intervals as I
from f2depth.report import tables as T
from f2depth.report.results import VariantResults, headline

ROOT = Path(__file__).resolve().parents[1]
NYU_KEYS, SEVENSCENES_KEYS, CAMPUS_KEYS = ("index",), ("scene", "seq", "frame"), ("scene", "image")


def write_set(path: Path, a1: np.ndarray, abs_rel: np.ndarray | None = None, keys: list[dict] | None = None,
              seeds: list[int] | None = None) -> Path:
    """``path``: a per-image CSV as the evaluate stage writes it, from (S, N) arrays of δ1 (and AbsRel; 1 − δ1
    when None): every seed's rows without and with PP (PP rows: other numbers, which must not count).
    ``keys``: N dicts of key columns and ``scene`` (NYU-style ``index`` by default)."""
    abs_rel = 1.0 - a1 if abs_rel is None else abs_rel
    n_seeds, n = a1.shape
    keys = keys or [{"index": i, "scene": f"room_{i // 3}"} for i in range(n)]
    rows = [{"seed": s, "post_process": pp, **keys[i], "abs_rel": float(abs_rel[k, i] + pp),
             "a1": float(a1[k, i] - pp), "ratio": 1.0}
            for k, s in enumerate(seeds or range(n_seeds)) for pp in (False, True)
            for i in range(n)]  # fmt: skip
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(rows_csv(rows))
    return path


def nyu_pair(tmp_path: Path, a1_a: np.ndarray, a1_b: np.ndarray) -> I.SetScores:
    files = {v: write_set(tmp_path / v / "nyu.csv", a1) for v, a1 in (("a", a1_a), ("b", a1_b))}
    return I.load_set("nyu", files, NYU_KEYS, NYU_KEYS, False, ("a1", "abs_rel"))


def test_a_large_true_difference_with_three_seeds_is_significant_and_covered(tmp_path):
    rng = np.random.default_rng(1)
    difficulty = rng.uniform(0.3, 0.7, 80)  # per image, shared by both variants
    seed_effect = rng.normal(0, 0.01, (3, 1))
    b = difficulty + seed_effect + rng.normal(0, 0.03, (3, 80))
    a = b + 0.05 + rng.normal(0, 0.02, (3, 80))  # true difference: +0.05
    result = I.summarize(nyu_pair(tmp_path, a, b), [("a", "b")], 2000, 0.95, 0)
    gap = result.gaps[("a", "b")]["a1"]
    assert gap.significant and gap.lo > 0 and gap.lo < 0.05 < gap.hi
    assert gap.estimate == pytest.approx(float(a.mean() - b.mean()))
    means = result.variants
    assert gap.estimate == pytest.approx(means["a"]["a1"].estimate - means["b"]["a1"].estimate)
    assert result.gaps[("a", "b")]["abs_rel"].significant and result.gaps[("a", "b")]["abs_rel"].hi < 0
    assert (result.n_seeds, result.n_images, result.n_units) == (3, 80, 80)
    mean = result.variants["a"]["a1"]
    assert mean.lo < float(a.mean()) < mean.hi


def test_two_variants_equal_up_to_noise_are_a_tie(tmp_path):
    rng = np.random.default_rng(2)
    difficulty = rng.uniform(0.3, 0.7, 80)
    a, b = (difficulty + rng.normal(0, 0.03, (3, 80)) for _ in range(2))
    gap = I.summarize(nyu_pair(tmp_path, a, b), [("a", "b")], 2000, 0.95, 0).gaps[("a", "b")]["a1"]
    assert not gap.significant and gap.lo < 0 < gap.hi


def test_pairing_matters_a_shared_difficulty_cancels_in_the_paired_difference(tmp_path):
    """Per-image difficulty (sd 0.15) far larger than the variant difference (0.01): the paired interval
    excludes 0; the unpaired one (a and b resampled independently) does not."""
    rng = np.random.default_rng(3)
    difficulty = rng.normal(0.5, 0.15, 60)
    b = difficulty + rng.normal(0, 0.003, (3, 60))
    a = b + 0.01 + rng.normal(0, 0.003, (3, 60))
    scores = nyu_pair(tmp_path, a, b)
    paired = I.summarize(scores, [("a", "b")], 2000, 0.95, 0).gaps[("a", "b")]["a1"]
    assert paired.significant and paired.lo > 0.005
    alone = {v: I.SetScores("nyu", scores.seeds, scores.keys, scores.units, scores.strata,
                            {v: scores.values[v]}) for v in ("a", "b")}  # fmt: skip
    draws_a = I.bootstrap(alone["a"], 2000, 1)["a"]["a1"]
    draws_b = I.bootstrap(alone["b"], 2000, 2)["b"]["a1"]  # other draws: unpaired
    unpaired = I.percentile(draws_a - draws_b, paired.estimate, 0.95)
    assert not unpaired.significant and unpaired.lo < 0 < unpaired.hi
    assert (unpaired.hi - unpaired.lo) > 10 * (paired.hi - paired.lo)


def test_the_same_inputs_give_the_same_intervals(tmp_path):
    rng = np.random.default_rng(4)
    scores = nyu_pair(tmp_path, rng.uniform(0, 1, (3, 30)), rng.uniform(0, 1, (3, 30)))
    first, again = (I.summarize(scores, [("a", "b")], 500, 0.95, 7) for _ in range(2))
    assert first == again
    reread = nyu_pair(tmp_path / "again", *(scores.values[v]["a1"] for v in ("a", "b")))
    assert I.summarize(reread, [("a", "b")], 500, 0.95, 7) == first
    assert I.summarize(scores, [("a", "b")], 500, 0.95, 8).gaps != first.gaps  # the seed is what fixes them


def test_mismatched_images_or_seeds_are_refused_in_one_line(tmp_path):
    a1 = np.full((3, 6), 0.5)
    a = write_set(tmp_path / "a" / "nyu.csv", a1)
    moved = [{"index": i + 1, "scene": "room"} for i in range(6)]
    other = write_set(tmp_path / "b" / "nyu.csv", a1, keys=moved)
    with pytest.raises(ValueError) as err:
        I.load_set("nyu", {"a": a, "b": other}, NYU_KEYS, NYU_KEYS, False, ("a1",))
    message = str(err.value)
    assert "\n" not in message and message.startswith(f"{other}: 2 test image(s) not in both it and {a}")
    assert "paired difference needs the same test images" in message
    seeds = write_set(tmp_path / "c" / "nyu.csv", a1, seeds=[0, 1, 5])
    with pytest.raises(ValueError, match=r"nyu\.csv: seeds \[0, 1, 5\], but .* has \[0, 1, 2\];") as err:
        I.load_set("nyu", {"a": a, "c": seeds}, NYU_KEYS, NYU_KEYS, False, ("a1",))
    assert "\n" not in str(err.value)
    shuffled = write_set(tmp_path / "d" / "nyu.csv", a1[:, ::-1], keys=[{"index": 5 - i, "scene": "room"}
                                                                         for i in range(6)])
    aligned = I.load_set("nyu", {"a": a, "d": shuffled}, NYU_KEYS, NYU_KEYS, False, ("a1",))
    assert aligned.keys == tuple((str(i),) for i in range(6))  # the same images in another order: aligned


def test_campus_point_estimate_is_the_evaluate_stages_mean_of_scene_means(tmp_path):
    rng = np.random.default_rng(5)
    sizes = {"lab_01": 1, "hall_02": 4, "room_03": 2}  # unequal: the mean over images differs
    keys = [{"scene": s, "image": f"img_{k}.jpg"} for s, n in sizes.items() for k in range(n)]
    a1, abs_rel = rng.uniform(0, 0.5, (2, 7)), rng.uniform(0, 1, (2, 7))
    a1[:, 0] = 1.0  # the one image of lab_01 weighs a third
    path = write_set(tmp_path / "full" / "campus.csv", a1, abs_rel, keys)
    scores = I.load_set("campus", {"full": path}, CAMPUS_KEYS, CAMPUS_KEYS, True, ("a1", "abs_rel"))
    scenes = [k["scene"] for k in keys]
    per_seed = []
    for s in range(2):  # f2depth.protocols.scoring: per-scene aggregate, then mean_of_rows of the scene means
        rows = [{"a1": a1[s, i], "abs_rel": abs_rel[s, i]} for i in range(7)]
        means = [aggregate([r for r, sc in zip(rows, scenes) if sc == name]).mean for name in sizes]
        per_seed.append(mean_of_rows(means))
    expected = {m: float(np.mean([h[m] for h in per_seed])) for m in ("a1", "abs_rel")}
    assert I.point(scores)["full"] == pytest.approx(expected, rel=1e-12)
    assert abs(I.point(scores)["full"]["a1"] - float(a1.mean())) > 0.05
    result = I.summarize(scores, [], 300, 0.95, 0)
    assert result.variants["full"]["a1"].estimate == pytest.approx(expected["a1"], rel=1e-12)
    assert result.n_units == 7  # images, resampled within each scene


def test_sevenscenes_resamples_whole_sequences(tmp_path):
    """Consecutive frames of a sequence share its luck: drawing sequences gives a wider interval than drawing
    frames one by one would, around the same mean over all frames."""
    rng = np.random.default_rng(6)
    keys = [{"scene": sc, "seq": f"seq-0{q}", "frame": f} for sc in ("chess", "fire", "heads")
            for q in (1, 2) for f in range(20)]  # fmt: skip
    luck = np.repeat(rng.normal(0, 0.1, 6), 20)
    a1 = 0.6 + luck + rng.normal(0, 0.01, (1, 120))
    files = {"full": write_set(tmp_path / "full" / "sevenscenes.csv", a1, keys=keys)}
    by_sequence = I.load_set("sevenscenes", files, SEVENSCENES_KEYS, ("scene", "seq"), False, ("a1",))
    by_frame = I.load_set("sevenscenes", files, SEVENSCENES_KEYS, SEVENSCENES_KEYS, False, ("a1",))
    seq, frame = (I.summarize(s, [], 1000, 0.95, 0) for s in (by_sequence, by_frame))
    assert seq.n_units == 6 and frame.n_units == 120 and seq.n_seeds == 1
    assert seq.variants["full"]["a1"].estimate == pytest.approx(float(a1.mean()), rel=1e-12)
    width = {k: r.variants["full"]["a1"].hi - r.variants["full"]["a1"].lo for k, r in (("seq", seq),
                                                                                      ("frame", frame))}
    assert width["seq"] > 3 * width["frame"]


def test_one_seed_intervals_cover_the_images(tmp_path):
    rng = np.random.default_rng(7)
    result = I.summarize(nyu_pair(tmp_path, rng.uniform(0, 1, (1, 40)), rng.uniform(0, 1, (1, 40))),
                         [("a", "b")], 500, 0.95, 0)
    assert result.n_seeds == 1
    iv = result.variants["a"]["a1"]
    assert iv.lo < iv.estimate < iv.hi  # the spread of the test images


def test_nothing_to_resample_gives_no_interval_rather_than_a_point(tmp_path):
    """One seed and one image per scene (a tiny Campus): no interval, so no difference is marked significant;
    tables.json gets null."""
    keys = [{"scene": f"s{k}", "image": "img.jpg"} for k in range(3)]
    files = {v: write_set(tmp_path / v / "campus.csv", np.full((1, 3), 0.5 + d), keys=keys)
             for v, d in (("a", 0.1), ("b", 0.0))}
    scores = I.load_set("campus", files, CAMPUS_KEYS, CAMPUS_KEYS, True, ("a1", "abs_rel"))
    result = I.summarize(scores, [("a", "b")], 100, 0.95, 0)
    gap = result.gaps[("a", "b")]["a1"]
    assert gap.estimate == pytest.approx(0.1) and math.isnan(gap.lo) and not gap.significant
    assert math.isnan(result.variants["a"]["a1"].hi)
    two = [{"scene": "s0", "image": f"img_{k}.jpg"} for k in range(2)]  # two images of one scene: resampled
    pair = {v: write_set(tmp_path / "two" / v / "campus.csv", np.array([[0.4, 0.6]]) + d, keys=two)
            for v, d in (("a", 0.1), ("b", 0.0))}
    again = I.summarize(I.load_set("campus", pair, CAMPUS_KEYS, CAMPUS_KEYS, True, ("a1",)), [], 100, 0.95, 0)
    assert again.variants["a"]["a1"].lo < again.variants["a"]["a1"].hi


def test_cells_render_mean_with_interval_and_signed_differences():
    cell = T.MeanInterval((0.43, 0.436), 0.421, 0.445, 0.95)
    gap = I.Interval(0.0421, 0.0204, 0.0613)
    assert T.format_value(cell) == "0.433 [0.421, 0.445]"
    assert T.format_value(gap) == "+0.042 [0.020, 0.061]"
    assert T.format_value(I.Interval(-0.012, -0.02, -0.004)) == "-0.012 [-0.020, -0.004]"
    cols = [T.Column("v", "V"), T.Column("a1", "δ1"), T.Column("d", "Δ")]
    rows = [{"v": "full", "a1": cell, "d": gap}, {"v": "pp", "a1": [0.5, 0.6], "d": None}]
    lines = T.to_csv(rows, cols).splitlines()
    assert lines[0] == "v,a1,a1_std,a1_n,a1_lo,a1_hi,d,d_lo,d_hi"
    assert lines[1].startswith(f"full,{float(np.mean([0.43, 0.436]))!r},")
    assert lines[1].endswith(",2,0.421,0.445,0.0421,0.0204,0.0613")
    assert lines[2].endswith(",2,,,,,")
    md = T.to_markdown(rows, cols)
    assert "a [lo, hi]: mean over n = 2 seeds and its 95 % bootstrap interval" in md
    tex = T.to_latex(rows, cols)
    assert "0.433 [0.421, 0.445]" in tex and "+0.042 [0.020, 0.061]" in tex


def test_headline_without_intervals_has_the_same_keys_with_null():
    scores = {g: {"a1": 0.5, "abs_rel": 0.2} for g in ("nyu", "sevenscenes", "campus")}
    doc = headline({"full": VariantResults("full", {**scores, "per_seed": {"seed0": scores}})}, {}, {})
    assert doc["full"]["nyu_a1"] == 0.5
    assert doc["full"]["nyu_a1_lo"] is None and doc["full"]["campus_abs_rel_hi"] is None
    assert doc["gaps"] == {} and doc["confidence"] is None
    nan = I.Interval(float("nan"), float("nan"), 0.1)
    nyu = I.SetIntervals("nyu", 1, 3, 3, {"full": {"a1": nan}}, {("full", "full"): {"a1": nan}})
    iv = I.Intervals((("full", "full"),), 0.9, 10, {"nyu": nyu})
    doc = headline({"full": VariantResults("full", {**scores, "per_seed": {"seed0": scores}})}, {}, {}, iv)
    assert doc["full"]["nyu_a1_lo"] is None and doc["full"]["nyu_a1_hi"] == 0.1
    assert doc["gaps"]["full-full"]["nyu_a1"] is None and doc["gaps"]["full-full"]["7scenes_a1"] is None
    assert doc["gaps"]["full-full"]["nyu_a1_significant"] is None  # no interval: no verdict
    json.dumps(doc, allow_nan=False)  # finite JSON only


# ---- the `tables` stage ---------------------------------------------------------------------------------


def _stage_inputs(tmp_path: Path, **tables) -> Path:
    import test_stage_tables

    params = test_stage_tables.write_inputs(tmp_path)
    p = yaml.safe_load(params.read_text())
    p["tables"] |= tables
    params.write_text(yaml.safe_dump(p, sort_keys=False))
    return params


def _run_stage(tmp_path: Path) -> None:
    import test_stage_tables

    test_stage_tables.run(tmp_path)


@pytest.mark.parametrize(("given", "message"), [
    ({"gaps": [["full", "nope"]]}, r"params\.yaml: tables\.gaps\[0\] names 'nope', no variant of `variants` "
                                   r"\(full, no_feature, baseline, flow_pretrained, flow_full_ft\)$"),
    ({"gaps": [["full", "baseline"], ["full", "full"]]},
     r"params\.yaml: tables\.gaps\[1\] compares 'full' with itself"),
    ({"gaps": [["full"]]}, r"params\.yaml: tables\.gaps\[0\] is \['full'\]; set it to a list of 2 values"),
    ({"confidence": 1.5}, r"params\.yaml: tables\.confidence is 1\.5; set it to a level between 0 and 1"),
])  # fmt: skip
def test_a_bad_tables_section_is_a_one_line_params_error(tmp_path, monkeypatch, given, message):
    monkeypatch.setenv("F2DEPTH_MLFLOW", "0")
    _stage_inputs(tmp_path, **given)
    with pytest.raises(P.ParamsError, match=message) as err:
        _run_stage(tmp_path)
    assert "\n" not in str(err.value)
    assert not (tmp_path / "reports" / "tables").exists()  # refused before any work


def test_a_stale_per_image_file_is_refused(tmp_path, monkeypatch):
    """A CSV from another evaluate run than the metrics file (its mean differs) would give intervals around
    other numbers than the tables show."""
    monkeypatch.setenv("F2DEPTH_MLFLOW", "0")
    _stage_inputs(tmp_path)
    path = tmp_path / "reports" / "eval" / "baseline" / "campus.csv"
    lines = path.read_text().splitlines()
    cells = lines[1].split(",")
    column = lines[0].split(",").index("a1")
    cells[column] = repr(float(cells[column]) + 0.1)
    path.write_text("\n".join([lines[0], ",".join(cells), *lines[2:]]) + "\n")
    with pytest.raises(ValueError, match=r"baseline/campus\.csv: mean a1 .*, but baseline\.json has "
                                         r"campus\.a1 .*; the evaluate runs differ; run `dvc repro "
                                         r"evaluate@baseline`"):
        _run_stage(tmp_path)


def test_the_tables_run_logs_every_interval_and_gap_to_mlflow(tmp_path, monkeypatch):
    from mlflow.tracking import MlflowClient

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    for key, value in (("MLFLOW_TRACKING_URI", uri), ("F2DEPTH_MLFLOW", "1"), ("DVC_EXP_NAME", "exp-test")):
        monkeypatch.setenv(key, value)
    monkeypatch.delenv("DVC_STAGE", raising=False)
    _stage_inputs(tmp_path)
    monkeypatch.chdir(tmp_path)
    _run_stage(tmp_path)
    client = MlflowClient(tracking_uri=uri)
    (run,) = [r for r in client.search_runs(client.get_experiment_by_name("f2depth").experiment_id)
              if r.data.tags.get("stage") == "tables"]
    doc = json.loads((tmp_path / "metrics" / "tables.json").read_text())
    logged = run.data.metrics
    for name in ("full.nyu_a1_lo", "full.campus_abs_rel_hi", "gaps.full-no_feature.nyu_a1",
                 "gaps.no_feature-baseline.7scenes_abs_rel_hi",
                 "gaps.full-flow_full_ft.campus_a1_significant"):
        section, _, rest = name.partition(".")
        top, _, leaf = rest.rpartition(".") if section == "gaps" else ("", "", rest)
        value = doc[section][top][leaf] if section == "gaps" else doc[section][leaf]
        assert math.isclose(logged[name], value), name
    assert logged["confidence"] == 0.95
    assert run.data.params["tables.bootstrap"] == "200"


def test_repository_params_declare_the_gaps_of_tables_5_and_6():
    """Table 5's three gaps, Table 6's two against `full`, and each Table 6 teacher against `baseline`."""
    p = P.load(ROOT / "params.yaml")
    spec = importlib.util.spec_from_file_location("tables_stage_params", ROOT / "stages" / "tables.py")
    stage = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(stage)
    cfg = stage.config_from_params(p, list(p["variants"]))
    assert cfg.gaps == (("full", "no_feature"), ("full", "baseline"), ("no_feature", "baseline"),
                        ("full", "flow_pretrained"), ("full", "flow_full_ft"),
                        ("flow_pretrained", "baseline"), ("flow_full_ft", "baseline"))
    assert (cfg.bootstrap, cfg.confidence, cfg.bootstrap_seed) == (2000, 0.95, 0)
    dvc = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]["tables"]
    assert "tables" in dvc["params"] and "f2depth/report/" in dvc["deps"]
