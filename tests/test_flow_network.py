"""The flow-network interface (f2depth.flow.net.network) and its registry
(f2depth.flow.net.checkpoint.NETWORKS): a second network, registered for the test only, goes through the
checkpoint, the `flow_pretrain` stage, the frozen teacher of depth training, fine-tuning and evaluation, none
of which names PWC-Lite (the walk-through "Swapping the flow network" of docs/flow_finetune.md)."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F
import train_fakes
from test_flow_pretrain import run_stage
from torch import nn

from f2depth.flow import NETWORKS, CheckpointError, FlowNetwork, PWCLite, build_network, load_flow_model
from f2depth.flow.finetune import FinetuneConfig, finetune
from f2depth.flow.finetune_data import FlowPairs, gt_pairs
from f2depth.flow.net.checkpoint import read_flow_checkpoint, save_flow_model
from f2depth.formats.prepared import PreparedSet
from f2depth.keypoints import KeypointFile
from f2depth.train.teacher import FlowTeacher


class TinyFlow(FlowNetwork):
    """One flow level at the input size from a one-level stride-2 encoder (RAFT-like output: no pyramid)."""

    def __init__(self, channels: int = 4) -> None:
        super().__init__()
        self.channels = channels
        self.encoder = nn.Conv2d(3, channels, 3, stride=2, padding=1)
        self.head = nn.Conv2d(2 * channels, 2, 3, padding=1)

    def architecture(self) -> dict:
        return {"channels": self.channels}

    def features(self, img: torch.Tensor) -> list[torch.Tensor]:
        return [self.encoder(img)]

    def _flow(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        f = self.head(torch.cat([self.features(a)[0], self.features(b)[0]], 1))
        return 2 * F.interpolate(f, size=a.shape[-2:], mode="bilinear", align_corners=True)

    def forward(self, img1, img2, with_backward=True):
        return [self._flow(img1, img2)], ([self._flow(img2, img1)] if with_backward else None)


@pytest.fixture
def tiny(monkeypatch):
    monkeypatch.setitem(NETWORKS, "tiny", TinyFlow)


def _same(a: nn.Module, b: nn.Module) -> bool:
    sa, sb = a.state_dict(), b.state_dict()
    return list(sa) == list(sb) and all(torch.equal(v, sb[k]) for k, v in sa.items())


def test_pwclite_is_the_registered_default_and_the_interface_is_abstract():
    assert dict(NETWORKS) == {"pwclite": PWCLite}
    assert isinstance(build_network("pwclite"), FlowNetwork)
    assert PWCLite().architecture() == {}
    with pytest.raises(ValueError, match=r"unknown flow network 'raft'.*\['pwclite'\]"):
        build_network("raft")
    with pytest.raises(TypeError, match="abstract"):
        FlowNetwork()


def test_checkpoint_records_the_network_and_its_architecture(tiny, tmp_path):
    torch.manual_seed(0)
    model = TinyFlow(channels=6)
    save_flow_model(tmp_path / "flow.pt", model, config={"source": "test"})
    raw = torch.load(tmp_path / "flow.pt", weights_only=True)
    assert raw["network"] == "tiny" and raw["network_kwargs"] == {"channels": 6}
    loaded, meta = read_flow_checkpoint(tmp_path / "flow.pt")
    assert type(loaded) is TinyFlow and loaded.channels == 6 and not loaded.training and _same(loaded, model)
    assert meta["network"] == "tiny" and meta["network_kwargs"] == {"channels": 6}
    x1, x2 = torch.rand(1, 3, 16, 24), torch.rand(1, 3, 16, 24)
    assert torch.equal(loaded(x1, x2)[0][0], model.eval()(x1, x2)[0][0])


def test_a_foreign_state_dict_is_read_into_the_network_named(tiny, tmp_path):
    model = TinyFlow()
    torch.save({"epoch": 2, "state_dict": {f"module.{k}": v for k, v in model.state_dict().items()}},
               tmp_path / "released.pth")
    assert _same(load_flow_model(tmp_path / "released.pth", "tiny"), model)
    with pytest.raises(CheckpointError, match="does not fit the flow network 'pwclite'; 60 missing key"):
        load_flow_model(tmp_path / "released.pth")


def test_unregistered_networks_are_named_in_the_error(tmp_path):
    with pytest.raises(ValueError, match="TinyFlow is not a registered flow network"):
        save_flow_model(tmp_path / "flow.pt", TinyFlow())
    torch.save({"format": "f2depth.flow", "version": 2, "network": "tiny", "network_kwargs": {},
                "state_dict": TinyFlow().state_dict()}, tmp_path / "flow.pt")
    with pytest.raises(CheckpointError, match=r"'tiny' is not in f2depth\.flow\.net\.checkpoint\.NETWORKS"):
        load_flow_model(tmp_path / "flow.pt")


def test_the_stage_pretrains_the_network_params_name_and_training_uses_it(tiny, tmp_path, monkeypatch):
    run_stage(tmp_path, monkeypatch, network="tiny", passes=["clean"], figures=0)
    path = tmp_path / "models" / "flow_pretrained.pt"
    assert torch.load(path, weights_only=True)["network"] == "tiny"

    # the frozen teacher of depth training: the finest forward flow and the network's own pyramid
    teacher = FlowTeacher.load(path)
    assert type(teacher.net) is TinyFlow
    target, source = torch.rand(2, 3, 24, 32), torch.rand(2, 3, 24, 32)
    out = teacher(target, source)
    with torch.no_grad():
        assert torch.equal(out.flow, teacher.net(target, source, with_backward=False)[0][0])
        assert [f.shape for f in out.feats_tgt] == [f.shape for f in out.feats_src] == [(2, 4, 12, 16)]
        assert torch.equal(out.feats_src[0], teacher.net.features(source)[0])

    # fine-tuning with either loss on the one level the network has, scored on ground truth
    prep = train_fakes.write_prepared(tmp_path / "prepared", hw=(64, 64), scenes=1, frames=4, seed=4)
    ds = PreparedSet(prep)
    pairs = FlowPairs(ds, ds.pairs, KeypointFile(tmp_path / "keypoints" / "train.npz"))
    for loss in ("patch", "full"):
        model = load_flow_model(path)
        before = {k: v.clone() for k, v in model.state_dict().items()}
        cfg = FinetuneConfig(loss=loss, epochs=1, batch_size=2, w_scales=(1.0,), backward=True,
                             occlusion="range_map")
        info = finetune(model, pairs, cfg, gt_pairs(ds, ds.pairs), progress=False)
        row = info["history"][0]
        assert row["steps"] == 2 and row["skipped_steps"] == 0 and math.isfinite(row["loss"])
        assert row["photometric"] > 0 and row["noc_fraction"] > 0
        assert math.isfinite(row["epe_all"])
        assert any(not torch.equal(v, before[k]) for k, v in model.state_dict().items())
