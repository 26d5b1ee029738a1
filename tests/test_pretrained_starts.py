"""The paper's pretrained starts (ImageNet ResNet-18s, ARFlow's Sintel PWC-Lite) are required under the
`paper` profile: every training stage stops at once, in one line, naming the key, the file expected and
the opt-out; with `allow_random_init: true` it trains from random weights and says so."""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import train_fakes
import yaml

from f2depth import params as P
from f2depth import profile
from f2depth.train.settings import settings_from_params

ROOT = Path(__file__).resolve().parents[1]


def _params(tmp_path: Path, **top) -> dict:
    p = {"_file": str(tmp_path / "params.yaml"), "allow_random_init": False,
         "train_depth": {"imagenet_weights": None}, "flow_pretrain": {"checkpoint": None}}
    p.update(top)
    return p


def test_required_starts_name_the_key_the_file_and_the_opt_out(tmp_path):
    keys = ("train_depth.imagenet_weights", "flow_pretrain.checkpoint")
    p = _params(tmp_path)
    with pytest.raises(P.ParamsError) as info:
        P.pretrained_starts(p, keys)
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith(f"{tmp_path / 'params.yaml'}: train_depth.imagenet_weights")
    assert "torchvision resnet18 ImageNet state_dict" in msg and "allow_random_init: true" in msg
    resnet = tmp_path / "resnet18.pth"
    resnet.write_bytes(b"weights")
    p["train_depth"]["imagenet_weights"] = str(resnet)
    with pytest.raises(P.ParamsError, match=r"flow_pretrain.checkpoint is not set; .*Sintel/pwclite_ar\.tar "
                                            r"\(pwclite_ar_mv is a 3-frame model"):
        P.pretrained_starts(p, keys)
    p["flow_pretrain"]["checkpoint"] = str(tmp_path / "missing.tar")
    with pytest.raises(P.ParamsError, match=r"flow_pretrain.checkpoint = .*missing\.tar: file not found"):
        P.pretrained_starts(p, keys)
    (tmp_path / "missing.tar").write_bytes(b"arflow")
    assert P.pretrained_starts(p, keys) == {keys[0]: str(resnet), keys[1]: str(tmp_path / "missing.tar")}
    # the CPU default: unset means random, a set key must still exist
    p = _params(tmp_path, allow_random_init=True)
    assert P.pretrained_starts(p, keys) == dict.fromkeys(keys)
    p["flow_pretrain"]["checkpoint"] = str(tmp_path / "nope.tar")
    with pytest.raises(P.ParamsError, match="file not found"):
        P.pretrained_starts(p, keys)
    with pytest.raises(P.ParamsError, match="allow_random_init must be true or false, got 'false'"):
        P.pretrained_starts(_params(tmp_path, allow_random_init="false"), keys)


@pytest.fixture
def paper_params(tmp_path):
    """The repository's params.yaml switched to the paper profile (`make paper`), in an empty folder."""
    params = tmp_path / "params.yaml"
    shutil.copy(ROOT / "params.yaml", params)
    shutil.copytree(ROOT / "configs", tmp_path / "configs")
    profile.apply("paper", params, tmp_path / "configs" / "profiles.yaml")
    p = yaml.safe_load(params.read_text())
    assert p["allow_random_init"] is False and p["train_depth"]["imagenet_weights"] is None
    return params


@pytest.mark.parametrize("stage,args,key", [
    ("flow_pretrain", ["params.yaml"], "flow_pretrain.checkpoint"),
    ("flow_finetune", ["--loss", "patch", "--params", "params.yaml"], "flow_pretrain.checkpoint"),
    ("train_depth", ["--variant", "full", "--params", "params.yaml"], "train_depth.imagenet_weights"),
    ("train_depth", ["--variant", "baseline", "--params", "params.yaml"], "train_depth.imagenet_weights"),
])
def test_paper_profile_training_stages_stop_at_once_without_the_weight_files(paper_params, stage, args, key):
    root = paper_params.parent
    before = sorted(p.name for p in root.iterdir())
    env = {**os.environ, "F2DEPTH_MLFLOW": "0"}
    res = subprocess.run([sys.executable, str(ROOT / "stages" / f"{stage}.py"), *args], cwd=root,
                         capture_output=True, text=True, timeout=120, env=env)
    assert res.returncode == 1, res.stderr
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    assert lines[0].startswith(f"{stage}: params.yaml: {key} is not set; the paper's model needs ")
    assert "allow_random_init: true" in lines[0]
    assert sorted(p.name for p in root.iterdir()) == before  # no work, nothing written


def test_allow_random_init_trains_from_random_weights_and_says_so(tmp_path, monkeypatch):
    prep = train_fakes.write_prepared(tmp_path / "prepared", hw=(64, 64), scenes=1, frames=5)
    mat, splits = train_fakes.write_nyu_test(tmp_path, n=2)
    flow = train_fakes.write_flow_model(tmp_path / "flow.pt")
    path = train_fakes.write_params(tmp_path, prep, mat, splits, flow, epochs=1, diagnostic_tuples=0)
    p = yaml.safe_load(path.read_text())
    p["allow_random_init"] = False
    path.write_text(yaml.safe_dump(p))
    for variant in ("full", "baseline"):
        with pytest.raises(P.ParamsError, match="train_depth.imagenet_weights is not set"):
            settings_from_params(P.load(path), variant)
    (tmp_path / "resnet18.pth").write_bytes(b"x")  # only its existence is checked before any work
    p["train_depth"]["imagenet_weights"] = str(tmp_path / "resnet18.pth")
    path.write_text(yaml.safe_dump(p))
    with pytest.raises(P.ParamsError, match="flow_pretrain.checkpoint is not set"):
        settings_from_params(P.load(path), "full")  # a flow variant also needs ARFlow's start
    assert settings_from_params(P.load(path), "baseline").imagenet_weights == str(tmp_path / "resnet18.pth")

    p["allow_random_init"] = True
    p["train_depth"]["imagenet_weights"] = None
    path.write_text(yaml.safe_dump(p))
    monkeypatch.setenv("F2DEPTH_MLFLOW", "0")
    torch.set_num_threads(1)
    spec = importlib.util.spec_from_file_location("train_depth_stage", ROOT / "stages" / "train_depth.py")
    stage = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(stage)
    stage.main(["train_depth.py", "--variant", "full", "--params", str(path),
                "--models", str(tmp_path / "models"), "--metrics", str(tmp_path / "metrics")])
    m = json.loads((tmp_path / "metrics" / "full.json").read_text())
    assert m["resnet_init"] == "random" and m["amp"] is False
    assert (tmp_path / "models" / "depth_full" / "model.pt").is_file()
