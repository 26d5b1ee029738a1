"""Tests for the train_depth stage: variant settings from params.yaml and an end-to-end tiny run."""

from __future__ import annotations

import csv
import importlib.util
import json
from pathlib import Path

import pytest
import torch
import train_fakes
import yaml

from f2depth import params as P
from f2depth.depth import load_checkpoint, read_checkpoint
from f2depth.errors import DataError
from f2depth.io import OUTPUT_MARKER
from f2depth.train.settings import settings_from_params
from f2depth.train.step import TERMS, WEIGHT_KEYS

STAGE = Path(__file__).resolve().parents[1] / "stages" / "train_depth.py"


def load_stage(monkeypatch):
    """The train_depth stage script as a module, without MLflow, on one thread."""
    monkeypatch.setenv("F2DEPTH_MLFLOW", "0")
    torch.set_num_threads(1)
    spec = importlib.util.spec_from_file_location("train_depth_stage", STAGE)
    stage = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(stage)
    return stage


@pytest.fixture
def setup(tmp_path):
    prep = train_fakes.write_prepared(tmp_path / "prepared", hw=(64, 64), scenes=1, frames=6)
    mat, splits = train_fakes.write_nyu_test(tmp_path, n=3)
    flow = train_fakes.write_flow_model(tmp_path / "flow.pt")
    return tmp_path, train_fakes.write_params(tmp_path, prep, mat, splits, flow, epochs=1, seeds=[3, 1])


def test_variant_weights_are_loss_weights_with_the_terms_it_is_without_at_zero(setup):
    _, path = setup
    p = P.load(path)
    full, nof, base = (settings_from_params(p, v) for v in ("full", "no_feature", "baseline"))
    assert full.weights == train_fakes.WEIGHTS and full.weights["feature"] > 0
    assert list(full.weights) == list(TERMS)  # every term of L_depth by name, flow_smooth is none
    assert nof.weights == {**full.weights, "feature": 0.0} and nof.without == ("feature",)
    assert base.weights == {**full.weights, "rigid": 0.0, "feature": 0.0} and base.flow_model is None
    assert full.flow_model.endswith("flow.pt") and full.without == () and full.seeds == (3, 1)
    p["lambda3"] = 0.5  # what `dvc exp run -S lambda3=0.5` changes
    assert settings_from_params(p, "full").weights["feature"] == 0.5
    assert settings_from_params(p, "no_feature").weights["feature"] == 0.0  # its switched-off term stays off
    p["lambda1"] = 0.01
    assert settings_from_params(p, "baseline").weights == {**base.weights, "smooth": 0.01}


@pytest.mark.parametrize("variant, edit, expected", [
    ("full", lambda p: p["variants"].pop("full"),
     "unknown variant 'full'; variants: ['baseline', 'no_feature']"),
    ("full", lambda p: p["variants"]["full"].update(without=["featur"]),
     "variants.full.without: unknown terms ['featur']; 'featur': did you mean feature?"),
    ("full", lambda p: p["variants"]["full"].update(without=["flow_smooth"]),
     "variants.full.without: unknown terms ['flow_smooth']; 'flow_smooth': did you mean smooth?"),
    ("baseline", lambda p: p["variants"]["baseline"].update(without=["feature"]),
     "variants.baseline has no flow network (flow: null) but leaves rigid on; add it to "
     "variants.baseline.without or give it a flow model"),
    ("full", lambda p: p["variants"]["full"].update(flow=None),
     "variants.full has no flow network (flow: null) but leaves rigid, feature on; add them to"),
    ("full", lambda p: p["variants"]["full"].update(flow_model="models/x.pt"),
     "variants.full: unknown keys ['flow_model']; known: flow, without"),
    ("full", lambda p: p["variants"]["full"].pop("without"), "missing parameter 'variants.full.without'"),
    ("baseline", lambda p: p.pop("lambda2"), "missing parameter 'lambda2'"),
    ("baseline", lambda p: p.update(lambda_rigid=-1),
     "lambda_rigid is -1.0; set it to a value >= 0"),  # checked even where the term is off
])  # fmt: skip
def test_variant_errors_are_one_line_naming_the_key(setup, variant, edit, expected):
    _, path = setup
    p = P.load(path)
    edit(p)
    with pytest.raises(P.ParamsError) as info:
        settings_from_params(p, variant)
    assert str(info.value).startswith(f"{path}: {expected}") and "\n" not in str(info.value)


def test_stage_trains_every_seed_and_writes_outputs(setup, monkeypatch):
    root, path = setup
    stage = load_stage(monkeypatch)
    stage.main(["train_depth.py", "--variant", "full", "--params", str(path),
                "--models", str(root / "models"), "--metrics", str(root / "metrics")])
    out = root / "models" / "depth_full"
    assert sorted(f.name for f in out.iterdir()) == [OUTPUT_MARKER, "model.pt", "seed1.pt", "seed3.pt"]
    assert (out / "model.pt").read_bytes() == (out / "seed3.pt").read_bytes()  # the first listed seed
    ck = read_checkpoint(out / "seed1.pt")
    assert ck["seed"] == 1 and ck["variant"] == "full"
    assert ck["params"]["weights"]["feature"] == train_fakes.WEIGHTS["feature"] > 0
    model = load_checkpoint(out / "model.pt")
    assert model.config.height == 64
    m = json.loads((root / "metrics" / "full.json").read_text())
    assert m["seeds"] == [3, 1] and m["main_seed"] == 3 and [s["seed"] for s in m["per_seed"]] == [3, 1]
    assert m["train_tuples"] == 4 and m["steps_per_epoch"] == 2 and m["flow_model"].endswith("flow.pt")
    assert set(m["final_losses"]) == {"ph", *TERMS, "total"}
    assert m["weights"] == train_fakes.WEIGHTS and m["without"] == []  # the effective weights, per term
    assert 0.0 <= m["val_untrained"]["a1"] <= 1.0 and 0.0 <= m["val_trained"]["a1"] <= 1.0
    with (root / "metrics" / "full" / "history.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [r["epoch"] for r in rows] == ["1"] and float(rows[0]["ph"]) > 0  # the training epochs
    with (root / "metrics" / "full" / "validation.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert [r["epoch"] for r in rows] == ["0", "1"]  # the measured epochs: untrained and trained
    assert all(r[k] != "" for r in rows for k in ("val_a1", "val_abs_rel", "train_a1", "pose_rot_err"))
    assert not list((root / "ckpt" / "full").glob("*.pt"))  # resume states removed after success


def test_a_failed_run_keeps_the_previous_models_and_a_new_one_replaces_them(setup, monkeypatch):
    root, path = setup
    stage = load_stage(monkeypatch)
    argv = ["train_depth.py", "--variant", "baseline", "--params", str(path),
            "--models", str(root / "models"), "--metrics", str(root / "metrics")]
    stage.main(argv)
    out = root / "models" / "depth_baseline"
    before = {f.name: f.read_bytes() for f in out.iterdir()}
    assert sorted(before) == [OUTPUT_MARKER, "model.pt", "seed1.pt", "seed3.pt"]

    import f2depth.train.run as run_module
    real_fit, calls = run_module.fit, []

    def fit_that_dies_on_the_second_seed(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt  # the user stops the run during seed 1
        return real_fit(*args, **kwargs)

    monkeypatch.setattr(run_module, "fit", fit_that_dies_on_the_second_seed)
    with pytest.raises(KeyboardInterrupt):
        stage.main(argv)
    assert {f.name: f.read_bytes() for f in out.iterdir()} == before  # seed 3 was retrained, not swapped in
    assert sorted(p.name for p in out.parent.iterdir()) == ["depth_baseline"]  # no temporary folder left

    monkeypatch.setattr(run_module, "fit", real_fit)
    params = yaml.safe_load(path.read_text())
    params["train_depth"]["seeds"] = [3]
    path.write_text(yaml.safe_dump(params))
    stage.main(argv)
    assert sorted(f.name for f in out.iterdir()) == [OUTPUT_MARKER, "model.pt", "seed3.pt"]  # stale seed gone


def test_init_depth_setting(setup):
    _, path = setup
    p = P.load(path)
    assert settings_from_params(p, "full").init_depth is None  # P²Net's start unless asked
    p["train_depth"]["init_depth"] = 2
    assert settings_from_params(p, "baseline").init_depth == 2.0
    for bad in (10.0, 0.1, -1, "2 m", True):
        p["train_depth"]["init_depth"] = bad
        with pytest.raises(P.ParamsError, match="train_depth.init_depth must be null or a depth in metres"):
            settings_from_params(p, "full")


def test_stage_starts_the_depth_at_init_depth(tmp_path, monkeypatch):
    """With a negligible lr the trained model is the initial one: its depth is the requested 2 m, not the
    ≈ 0.2 m of P²Net's start."""
    prep = train_fakes.write_prepared(tmp_path / "prepared", hw=(64, 64), scenes=1, frames=4)
    mat, splits = train_fakes.write_nyu_test(tmp_path, n=2)
    stage = load_stage(monkeypatch)
    img = torch.rand(1, 3, 64, 64, generator=torch.Generator().manual_seed(0))
    medians = {}
    for init in (None, 2.0):
        (tmp_path / f"run_{init}").mkdir()
        path = train_fakes.write_params(tmp_path / f"run_{init}", prep, mat, splits, None, epochs=1,
                                        lr=[1e-12, 1e-12, 1e-12], init_depth=init, diagnostic_tuples=0)
        out = tmp_path / f"run_{init}"
        stage.main(["train_depth.py", "--variant", "baseline", "--params", str(path),
                    "--models", str(out / "models"), "--metrics", str(out / "metrics")])
        with torch.no_grad():
            model = load_checkpoint(out / "models" / "depth_baseline" / "model.pt").eval()
            medians[init] = model.predict_depth(img).median().item()
    assert medians[None] == pytest.approx(0.2, rel=0.1)
    assert medians[2.0] == pytest.approx(2.0, rel=0.1)


def test_repository_variants_are_consistent_with_dvc_yaml():
    """The variants of the repository's params.yaml resolve to the paper's ablations (Tables 5, 6), and
    dvc.yaml's train_depth stage iterates over the same names, each tracking the flow model the variant
    uses (the stage script where it has none)."""
    root = STAGE.parents[1]
    p = P.load(root / "params.yaml")
    expected = {"full": (), "no_feature": ("feature",), "baseline": ("rigid", "feature"),
                "flow_pretrained": (), "flow_full_ft": ()}
    assert list(p["variants"]) == list(expected)
    for name, without in expected.items():
        s = settings_from_params(p, name)
        assert s.without == without, name
        assert s.weights == {t: 0.0 if t in without else p[WEIGHT_KEYS[t]] for t in TERMS}, name
        assert (s.flow_model is None) == (name == "baseline"), name
    stage = yaml.safe_load((root / "dvc.yaml").read_text())["stages"]["train_depth"]
    tracked = {name: v["flow"] or "stages/train_depth.py" for name, v in p["variants"].items()}
    assert {name: item["flow"] for name, item in stage["foreach"].items()} == tracked
    assert "--variant ${key}" in stage["do"]["cmd"] and "${item.flow}" in stage["do"]["deps"]
    assert "variants.${key}" in stage["do"]["params"]  # its loss weights: tests/test_dvc_deps.py


def test_an_unwritable_metrics_folder_ends_the_stage_before_any_training(setup, monkeypatch):
    """Before: the stage trained, replaced the models, deleted the resume state and then crashed on the
    metrics folder, so a re-run retrained from scratch. Now every output location is probed first."""
    import f2depth.formats.writable as writable
    import f2depth.train.run as run_module

    root, path = setup
    stage = load_stage(monkeypatch)
    locked = root / "locked"
    real_mkstemp = writable.tempfile.mkstemp

    def refuse(*args, dir=None, **kwargs):  # what mkstemp does in a folder without write permission
        if Path(dir) == locked:
            raise PermissionError(13, "Permission denied", str(Path(dir) / ".f2depth-write-test.x"))
        return real_mkstemp(*args, dir=dir, **kwargs)

    def fit_must_not_run(*args, **kwargs):
        raise AssertionError("training started before the output locations were checked")

    monkeypatch.setattr(writable.tempfile, "mkstemp", refuse)
    monkeypatch.setattr(run_module, "fit", fit_must_not_run)
    with pytest.raises(DataError,
                       match=r"locked: output folder is not writable .*give --metrics a folder"):
        stage.main(["train_depth.py", "--variant", "baseline", "--params", str(path),
                    "--models", str(root / "models"), "--metrics", str(locked)])
    assert not (root / "models" / "depth_baseline").exists()
