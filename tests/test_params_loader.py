"""The one way from params.yaml to a config (f2depth.params.section / value): typed, range-checked reads
that name file:key, strict booleans, unknown keys rejected with a did-you-mean, no defaults outside
params.yaml; every migrated stage builds its config from params.yaml and from each profile, and a bad
value ends a stage with one line."""

from __future__ import annotations

import copy
import importlib.util
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import pytest
import yaml

from f2depth import params as P
from f2depth import profile
from f2depth.train.settings import settings_from_params
from f2depth.train.step import TERMS, WEIGHT_KEYS

ROOT = Path(__file__).resolve().parents[1]
STAGES = ("synth", "poses", "keypoints", "prepare", "flow_pretrain", "flow_finetune", "flow_figure",
          "evaluate")


@dataclass(frozen=True)
class Inner:
    count: int = field(metadata={"min": 1, "multiple_of": 2})
    scale: float | None


@dataclass(frozen=True)
class Section:
    epochs: int = field(metadata={"min": 1})
    lr: float = field(metadata={"gt": 0})
    augment: bool
    mode: Literal["a", "b"]
    weights: tuple[float, ...]
    size: tuple[int, int]
    path: str | None
    inner: Inner
    init_depth: float | None = None  # a library default: the loader still wants the key
    decay: float = field(default=0.5, metadata={"fixed": True})

    def __post_init__(self) -> None:
        if self.size[0] > self.size[1]:
            raise ValueError(f"size is {list(self.size)}; give [small, large]")


def good() -> dict:
    return {"_file": "p.yaml", "weight": 3.0, "device": "cpu",
            "s": {"epochs": 2, "lr": 1.0e-4, "augment": False, "mode": "b", "weights": [1, 0.5],
                  "size": [2, 3], "path": None, "inner": {"count": 4, "scale": 2}, "init_depth": None}}


def error(params: dict, key: str = "s", cls: type = Section) -> str:
    with pytest.raises(P.ParamsError) as info:
        P.section(params, key, cls)
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith("p.yaml: ")
    return msg


def test_section_coerces_every_kind_of_field():
    cfg = P.section(good(), "s", Section)
    assert cfg == Section(epochs=2, lr=1e-4, augment=False, mode="b", weights=(1.0, 0.5), size=(2, 3),
                          path=None, inner=Inner(count=4, scale=2.0), init_depth=None)
    assert isinstance(cfg.weights[0], float) and isinstance(cfg.inner.scale, float) and cfg.decay == 0.5
    p = good()
    p["s"]["lr"] = "1e-4"  # YAML 1.1 reads a float without a dot as a string
    assert P.section(p, "s", Section).lr == 1e-4


@pytest.mark.parametrize("key, bad, expected", [
    ("epochs", "abc", "p.yaml: s.epochs is 'abc'; set it to an integer"),
    ("epochs", 2.5, "p.yaml: s.epochs is 2.5; set it to an integer"),
    ("epochs", 0, "p.yaml: s.epochs is 0; set it to a value >= 1"),
    ("lr", "abc", "p.yaml: s.lr is 'abc'; set it to a finite number"),
    ("lr", 0, "p.yaml: s.lr is 0.0; set it to a value > 0"),
    ("augment", "false", "p.yaml: s.augment is 'false'; set it to true or false (YAML booleans, without "
                         "quotes)"),
    ("augment", 1, "p.yaml: s.augment is 1; set it to true or false"),
    ("mode", "c", "p.yaml: s.mode is 'c'; set it to one of a, b"),
    ("weights", 1.0, "p.yaml: s.weights is 1.0; set it to a list [...]"),
    ("size", [1, 2, 3], "p.yaml: s.size is [1, 2, 3]; set it to a list of 2 values"),
    ("size", [3, 2], "p.yaml: s.size is [3, 2]; give [small, large]"),
    ("path", 3, "p.yaml: s.path is 3; set it to a string"),
    ("inner", {"count": 3, "scale": None}, "p.yaml: s.inner.count is 3; set it to a multiple of 2"),
    ("inner", {"count": 2}, "p.yaml: missing parameter 's.inner.scale'; add it to p.yaml"),
    ("inner", 5, "p.yaml: s.inner: expected a section of keys, got 5"),
])  # fmt: skip
def test_a_bad_value_is_one_line_naming_file_key_and_fix(key, bad, expected):
    p = good()
    p["s"][key] = bad
    assert error(p) == expected


def test_unknown_and_missing_keys():
    p = good()
    p["s"]["init_dpeth"] = 2.0
    assert error(p) == "p.yaml: s: unknown keys ['init_dpeth']; s.init_dpeth: did you mean init_depth?"
    p = good()
    p["s"]["zzz"] = 1
    assert error(p).startswith("p.yaml: s: unknown keys ['zzz']; known: augment, epochs, init_depth, inner,")
    p = good()
    del p["s"]["init_depth"]  # a dataclass default does not stand in for params.yaml
    assert error(p) == "p.yaml: missing parameter 's.init_depth'; add it to p.yaml"
    p["s"]["decay"] = 0.1  # a fixed constant of the method is no parameter
    assert "unknown keys ['decay']" in error(p)
    assert error(good(), "t") == "p.yaml: missing parameter 't'"


def test_a_given_field_is_no_key_of_the_section():
    """Values resolved elsewhere (``given``) are fields of the dataclass, not keys the section may hold."""
    p = good()
    del p["s"]["path"]
    assert P.section(p, "s", Section, path="x").path == "x"
    p["s"]["path"] = "y"
    with pytest.raises(P.ParamsError, match=r"^p.yaml: s: unknown keys \['path'\]"):
        P.section(p, "s", Section, path="x")


def test_reject_unknown_names_keys_or_entries_with_a_hint():
    P.reject_unknown("p.yaml", "w", {"smooth": 1}, ("smooth", "planar"))
    with pytest.raises(P.ParamsError) as info:
        P.reject_unknown("p.yaml", "w", {"smoth": 1, "zzz": 2}, ("smooth", "planar"))
    assert str(info.value) == "p.yaml: w: unknown keys ['smoth', 'zzz']; w.smoth: did you mean smooth?"
    with pytest.raises(P.ParamsError) as info:
        P.reject_unknown("p.yaml", "v.without", ["zzz"], ("smooth", "planar"), what="terms")
    assert str(info.value) == "p.yaml: v.without: unknown terms ['zzz']; known: planar, smooth"


def test_value_and_device():
    assert P.value(good(), "weight", float, min=0) == 3.0
    for bad, expected in (("abc", "p.yaml: weight is 'abc'; set it to a finite number"),
                          (-1, "p.yaml: weight is -1.0; set it to a value >= 0")):
        with pytest.raises(P.ParamsError) as info:
            P.value({**good(), "weight": bad}, "weight", float, min=0)
        assert str(info.value) == expected
    assert P.device(good()) == "cpu"
    for bad in ("foo", "cuda:x", "gpu"):
        with pytest.raises(P.ParamsError) as info:
            P.device({**good(), "device": bad})
        assert str(info.value) == f"p.yaml: device is '{bad}'; set it to auto, cpu, cuda, cuda:N or mps"


def load_stage(name: str):
    spec = importlib.util.spec_from_file_location(f"{name}_stage", ROOT / "stages" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def configs(params: dict) -> dict:
    out = {name: load_stage(name).config_from_params(params) for name in STAGES if name != "flow_finetune"}
    stage = load_stage("flow_finetune")
    out |= {f"flow_finetune_{loss}": stage.config_from_params(params, loss) for loss in ("patch", "full")}
    return out


@pytest.mark.parametrize("name", [None, *profile.load_profiles(ROOT / "configs" / "profiles.yaml")])
def test_every_migrated_stage_builds_its_config_from_params_and_each_profile(tmp_path, name):
    path = tmp_path / "params.yaml"
    shutil.copy(ROOT / "params.yaml", path)
    if name:
        profile.apply(name, path, ROOT / "configs" / "profiles.yaml")
    params = P.load(path)
    cfg = configs(params)
    assert cfg["prepare"][0].height == params["prepare"]["height"]
    assert cfg["poses"].tracker.window == params["poses"]["tracker"]["window"]
    assert cfg["flow_pretrain"][0].lr == params["flow_pretrain"]["lr"]
    finetune = cfg["flow_finetune_patch"][0]
    assert finetune.epochs == params["flow_finetune"]["epochs"] and finetune.loss == "patch"
    assert finetune.w_scales == tuple(params["flow_finetune"]["w_scales"])
    assert finetune.smooth_weight == params["lambda_flow_smooth"]
    assert cfg["evaluate"][0].timing_repeats == params["evaluate"]["timing_repeats"]
    assert cfg["keypoints"].preset == params["keypoints"]["preset"]
    assert cfg["synth"].campus_hw == (params["synth"]["campus"]["height"], params["synth"]["campus"]["width"])
    params["allow_random_init"] = True  # the paper's weight files are checked in test_pretrained_starts
    for variant in params["variants"]:
        settings = settings_from_params(params, variant)
        assert settings.epochs == params["train_depth"]["epochs"]
        assert settings.lr == tuple(params["train_depth"]["lr"])
        assert settings.init_depth == params["train_depth"]["init_depth"]
        assert settings.weights == {term: 0.0 if term in params["variants"][variant]["without"]
                                    else params[WEIGHT_KEYS[term]] for term in TERMS}


@pytest.mark.parametrize("stage, dotted, bad, expected", [
    ("flow_finetune", "flow_finetune.augment", "false",
     "flow_finetune.augment is 'false'; set it to true or false"),
    ("poses", "poses.median_dpeth", 2.0,
     "poses: unknown keys ['median_dpeth']; poses.median_dpeth: did you mean median_depth?"),
    ("prepare", "prepare.height", 100, "prepare.height is 100; set it to a multiple of 32"),
    ("flow_finetune", "flow_finetune.w_scales", [0, 0], "FinetuneLossConfig.w_scales must be non-negative"),
    ("flow_pretrain", "flow_pretrain.source", "kitti", "flow_pretrain.source is 'kitti'; set it to one of"),
    ("keypoints", "keypoints.options", {"densty": 3}, "keypoints: unknown selector option(s) ['densty']"),
    ("evaluate", "evaluate.timing_repeats", 0, "evaluate.timing_repeats is 0; set it to a value >= 1"),
    ("flow_figure", "device", "foo", "device is 'foo'; set it to auto, cpu, cuda, cuda:N or mps"),
    ("synth", "synth.compress_gt", "false", "synth.compress_gt is 'false'; set it to true or false"),
    ("synth", "synth.sevenscenes.scenes", 8, "synth.sevenscenes.scenes is 8; set it to a value <= 7"),
    ("synth", "synth.nyu_labeled.test_fraction", 1.0, "synth.nyu_labeled.test_fraction must be < 1"),
])  # fmt: skip
def test_each_stage_config_rejects_a_bad_value(stage, dotted, bad, expected):
    params = P.load(ROOT / "params.yaml")
    node = params
    *parents, leaf = dotted.split(".")
    for part in parents:
        node = node[part]
    node[leaf] = copy.deepcopy(bad)
    module = load_stage(stage)
    with pytest.raises(P.ParamsError) as info:
        module.config_from_params(params) if stage != "flow_figure" else P.device(params)
    assert expected in str(info.value) and str(info.value).startswith(f"{ROOT / 'params.yaml'}: ")


def test_a_stage_given_a_bad_value_prints_one_line_and_touches_nothing(tmp_path):
    """prepare.height: 100 used to pass `prepare` and `keypoints` and fail only in training."""
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    params["prepare"]["height"] = 100
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params))
    run = subprocess.run([sys.executable, str(ROOT / "stages" / "prepare.py"), "params.yaml"], cwd=tmp_path,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 1
    assert run.stderr == "prepare: params.yaml: prepare.height is 100; set it to a multiple of 32\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["params.yaml"]


@pytest.mark.parametrize("dotted, bad, expected", [
    ("lambda3", "abc", "params.yaml: lambda3 is 'abc'; set it to a finite number"),
    ("lambda3", -1, "params.yaml: lambda3 is -1.0; set it to a value >= 0"),
    ("lambda1", None, "params.yaml: lambda1 is None; set it to a finite number"),
    ("variants.full.without", ["featur"], "params.yaml: variants.full.without: unknown terms ['featur']"),
    ("train_depth.epochs", 0, "params.yaml: train_depth.epochs is 0; set it to a value >= 1"),
    ("train_depth.augment", "false", "params.yaml: train_depth.augment is 'false'; set it to true or false"),
    ("train_depth.init_dpeth", 2.0, "params.yaml: train_depth: unknown keys ['init_dpeth']; "
                                    "train_depth.init_dpeth: did you mean init_depth?"),
    ("train_depth.seeds", [0, 0], "params.yaml: train_depth.seeds must be a non-empty list of distinct"),
    ("device", "foo", "params.yaml: device is 'foo'; set it to auto, cpu, cuda, cuda:N or mps"),
])  # fmt: skip
def test_train_depth_settings_reject_bad_values(dotted, bad, expected):
    """The failures of params.yaml without a schema: a bare ValueError for a loss weight "abc", a weight of -1
    and epochs: 0 accepted, augment: "false" counted as true, a typo in an optional key silently ignored."""
    params = P.load(ROOT / "params.yaml")
    params["_file"] = "params.yaml"
    node = params
    *parents, leaf = dotted.split(".")
    for part in parents:
        node = node[part]
    node[leaf] = bad
    with pytest.raises(P.ParamsError) as info:
        settings_from_params(params, "full")
    assert str(info.value).startswith(expected) and "\n" not in str(info.value)


def test_a_key_given_twice_is_refused_with_its_lines(tmp_path):
    """Issue 25 item 9. Before: `train_depth.epochs` twice was refused by DVC but silently last-wins in the
    stage scripts and torchrun. Now the loader names the key and both lines."""
    path = tmp_path / "params.yaml"
    path.write_text("seed: 0\ntrain_depth:\n  epochs: 25\n  batch_size: 4\n  epochs: 3\n"
                    "other:\n  epochs: 1\n")
    with pytest.raises(P.ParamsError, match=rf"^{path}: key 'epochs' is given twice, on lines 3 and 5 "):
        P.load(path)
    path.write_text("base: &b {epochs: 1, lr: 2}\ntrain: {<<: *b, epochs: 3}\n")  # overriding a merge is fine
    assert P.load(path)["train"] == {"epochs": 3, "lr": 2}


def test_a_file_that_is_not_yaml_is_one_line_with_its_line(tmp_path):
    path = tmp_path / "params.yaml"
    path.write_text("seed: 0\ntrain_depth:\n  epochs: [1, 2\n  lr: 3\n")
    with pytest.raises(P.ParamsError, match=rf"^{path}: line \d+ is not valid YAML \(.+\); fix the file$"):
        P.load(path)


def test_params_and_the_cli_share_one_device_grammar():
    import argparse

    import torch

    from f2depth.cli import _device

    missing = f"cuda:{torch.cuda.device_count()}"  # never on this machine: no CUDA, or one index too far
    for name in ("auto", "cpu", "mps", "cuda", missing, "gpu", "cuda:x"):
        problem = P.device_problem(name)
        try:
            cli_problem = None if _device(name) == name else "changed"
        except argparse.ArgumentTypeError as exc:
            cli_problem = str(exc)
        assert cli_problem == problem, name
        if problem is None:
            assert P.device({**good(), "device": name}) in ("cpu", "cuda", name)
        else:
            with pytest.raises(P.ParamsError) as info:
                P.device({**good(), "device": name})
            assert str(info.value).startswith("p.yaml: ") and ("device is" in str(info.value)
                                                               or str(info.value).endswith(problem))
    assert P.device_problem("gpu") == "unknown device 'gpu': use auto, cpu, cuda, cuda:N or mps"
    assert P.device_problem(missing) is not None and missing in P.device_problem(missing)
    assert P.device_problem("cpu") is None
