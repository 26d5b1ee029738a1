"""MLflow mirror of what the DVC stages do.

DVC metrics files are the source of truth; this module mirrors params, per-epoch metrics and
artifacts into MLflow so the UI can compare ablations. Every ``dvc repro`` / ``dvc exp run``
appears as ONE parent run (keyed by the git commit, the DVC experiment name and the id of the DVC
process that runs the stages) with one child run per stage (and variant).

What the UI shows (issue 52): the experiment carries MLflow 3's kind tag ``mlflow.experimentKind =
custom_model_development`` (a machine-learning experiment, not a GenAI one; MLflow 3.17's UI opens it
on its own "GenAI / Model training" switch instead, see tools/mlflow_compare.py). Each pipeline has a label:
the DVC experiment's name (``$DVC_EXP_NAME``, set by ``dvc exp run``), else the git commit's short hash,
with `` #2``, `` #3``, ... for later pipelines of the same label; a child run is named variant first,
``full · evaluate · <label>`` (``prepare · <label>`` without a variant), so names stay apart in the runs
list and across experiments (``tags.dvc_stage`` keeps DVC's ``evaluate@full``). The ``train_depth`` and
``evaluate`` runs carry what the depth model was trained with under the paper's names
(:func:`trained_params`: ``lambda1``, ``lambda2``, ``lambda3``, ``lambda_rigid`` as the variant applied
them, ``flow_model``, ``seeds``, ``epochs``, ``variant``); an ``evaluate`` run also logs its
:data:`HEADLINES`, which MLflow's tables list first. Each depth model file is an external MLflow logged
model (its bytes stay in DVC's output; :meth:`StageRun.log_model`), the output of its ``train_depth`` run
and an input of the ``evaluate`` run, which links its results to it.

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
import hashlib
import logging
import os
import re
import subprocess
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

EXPERIMENT = "f2depth"
#: MLflow 3's experiment kind, ``custom_model_development``: machine learning (runs), not GenAI (traces); set
#: when the experiment is created and on an existing one that says otherwise
EXPERIMENT_KIND_TAG = "mlflow.experimentKind"
EXPERIMENT_KIND = "custom_model_development"
PARENT_KEY_TAG = "f2depth.pipeline_key"
LABEL_BASE_TAG = "f2depth.pipeline_base"  # the DVC experiment's name or the commit's short hash
LABEL_TAG = "f2depth.pipeline_label"  # the base, with " #k" for the k-th pipeline of that base
MODEL_MD5_TAG = "f2depth.model_md5"  # a logged model's file contents (DVC's md5 of the file)
MODEL_PATH_TAG = "f2depth.model_path"  # where its bytes are: the DVC output, relative to the repository
EXTERNAL_MODEL_TAG = "mlflow.model.isExternal"  # MLflow 3: a logged model whose artifacts live elsewhere
#: Headline metrics of a stage's results: MLflow name → path in its metrics file. MLflow's tables sort
#: names by code point (digits before letters): the leading digit lists them first, NYU, 7-Scenes, Campus.
HEADLINES: dict[str, dict[str, str]] = {"evaluate": {
    "1_nyu_delta1": "nyu.a1", "1_nyu_abs_rel": "nyu.abs_rel",
    "2_sevenscenes_delta1": "sevenscenes.a1", "2_sevenscenes_abs_rel": "sevenscenes.abs_rel",
    "3_campus_delta1": "campus.a1", "3_campus_abs_rel": "campus.abs_rel"}}
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


def trained_params(variant: str, weights: Mapping[str, float], flow_model: str | None, epochs: int,
                   seeds: Sequence[int], without: Sequence[str] = ()) -> dict[str, Any]:
    """What a depth model was trained with, as its ``train_depth`` and ``evaluate`` runs log it: ``weights``
    under their params.yaml names (``lambda1``, ``lambda2``, ``lambda3``, ``lambda_rigid``:
    ``f2depth.train.step.WEIGHT_KEYS``) as the variant applied them (0 for a term it trains ``without``), the
    flow model file (``"none"``: the P²Net baseline), ``seeds`` (``"0,1"``), ``epochs`` and ``variant``."""
    return {**weights, "flow_model": flow_model or "none", "seeds": ",".join(str(s) for s in seeds),
            "epochs": epochs, "variant": variant, "without": ",".join(without) or "none"}


def run_name(stage: str, variant: str | None, label: str, seed: int | None = None) -> str:
    """``full · evaluate · <label>``: the variant first (MLflow's runs list cuts long names at the end),
    ``seed k`` after the stage when a variant trains several seeds, the pipeline's label last."""
    what = stage if seed is None else f"{stage} seed {seed}"
    return " · ".join(part for part in (variant, what, label) if part)


def file_md5(path: str | os.PathLike) -> str:
    """The md5 of a file's contents (what DVC records for a file)."""
    digest = hashlib.md5()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 22), b""):
            digest.update(block)
    return digest.hexdigest()


class StageRun:
    """A handle on the child run of one stage; every method is a no-op when MLflow is disabled, and the
    first MLflow error turns the handle off for good (one warning line, see the module docstring)."""

    def __init__(self, client: Any = None, run_id: str | None = None, experiment_id: str | None = None,
                 headline: Mapping[str, str] | None = None) -> None:
        self._client = client
        self.run_id = run_id
        self.experiment_id = experiment_id
        self._headline = dict(headline or {})  # MLflow name → path of a headline metric (HEADLINES)
        self._last_ms = 0

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

    def log_metrics(self, metrics: Mapping[str, Any], step: int | None = None,
                    model_id: str | None = None) -> None:
        """Every number of ``metrics`` (nested keys joined with ``.``) at ``step``; with ``model_id`` also as
        that logged model's metrics. Timestamps increase from call to call, so the latest of two values
        logged at one step is the later call's."""
        if not self.active:
            return
        import time

        from mlflow.entities import Metric

        now = self._last_ms = max(int(time.time() * 1000), self._last_ms + 1)
        items = [Metric(metric_name(k), float(v), now, step or 0, model_id=model_id)
                 for k, v in flatten(metrics).items()
                 if isinstance(v, (int, float)) and not isinstance(v, bool)]
        if items:
            with self._guard():
                self._client.log_batch(self.run_id, metrics=items)

    def log_epoch(self, row: Mapping[str, Any]) -> None:
        """One history row (:class:`f2depth.epochs.EpochLoop`'s): each number under its history.csv column
        name, at step = the row's epoch — the one name scheme of every trainer's curves."""
        self.log_metrics({k: v for k, v in row.items() if k != "epoch"}, step=int(row["epoch"]))

    def log_summary(self, metrics: Mapping[str, Any],
                    models: Mapping[str | None, Mapping[str, Any]] | None = None) -> None:
        """A stage's metrics file (or one seed's part of it): each number under its path in the JSON, keys
        joined with ``.`` (``finetuned.test.epe_all``) — the one name scheme of every stage's results —, and
        again under its headline name (:data:`HEADLINES`: ``1_nyu_delta1`` = ``nyu.a1``).

        ``models``: logged model id (:meth:`log_model`; None: none) → that model's own results (one seed's
        part of ``metrics``), linked to the model as its metrics. Several are logged first, so that the run's
        latest values are ``metrics`` (the mean over seeds); a single one is ``metrics`` itself, which is then
        linked to its model."""
        if not self.active:
            return
        linked = {m: results for m, results in (models or {}).items() if m is not None}
        if len(models or {}) > 1:
            for model_id, results in linked.items():
                self._log_results(results, model_id)
        self._log_results(metrics, next(iter(linked)) if len(models or {}) == 1 and linked else None)

    def _log_results(self, metrics: Mapping[str, Any], model_id: str | None) -> None:
        flat = flatten(metrics)
        headline = {name: flat[path] for name, path in self._headline.items() if path in flat}
        self.log_metrics({**headline, **metrics}, model_id=model_id)

    def log_model(self, path: str | os.PathLike, name: str, params: Mapping[str, Any] | None = None,
                  produced: bool = True) -> str | None:
        """Link the model file ``path`` (a DVC output) to this run as an MLflow 3 logged model and return its
        id (None when the mirror is off or there is no such file). Its bytes are not copied: the model is
        external (``mlflow.model.isExternal``), tagged with the file's path and md5 (:data:`MODEL_PATH_TAG`,
        :data:`MODEL_MD5_TAG`), ``params`` its params. ``produced`` (the ``train_depth`` run): a new model,
        the run's output. Else (the ``evaluate`` run): the run's input, the model its training logged with
        the same md5, or a new one when the store has none (training ran with the mirror off)."""
        p = Path(path)
        if not self.active or not p.is_file():
            return None
        from mlflow.entities import LoggedModelInput, LoggedModelOutput

        root = Path(os.environ.get("DVC_ROOT", ".")).resolve()
        where = p.resolve()
        where = where.relative_to(root) if where.is_relative_to(root) else where
        with self._guard():
            digest = file_md5(p)
            found = [] if produced else self._client.search_logged_models(
                [self.experiment_id], filter_string=f"tags.`{MODEL_MD5_TAG}` = '{digest}'", max_results=1)
            if found:
                model_id = found[0].model_id
            else:
                model = self._client.create_logged_model(
                    self.experiment_id, name=name, source_run_id=self.run_id, model_type="f2depth.depth",
                    params={k: str(v)[:6000] for k, v in flatten(params or {}).items()},
                    tags={EXTERNAL_MODEL_TAG: "true", MODEL_PATH_TAG: where.as_posix(),
                          MODEL_MD5_TAG: digest})
                model_id = model.model_id
                self._client.finalize_logged_model(model_id, "READY")
            if produced:
                self._client.log_outputs(self.run_id, [LoggedModelOutput(model_id, step=0)])
            else:
                self._client.log_inputs(self.run_id, models=[LoggedModelInput(model_id)])
            return model_id
        return None

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


def _parent_run(client: Any, experiment_id: str, commit: str, exp_name: str) -> tuple[str, str]:
    """(the id, the label) of this pipeline's parent run, created by its first stage (module docstring)."""
    dvc_pid = _dvc_process_id()
    key = f"{commit}:{exp_name}:{dvc_pid if dvc_pid is not None else os.getpid()}"
    found = client.search_runs([experiment_id], filter_string=f"tags.`{PARENT_KEY_TAG}` = '{key}'",
                               max_results=1)
    if found:
        return found[0].info.run_id, found[0].data.tags.get(LABEL_TAG, exp_name)
    base = (exp_name if "DVC_EXP_NAME" in os.environ else commit[:7] if commit != "unknown"
            else exp_name).replace("'", "")
    earlier = client.search_runs([experiment_id], filter_string=f"tags.`{LABEL_BASE_TAG}` = '{base}'",
                                 max_results=10000)
    label = f"{base} #{len(earlier) + 1}" if earlier else base
    run = client.create_run(experiment_id, run_name=f"pipeline · {label}", tags={
        PARENT_KEY_TAG: key, LABEL_BASE_TAG: base, LABEL_TAG: label, "git_commit": commit,
        "dvc_experiment": exp_name, "kind": "pipeline"})
    return run.info.run_id, label


def _experiment(client: Any) -> str:
    """The id of the ``f2depth`` experiment, created with (or given) MLflow 3's machine-learning kind."""
    exp = client.get_experiment_by_name(EXPERIMENT)
    if exp is None:
        return client.create_experiment(EXPERIMENT, tags={EXPERIMENT_KIND_TAG: EXPERIMENT_KIND})
    if exp.tags.get(EXPERIMENT_KIND_TAG) != EXPERIMENT_KIND:
        client.set_experiment_tag(exp.experiment_id, EXPERIMENT_KIND_TAG, EXPERIMENT_KIND)
    return exp.experiment_id


@contextlib.contextmanager
def stage_run(stage: str, params: Mapping[str, Any], variant: str | None = None,
              sections: tuple[str, ...] = (), closes_pipeline: bool = False,
              run_params: Mapping[str, Any] | None = None, seed: int | None = None) -> Iterator[StageRun]:
    """Open the child run of ``stage`` (and ``variant``; ``seed``: one of several a variant trains) under
    this pipeline's parent run, named by :func:`run_name`.

    ``params`` is the whole params.yaml dict; ``sections`` selects what is logged (default: the
    stage's own section plus the top-level scalars such as the lambdas). ``run_params`` are logged at the
    top level too and replace a top-level key of the same name (:func:`trained_params`: ``lambda3`` is 0 in
    a run of a variant without L_feature; MLflow keeps a param's first value). A failing stage marks the
    parent run FAILED; the last stage of the pipeline (``closes_pipeline``, the ``tables`` stage) marks it
    FINISHED, so the parent runs of completed ``dvc repro`` / ``dvc exp run`` calls do not stay RUNNING.
    """
    handle, parent_id = _open_run(stage, variant, seed) if enabled() else (StageRun(), None)
    chosen = sections or (stage,)
    logged = {k: v for k, v in params.items() if not isinstance(v, Mapping) and not k.startswith("_")}
    logged.update({s: params[s] for s in chosen if s in params})
    logged.update(run_params or {})
    handle.log_params(logged)
    status = "FAILED"
    try:
        yield handle
        status = "FINISHED"
    finally:
        handle.terminate(status, parent_id if status == "FAILED" or closes_pipeline else None)


def _open_run(stage: str, variant: str | None, seed: int | None = None) -> tuple[StageRun, str | None]:
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
        experiment_id = _experiment(client)
        commit = git_commit(os.environ.get("DVC_ROOT", "."))
        exp_name = os.environ.get("DVC_EXP_NAME", "workspace")
        parent_id, label = _parent_run(client, experiment_id, commit, exp_name)
        tags = {"mlflow.parentRunId": parent_id, "git_commit": commit, "dvc_experiment": exp_name,
                "dvc_stage": os.environ.get("DVC_STAGE") or (f"{stage}@{variant}" if variant else stage),
                "stage": stage, "variant": variant or "", LABEL_TAG: label}
        run = client.create_run(experiment_id, run_name=run_name(stage, variant, label, seed), tags=tags)
    except Exception as exc:  # noqa: BLE001 — the mirror must never break a stage
        mirror_off(_first_line(exc))
        return StageRun(), None
    return StageRun(client, run.info.run_id, experiment_id, HEADLINES.get(stage)), parent_id


def mirror_stage(stage: str, params: Mapping[str, Any], metrics: Mapping[str, Any],
                 artifacts: tuple[str | os.PathLike, ...] = ()) -> None:
    """Mirror a finished stage that needs no per-epoch logging (synth, prepare, keypoints, figures):
    its params, the numbers of its metrics file and ``artifacts`` (files or folders), as a child run."""
    with stage_run(stage, params) as run:
        run.log_summary(metrics)
        for path in artifacts:
            run.log_artifact(path)
