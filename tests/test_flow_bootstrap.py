"""The supervised bootstrap of a from-scratch flow network (f2depth.flow.bootstrap): the data-dependent
init normalises every convolution and gives the cost volume per-pixel information that MSRA does not, the
matching loss and the multi-scale EPE score what they claim, and a short run on generated pairs makes a
PWC-Lite whose flow follows the images (EPE well below zero flow's, positive swap consistency)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F
import train_fakes

from f2depth import precision
from f2depth.flow import PWCLite
from f2depth.flow.bootstrap import (
    BootstrapConfig,
    data_dependent_init,
    flow_at,
    heldout_pairs,
    matching_loss,
    multiscale_epe,
    pretrain_chairs,
    zero_flow_heads,
)
from f2depth.flow.chairs import ChairsSpec, texture_pool
from f2depth.flow.net.correlation import correlation
from f2depth.flow.net.network import msra_init


def small_config(data_changes: dict | None = None, **changes) -> BootstrapConfig:
    """A bootstrap that runs in seconds: 64×64 pairs of one or two still shapes, batch 2, one phase-A and
    three phase-B epochs of 2 steps, float32; ``changes`` (and ``data_changes``) override keys."""
    data = ChairsSpec(**{"height": 64, "width": 64, "max_shift": 4, "small_share": 0.25, "rotation_deg": 0,
                         "scale": 0.0, "min_shapes": 1, "max_shapes": 1, "min_size": 0.2, "max_size": 0.4,
                         "supersample": 1, "textures": 2, "image_crops": 0, **(data_changes or {})})
    return BootstrapConfig(**{"data": data, "batch_size": 2, "steps_per_epoch": 2, "feature_epochs": 1,
                              "feature_lr": 1e-3, "epochs": 3, "lr": 3e-4, "final_lr": 3e-5,
                              "matching_weight": 0.5, "matching_strides": (4,),
                              "w_scales": (0.32, 0.08, 0.02, 0.01, 0.005), "calibration_pairs": 2,
                              "heldout_pairs": 2, "average_epochs": 1, "amp": False, "cpu_ranks": None,
                              **changes})


def textured_shift(shift: int, generator: torch.Generator, n: int = 2) -> tuple[torch.Tensor, torch.Tensor]:
    """``n`` random textured 64×128 images and the same shifted ``shift`` px right (wrapping)."""
    coarse = torch.rand(n, 3, 32, 64, generator=generator)
    img = F.interpolate(coarse, size=(64, 128), mode="bilinear", align_corners=False)
    return img, torch.roll(img, shifts=shift, dims=-1)


def per_pixel_hits(model: PWCLite, img: torch.Tensor, shifted: torch.Tensor, level: int, true_dx: int
                   ) -> float:
    """Share of interior pixels of pyramid ``level`` whose cost-volume argmax is the true displacement."""
    with torch.no_grad():
        f1, f2 = model.features(img)[level], model.features(shifted)[level]
        best = correlation(f1, f2).argmax(1)[..., 4:-4, 4:-4]
    return float((best == (0 + 4) * 9 + true_dx + 4).float().mean())


def test_msra_init_draws_kaiming_normal_with_zero_bias():
    model = msra_init(PWCLite(), torch.Generator().manual_seed(0))
    w = model.flow_estimators.conv3[0].weight.detach()
    assert abs(float(w.std()) - (2 / (256 * 9)) ** 0.5) < 0.1 * (2 / (256 * 9)) ** 0.5
    convs = [m for m in model.modules() if isinstance(m, torch.nn.Conv2d)]
    assert all(float(m.bias.detach().abs().max()) == 0 for m in convs)


def test_data_dependent_init_gives_the_cost_volume_per_pixel_information():
    """Per pixel (not averaged over the image, which hides it): after MSRA the 1/4-level argmax is at the
    true 8 px shift (2 px there) about as often as chance (1/81); after the data-dependent init far more."""
    g = torch.Generator().manual_seed(0)
    msra = msra_init(PWCLite(), torch.Generator().manual_seed(1))
    img, shifted = textured_shift(8, g)
    before = per_pixel_hits(msra, img, shifted, 1, 2)
    ddi = msra_init(PWCLite(), torch.Generator().manual_seed(1))
    zero_flow_heads(ddi)
    calib, calib_shifted = textured_shift(4, g, n=4)
    report = data_dependent_init(ddi, calib, calib_shifted, skip=ddi.flow_heads())
    after = per_pixel_hits(ddi, img, shifted, 1, 2)
    assert before < 0.05
    assert after > 0.15 and after > 4 * before
    assert report["convolutions"] == 28 and report["max_std_error"] < 1e-3 and report["max_abs_mean"] < 1e-3


def test_zeroed_heads_start_from_zero_flow():
    model = msra_init(PWCLite(), torch.Generator().manual_seed(0))
    assert zero_flow_heads(model) == 2
    with torch.no_grad():
        fw, bw = model(torch.rand(1, 3, 64, 64), torch.rand(1, 3, 64, 64))
    assert all(float(f.abs().max()) == 0 for f in fw + bw)


def test_matching_loss_scores_the_true_displacement():
    g = torch.Generator().manual_seed(0)
    f1 = torch.randn(2, 64, 16, 24, generator=g)   # stride 4 of a 64×96 image
    f2 = torch.roll(f1, shifts=(1, -2), dims=(-2, -1)) * 4
    flow = torch.zeros(2, 2, 64, 96)
    flow[:, 0], flow[:, 1] = -8.0, 4.0            # (−2, +1) at stride 4
    occluded = torch.zeros(2, 1, 64, 96, dtype=torch.bool)
    occluded[..., :8, :] = True                    # the top two rows of the level are not scored
    occluded[..., -4:, :] = True                   # and where the match leaves the image (bottom row, two
    occluded[..., :, :8] = True                    # left columns of the level)
    loss, stats = matching_loss([f1], [f2], flow, occluded, strides=(4,))
    assert stats["top1_s4"] > 0.95 and float(loss) < 0.1
    wrong, wstats = matching_loss([f1], [f2], -flow, occluded, strides=(4,))
    assert wstats["top1_s4"] < 0.05 and float(wrong) > 10 * float(loss)
    with pytest.raises(ValueError, match="stride"):
        matching_loss([f1], [f2], flow, occluded, strides=(8,))


def test_multiscale_epe_is_zero_for_the_area_averaged_truth_and_weighs_levels():
    gt = torch.randn(2, 2, 64, 64) * 3
    flows = [flow_at(gt, (64 // 2**i, 64 // 2**i)) for i in range(3)]
    loss, levels = multiscale_epe(flows, gt, (0.32, 0.08, 0.02))
    assert float(loss) < 1e-5 and max(levels) < 1e-5
    off = [flows[0] + torch.tensor([3.0, 4.0]).view(1, 2, 1, 1), flows[1], flows[2]]
    loss, levels = multiscale_epe(off, gt, (0.32, 0.08, 0.02))
    assert levels[0] == pytest.approx(5.0, rel=1e-5) and float(loss) == pytest.approx(0.32 * 5.0, rel=1e-5)


@pytest.mark.slow
def test_a_short_bootstrap_learns_flow_that_follows_the_images():
    """The whole recipe at a small scale (≈ 5 minutes on one slow thread; the default's generator at 64×64,
    100 phase-A steps and 200 phase-B steps of batch 8, lr 6e-4 falling to 1e-4): matching top-1 far
    above chance (1/81) after phase A, then on held-out pairs an EPE well below zero flow's and a clearly
    positive swap consistency. A network that ignores its inputs (what plain training from MSRA ends at)
    has swap ≈ −1 and the EPE of zero flow. Measured: top-1 0.15 → 0.32, EPE 0.69× zero flow's, swap 0.72."""
    torch.manual_seed(0)
    data = ChairsSpec(height=64, width=64, max_shift=8, small_share=0.25, rotation_deg=5, scale=0.05,
                      min_shapes=1, max_shapes=4, min_size=0.12, max_size=0.4, supersample=1, textures=24,
                      image_crops=0)
    cfg = BootstrapConfig(data=data, batch_size=8, steps_per_epoch=50, feature_epochs=2, feature_lr=2e-3,
                          epochs=4, lr=6e-4, final_lr=1e-4, matching_weight=0.5, matching_strides=(4, 8),
                          w_scales=(0.32, 0.08, 0.02, 0.01, 0.005), calibration_pairs=4, heldout_pairs=16,
                          average_epochs=1, amp=False, cpu_ranks=None)
    pool = texture_pool(data, np.random.default_rng(0))
    model = PWCLite()
    out = pretrain_chairs(model, pool, cfg, seed=0, network="pwclite", heldout=heldout_pairs(cfg, 0, pool),
                          device="cpu", progress=False)
    start, after, final = out["start"], out["after_features"], out["final"]
    assert start["heldout_epe"] == pytest.approx(start["heldout_zero_epe"])  # zeroed heads: zero flow
    assert after["heldout_top1_s4"] > 0.2 and after["heldout_top1_s4"] > start["heldout_top1_s4"] + 0.08
    assert final["heldout_epe"] < 0.85 * final["heldout_zero_epe"]
    assert final["heldout_swap"] > 0.35
    assert [r["phase"] for r in out["history"]] == ["features"] * 2 + ["all"] * 4


def test_phase_b_lr_falls_along_a_cosine_from_lr_to_final_lr():
    kw = {"steps_per_epoch": 10, "w_scales": (1.0,)}
    cfg = small_config(lr=3e-4, final_lr=3e-5, **kw)
    lrs = [cfg.phase_b_lr(i) for i in range(30)]
    assert lrs[0] == pytest.approx(3e-4) and lrs[-1] == pytest.approx(3e-5)
    assert lrs[14] == pytest.approx(3e-5 + 0.5 * 2.7e-4 * (1 + np.cos(np.pi * 14 / 29)))
    assert all(a > b for a, b in zip(lrs, lrs[1:]))
    assert cfg.phase_b_lr(100) == pytest.approx(3e-5)  # past the end: stays at final_lr
    assert small_config(lr=3e-4, final_lr=3e-4, **kw).phase_b_lr(7) == pytest.approx(3e-4)
    with pytest.raises(ValueError, match="final_lr"):
        small_config(lr=3e-4, final_lr=1e-3, **kw)
    with pytest.raises(ValueError, match="average_epochs"):
        small_config(lr=3e-4, final_lr=3e-5, **{**kw, "average_epochs": 4})


def test_the_kept_weights_are_the_mean_of_the_last_epochs_and_survive_a_resume(tmp_path):
    """average_epochs = 2: the network left behind is the mean of phase B's last two epoch ends (read from
    each epoch's state), and a run broken between those two epochs resumes to the same mean, bit for bit."""
    cfg = small_config(average_epochs=2)
    pool = texture_pool(cfg.data, np.random.default_rng(0))
    test = heldout_pairs(cfg, 0, pool)
    torch.set_num_threads(1)
    ends = {}

    def keep(model):
        def on_epoch(row):
            ends[row["epoch"]] = {k: v.clone() for k, v in model.state_dict().items()}
        return on_epoch

    torch.manual_seed(0)
    whole = PWCLite()
    out = pretrain_chairs(whole, pool, cfg, 0, "pwclite", test, tmp_path / "a", on_epoch=keep(whole),
                          progress=False)
    assert out["averaged_epochs"] == 2 and sorted(ends) == [1, 2, 3, 4]
    for name, value in whole.state_dict().items():
        torch.testing.assert_close(value, (ends[3][name] + ends[4][name]) / 2, rtol=1e-6, atol=1e-7)
    assert not torch.equal(whole.state_dict()["flow_estimators.conv1.0.weight"],
                           ends[4]["flow_estimators.conv1.0.weight"])

    torch.manual_seed(0)
    with pytest.raises(train_fakes.Crash):
        pretrain_chairs(PWCLite(), pool, cfg, 0, "pwclite", test, tmp_path / "b",
                        on_epoch=train_fakes.crash_after(3), progress=False)
    resumed = PWCLite()
    again = pretrain_chairs(resumed, pool, cfg, 0, "pwclite", test, tmp_path / "b", progress=False)
    assert again["resumed_from"] == 3 and again["averaged_epochs"] == 2
    assert all(torch.equal(v, resumed.state_dict()[k]) for k, v in whole.state_dict().items())


def test_amp_runs_the_network_in_bfloat16_and_keeps_the_losses_float32(monkeypatch):
    """flow_pretrain.chairs.amp (off in the CPU default, docs/flow_pretrain.md): phase A's pyramid and
    phase B's whole network run under bfloat16 autocast while the matching loss and the multi-scale EPE are
    computed in float32; each epoch's training loss stays within a few per cent of the float32 run's from
    the same start, and the weights stay float32."""
    monkeypatch.setattr(precision, "bfloat16_units", lambda: True)  # autocast acts on any CPU
    shapes = {"max_shapes": 2, "textures": 3}
    pool = texture_pool(small_config(shapes).data, np.random.default_rng(0))
    runs, seen = {}, {}
    torch.set_num_threads(1)
    for amp in (False, True):
        cfg = small_config(shapes, epochs=1, amp=amp)
        torch.manual_seed(0)
        model = PWCLite()
        dtypes = seen.setdefault(amp, set())
        model.flow_estimators.conv1.register_forward_hook(lambda _m, _i, y, d=dtypes: d.add(y.dtype))
        model.feature_pyramid_extractor.register_forward_hook(lambda _m, _i, y, d=dtypes: d.add(y[0].dtype))
        runs[amp] = pretrain_chairs(model, pool, cfg, 0, "pwclite", heldout_pairs(cfg, 0, pool),
                                    progress=False)
        assert all(p.dtype == torch.float32 for p in model.parameters())
    assert seen[False] == {torch.float32} and torch.bfloat16 in seen[True]
    for fp32, amp in zip(runs[False]["history"], runs[True]["history"]):
        assert amp["loss"] == pytest.approx(fp32["loss"], rel=0.05) and amp["loss"] != fp32["loss"]
