"""Tests for f2depth.train.diagnostics: pose errors, depth accuracy, ground truth of the training tuples."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import train_fakes
from torch import nn

from f2depth.depth import DepthModel, DepthModelConfig
from f2depth.flow import PWCLite
from f2depth.formats.prepared import PreparedSet
from f2depth.geometry import axis_angle_to_matrix, make_transform
from f2depth.train.diagnostics import (
    DIAGNOSTIC_KEYS,
    TrainTruth,
    constant_depth_metrics,
    depth_accuracy,
    diagnose,
    pose_errors,
    rotation_angle,
    teacher_epe,
)
from f2depth.train.teacher import FlowTeacher
from f2depth.train.validate import make_validator


def _T(deg: float, axis=(0.0, 0.0, 1.0), t=(0.0, 0.0, 0.0)) -> torch.Tensor:
    aa = torch.tensor([axis], dtype=torch.float64) * math.radians(deg)
    return make_transform(axis_angle_to_matrix(aa), torch.tensor([t], dtype=torch.float64))


def test_rotation_angle_hand_computed():
    R = torch.cat([_T(0.0), _T(10.0), _T(90.0, axis=(1.0, 0.0, 0.0)), _T(180.0)])[:, :3, :3]
    assert rotation_angle(R).tolist() == pytest.approx([0.0, 10.0, 90.0, 180.0], abs=1e-6)


def test_pose_errors_hand_computed():
    pred = torch.cat([_T(10.0, t=(1.0, 0.0, 0.0)), _T(0.0, t=(0.0, -2.0, 0.0))])
    true = torch.cat([_T(4.0, t=(3.0, 0.0, 0.0)), _T(0.0, t=(0.0, 1.0, 0.0))])
    e = pose_errors(pred, true)
    assert e["pose_rot_err"] == pytest.approx((6.0 + 0.0) / 2)  # same axis: the angles subtract
    assert e["pose_rot_true"] == pytest.approx(2.0) and e["pose_rot_pred"] == pytest.approx(5.0)
    assert e["pose_trans_cos"] == pytest.approx((1.0 - 1.0) / 2)  # parallel, then opposite
    zero = pose_errors(_T(0.0), _T(0.0, t=(0.0, 0.0, 1.0)))
    assert zero["pose_trans_cos"] == 0.0 and zero["pose_rot_err"] == 0.0  # no translation: cosine 0


def test_depth_accuracy_median_scaled_and_skips_empty_images():
    gt = np.stack([np.full((4, 4), 2.0), np.zeros((4, 4)), np.linspace(1, 4, 16).reshape(4, 4)])
    pred = np.stack([np.full((4, 4), 7.0), np.ones((4, 4)), 3.0 * gt[2]])  # right up to a scale
    m = depth_accuracy(pred, gt)
    assert m == {"train_a1": pytest.approx(1.0), "train_abs_rel": pytest.approx(0.0, abs=1e-12)}
    wrong = np.stack([np.full((4, 4), 2.0), np.ones((4, 4)), gt[2][::-1, ::-1].copy()])
    r = np.maximum(np.median(gt[2]) * wrong[2] / np.median(wrong[2]) / gt[2],
                   gt[2] / (np.median(gt[2]) * wrong[2] / np.median(wrong[2])))
    assert depth_accuracy(wrong, gt)["train_a1"] == pytest.approx((1.0 + (r < 1.25).mean()) / 2)
    assert math.isnan(depth_accuracy(np.ones((1, 2, 2)), np.zeros((1, 2, 2)))["train_a1"])


@pytest.fixture
def prepared(tmp_path):
    return PreparedSet(train_fakes.write_prepared(tmp_path / "prepared", hw=(64, 64), scenes=2, frames=4))


def test_truth_from_prepared(prepared):
    truth = TrainTruth.from_prepared(prepared)
    assert len(truth) == len(prepared.tuples) == 4
    assert truth.target.shape == (4, 3, 64, 64) and truth.depth.shape == (4, 64, 64)
    # the fake camera moves +5 cm along x per frame: the next camera sees the target's points 5 cm to -x
    assert truth.T_next[:, 0, 3].tolist() == pytest.approx([-0.05] * 4)
    assert truth.T_prev[:, 0, 3].tolist() == pytest.approx([0.05] * 4)
    assert torch.allclose(truth.T_next[:, :3, :3], torch.eye(3, dtype=torch.float64).expand(4, 3, 3))
    assert len(TrainTruth.from_prepared(prepared, max_tuples=2)) == 2


def test_truth_is_none_without_ground_truth(prepared, monkeypatch):
    monkeypatch.setattr(PreparedSet, "has_gt", lambda self, fid: False)
    assert TrainTruth.from_prepared(prepared) is None


class _Oracle(nn.Module):
    """Predicts the ground truth (times a scale) whatever the input: diagnose must score it perfect."""

    def __init__(self, truth: TrainTruth, scale: float) -> None:
        super().__init__()
        self.config = DepthModelConfig(height=64, width=64)
        self.truth, self.scale, self.calls = truth, scale, []

    def predict_depth(self, img):
        self.calls.append(self.training)
        return torch.from_numpy(self.truth.depth * self.scale)[: img.shape[0], None].float()

    def predict_pose(self, a, b, invert=False):
        T = (self.truth.T_prev if invert else self.truth.T_next)[: a.shape[0]].clone()
        T[:, :3, 3] *= self.scale
        return T


def test_diagnose_scores_an_oracle_perfectly_and_restores_train_mode(prepared):
    truth = TrainTruth.from_prepared(prepared)
    oracle = _Oracle(truth, scale=0.3).train()
    d = diagnose(oracle, truth, batch_size=len(truth))
    assert set(d) == set(DIAGNOSTIC_KEYS)
    assert d["train_a1"] == pytest.approx(1.0) and d["train_abs_rel"] == pytest.approx(0.0, abs=1e-6)
    assert d["pose_rot_err"] == pytest.approx(0.0, abs=1e-4) and d["pose_trans_cos"] == pytest.approx(1.0)
    assert d["rigid_epe"] == pytest.approx(0.0, abs=1e-4)  # depth and translation share the 0.3: flow exact
    assert oracle.calls == [False] and oracle.training


def test_diagnose_on_a_real_network(prepared):
    truth = TrainTruth.from_prepared(prepared)
    torch.manual_seed(0)
    d = diagnose(DepthModel(DepthModelConfig(height=64, width=64)), truth, batch_size=3)
    assert set(d) == set(DIAGNOSTIC_KEYS) and all(math.isfinite(v) for v in d.values())
    assert 0.0 <= d["train_a1"] <= 1.0 and -1.0 <= d["pose_trans_cos"] <= 1.0
    assert d["pose_rot_pred"] < 1.0  # Monodepth2's 0.01 output scale: an untrained PoseCNN barely turns


def test_constant_depth_metrics_is_the_floor(tmp_path):
    mat, splits = train_fakes.write_nyu_test(tmp_path, n=3)
    v = make_validator(mat, splits, 64, 64, max_images=None)
    floor = constant_depth_metrics(v)
    ones = v.score(lambda x: torch.full((x.shape[0], 1, x.shape[2], x.shape[3]), 0.25))
    assert floor == pytest.approx(ones)  # median scaling: every constant scores the same
    assert 0.0 < floor["val_a1"] < 1.0 and floor["val_abs_rel"] > 0.0
    v.close()


class _FlowOf:
    """A teacher that serves the rows of a fixed field, batch after batch."""

    def __init__(self, flow: torch.Tensor) -> None:
        self.field, self.start = flow, 0

    def flow(self, target, source):
        out = self.field[self.start:self.start + target.shape[0]]
        self.start += target.shape[0]
        return out


def test_teacher_epe_is_zero_for_the_exact_flow_and_zero_flows_for_zeros(prepared):
    """The teacher's EPE on the training pairs: the exact rigid flow scores 0, a zero field scores what
    zero flow scores (the fake camera's 5 cm step moves the pixels), in one batch or in several."""
    truth = TrainTruth.from_prepared(prepared)
    exact, valid = truth.exact_flow
    assert exact.shape == (4, 2, 64, 64) and valid.shape == (4, 1, 64, 64) and valid.any()
    perfect = teacher_epe(_FlowOf(exact), truth, batch_size=3)
    assert perfect["teacher"] == pytest.approx(0.0, abs=1e-6) and perfect["zero_flow"] > 0.5
    blind = teacher_epe(_FlowOf(torch.zeros_like(exact)), truth, batch_size=4)
    assert blind["teacher"] == pytest.approx(blind["zero_flow"])


def test_a_teachers_flow_for_a_diagnosis_leaves_its_memo_alone(prepared):
    """FlowTeacher.flow runs the network now and keeps nothing: training is served what it was before."""
    truth = TrainTruth.from_prepared(prepared)
    torch.manual_seed(0)
    teacher = FlowTeacher(PWCLite(), memo_mb=64)
    flow = teacher.flow(truth.target, truth.next)
    assert flow.shape == (4, 2, 64, 64) and not teacher.memo
    assert torch.equal(flow, teacher(truth.target, truth.next, features=False).flow)
    epe = teacher_epe(teacher, truth, batch_size=2)
    assert len(teacher.memo) == 4 and epe["teacher"] > 0
