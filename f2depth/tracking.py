"""MLflow mirror of what the DVC stages do.

DVC metrics files are the source of truth; this module mirrors params, per-epoch metrics and
artifacts into MLflow so the UI can compare ablations. Every ``dvc repro`` / ``dvc exp run``
appears as ONE parent run (keyed by the git commit, the DVC experiment name and the id of the DVC
process that runs the stages) with one child run per stage (and variant).

Tracking URI: ``$MLFLOW_TRACKING_URI`` or ``sqlite:///mlflow.db`` in the repository root.
Set ``F2DEPTH_MLFLOW=0`` to disable mirroring (the stage still writes its DVC outputs).

**The mirror never breaks a stage.** A tracking server is probed once, with a ``PROBE_TIMEOUT`` s
timeout, before a stage opens its run; when it does not answer, or when any MLflow call fails later
(server gone, database locked, a rejected value), one warning line names the tracking URI and the
error, and the stage carries on without mirroring. MLflow's own HTTP retries are cut to
``HTTP_RETRIES`` (its default retries for minutes) unless the user set ``MLFLOW_HTTP_REQUEST_*``.
Exceptions of the stage's own work are never swallowed.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import subprocess
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

EXPERIMENT = "f2depth"
PARENT_KEY_TAG = "f2depth.pipeline_key"
PROBE_TIMEOUT = 3.0  # seconds to wait for a tracking server's /health before mirroring is given up
HTTP_RETRIES = "1"
HTTP_TIMEOUT = "10"

log = logging.getLogger(__name__)


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return f"{type(exc).__name__}: {text.splitlines()[0][:200]}" if text else type(exc).__name__


def mirror_off(reason: str) -> None:
    """The one warning line of a mirror that stops (the stage goes on; DVC's files are the truth)."""
    log.warning("MLflow mirror off (%s): %s; the stage goes on, DVC's metrics files are the record",
                tracking_uri(), reason)


def probe(uri: str, timeout: float | None = None) -> str | None:
    """None when ``uri`` can be tracked into, else why not. HTTP(S) servers are asked for ``/health``
    once (``timeout`` s, default :data:`PROBE_TIMEOUT`); local stores (sqlite, file) are checked when the
    client first touches them."""
    if not uri.startswith(("http://", "https://")):
        return None
    timeout = PROBE_TIMEOUT if timeout is None else timeout
    import urllib.error
    import urllib.request

    try:
        with urllib.request.urlopen(uri.rstrip("/") + "/health", timeout=timeout):
            return None
    except (urllib.error.URLError, OSError, ValueError) as exc:
        return f"no answer from the tracking server within {timeout:g} s ({_first_line(exc)})"


def enabled() -> bool:
    return os.environ.get("F2DEPTH_MLFLOW", "1").lower() not in ("0", "false", "no", "off")


def tracking_uri() -> str:
    root = Path(os.environ.get("DVC_ROOT", "."))
    return os.environ.get("MLFLOW_TRACKING_URI") or f"sqlite:///{(root / 'mlflow.db').resolve()}"


def git_commit(cwd: str | os.PathLike = ".") -> str:
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=cwd, capture_output=True, text=True,
                             check=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return out.stdout.strip()


def _dvc_process_id() -> int | None:
    """PID of the ``dvc`` process that launched this stage, if any (walks up the process tree)."""
    try:
        import psutil
    except ImportError:  # psutil comes with dvc; without it every stage gets its own parent
        return None
    proc = psutil.Process()
    for parent in proc.parents():
        with contextlib.suppress(psutil.Error):
            cmd = " ".join(parent.cmdline())
            if "dvc" in Path(cmd.split(" ")[0]).name or " -m dvc" in cmd or "/dvc " in cmd + " ":
                return parent.pid
    return None


def flatten(d: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"a": {"b": 1}}`` → ``{"a.b": 1}``; lists become their string form."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        if str(k).startswith("_"):
            continue
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(flatten(v, key + "."))
        else:
            out[key] = v
    return out


def metric_name(name: str) -> str:
    """``name`` with every character MLflow rejects in a metric name (anything but letters, digits, ``_ - . :
    /`` and spaces) replaced by ``_``: "epe.Fine-tuned patch (F²Depth)" → "epe.Fine-tuned patch _F_Depth_"."""
    return re.sub(r"[^A-Za-z0-9_\-.:/ ]", "_", name)


class StageRun:
    """A handle on the child run of one stage; every method is a no-op when MLflow is disabled, and the
    first MLflow error turns the handle off for good (one warning line, see the module docstring)."""

    def __init__(self, client: Any = None, run_id: str | None = None) -> None:
        self._client = client
        self.run_id = run_id

    @property
    def active(self) -> bool:
        return self._client is not None

    @contextlib.contextmanager
    def _guard(self) -> Iterator[None]:
        try:
            yield
        except Exception as exc:  # noqa: BLE001 — any failure of the mirror: stop mirroring, not the stage
            self._client = None
            mirror_off(_first_line(exc))

    def log_params(self, params: Mapping[str, Any]) -> None:
        if not self.active:
            return
        from mlflow.entities import Param

        items = [Param(k, str(v)[:6000]) for k, v in flatten(params).items()]
        with self._guard():
            for i in range(0, len(items), 100):
                self._client.log_batch(self.run_id, params=items[i : i + 100])

    def log_metrics(self, metrics: Mapping[str, Any], step: int | None = None) -> None:
        if not self.active:
            return
        import time

        from mlflow.entities import Metric

        now = int(time.time() * 1000)
        items = [Metric(metric_name(k), float(v), now, step or 0) for k, v in flatten(metrics).items()
                 if isinstance(v, (int, float)) and not isinstance(v, bool)]
        if items:
            with self._guard():
                self._client.log_batch(self.run_id, metrics=items)

    def log_epoch(self, row: Mapping[str, Any]) -> None:
        """One history row (:class:`f2depth.epochs.EpochLoop`'s): each number under its history.csv column
        name, at step = the row's epoch — the one name scheme of every trainer's curves."""
        self.log_metrics({k: v for k, v in row.items() if k != "epoch"}, step=int(row["epoch"]))

    def log_summary(self, metrics: Mapping[str, Any]) -> None:
        """A stage's metrics file (or one seed's part of it): each number under its path in the JSON, keys
        joined with ``.`` (``finetuned.test.epe_all``) — the one name scheme of every stage's results."""
        self.log_metrics(metrics)

    def log_artifact(self, path: str | os.PathLike, artifact_path: str | None = None) -> None:
        """Upload a file (into ``artifact_path``) or a folder (into ``artifact_path``, default its name)."""
        if not self.active:
            return
        p = Path(path)
        with self._guard():
            if p.is_dir():
                self._client.log_artifacts(self.run_id, str(p), artifact_path or p.name)
            elif p.exists():
                self._client.log_artifact(self.run_id, str(p), artifact_path)

    def set_tags(self, tags: Mapping[str, Any]) -> None:
        if self.active:
            with self._guard():
                for k, v in tags.items():
                    self._client.set_tag(self.run_id, k, str(v))

    def terminate(self, status: str, parent_id: str | None = None) -> None:
        """End this run with ``status``; also the pipeline's parent run when ``parent_id`` is given."""
        if self.active:
            with self._guard():
                self._client.set_terminated(self.run_id, status=status)
                if parent_id is not None:
                    self._client.set_terminated(parent_id, status=status)


def _parent_run(client: Any, experiment_id: str, commit: str, exp_name: str) -> str:
    dvc_pid = _dvc_process_id()
    key = f"{commit}:{exp_name}:{dvc_pid if dvc_pid is not None else os.getpid()}"
    found = client.search_runs([experiment_id], filter_string=f"tags.`{PARENT_KEY_TAG}` = '{key}'",
                               max_results=1)
    if found:
        return found[0].info.run_id
    run = client.create_run(experiment_id, run_name=f"{exp_name}@{commit[:7]}", tags={
        PARENT_KEY_TAG: key, "git_commit": commit, "dvc_experiment": exp_name, "kind": "pipeline"})
    return run.info.run_id


@contextlib.contextmanager
def stage_run(stage: str, params: Mapping[str, Any], variant: str | None = None,
              sections: tuple[str, ...] = (), closes_pipeline: bool = False) -> Iterator[StageRun]:
    """Open the child run of ``stage`` (and ``variant``) under this pipeline's parent run.

    ``params`` is the whole params.yaml dict; ``sections`` selects what is logged (default: the
    stage's own section plus the top-level scalars such as the lambdas). A failing stage marks the
    parent run FAILED; the last stage of the pipeline (``closes_pipeline``, the ``tables`` stage) marks it
    FINISHED, so the parent runs of completed ``dvc repro`` / ``dvc exp run`` calls do not stay RUNNING.
    """
    handle, parent_id = _open_run(stage, variant) if enabled() else (StageRun(), None)
    chosen = sections or (stage,)
    logged = {k: v for k, v in params.items() if not isinstance(v, Mapping) and not k.startswith("_")}
    logged.update({s: params[s] for s in chosen if s in params})
    handle.log_params(logged)
    status = "FAILED"
    try:
        yield handle
        status = "FINISHED"
    finally:
        handle.terminate(status, parent_id if status == "FAILED" or closes_pipeline else None)


def _open_run(stage: str, variant: str | None) -> tuple[StageRun, str | None]:
    """(the child run of ``stage`` under this pipeline's parent, the parent's id), or an inactive handle
    and None when the tracking store cannot be reached (one warning line)."""
    uri = tracking_uri()
    why = probe(uri)
    if why is not None:
        mirror_off(why)
        return StageRun(), None
    for key, value in (("MLFLOW_HTTP_REQUEST_MAX_RETRIES", HTTP_RETRIES),
                       ("MLFLOW_HTTP_REQUEST_TIMEOUT", HTTP_TIMEOUT)):
        os.environ.setdefault(key, value)
    from mlflow.tracking import MlflowClient

    logging.getLogger("alembic").setLevel(logging.WARNING)
    try:
        client = MlflowClient(tracking_uri=uri)
        exp = client.get_experiment_by_name(EXPERIMENT)
        experiment_id = exp.experiment_id if exp else client.create_experiment(EXPERIMENT)
        commit = git_commit(os.environ.get("DVC_ROOT", "."))
        exp_name = os.environ.get("DVC_EXP_NAME", "workspace")
        parent_id = _parent_run(client, experiment_id, commit, exp_name)
        name = os.environ.get("DVC_STAGE") or (f"{stage}@{variant}" if variant else stage)
        run = client.create_run(experiment_id, run_name=name, tags={
            "mlflow.parentRunId": parent_id, "git_commit": commit, "dvc_experiment": exp_name, "stage": stage,
            "variant": variant or ""})
    except Exception as exc:  # noqa: BLE001 — the mirror must never break a stage
        mirror_off(_first_line(exc))
        return StageRun(), None
    return StageRun(client, run.info.run_id), parent_id


def mirror_stage(stage: str, params: Mapping[str, Any], metrics: Mapping[str, Any],
                 artifacts: tuple[str | os.PathLike, ...] = ()) -> None:
    """Mirror a finished stage that needs no per-epoch logging (synth, prepare, keypoints, figures):
    its params, the numbers of its metrics file and ``artifacts`` (files or folders), as a child run."""
    with stage_run(stage, params) as run:
        run.log_summary(metrics)
        for path in artifacts:
            run.log_artifact(path)
