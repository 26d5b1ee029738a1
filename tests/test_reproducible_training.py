"""Same inputs, same weights: a training stage's thread count stays what it was given for the whole run,
whatever else the machine runs; only inference, whose result no thread count changes, follows the cores
that other processes leave free (f2depth.threads)."""

from __future__ import annotations

import itertools

import torch
import train_fakes
import yaml
from test_train_stage import load_stage

from f2depth import threads
from f2depth.depth import DepthModel, DepthModelConfig


def test_a_forward_pass_gives_the_same_bits_at_any_thread_count(restore_threads):
    """Why evaluate and predict may follow the free cores: inference does not depend on the count."""
    torch.manual_seed(0)
    model = DepthModel(DepthModelConfig(64, 96)).eval()
    images = torch.rand(3, 3, 64, 96)
    outs = []
    for n in (1, 2, 3, 1):
        torch.set_num_threads(n)
        with torch.no_grad():
            outs.append(model.predict_disp(images))
    assert all(torch.equal(outs[0], out) for out in outs[1:])


def test_use_follows_the_free_cores_only_when_asked(monkeypatch, restore_threads):
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.setattr(threads, "usable_cpus", lambda cgroup=threads.CGROUP: 2)
    assert threads.use(None) == 2 and threads._free is None and threads.adapt() is None  # training
    assert threads.use(None, follow_free_cores=True) == 2 and threads._free is not None  # inference
    assert threads.use(2, follow_free_cores=True) == 2 and threads._free is None  # a fixed count stays


def _train(root, params_path, monkeypatch) -> dict[str, torch.Tensor]:
    stage = load_stage(monkeypatch)
    out = root / "out"
    stage.main(["train_depth.py", "--variant", "full", "--params", str(params_path),
                "--models", str(out / "models"), "--metrics", str(out / "metrics"), "--no-resume"])
    state = torch.load(out / "models" / "depth_full" / "model.pt", map_location="cpu", weights_only=True)
    return state.get("state_dict", state)


def test_train_depth_gives_the_same_weights_beside_a_busy_process(tmp_path, monkeypatch, restore_threads):
    """The automatic count (threads: null) under a load that comes and goes — the free cores measured as
    1, 2, 1, 2 … between steps — trains the same weights as a fixed count of 2 on a quiet machine. Before
    the training loop stopped following the free cores, the count changed between steps and with it the
    summation order of the backward pass."""
    prep = train_fakes.write_prepared(tmp_path / "prepared", hw=(64, 64), scenes=1, frames=6)
    mat, splits = train_fakes.write_nyu_test(tmp_path, n=2)
    flow = train_fakes.write_flow_model(tmp_path / "flow.pt")
    path = train_fakes.write_params(tmp_path, prep, mat, splits, flow, epochs=2, seeds=[0], val_every=2)
    params = yaml.safe_load(path.read_text())
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.setattr(threads, "usable_cpus", lambda cgroup=threads.CGROUP: 2)

    params["threads"] = 2
    path.write_text(yaml.safe_dump(params))
    quiet = _train(tmp_path / "quiet", path, monkeypatch)

    schedule = itertools.cycle((1, 2))
    monkeypatch.setattr(threads.FreeCores, "threads", lambda self: next(schedule))
    params["threads"] = None
    path.write_text(yaml.safe_dump(params))
    busy = _train(tmp_path / "busy", path, monkeypatch)

    assert list(quiet) == list(busy) and len(quiet) > 100
    assert all(torch.equal(quiet[k], busy[k]) for k in quiet)


def _seed_weights(root, params_path, monkeypatch, seed: int) -> tuple[dict[str, torch.Tensor], dict]:
    stage = load_stage(monkeypatch)
    stage.main(["train_depth.py", "--variant", "full", "--params", str(params_path),
                "--models", str(root / "models"), "--metrics", str(root / "metrics"), "--no-resume"])
    state = torch.load(root / "models" / "depth_full" / f"seed{seed}.pt", map_location="cpu",
                       weights_only=True)
    metrics = yaml.safe_load((root / "metrics" / "full.json").read_text())
    return state.get("state_dict", state), metrics


def test_seeds_side_by_side_give_each_seed_the_weights_it_gets_alone(tmp_path, monkeypatch, restore_threads):
    """train_depth.seed_threads: 1 trains seeds 0 and 1 in two processes at once (f2depth.processes);
    seed 1's weights are bit-identical to seed 1 trained alone in the stage's own process at one thread, so
    neither the other seed's process, nor how the OS shares the cores, nor the process boundary changes a
    result. The metrics file records both seeds, the stage process's metrics come from the processes."""
    prep = train_fakes.write_prepared(tmp_path / "prepared", hw=(64, 64), scenes=1, frames=6)
    mat, splits = train_fakes.write_nyu_test(tmp_path, n=2)
    flow = train_fakes.write_flow_model(tmp_path / "flow.pt")
    path = train_fakes.write_params(tmp_path, prep, mat, splits, flow, epochs=2, seeds=[0, 1], val_every=2,
                                    seed_threads=1)
    side_by_side, metrics = _seed_weights(tmp_path / "pool", path, monkeypatch, seed=1)
    assert metrics["seed_threads"] == 1 and [s["seed"] for s in metrics["per_seed"]] == [0, 1]
    assert metrics["per_seed"][0]["val_trained"] != metrics["per_seed"][1]["val_trained"]  # two trainings

    params = yaml.safe_load(path.read_text())
    params["threads"], params["train_depth"]["seeds"], params["train_depth"]["seed_threads"] = 1, [1], None
    path.write_text(yaml.safe_dump(params))
    alone, metrics_alone = _seed_weights(tmp_path / "alone", path, monkeypatch, seed=1)
    assert metrics_alone["seed_threads"] is None
    assert list(alone) == list(side_by_side) and len(alone) > 100
    assert all(torch.equal(alone[k], side_by_side[k]) for k in alone)
    assert metrics_alone["per_seed"][0]["val_trained"] == metrics["per_seed"][1]["val_trained"]
    assert metrics["val_constant_depth"] == metrics_alone["val_constant_depth"]  # the floors, from a process
    assert metrics["val_constant_depth"]["a1"] is not None
