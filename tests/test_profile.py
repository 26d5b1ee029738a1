"""Switching params.yaml between the CPU default and the paper scale."""

from __future__ import annotations

import shutil
from pathlib import Path

import yaml

from f2depth import profile

ROOT = Path(__file__).resolve().parents[1]


def test_profiles_round_trip_keeps_comments(tmp_path):
    params = tmp_path / "params.yaml"
    shutil.copy(ROOT / "params.yaml", params)
    before = params.read_text()
    changed = profile.apply("paper", params, ROOT / "configs/profiles.yaml")
    paper = yaml.safe_load(params.read_text())
    assert paper["prepare"]["height"] == 288 and paper["prepare"]["width"] == 384
    assert paper["train_depth"]["epochs"] == 44 and paper["train_depth"]["batch_size"] == 12
    assert paper["flow_finetune"]["epochs"] == 37 and paper["flow_finetune"]["batch_size"] == 20
    # the paper's λ1, λ2, L_rigid's 1, λ3 and eq. (9)'s λ (a term added later may be pinned to 0 there)
    paper_weights = {"lambda1": 0.001, "lambda2": 0.05, "lambda_rigid": 1.0, "lambda3": 3.0,
                     "lambda_flow_smooth": 50}
    assert {key: paper[key] for key in paper_weights} == paper_weights
    assert "prepare.height" in changed and "lambda3" in changed
    assert "# ---- the paper's loss weights" in params.read_text() and "# L_feature:" in params.read_text()
    profile.apply("cpu", params, ROOT / "configs/profiles.yaml")
    assert yaml.safe_load(params.read_text()) == yaml.safe_load(before)


def test_every_profile_key_exists_in_params():
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    for name, values in profile.load_profiles(ROOT / "configs/profiles.yaml").items():
        for dotted in values:
            node = params
            for part in dotted.split("."):
                assert part in node, f"profile {name}: {dotted} missing in params.yaml"
                node = node[part]


def test_cpu_profile_matches_committed_params():
    """The committed params.yaml is the CPU default: applying `cpu` changes nothing."""
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    for dotted, value in profile.load_profiles(ROOT / "configs/profiles.yaml")["cpu"].items():
        node = params
        for part in dotted.split("."):
            node = node[part]
        assert node == value, dotted


def test_applying_the_cpu_profile_leaves_the_committed_file_byte_for_byte(tmp_path):
    """Nulls stay `null`, comments and their columns stay: `make cpu` on the CPU default is no diff."""
    params = tmp_path / "params.yaml"
    shutil.copy(ROOT / "params.yaml", params)
    assert "threads: null" in params.read_text()
    assert profile.apply("cpu", params, ROOT / "configs/profiles.yaml") == []
    assert params.read_text() == (ROOT / "params.yaml").read_text()


def test_the_cpu_profile_holds_only_what_the_paper_profile_changes():
    """params.yaml is the CPU default; the `cpu` block is only the way back from `make paper`, so it names
    no key that `paper` leaves alone (a third copy of a default would drift)."""
    profiles = profile.load_profiles(ROOT / "configs/profiles.yaml")
    extra = sorted(set(profiles["cpu"]) - set(profiles["paper"]))
    assert extra == [], f"configs/profiles.yaml: cpu sets {extra}, which paper never changes; drop them"
