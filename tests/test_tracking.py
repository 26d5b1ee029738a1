"""MLflow mirror: one parent run per pipeline invocation, one child per stage, params/metrics logged."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mlflow.tracking import MlflowClient

from f2depth import tracking

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture()
def mlflow_uri(tmp_path, monkeypatch):
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    monkeypatch.setenv("F2DEPTH_MLFLOW", "1")
    monkeypatch.delenv("DVC_STAGE", raising=False)
    monkeypatch.setenv("DVC_EXP_NAME", "exp-test")
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
