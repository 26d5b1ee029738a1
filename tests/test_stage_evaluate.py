"""The `evaluate` stage on a tiny labeled .mat, 7-Scenes and Campus set with tiny saved depth models.

The ground truth is one constant depth per image (the fakes' 7-Scenes frames already are; the NYU
``depths`` and the Campus points are rewritten so), so a depth model whose decoder outputs a constant
disparity scores perfectly through the whole stage: checkpoint loading, the scaled disparity, both PP
settings, median scaling, and the metrics JSON.
"""

from __future__ import annotations

import csv
import importlib.util
import json
from pathlib import Path

import fakes
import h5py
import numpy as np
import pytest
import torch
import yaml

from f2depth.depth import DepthModel, DepthModelConfig, save_checkpoint
from f2depth.errors import DataError
from f2depth.eval.suite import GROUPS
from f2depth.params import ParamsError
from f2depth.protocols.metrics import METRIC_NAMES

ROOT = Path(__file__).resolve().parents[1]
NET_HW = (64, 96)


def load_stage():
    spec = importlib.util.spec_from_file_location("evaluate_stage", ROOT / "stages" / "evaluate.py")
    stage = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(stage)
    return stage


def write_model(path: Path, seed: int, constant: bool = False, params: dict | None = None) -> None:
    torch.manual_seed(seed)
    model = DepthModel(DepthModelConfig(*NET_HW))
    if constant:  # sigmoid(0.3) everywhere: a constant depth map
        with torch.no_grad():
            model.depth_decoder.dispconv.weight.zero_()
            model.depth_decoder.dispconv.bias.fill_(0.3)
    save_checkpoint(path, model, params=params)


@pytest.fixture
def tree(tmp_path, monkeypatch):
    monkeypatch.setenv("F2DEPTH_MLFLOW", "0")
    torch.set_num_threads(1)
    mat, splits = tmp_path / "nyu" / "labeled.mat", tmp_path / "nyu" / "splits.mat"
    fakes.write_labeled_mat(mat, ["bedroom_0001", "office_0002", "kitchen_0003", "office_0004"])
    with h5py.File(mat, "r+") as f:  # one constant depth per image (h5py axes: N, 640, 480)
        const = np.array([1.5, 2.0, 3.0, 4.5], np.float32)[:, None, None]
        f["depths"][...] = np.broadcast_to(const, f["depths"].shape).copy()  # whole array: fast in h5py
    fakes.write_splits(splits, [4], [1, 2, 3])
    fakes.write_sevenscenes(tmp_path / "7scenes", {"chess": ([1], [2]), "fire": ([2], [1])}, frames=2)
    rows = fakes.write_campus(tmp_path / "campus", {"1": 2, "2": 1}, points_per_image=3)
    for r in rows:  # one depth per image
        r[4] = 2.0 + 0.5 * int(r[1][-1])
    fakes.write_points_csv(tmp_path / "campus" / "points.csv", rows)
    params = {
        "device": "cpu",
        "threads": 1,
        "data": {"nyu_labeled": str(mat), "nyu_splits": str(splits), "sevenscenes": str(tmp_path / "7scenes"),
                 "campus": str(tmp_path / "campus")},
        "train_depth": {"seeds": [0, 1]},
        "variants": {"full": {"flow": None, "without": ["rigid", "feature"]}},
        "evaluate": {"nyu_gt": "depths", "nyu_crop": "eigen", "sevenscenes_stride": 1,
                     "datasets": ["nyu", "sevenscenes", "campus"], "height": None, "width": None,
                     "interpolation": "area", "upsample": "nearest", "decoder_upsample": "bilinear",
                     "batch_size": 2, "max_images": None,
                     "timing_height": 64, "timing_width": 64, "timing_repeats": 2,
                     "timing_warmup": 1, "figure_images": 2, "figure_width": 80},
    }  # fmt: skip
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params))
    return tmp_path


def run(root: Path, variant: str = "full") -> dict:
    load_stage().main(["evaluate.py", "--variant", variant, "--params", str(root / "params.yaml"),
                       "--models", str(root / "models"), "--metrics", str(root / "metrics"),
                       "--reports", str(root / "reports")])
    return json.loads((root / "metrics" / f"{variant}.json").read_text())


def test_stage_writes_metrics_per_seed_and_reports(tree):
    for seed in (0, 1):
        write_model(tree / "models" / "depth_full" / f"seed{seed}.pt", seed)
    m = run(tree)
    assert m["n_seeds"] == 2 and list(m["per_seed"]) == ["seed0", "seed1"] and m["variant"] == "full"
    for group in GROUPS:
        assert set(m[group]) == set(METRIC_NAMES)
        for name in METRIC_NAMES:
            per = [m["per_seed"][s][group][name] for s in ("seed0", "seed1")]
            assert m[group][name] == pytest.approx(np.mean(per)), (group, name)
        assert 0.0 <= m[group]["a1"] <= m[group]["a2"] <= m[group]["a3"] <= 1.0
    assert m["ms"] > 0 and m["ms_pp"] > 0
    # two different random models give different numbers
    assert m["per_seed"]["seed0"]["nyu"]["abs_rel"] != m["per_seed"]["seed1"]["nyu"]["abs_rel"]

    out = tree / "reports" / "full"
    details = json.loads((out / "details.json").read_text())
    assert details["test_set_sizes"] == {"nyu": 3, "sevenscenes": 4, "campus": 3}
    s0 = details["seeds"]["seed0"]
    assert s0["input_hw"] == list(NET_HW) and s0["timing"]["ms"]["height"] == 64
    assert list(s0["sevenscenes_pp"]["scenes"]) == ["chess", "fire"]
    assert list(s0["campus"]["scenes"]) == ["1", "2"]
    with (out / "nyu.csv").open() as fh:
        nyu_rows = list(csv.DictReader(fh))
    assert len(nyu_rows) == 3 * 2 * 2  # images × PP × seeds
    pairs = {(r["seed"], r["post_process"]) for r in nyu_rows}
    assert pairs == {(s, p) for s in "01" for p in ("False", "True")}
    assert {r["index"] for r in nyu_rows} == {"1", "2", "3"}
    with (out / "sevenscenes.csv").open() as fh:
        assert len(list(csv.DictReader(fh))) == 4 * 2 * 2
    with np.load(out / "figures.npz") as z:
        assert z["nyu_id"].tolist() == ["1", "3"] and z["nyu_pred"].shape == z["nyu_gt"].shape
        assert z["nyu_rgb"].shape[2] == 80
        assert z["sevenscenes_id"].tolist() == ["chess/seq-01/1", "fire/seq-02/1"]


def test_constant_model_on_constant_depth_is_perfect_through_the_stage(tree):
    write_model(tree / "models" / "depth_full" / "seed0.pt", 0, constant=True)
    params = yaml.safe_load((tree / "params.yaml").read_text())
    params["train_depth"]["seeds"] = [0]
    params["evaluate"]["figure_images"] = 0
    (tree / "params.yaml").write_text(yaml.safe_dump(params))
    m = run(tree)
    for group in GROUPS:
        assert m[group]["abs_rel"] == pytest.approx(0.0, abs=1e-6), group
        assert m[group]["rmse"] == pytest.approx(0.0, abs=1e-5), group
        assert m[group]["a1"] == 1.0, group
    with np.load(tree / "reports" / "full" / "figures.npz") as z:
        assert z.files == []


def test_decoder_upsample_is_applied_and_recorded_with_the_training_weights(tree):
    """evaluate.decoder_upsample rebuilds the decoder (bilinear ×2 upsampling, as P²Net's NYU evaluation)
    and the metrics record it with the loss weights the checkpoint was trained with (Table 5's marks)."""
    weights = {"smooth": 0.001, "planar": 0.05, "rigid": 1.0, "feature": 0.0}
    write_model(tree / "models" / "depth_full" / "seed0.pt", 0,
                params={"weights": weights, "flow_model": "models/flow_patch.pt", "epochs": 2})
    params = yaml.safe_load((tree / "params.yaml").read_text())
    params["train_depth"]["seeds"] = [0]
    params["evaluate"]["datasets"] = ["nyu"]
    docs = {}
    for mode in ("nearest", "bilinear"):
        params["evaluate"]["decoder_upsample"] = mode
        (tree / "params.yaml").write_text(yaml.safe_dump(params))
        docs[mode] = run(tree)
        assert docs[mode]["decoder_upsample"] == mode
        assert docs[mode]["trained_with"] == {"flow_model": "models/flow_patch.pt", "weights": weights}
        details = json.loads((tree / "reports" / "full" / "details.json").read_text())
        assert details["settings"]["decoder_upsample"] == mode
    assert docs["nearest"]["nyu"]["abs_rel"] != pytest.approx(docs["bilinear"]["nyu"]["abs_rel"], rel=1e-6)
    params["evaluate"]["decoder_upsample"] = "cubic"
    (tree / "params.yaml").write_text(yaml.safe_dump(params))
    with pytest.raises(ValueError, match="evaluate.decoder_upsample is 'cubic'"):
        run(tree)


def test_absent_test_sets_are_skipped_with_one_line_and_the_rest_scored(tree):
    """Issue 23 item 4: your own video without Campus or 7-Scenes copies still evaluates on what is set."""
    for seed in (0, 1):
        write_model(tree / "models" / "depth_full" / f"seed{seed}.pt", seed)
    params = yaml.safe_load((tree / "params.yaml").read_text())
    params["data"]["campus"] = None
    params["data"]["sevenscenes"] = str(tree / "no_such_folder")
    (tree / "params.yaml").write_text(yaml.safe_dump(params))
    with pytest.warns(UserWarning) as seen:
        doc = run(tree)
    lines = [str(w.message) for w in seen if "skipping" in str(w.message)]
    assert len(lines) == 2 and all("\n" not in line for line in lines)
    assert "skipping test set sevenscenes: data.sevenscenes is" in lines[0] and "no_such_folder" in lines[0]
    assert "skipping test set campus: data.campus is None" in lines[1]
    assert {"nyu", "nyu_pp"} <= set(doc) and not {"campus", "sevenscenes"} & set(doc)
    assert doc["nyu"]["abs_rel"] > 0
    params["data"]["nyu_labeled"] = None
    (tree / "params.yaml").write_text(yaml.safe_dump(params))
    with pytest.warns(UserWarning), pytest.raises(ParamsError, match="none of evaluate.datasets"):
        run(tree)


def test_missing_seed_model_names_the_file_and_the_fix(tree):
    write_model(tree / "models" / "depth_full" / "seed0.pt", 0)
    fix = r"depth_full/seed1\.pt: not found; run `dvc repro train_depth@full`"
    with pytest.raises(DataError, match=fix):  # run_stage turns it into one line
        run(tree)


def test_a_depth_model_that_does_not_fit_ends_the_stage_with_one_line(tree, capsys):
    from f2depth.stage import run_stage

    write_model(tree / "models" / "depth_full" / "seed0.pt", 0)
    bad = tree / "models" / "depth_full" / "seed1.pt"  # a wider first convolution than DepthCNN's
    model = DepthModel(DepthModelConfig(*NET_HW))
    state = {**model.state_dict(), "depth_encoder.conv1.weight": torch.zeros(64, 4, 7, 7)}
    torch.save({**torch.load(tree / "models" / "depth_full" / "seed0.pt", weights_only=True),
                "state_dict": state}, bad)
    argv = ["evaluate.py", "--variant", "full", "--params", str(tree / "params.yaml"), "--models",
            str(tree / "models"), "--metrics", str(tree / "metrics"), "--reports", str(tree / "reports")]
    with pytest.raises(SystemExit) as exit_:
        run_stage("evaluate", load_stage().main, argv)
    assert exit_.value.code == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert err.startswith(f"evaluate: {bad}: state_dict does not fit DepthModel(") and "retrain" in err, err
    assert not (tree / "metrics" / "full.json").exists()  # nothing written that looks valid


def test_unknown_variant(tree):
    with pytest.raises(ValueError, match="no variant 'nope' under `variants`"):
        run(tree, "nope")


def test_repository_dvc_stage_tracks_what_the_stage_reads():
    stage = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]["evaluate"]
    assert stage["foreach"] == "${variants}"
    do = stage["do"]
    assert "--variant ${key}" in do["cmd"] and "models/depth_${key}" in do["deps"]
    for dep in ("${data.nyu_labeled}", "${data.nyu_splits}", "${data.sevenscenes}", "${data.campus}",
                "f2depth/eval/", "stages/evaluate.py"):
        assert dep in do["deps"], dep
    assert {"evaluate", "device", "train_depth.seeds"} <= set(do["params"])
    assert "metrics" not in do  # a plain output: metrics/tables.json is the declared summary
    assert do["outs"] == ["reports/eval/${key}", {"metrics/evaluate/${key}.json": {"cache": False}}]
    params = yaml.safe_load((ROOT / "params.yaml").read_text())["evaluate"]
    assert {"nyu_gt", "nyu_crop", "sevenscenes_stride", "timing_repeats", "datasets"} <= set(params)
