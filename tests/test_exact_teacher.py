"""train_depth.teacher: exact — the frozen teacher's flow replaced by the ground-truth rigid flow (a
diagnosis of the synthetic default, f2depth.train.exact_teacher): its flow is the ray-traced flow of an
independent renderer, flipped pairs get the mirrored flow, the features stay the network's, real data and the
paper's profile refuse it, and the train_depth stage runs and records it."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
import train_fakes
import yaml
from depth_scenes import plane_scene
from test_train_stage import load_stage

from f2depth import params as P
from f2depth.errors import DataError
from f2depth.flow import PWCLite
from f2depth.formats.prepared import PreparedSet
from f2depth.train.augment import flip_image
from f2depth.train.exact_teacher import ExactTeacher, image_key
from f2depth.train.settings import settings_from_params
from f2depth.train.teacher import FlowTeacher


@pytest.fixture(scope="module")
def scene_teacher():
    """An ExactTeacher that knows the two views of the ray-traced plane (target at the world origin)."""
    scene = plane_scene(64, 64)
    tgt = torch.from_numpy(scene.img_t).permute(2, 0, 1).float().contiguous()
    src = torch.from_numpy(scene.img_s).permute(2, 0, 1).float().contiguous()
    truth = {image_key(tgt): ("t", False), image_key(flip_image(tgt)): ("t", True),
             image_key(src): ("s", False), image_key(flip_image(src)): ("s", True)}
    depth = {"t": torch.from_numpy(scene.depth_t)[None], "s": torch.from_numpy(scene.depth_s)[None]}
    world = {"t": torch.eye(4, dtype=torch.float64), "s": torch.linalg.inv(torch.from_numpy(scene.src_T_tgt))}
    torch.manual_seed(0)
    net = PWCLite()
    return scene, tgt, src, ExactTeacher(net, truth, depth, world, torch.from_numpy(scene.K)), net


def test_the_flow_is_the_ray_traced_flow_and_the_features_the_networks(scene_teacher):
    scene, tgt, src, teacher, net = scene_teacher
    out = teacher(tgt[None], src[None])
    reference = torch.from_numpy(scene.flow).permute(2, 0, 1).float()
    assert (out.flow[0] - reference).abs().max() < 1e-3 and reference.abs().max() > 1.0
    network = FlowTeacher(net)(tgt[None], src[None])
    assert (network.flow - reference).abs().mean() > 0.5  # the random network's flow is not it
    assert all(torch.equal(a, b) for a, b in zip(out.feats_tgt, network.feats_tgt))


def test_a_flipped_pair_gets_the_mirrored_flow(scene_teacher):
    scene, tgt, src, teacher, _ = scene_teacher
    out = teacher(torch.stack([tgt, flip_image(tgt)]), torch.stack([src, flip_image(src)]))
    reference = torch.from_numpy(scene.flow).permute(2, 0, 1).float()
    mirrored = torch.flip(reference, dims=(-1,)) * torch.tensor([-1.0, 1.0])[:, None, None]
    assert (out.flow[0] - reference).abs().max() < 1e-3
    assert (out.flow[1] - mirrored).abs().max() < 1e-3
    with pytest.raises(ValueError, match="one frame flipped"):
        teacher(tgt[None], flip_image(src)[None])
    with pytest.raises(ValueError, match="no training frame"):
        teacher((tgt * 0.5)[None], src[None])


def _setup(tmp_path, **train):
    prep = train_fakes.write_prepared(tmp_path / "prepared", hw=(64, 64), scenes=1, frames=6)
    mat, splits = train_fakes.write_nyu_test(tmp_path, n=2)
    flow = train_fakes.write_flow_model(tmp_path / "flow.pt")
    path = train_fakes.write_params(tmp_path, prep, mat, splits, flow, epochs=1, seeds=[0], **train)
    params = yaml.safe_load(path.read_text())
    params["data_source"] = "synthetic"
    path.write_text(yaml.safe_dump(params))
    return prep, flow, path


def test_the_prepared_sets_ground_truth_gives_the_flow_and_real_data_is_refused(tmp_path):
    prep, flow, _ = _setup(tmp_path)
    prepared = PreparedSet(prep)
    teacher = ExactTeacher.from_prepared(str(flow), prepared)
    t = prepared.tuples[0]
    images = [torch.from_numpy(prepared.image(f)).permute(2, 0, 1).float() / 255 for f in (t.target, t.next)]
    out = teacher(images[0][None], images[1][None])
    # the fake world: a fronto-parallel wall at 2 m, the camera 5 cm to the right a frame (fx ≈ 0.9·64)
    expected = -0.05 * prepared.K[0, 0] / 2.0
    assert torch.allclose(out.flow[0, 0], torch.full((64, 64), expected), atol=1e-4)
    assert out.flow[0, 1].abs().max() < 1e-5
    frames = (prep / "frames.csv").read_text().splitlines()
    (prep / "frames.csv").write_text("\n".join([frames[0]] + [r.rsplit(",", 1)[0] + "," for r in frames[1:]])
                                     + "\n")
    with pytest.raises(DataError, match="has no ground truth.*set train_depth.teacher: network"):
        ExactTeacher.from_prepared(str(flow), PreparedSet(prep))


@pytest.mark.parametrize("edit", [{"data_source": "real"}, {"allow_random_init": False}])
def test_exact_is_refused_outside_the_synthetic_default_in_one_line(tmp_path, edit):
    _, _, path = _setup(tmp_path, teacher="exact")
    params = P.load(path)
    assert settings_from_params(params, "full").teacher == "exact"
    params.update(edit)
    with pytest.raises(P.ParamsError, match="train_depth.teacher: exact needs") as info:
        settings_from_params(params, "full")
    assert "\n" not in str(info.value)


def test_the_stage_trains_with_the_exact_teacher_and_records_it(tmp_path, monkeypatch):
    _, _, path = _setup(tmp_path, teacher="exact")
    stage = load_stage(monkeypatch)
    stage.main(["train_depth.py", "--variant", "full", "--params", str(path),
                "--models", str(tmp_path / "models"), "--metrics", str(tmp_path / "metrics")])
    metrics = json.loads((tmp_path / "metrics" / "full.json").read_text())
    assert metrics["teacher"] == "exact" and np.isfinite(metrics["final_losses"]["rigid"])
