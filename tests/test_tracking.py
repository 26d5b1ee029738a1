"""MLflow mirror: one parent run per pipeline invocation, one child per stage, params/metrics logged."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
import urllib.parse
from pathlib import Path

import pytest
import torch
from mlflow.tracking import MlflowClient
from test_stage_evaluate import tree  # noqa: F401 (the evaluate stage's tiny test sets, a fixture)

from f2depth import tracking

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture()
def mlflow_uri(tmp_path, monkeypatch):
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    monkeypatch.setenv("F2DEPTH_MLFLOW", "1")
    monkeypatch.delenv("DVC_STAGE", raising=False)
    monkeypatch.setenv("DVC_EXP_NAME", "exp-test")
    monkeypatch.chdir(tmp_path)  # the store's artifacts (./mlruns) stay in the test's folder
    return uri


def test_flatten_nested_params():
    assert tracking.flatten({"a": {"b": 1, "c": {"d": [1, 2]}}, "_file": "x", "e": 2}) == {
        "a.b": 1,
        "a.c.d": [1, 2],
        "e": 2,
    }


def test_stages_share_one_parent_and_log(mlflow_uri, tmp_path):
    params = {"seed": 3, "train_depth": {"epochs": 2, "lr": [1e-4, 1e-5]}, "prepare": {"height": 96}}
    art = tmp_path / "table.md"
    art.write_text("| a |\n")
    with tracking.stage_run("train_depth", params, variant="full") as run:
        run.log_metrics({"loss": 1.5, "val": {"a1": 0.5}}, step=0)
        run.log_metrics({"loss": 1.0}, step=1)
        run.log_artifact(art)
        first = run.run_id
    with tracking.stage_run("prepare", params) as run:
        second = run.run_id

    client = MlflowClient(tracking_uri=mlflow_uri)
    r1, r2 = client.get_run(first), client.get_run(second)
    parent = r1.data.tags["mlflow.parentRunId"]
    assert parent == r2.data.tags["mlflow.parentRunId"]
    assert client.get_run(parent).data.tags["dvc_experiment"] == "exp-test"
    assert r1.data.params["seed"] == "3"
    assert r1.data.params["train_depth.epochs"] == "2"
    assert "prepare.height" not in r1.data.params
    assert r1.data.metrics["loss"] == 1.0
    assert [m.value for m in client.get_metric_history(first, "loss")] == [1.5, 1.0]
    assert r1.data.metrics["val.a1"] == 0.5
    assert r1.info.status == "FINISHED"
    assert [a.path for a in client.list_artifacts(first)] == ["table.md"]


def test_metric_names_are_the_history_columns_and_the_metrics_file_paths(mlflow_uri):
    """One scheme (issue 24 item 5): curves under their history.csv column at step = epoch, results under
    their metrics-JSON path; strings, bools, None and lists are not metrics."""
    history = [{"epoch": 1, "loss": 2.0, "epe_all": None, "phase": "features", "steps": 4},
               {"epoch": 2, "loss": 1.5, "epe_all": 3.0, "phase": "all", "steps": 4}]
    summary = {"loss": "patch", "finetuned": {"test": {"epe_all": 2.5, "pairs": 5}}, "ground_truth": True,
               "test_scenes": ["a"], "history": history}
    with tracking.stage_run("flow_finetune", {}, variant="patch") as run:
        for row in history:
            run.log_epoch(row)
        run.log_summary(summary)
        run_id = run.run_id
    client = MlflowClient(tracking_uri=mlflow_uri)
    metrics = client.get_run(run_id).data.metrics
    assert set(metrics) == {"loss", "epe_all", "steps", "finetuned.test.epe_all", "finetuned.test.pairs"}
    assert [(m.step, m.value) for m in client.get_metric_history(run_id, "loss")] == [(1, 2.0), (2, 1.5)]
    assert [(m.step, m.value) for m in client.get_metric_history(run_id, "epe_all")] == [(2, 3.0)]
    assert metrics["finetuned.test.epe_all"] == 2.5


def test_failed_stage_marks_run_failed(mlflow_uri):
    with pytest.raises(RuntimeError), tracking.stage_run("synth", {"synth": {}}) as run:
        rid = run.run_id
        raise RuntimeError("boom")
    client = MlflowClient(tracking_uri=mlflow_uri)
    run = client.get_run(rid)
    assert run.info.status == "FAILED"
    assert client.get_run(run.data.tags["mlflow.parentRunId"]).info.status == "FAILED"


def test_last_stage_closes_the_pipeline_run(mlflow_uri, tmp_path):
    overlays = tmp_path / "overlays"
    overlays.mkdir()
    (overlays / "a.png").write_bytes(b"png")
    tracking.mirror_stage("keypoints", {"keypoints": {"preset": "p2net"}},
                          {"frames": 36, "points_per_image": {"mean": 2000.5}, "preset": "p2net",
                           "epe": {"Fine-tuned patch (F²Depth)": 1.5}},
                          artifacts=(overlays,))
    client = MlflowClient(tracking_uri=mlflow_uri)
    (child,) = client.search_runs([client.get_experiment_by_name("f2depth").experiment_id],
                                  filter_string="tags.stage = 'keypoints'")
    assert child.data.metrics == {"frames": 36.0, "points_per_image.mean": 2000.5,
                                  "epe.Fine-tuned patch _F_Depth_": 1.5}
    assert child.data.params == {"keypoints.preset": "p2net"}
    assert [a.path for a in client.list_artifacts(child.info.run_id, "overlays")] == ["overlays/a.png"]
    parent = child.data.tags["mlflow.parentRunId"]
    assert client.get_run(parent).info.status == "RUNNING"  # more stages may follow
    with tracking.stage_run("tables", {}, closes_pipeline=True):
        pass
    assert client.get_run(parent).info.status == "FINISHED"


def test_disabled_is_a_no_op(monkeypatch):
    monkeypatch.setenv("F2DEPTH_MLFLOW", "0")
    with tracking.stage_run("synth", {}) as run:
        assert not run.active
        run.log_metrics({"a": 1.0})
        run.log_artifact("does-not-exist")


# ---- the mirror never breaks a stage ---------------------------------------------------------------------

def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_unreachable_server_warns_once_and_the_stage_writes_its_outputs(tmp_path):
    """The probe from issue #17: a tracking server that does not answer. Before: `prepare` retried for 249 s
    and exited 1 with a 112-line traceback although its outputs were written. Here the `tables` stage on
    hand-written evaluation results (tests/test_stage_tables.py) runs with such a server."""
    import test_stage_tables

    params = test_stage_tables.write_inputs(tmp_path)
    env = {**os.environ, "F2DEPTH_MLFLOW": "1", "MLFLOW_TRACKING_URI": f"http://127.0.0.1:{_closed_port()}"}
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, str(ROOT / "stages" / "tables.py"), "--params", str(params),
                          "--metrics", str(tmp_path / "metrics" / "evaluate"), "--eval",
                          str(tmp_path / "reports" / "eval"), "--train-metrics",
                          str(tmp_path / "metrics" / "train_depth"), "--out", str(tmp_path / "reports")],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    lines = [line for line in res.stderr.strip().splitlines() if "MLflow" in line]
    assert len(lines) == 1 and lines[0].startswith(f"MLflow mirror off ({env['MLFLOW_TRACKING_URI']}): no "
                                                   "answer from the tracking server within 3 s"), res.stderr
    assert "Traceback" not in res.stderr
    assert (tmp_path / "reports" / "tables" / "table5_losses.md").stat().st_size > 100
    assert time.perf_counter() - t0 < 120  # not MLflow's minutes of retries (the probe waits at most 3 s)


def test_a_silent_server_is_given_up_after_the_probe_timeout(monkeypatch, caplog):
    """A server that accepts the connection but never answers."""
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen(1)
        uri = f"http://127.0.0.1:{server.getsockname()[1]}"
        monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
        monkeypatch.setenv("F2DEPTH_MLFLOW", "1")
        monkeypatch.setattr(tracking, "PROBE_TIMEOUT", 0.3)
        with tracking.stage_run("prepare", {"prepare": {"height": 96}}) as run:
            assert not run.active
            run.log_metrics({"frames": 1.0})
    (msg,) = [r.getMessage() for r in caplog.records]
    assert msg.startswith(f"MLflow mirror off ({uri}): no answer from the tracking server within 0.3 s")


def test_a_failing_mlflow_call_turns_the_mirror_off_not_the_stage(mlflow_uri, monkeypatch, caplog):
    """A store that fails mid-stage (server gone, database locked): one warning, the stage's own work
    goes on, and an error of the stage itself still propagates."""
    calls = []

    def broken(self, *args, **kwargs):
        calls.append(args)
        raise ConnectionError("connection reset by peer")

    with tracking.stage_run("train_depth", {"train_depth": {"epochs": 2}}) as run:
        assert run.active
        monkeypatch.setattr(MlflowClient, "log_batch", broken)
        run.log_metrics({"loss": 1.0}, step=1)
        assert not run.active
        run.log_metrics({"loss": 0.5}, step=2)  # no second call, no second warning
        run.log_artifact(__file__)
    assert len(calls) == 1
    warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warnings) == 1 and "ConnectionError: connection reset by peer" in warnings[0]
    with pytest.raises(ZeroDivisionError), tracking.stage_run("prepare", {}):
        _ = 1 / 0


# ---- comparing the ablations in MLflow (issue 52 item 3) -------------------------------------------------

def _pipeline(monkeypatch, dvc_pid: int, exp_name: str | None) -> None:
    """What the stages of one `dvc repro` (exp_name None) or `dvc exp run` see."""
    monkeypatch.setattr(tracking, "_dvc_process_id", lambda: dvc_pid)
    if exp_name is None:
        monkeypatch.delenv("DVC_EXP_NAME", raising=False)
    else:
        monkeypatch.setenv("DVC_EXP_NAME", exp_name)


def test_runs_are_named_variant_first_and_apart_across_pipelines(mlflow_uri, monkeypatch):
    """Two `dvc repro` of one commit and a `dvc exp run`: every run name is unique and starts with the
    variant; the experiment (created earlier without it) gets MLflow 3's machine-learning kind."""
    client = MlflowClient(tracking_uri=mlflow_uri)
    client.create_experiment(tracking.EXPERIMENT)  # as the mirror before issue 52 made it
    monkeypatch.setattr(tracking, "git_commit", lambda cwd=".": "0123456789abcdef")
    names = []
    for pid, exp_name in ((101, None), (102, None), (103, "bluff-rain")):
        _pipeline(monkeypatch, pid, exp_name)
        for variant in ("flow_pretrained", "flow_full_ft"):
            with tracking.stage_run("evaluate", {}, variant=variant) as run:
                names.append(client.get_run(run.run_id).info.run_name)
        with tracking.stage_run("train_depth", {}, variant="full", seed=1) as run:
            names.append(client.get_run(run.run_id).info.run_name)
            assert client.get_run(run.run_id).data.tags["dvc_stage"] == "train_depth@full"
    assert names == ["flow_pretrained · evaluate · 0123456", "flow_full_ft · evaluate · 0123456",
                     "full · train_depth seed 1 · 0123456",
                     "flow_pretrained · evaluate · 0123456 #2", "flow_full_ft · evaluate · 0123456 #2",
                     "full · train_depth seed 1 · 0123456 #2",
                     "flow_pretrained · evaluate · bluff-rain", "flow_full_ft · evaluate · bluff-rain",
                     "full · train_depth seed 1 · bluff-rain"]
    experiment = client.get_experiment_by_name(tracking.EXPERIMENT)
    assert experiment.tags["mlflow.experimentKind"] == "custom_model_development"
    parents = client.search_runs([experiment.experiment_id], filter_string="tags.kind = 'pipeline'")
    assert sorted(r.info.run_name for r in parents) == ["pipeline · 0123456", "pipeline · 0123456 #2",
                                                        "pipeline · bluff-rain"]


def test_a_new_store_gets_the_experiment_kind(mlflow_uri):
    with tracking.stage_run("synth", {}):
        pass
    experiment = MlflowClient(tracking_uri=mlflow_uri).get_experiment_by_name(tracking.EXPERIMENT)
    assert experiment.tags["mlflow.experimentKind"] == "custom_model_development"


def test_train_and_evaluate_runs_carry_the_papers_names_and_share_the_logged_models(
        tree, mlflow_uri, monkeypatch):  # noqa: F811 (tree: the fixture imported above)
    """Fake train_depth results (two seeds' checkpoints of a variant trained without L_rigid and
    L_feature, mirrored as the stage does) and the real evaluate stage on them: both runs carry lambda1..3,
    lambda_rigid (0 for the terms the variant is without), flow_model, seeds, epochs, variant; each model is
    one logged model, the train run's output and the evaluate run's input, with its own seed's results."""
    from types import SimpleNamespace

    from test_stage_evaluate import run as run_evaluate

    from f2depth.depth import DepthModel, DepthModelConfig, save_checkpoint
    from f2depth.train.run import run_params
    from f2depth.train.settings import loss_weights
    from f2depth.train.step import WEIGHT_KEYS

    monkeypatch.setenv("F2DEPTH_MLFLOW", "1")  # the evaluate fixture switches it off
    monkeypatch.setenv("DVC_ROOT", str(tree))
    lambdas = {"lambda1": 0.001, "lambda2": 0.05, "lambda3": 0.3, "lambda_rigid": 0.1}
    s = SimpleNamespace(variant="full", weights=loss_weights(lambdas, ["rigid", "feature"]), flow_model=None,
                        epochs=2, without=("rigid", "feature"))
    train_runs = {}
    for seed in (0, 1):  # what stages/train_depth.py writes and mirrors
        path = tree / "models" / "depth_full" / f"seed{seed}.pt"
        path.parent.mkdir(parents=True, exist_ok=True)
        torch.manual_seed(seed)
        save_checkpoint(path, DepthModel(DepthModelConfig(64, 96)), variant="full", seed=seed,
                        params={"weights": s.weights, "flow_model": None, "epochs": 2,
                                "without": ["rigid", "feature"], "seeds": [0, 1], "variant": "full"},
                        weight_keys=dict(WEIGHT_KEYS))
        with tracking.stage_run("train_depth", {**lambdas, "train_depth": {"epochs": 2}}, variant="full",
                                run_params=run_params(s, [seed]), seed=seed) as run:
            run.log_epoch({"epoch": 1, "loss": 1.0})
        train_runs[run.log_model(path, f"depth_full-seed{seed}", run_params(s, [seed]))] = run.run_id
    doc = run_evaluate(tree)

    client = MlflowClient(tracking_uri=mlflow_uri)
    experiment_id = client.get_experiment_by_name(tracking.EXPERIMENT).experiment_id
    (found,) = client.search_runs([experiment_id], filter_string="tags.stage = 'evaluate'")
    evaluation = client.get_run(found.info.run_id)
    assert evaluation.info.run_name == "full · evaluate · exp-test"
    expected = {"lambda1": "0.001", "lambda2": "0.05", "lambda3": "0.0", "lambda_rigid": "0.0",
                "flow_model": "none", "epochs": "2", "variant": "full", "without": "rigid,feature"}
    assert {k: evaluation.data.params[k] for k in expected} == expected
    assert evaluation.data.params["seeds"] == "0,1"
    for seed, run_id in enumerate(train_runs.values()):
        params = client.get_run(run_id).data.params
        assert {k: params[k] for k in expected} == expected and params["seeds"] == str(seed)
        assert client.get_run(run_id).info.run_name == f"full · train_depth seed {seed} · exp-test"
    # the headline: named to sort first, the mean over seeds in the run
    metrics = evaluation.data.metrics
    assert sorted(metrics)[:6] == ["1_nyu_abs_rel", "1_nyu_delta1", "2_sevenscenes_abs_rel",
                                   "2_sevenscenes_delta1", "3_campus_abs_rel", "3_campus_delta1"]
    assert metrics["1_nyu_delta1"] == pytest.approx(doc["nyu"]["a1"])
    assert metrics["nyu.abs_rel"] == pytest.approx(doc["nyu"]["abs_rel"])
    # one logged model per seed: output of its train run, input of the evaluate run, with its seed's results
    assert sorted(m.model_id for m in evaluation.inputs.model_inputs) == sorted(train_runs)
    for seed, (model_id, run_id) in enumerate(train_runs.items()):
        assert [m.model_id for m in client.get_run(run_id).outputs.model_outputs] == [model_id]
        model = client.get_logged_model(model_id)
        assert model.source_run_id == run_id and model.params["lambda3"] == "0.0"
        assert model.tags["mlflow.model.isExternal"] == "true"
        assert model.tags["f2depth.model_path"] == f"models/depth_full/seed{seed}.pt"
        results = {m.key: m.value for m in model.metrics if m.run_id == evaluation.info.run_id}
        assert results["1_nyu_abs_rel"] == pytest.approx(doc["per_seed"][f"seed{seed}"]["nyu"]["abs_rel"])


def test_the_compare_command_picks_the_newest_pipelines_evaluate_runs(mlflow_uri, monkeypatch, capsys):
    """tools/mlflow_compare.py (`make mlflow-compare`): the evaluate runs of the newest pipeline, in the
    order they ran, in MLflow's compare route; without Chromium one line says how to install it."""
    sys.path.insert(0, str(ROOT / "tools"))
    import mlflow_compare

    ids = {}
    for pid, exp_name in ((201, None), (202, "bluff-rain")):
        _pipeline(monkeypatch, pid, exp_name)
        for variant in ("full", "baseline"):
            with tracking.stage_run("evaluate", {}, variant=variant) as run:
                ids[(pid, variant)] = run.run_id
        with tracking.stage_run("tables", {}, closes_pipeline=True):
            pass
    client = MlflowClient(tracking_uri=mlflow_uri)
    experiment_id = client.get_experiment_by_name(tracking.EXPERIMENT).experiment_id
    chosen = [r.info.run_id for r in mlflow_compare.evaluate_runs(client, experiment_id)]
    assert chosen == [ids[(202, "full")], ids[(202, "baseline")]]
    url = mlflow_compare.compare_url("http://127.0.0.1:5000", chosen, experiment_id)
    assert url.startswith("http://127.0.0.1:5000/#/compare-runs?runs=%5B%22")
    query = urllib.parse.parse_qs(url.split("?", 1)[1])
    assert json.loads(query["runs"][0]) == chosen and json.loads(query["experiments"][0]) == [experiment_id]

    monkeypatch.setattr(mlflow_compare.shutil, "which", lambda name: None)
    assert mlflow_compare.main(["mlflow_compare.py", "--out", str(ROOT / "never.png")]) == 3
    (line,) = [line for line in capsys.readouterr().err.splitlines() if "mlflow_compare" in line]
    assert "Chromium not found" in line and "apt-get install chromium" in line
