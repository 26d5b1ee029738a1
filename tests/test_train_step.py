"""Tests for f2depth.train.step and f2depth.train.teacher: rigid flow against the synthetic world's ground
truth, one training step, the frozen flow network and the NaN/inf guard."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import train_fakes
from torch.utils.data import default_collate

from f2depth import precision
from f2depth.depth import DepthModel, DepthModelConfig
from f2depth.flow import FlowNetwork, PWCLite
from f2depth.geometry import in_view_mask, relative_pose, rigid_flow, warp
from f2depth.losses import NonFiniteLossError, rigid_flow_loss, total_loss
from f2depth.precision import amp_dtype
from f2depth.synth.camera_path import handheld_path
from f2depth.synth.groundtruth import occlusion
from f2depth.synth.groundtruth import relative_pose as synth_relative_pose
from f2depth.synth.groundtruth import rigid_flow as synth_rigid_flow
from f2depth.synth.jobs import PATHS, room
from f2depth.synth.plan import rng_for
from f2depth.synth.render import render
from f2depth.train import augment as A
from f2depth.train.data import DataConfig, TupleDataset
from f2depth.train.step import (
    FLOW_TERMS,
    TERMS,
    NetOutput,
    StepConfig,
    compute_loss,
    loss_terms,
    network_forward,
    teacher_forward,
    train_step,
)
from f2depth.train.teacher import FlowTeacher, TeacherOutput

#: The CPU default's weights (f2depth.train.step.WEIGHT_KEYS), for the tiny set's superpixels
STEP = StepConfig(train_fakes.WEIGHTS, min_area=10)

HW = (48, 64)
K_SYNTH = np.array([[52.0, 0.0, 36.2], [0.0, 53.0, 22.7], [0.0, 0.0, 1.0]])  # principal point off-centre


@pytest.fixture(scope="module")
def synth_pair():
    """Two views of a synthetic room (ray-traced radiance and depth) with the generator's GT flow."""
    scene = room("nyu", "bedroom", "bedroom_0001", 0)
    poses, _ = handheld_path(scene, 60, rng_for(0, "train-step-test"), PATHS["nyu"])
    c0, d0 = render(scene, poses[0], K_SYNTH, HW, 1)
    for k in range(1, len(poses)):  # the first later frame that moved by > 2 px on average
        flow, z1 = synth_rigid_flow(d0, K_SYNTH, synth_relative_pose(poses[0], poses[k]))
        if np.linalg.norm(flow, axis=-1).mean() > 2.0:
            break
    c1, d1 = render(scene, poses[k], K_SYNTH, HW, 1)
    occ = occlusion(flow, z1, d1)
    return {"c0": c0, "c1": c1, "d0": d0, "pose0": poses[0], "pose1": poses[k], "flow": flow, "occ": occ}


def _t(a: np.ndarray, dtype=torch.float32) -> torch.Tensor:
    return torch.as_tensor(np.ascontiguousarray(a), dtype=dtype)


def _training_convention(pair, flip: bool = False):
    """(depth (1,1,H,W), K (1,3,3), src_T_tgt (1,4,4), GT flow (1,2,H,W), valid (1,1,H,W)) as the training
    code builds them: T+1 = 1_T_0 from the world_T_cam poses of the prepared set's GT files."""
    depth = _t(pair["d0"])[None, None]
    K = _t(K_SYNTH)[None]
    T = relative_pose(_t(pair["pose0"], torch.float64)[None], _t(pair["pose1"], torch.float64)[None]).float()
    gt = _t(pair["flow"]).permute(2, 0, 1)[None]
    valid = (~_t(pair["occ"], torch.bool))[None, None]
    if flip:  # the mirrored world: images, depth, masks flipped; K mirrored; poses conjugated by x → −x
        M = torch.diag(torch.tensor([-1.0, 1.0, 1.0, 1.0]))
        depth, valid = depth.flip(-1), valid.flip(-1)
        K = A.flip_intrinsics(K[0], HW[1])[None]
        T = M @ T @ M
        gt = gt.flip(-1) * torch.tensor([-1.0, 1.0]).view(1, 2, 1, 1)
    return depth, K, T, gt, valid


@pytest.mark.parametrize("flip", [False, True])
def test_rigid_flow_equals_synthetic_ground_truth(synth_pair, flip):
    depth, K, T, gt, valid = _training_convention(synth_pair, flip)
    assert valid.float().mean() > 0.6  # most of the view is visible in the other frame
    flow = rigid_flow(depth, K, T)
    err = (flow - gt).norm(dim=1, keepdim=True)[valid]
    assert float(err.max()) < 1e-2  # sub-pixel: float32 round-off only
    assert float(gt.norm(dim=1, keepdim=True)[valid].mean()) > 1.0  # and the motion is not trivial


def test_rigid_flow_warps_the_rendered_source_onto_the_target(synth_pair):
    depth, K, T, _, valid = _training_convention(synth_pair)
    flow = rigid_flow(depth, K, T)
    c0 = _t(synth_pair["c0"]).permute(2, 0, 1)[None]
    c1 = _t(synth_pair["c1"]).permute(2, 0, 1)[None]
    mask = valid & (in_view_mask(flow) > 0)

    def err(f):
        return float((warp(c1, f) - c0).abs().mean(dim=1, keepdim=True)[mask].mean())

    assert err(flow) < 0.5 * err(torch.zeros_like(flow))  # the rendered images agree where the flow says
    assert err(flow) < err(rigid_flow(depth * 1.3, K, T))  # and better than with a wrong depth


def test_rigid_loss_on_synthetic_pair_zero_at_gt_and_grows(synth_pair):
    depth, K, T, gt, valid = _training_convention(synth_pair)
    base = float(rigid_flow_loss(rigid_flow(depth, K, T), gt, valid.float()))
    assert base < 1e-3
    errs = [float(rigid_flow_loss(rigid_flow(depth * s, K, T), gt, valid.float())) for s in (1.05, 1.2, 1.5)]
    assert base < errs[0] < errs[1] < errs[2]


# ---- one step on the tiny prepared set ---------------------------------------------------------------

@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    root = tmp_path_factory.mktemp("step")
    prep = train_fakes.write_prepared(root / "prepared", hw=(64, 64), scenes=1, frames=4)
    ds = TupleDataset(prep, root / "keypoints" / "train.npz", DataConfig(num_points=30))
    batch = default_collate([ds.item(i, 0) for i in range(2)])
    torch.manual_seed(0)
    return {"batch": batch, "teacher": FlowTeacher(PWCLite())}


def test_terms_and_monitor_only_terms(tiny):
    torch.manual_seed(1)
    model = DepthModel(DepthModelConfig(64, 64))
    cfg = StepConfig({**train_fakes.WEIGHTS, "feature": 0.0}, min_area=10)
    net = network_forward(model, tiny["batch"])
    flow = teacher_forward(tiny["teacher"], tiny["batch"], features=True)
    assert flow.flow.shape == (2, 2, 64, 64) and len(flow.feats_tgt) == 6
    assert [f.shape[1] for f in flow.feats_src] == [16, 32, 64, 96, 128, 192]
    terms = loss_terms(net, tiny["batch"], flow, cfg)
    assert set(terms) == {"ph", *TERMS}  # named as their weights (f2depth.train.step.WEIGHT_KEYS)
    assert all(math.isfinite(float(v.detach())) for v in terms.values())
    assert terms["rigid"].requires_grad and not terms["feature"].requires_grad  # weight 0: logged only
    baseline = loss_terms(net, tiny["batch"], None, cfg)  # no flow network: no flow terms
    assert set(baseline) == {"ph", *TERMS} - set(FLOW_TERMS) and {"smooth", "planar"} <= set(baseline)


def test_train_step_updates_depth_not_teacher(tiny):
    torch.manual_seed(2)
    model = DepthModel(DepthModelConfig(64, 64))
    teacher = tiny["teacher"]
    before_t = {k: v.clone() for k, v in teacher.net.state_dict().items()}
    before_m = {k: v.clone() for k, v in model.state_dict().items()}
    opt = torch.optim.Adam(model.parameters(), lr=1e-4)
    loss, logs = train_step(model, opt, tiny["batch"], teacher, StepConfig(train_fakes.WEIGHTS, min_area=10))
    assert not loss.requires_grad and set(logs) == {"ph", *TERMS, "total"}
    assert all(not p.requires_grad and p.grad is None for p in teacher.net.parameters())
    assert all(torch.equal(v, before_t[k]) for k, v in teacher.net.state_dict().items())
    for name in ("depth_decoder", "pose_decoder", "depth_encoder", "pose_encoder"):
        key = next(k for k in before_m if k.startswith(name) and k.endswith("weight"))
        assert not torch.equal(model.state_dict()[key], before_m[key]), name
    assert not teacher.net.training


class CountingPWCLite(PWCLite):
    """PWC-Lite that counts the pairs its forward pass sees."""

    def __init__(self) -> None:
        super().__init__()
        self.pairs_run = 0

    def forward(self, img1, img2, with_backward=True):
        self.pairs_run += img1.shape[0]
        return super().forward(img1, img2, with_backward)


def test_teacher_memo_serves_seen_pairs_without_the_network_and_equals_a_fresh_run():
    torch.manual_seed(3)
    pairs = [(torch.rand(3, 64, 64), torch.rand(3, 64, 64)) for _ in range(5)]

    def batch(*ids):
        return torch.stack([pairs[i][0] for i in ids]), torch.stack([pairs[i][1] for i in ids])

    torch.manual_seed(4)
    net = CountingPWCLite()
    plain, memo = FlowTeacher(net), FlowTeacher(net, memo_mb=64)
    first = memo(*batch(0, 1, 2))
    assert net.pairs_run == 3 and memo.memo_hits == 0 and len(memo.memo) == 3
    mixed = memo(*batch(2, 3, 0))  # two seen pairs, one new: the network runs on the new one only
    assert net.pairs_run == 4 and memo.memo_hits == 2
    again = memo(*batch(3, 1))
    assert net.pairs_run == 4 and memo.memo_hits == 4
    ref = plain(*batch(2, 3, 0))
    for got, want in ((mixed, ref), (again, plain(*batch(3, 1)))):
        assert got.flow.shape == want.flow.shape and len(got.feats_tgt) == len(want.feats_tgt) == 6
        torch.testing.assert_close(got.flow, want.flow, rtol=1e-4, atol=1e-4)
        for a, b in zip(got.feats_tgt + got.feats_src, want.feats_tgt + want.feats_src):
            torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(mixed.flow[2], first.flow[0], rtol=0, atol=0)  # pair 0 from the memo
    # a changed image is a new pair, never served an old entry
    altered = (pairs[0][0].clone(), pairs[0][1])
    altered[0][0, 0, 0] += 0.5
    before = net.pairs_run
    memo(altered[0][None], altered[1][None])
    assert net.pairs_run == before + 1
    # the budget holds: an entry that does not fit is computed but not kept
    entry_mb = memo.memo_used / len(memo.memo) / 2**20
    small = FlowTeacher(net, memo_mb=1.5 * entry_mb)
    small(*batch(0, 1, 2))
    assert len(small.memo) == 1 and small.memo_used <= small.memo_bytes
    small(*batch(0, 1, 2))
    assert small.memo_hits == 1


def test_teacher_memo_keeps_a_pair_met_twice_in_one_batch_once():
    torch.manual_seed(5)
    img1, img2 = torch.rand(3, 64, 64), torch.rand(3, 64, 64)
    teacher = FlowTeacher(PWCLite(), memo_mb=64)
    out = teacher(torch.stack([img1, img1]), torch.stack([img2, img2]))
    assert len(teacher.memo) == 1 and teacher.memo_used == next(iter(teacher.memo.values())).nbytes
    torch.testing.assert_close(out.flow[0], out.flow[1])


def test_nan_guard_names_the_term_and_leaves_weights(tiny):
    torch.manual_seed(3)
    model = DepthModel(DepthModelConfig(64, 64))
    broken = PWCLite()
    with torch.no_grad():
        broken.flow_estimators.predict_flow[0].weight.fill_(float("nan"))
    before = {k: v.detach().clone() for k, v in model.named_parameters()}
    opt = torch.optim.Adam(model.parameters(), lr=1e-4)
    with pytest.raises(NonFiniteLossError, match=r"loss term 'rigid' is nan \(epoch 3, step 7\)") as info:
        train_step(model, opt, tiny["batch"], FlowTeacher(broken), STEP, context="epoch 3, step 7")
    assert info.value.term == "rigid"
    # no update (BatchNorm running statistics of the forward pass are buffers, not weights)
    assert all(torch.equal(v, before[k]) for k, v in model.named_parameters())
    seen = []
    with pytest.raises(NonFiniteLossError):
        train_step(model, opt, tiny["batch"], FlowTeacher(broken), STEP, agree=seen.append)
    assert len(seen) == 1 and seen[0].term == "rigid"  # the DDP hook sees the error before anything else


def test_mixed_precision_step_gives_the_fp32_loss(tiny, monkeypatch):
    """train_depth.amp: one step under autocast (bfloat16 on a CPU; float16 + GradScaler on CUDA) gives the
    float32 step's loss to 2 % per term (bfloat16 keeps 8 bits of mantissa: 0.4 % per rounding), updates
    the weights, and the networks really ran in reduced precision (on any CPU: bfloat16 units assumed)."""
    monkeypatch.setattr(precision, "bfloat16_units", lambda: True)
    results, dtypes = {}, {}
    for amp in (False, True):
        torch.manual_seed(5)
        model = DepthModel(DepthModelConfig(64, 64))
        def record(_module, _inputs, out, amp=amp) -> None:
            dtypes.setdefault(amp, out.dtype)

        model.depth_decoder.dispconv.register_forward_hook(record)
        opt = torch.optim.Adam(model.parameters(), lr=1e-4)
        before = model.depth_decoder.dispconv.weight.detach().clone()
        _, logs = train_step(model, opt, tiny["batch"], tiny["teacher"],
                             StepConfig(train_fakes.WEIGHTS, min_area=10, amp=amp))
        assert not torch.equal(before, model.depth_decoder.dispconv.weight)
        results[amp] = logs
    assert dtypes == {False: torch.float32, True: amp_dtype("cpu")} and amp_dtype("cpu") == torch.bfloat16
    assert amp_dtype("cuda") == torch.float16
    for term in ("ph", "smooth", "planar", "rigid", "feature", "total"):
        assert results[True][term] == pytest.approx(results[False][term], rel=0.02), term
    assert results[True]["total"] != results[False]["total"]  # autocast did change the arithmetic


def test_amp_on_a_cpu_without_bfloat16_units_runs_float32_and_says_so(monkeypatch):
    """Without bfloat16 units oneDNN emulates bfloat16 (slower than float32): autocast stays off, one warning
    names the key."""
    conv = torch.nn.Conv2d(3, 4, 3)
    x = torch.rand(1, 3, 8, 8)
    with precision.autocast("cpu", True):
        assert conv(x).dtype == (torch.bfloat16 if precision.bfloat16_units() else torch.float32)
    monkeypatch.setattr(precision, "bfloat16_units", lambda: False)
    with pytest.warns(UserWarning, match="no bfloat16 units.*amp: false"), precision.autocast("cpu", True):
        assert conv(x).dtype == torch.float32
    with precision.autocast("cpu", False):
        assert conv(x).dtype == torch.float32


def test_compute_loss_matches_weighted_terms(tiny):
    torch.manual_seed(4)
    model = DepthModel(DepthModelConfig(64, 64))
    w = {**dict.fromkeys(TERMS, 0.0), "smooth": 0.01, "planar": 0.1, "rigid": 0.5, "feature": 2.0}
    loss, logs = compute_loss(model, tiny["batch"], tiny["teacher"], StepConfig(w, min_area=10))
    expected = (logs["ph"] + 0.01 * logs["smooth"] + 0.1 * logs["planar"] + 0.5 * logs["rigid"]
                + 2.0 * logs["feature"])
    assert float(loss.detach()) == pytest.approx(expected, rel=1e-5)
    assert logs["total"] == pytest.approx(expected, rel=1e-5)


# ---- learning: with the true pose and the true flow, DepthCNN learns the depth -------------------------

def test_depth_network_learns_a_rendered_room_from_true_pose_and_flow():
    """The whole depth path (DepthCNN, disp → depth, rigid flow, L_rigid + L_ph + L_sm, Adam) moves a real
    network to the true depth of a ray-traced room when the pose and the flow are right — what ImageNet
    PoseCNN and a trained flow network give the paper, and what the CPU default cannot learn from scratch
    (docs/depth_training.md). One view pair, overfitted: this checks gradients and conventions end to end."""
    hw = (64, 96)
    K = K_SYNTH * np.array([[1.5], [4 / 3], [1.0]])  # the 48×64 camera scaled to 64×96
    scene = room("nyu", "bedroom", "bedroom_0001", 0)
    poses, _ = handheld_path(scene, 40, rng_for(0, "learning-test"), PATHS["nyu"])
    c0, d0 = render(scene, poses[0], K, hw, 1)
    c1, _ = render(scene, poses[10], K, hw, 1)  # a third of a second later, as prepare's frame_step 10
    T = relative_pose(_t(poses[0], torch.float64)[None], _t(poses[10], torch.float64)[None]).float()
    gt_depth = _t(d0)[None, None]
    Kt = _t(K)[None]
    flow = TeacherOutput(rigid_flow(gt_depth, Kt, T), [], [])
    assert float(flow.flow.norm(dim=1).mean()) > 2.0  # pixels of motion, not a trivial pair
    img0, img1 = (_t(np.clip(c, 0, 1)).permute(2, 0, 1)[None] for c in (c0, c1))
    gen = torch.Generator().manual_seed(0)
    points = torch.stack([torch.randint(4, hw[1] - 4, (300,), generator=gen),
                          torch.randint(4, hw[0] - 4, (300,), generator=gen)], dim=-1).float()[None]
    batch = {"target": img0, "prev": img1, "next": img1, "K": Kt, "points": points,
             "segments": torch.zeros(1, *hw, dtype=torch.int64)}
    cfg = StepConfig({**dict.fromkeys(TERMS, 0.0), "smooth": 1e-3, "rigid": 1.0}, min_area=10)
    torch.manual_seed(0)
    model = DepthModel(DepthModelConfig(*hw))
    model.set_initial_depth(2.0)
    opt = torch.optim.Adam(list(model.depth_encoder.parameters()) + list(model.depth_decoder.parameters()),
                           lr=1e-3)

    def errors() -> tuple[float, float]:
        """(median-scaled AbsRel, correlation of log depths) of the current prediction."""
        model.eval()
        with torch.no_grad():
            pred = model.predict_depth(img0)[0, 0]
        model.train()
        g = gt_depth[0, 0]
        scaled = pred * g.median() / pred.median()
        corr = torch.corrcoef(torch.stack([pred.log().flatten(), g.log().flatten()]))[0, 1]
        return float(((scaled - g).abs() / g).mean()), float(corr)

    abs_rel0, corr0 = errors()
    for _ in range(60):
        disp = model.predict_disp(img0)
        net = NetOutput(disp, model.disp_to_depth(disp), T, T)
        loss, _ = total_loss(loss_terms(net, batch, flow, cfg), cfg.weights)
        opt.zero_grad()
        loss.backward()
        opt.step()
    abs_rel, corr = errors()
    assert abs(corr0) < 0.5 and corr > 0.9, (corr0, corr)
    assert abs_rel < 0.4 * abs_rel0, (abs_rel0, abs_rel)


class _ShiftNetwork(FlowNetwork):
    """A flow network that reports a constant shift forwards and ``back`` backwards (the check's input)."""

    def __init__(self, back: float) -> None:
        super().__init__()
        self.scale = torch.nn.Parameter(torch.ones(()))
        self.back = back

    def forward(self, img1, img2, with_backward=True):
        b, _, h, w = img1.shape
        fw = torch.zeros(b, 2, h, w)
        fw[:, 0] = 3.0 * self.scale
        bw = torch.zeros(b, 2, h, w)
        bw[:, 0] = self.back
        return [fw], ([bw] if with_backward else None)

    def features(self, img):
        return [img.mean(1, keepdim=True)]


@pytest.mark.parametrize("memo_mb", [0, 64])
def test_consistency_mask_keeps_where_the_teachers_flows_agree_and_rigid_reads_only_there(memo_mb):
    """train_depth.rigid_mask: consistency. A teacher whose backward flow undoes its forward flow (3 px
    right, then 3 px left) is valid wherever the forward flow stays in the image (the last 3 columns leave
    it); one whose backward flow repeats the forward flow is valid nowhere. L_rigid then averages only the
    valid pixels: a rigid flow wrong on the invalid columns alone costs nothing."""
    img = torch.rand(2, 3, 16, 20)
    agree = FlowTeacher(_ShiftNetwork(back=-3.0), memo_mb=memo_mb, consistency_mask=True)
    for _ in range(2):  # the second call: from the memo when there is one
        out = agree(img, img.flip(0))
        assert out.valid.shape == (2, 1, 16, 20)
        assert torch.equal(out.valid[..., :17], torch.ones(2, 1, 16, 17))
        assert torch.equal(out.valid[..., 17:], torch.zeros(2, 1, 16, 3))
    disagree = FlowTeacher(_ShiftNetwork(back=3.0), memo_mb=memo_mb, consistency_mask=True)
    assert disagree(img, img.flip(0)).valid.sum() == 0
    assert FlowTeacher(_ShiftNetwork(back=-3.0)).__call__(img, img).valid is None  # the paper: every pixel
    rigid = out.flow.clone()
    rigid[..., 17:] += 5.0  # wrong only where the teacher is not trusted
    assert rigid_flow_loss(rigid, out.flow, out.valid) == 0
    assert rigid_flow_loss(rigid, out.flow) > 0
