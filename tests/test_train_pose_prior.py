"""train_depth.pose_prior: geometric — PoseCNN refines a prior pose; pairs without one get PoseCNN alone."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
import torch
import train_fakes
import yaml

from f2depth import params as P
from f2depth.depth import DepthModel, DepthModelConfig
from f2depth.formats.prepared import PreparedSet
from f2depth.geometry import invert_pose, pose_from_params
from f2depth.poses.estimate import PairPrior, PosesConfig, ScenePoses
from f2depth.poses.store import PosePriors, write_poses
from f2depth.train import augment as A
from f2depth.train.data import DataConfig, TupleDataset
from f2depth.train.run import train_variant
from f2depth.train.settings import settings_from_params
from f2depth.train.step import StepConfig, batch_to, compute_loss, pose_priors

ROOT = Path(__file__).resolve().parents[1]


def _pose(aa, t) -> torch.Tensor:
    return pose_from_params(torch.tensor([aa], dtype=torch.float32),
                            torch.tensor([t], dtype=torch.float32))[0]


def _model() -> DepthModel:
    torch.manual_seed(0)
    return DepthModel(DepthModelConfig(height=64, width=64)).eval()


def write_priors(prepared: Path, out: Path,
                 reliable: set[str]) -> dict[str, tuple[torch.Tensor, torch.Tensor]]:
    """A priors folder for ``prepared``: a fixed sideways motion for the tuples in ``reliable`` (both pairs),
    no prior for the others; returns {tuple_id: (prev_T_target, next_T_target)} of the reliable ones."""
    prep = PreparedSet(prepared)
    priors, truth, scene_of = {}, {}, {}
    for t in prep.tuples:
        T_next = _pose([0.0, 0.02, 0.0], [-0.05, 0.0, 0.01]).double().numpy()
        T_prev = np.linalg.inv(T_next)
        ok = t.tuple_id in reliable
        nan = np.full((4, 4), np.nan)
        priors[t.tuple_id] = (PairPrior(T_prev if ok else nan, ok, 50 if ok else 0),
                              PairPrior(T_next if ok else nan, ok, 50 if ok else 0))
        scene_of[t.tuple_id] = t.scene
        if ok:
            truth[t.tuple_id] = (torch.from_numpy(T_prev).float(), torch.from_numpy(T_next).float())
    scenes = {s: ScenePoses(s, [], np.zeros((0, 4, 4)), np.zeros(0, bool), np.zeros((0, 0), int), 0, 0, 0.0)
              for s in set(scene_of.values())}
    write_poses(out, scenes, priors, scene_of, PosesConfig())
    return truth


def test_a_zero_residual_returns_the_prior_and_its_inverse():
    model = _model()
    with torch.no_grad():  # the residual (second) output zeroed: ΔT = I exactly
        model.pose_decoder.pose_2.weight[6:].zero_()
        model.pose_decoder.pose_2.bias[6:].zero_()
    a, b = torch.rand(2, 3, 64, 64), torch.rand(2, 3, 64, 64)
    prior = torch.stack([_pose([0.01, -0.03, 0.02], [0.1, 0.0, -0.05]), _pose([0, 0, 0], [0.0, 0.2, 0.0])])
    with torch.no_grad():
        assert torch.allclose(model.predict_pose(a, b, prior=prior), prior, atol=1e-6)
        inverse = model.predict_pose(a, b, invert=True, prior=prior)
    assert torch.allclose(inverse, invert_pose(prior), atol=1e-6)


def test_the_second_output_refines_the_prior_on_the_left_and_the_first_serves_rows_without_one():
    model = _model()
    a, b = torch.rand(2, 3, 64, 64), torch.rand(2, 3, 64, 64)
    prior = torch.stack([_pose([0.02, 0.01, 0.0], [0.05, 0.0, 0.1]), torch.full((4, 4), float("nan"))])
    ok = torch.tensor([True, False])
    with torch.no_grad():
        aa, t = model.pose_params(a, b)
        got = model.predict_pose(a, b, prior=prior, prior_ok=ok)
        got_inv = model.predict_pose(a, b, invert=True, prior=prior, prior_ok=ok)
    residual = pose_from_params(aa[:, 1], t[:, 1])
    assert torch.allclose(got[0], residual[0] @ prior[0], atol=1e-6)
    assert not torch.allclose(got[0], prior[0] @ residual[0], atol=1e-6)
    assert torch.allclose(got[1], model.predict_pose(a, b)[1], atol=1e-6)  # PoseCNN alone, no NaN
    assert torch.allclose(got_inv, invert_pose(got), atol=1e-5)


def test_pose_priors_fall_back_to_the_identity_per_sample_without_nan():
    T = _pose([0.0, 0.03, 0.0], [0.1, 0.0, 0.0])
    batch = {"prior_prev": torch.stack([T, torch.full((4, 4), float("nan"))]),
             "prior_next": torch.stack([torch.full((4, 4), float("nan")), T]),
             "prior_prev_ok": torch.tensor([True, False]), "prior_next_ok": torch.tensor([False, True])}
    (prev, prev_ok), (nxt, next_ok) = pose_priors(batch)
    assert torch.isfinite(prev).all() and torch.isfinite(nxt).all()
    assert torch.allclose(prev[0], invert_pose(T), atol=1e-6) and torch.equal(prev[1], torch.eye(4))
    assert torch.equal(nxt[0], torch.eye(4)) and torch.allclose(nxt[1], T)
    assert prev_ok.tolist() == [True, False] and next_ok.tolist() == [False, True]
    assert pose_priors({"target": torch.zeros(1)}) is None


def test_flip_pose_maps_mirrored_target_points_to_mirrored_source_pixels():
    w = 64
    K = torch.tensor([[50.0, 0.0, 30.0], [0.0, 50.0, 33.0], [0.0, 0.0, 1.0]])
    T = _pose([0.02, -0.05, 0.01], [0.2, -0.1, 0.05])
    X = torch.tensor([0.3, -0.2, 2.5, 1.0])

    def pixel(K, X):
        p = K @ X[:3]
        return p[:2] / p[2]

    u_src = pixel(K, T @ X)
    F = torch.diag(torch.tensor([-1.0, 1.0, 1.0, 1.0]))
    mirrored = pixel(A.flip_intrinsics(K, w), A.flip_pose(T) @ (F @ X))
    assert torch.allclose(mirrored, torch.stack([w - 1 - u_src[0], u_src[1]]), atol=1e-5)


@pytest.fixture
def tiny(tmp_path):
    prep = train_fakes.write_prepared(tmp_path / "prepared", hw=(64, 64), scenes=1, frames=6)
    tuples = [t.tuple_id for t in PreparedSet(prep).tuples]
    truth = write_priors(prep, tmp_path / "poses", set(tuples[::2]))
    return tmp_path, prep, truth


def test_items_carry_the_priors_mirrored_with_the_sample(tiny):
    root, prep, truth = tiny
    ds = TupleDataset(prep, root / "keypoints" / "train.npz", DataConfig(num_points=20), seed=0,
                      priors=PosePriors(root / "poses"))
    seen_flip = seen_plain = seen_missing = False
    for epoch in range(6):
        for i, t in enumerate(ds.prepared.tuples):
            item = ds.item(i, epoch)
            if t.tuple_id not in truth:
                assert not item["prior_prev_ok"] and torch.equal(item["prior_next"], torch.eye(4))
                seen_missing = True
                continue
            T_prev, T_next = truth[t.tuple_id]
            if item["flipped"]:
                T_prev, T_next = A.flip_pose(T_prev), A.flip_pose(T_next)
                seen_flip = True
            else:
                seen_plain = True
            assert item["prior_prev_ok"] and torch.allclose(item["prior_next"], T_next, atol=1e-6)
            assert torch.allclose(item["prior_prev"], T_prev, atol=1e-6)
    assert seen_flip and seen_plain and seen_missing


def test_a_batch_mixing_reliable_and_missing_priors_gives_a_finite_loss_and_gradients(tiny):
    root, prep, _ = tiny
    ds = TupleDataset(prep, root / "keypoints" / "train.npz", DataConfig(num_points=20), seed=0,
                      priors=PosePriors(root / "poses"))
    batch = batch_to(torch.utils.data.default_collate([ds.item(i, 0) for i in range(len(ds))]), "cpu")
    assert batch["prior_prev_ok"].any() and not batch["prior_prev_ok"].all()
    model = DepthModel(DepthModelConfig(height=64, width=64))
    config = StepConfig({**train_fakes.WEIGHTS, "rigid": 0.0, "feature": 0.0}, min_area=10.0)
    loss, logs = compute_loss(model, batch, None, config)
    loss.backward()
    assert math.isfinite(logs["total"])
    grads = [p.grad for p in model.pose_decoder.parameters()]
    assert all(g is not None and torch.isfinite(g).all() for g in grads)
    last = model.pose_decoder.pose_2.weight.grad  # both outputs learn: the pose and the residual
    assert last[:6].abs().sum() > 0 and last[6:].abs().sum() > 0


def test_training_with_geometric_priors_runs_and_reports_the_poses_it_uses(tiny):
    root, prep, _ = tiny
    mat, splits = train_fakes.write_nyu_test(root, n=2)
    path = train_fakes.write_params(root, prep, mat, splits, None, epochs=1, pose_prior="geometric",
                                    init_depth=2.0)
    p = P.load(path)
    p["data"]["poses"] = str(root / "poses")
    s = settings_from_params(p, "baseline")
    assert (s.pose_prior, s.poses) == ("geometric", str(root / "poses"))
    m = train_variant(s, root / "models", progress=False).metrics
    assert math.isfinite(m["val_trained"]["a1"]) and math.isfinite(m["train_trained"]["pose_rot_err"])


def test_pose_prior_values_are_checked_and_the_paper_profile_keeps_none(tiny):
    root, prep, _ = tiny
    mat, splits = train_fakes.write_nyu_test(root, n=2)
    p = P.load(train_fakes.write_params(root, prep, mat, splits, None, pose_prior="colmap"))
    with pytest.raises(P.ParamsError, match="train_depth.pose_prior must be one of none, geometric"):
        settings_from_params(p, "baseline")
    p["train_depth"]["pose_prior"] = "none"
    assert settings_from_params(p, "baseline").poses is None
    profiles = yaml.safe_load((ROOT / "configs" / "profiles.yaml").read_text())
    assert profiles["paper"]["train_depth.pose_prior"] == "none"


def test_the_poses_stage_names_unknown_keys():
    spec = importlib.util.spec_from_file_location("poses_stage", ROOT / "stages" / "poses.py")
    stage = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(stage)
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    params["_file"] = "params.yaml"
    assert stage.config_from_params(params).tracker.window == params["poses"]["tracker"]["window"]
    params["poses"]["tracker"]["windw"] = 5
    with pytest.raises(P.ParamsError, match=r"poses.tracker: unknown keys \['windw'\]"):
        stage.config_from_params(params)
