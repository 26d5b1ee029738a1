"""MLflow's compare view of the latest pipeline's `evaluate` runs as a PNG, or the MLflow UI on the runs.

    python tools/mlflow_compare.py          # `make mlflow-compare`: docs/images/mlflow_compare.png
    python tools/mlflow_compare.py --serve  # the UI on a free local port: its runs and compare URLs (Ctrl-C)

The store is the mirror's (f2depth/tracking.py: $MLFLOW_TRACKING_URI, else sqlite:///mlflow.db in the
repository; --tracking-uri). The script starts `mlflow server` on a free local port and picks the
`evaluate` runs of the newest pipeline run that has any (one per variant, in the order they ran; --runs
names others). For the PNG it drives headless Chromium through its DevTools protocol over a pipe
(--remote-debugging-pipe; no browser package): it opens the compare view (`#/compare-runs?runs=[...]&
experiments=[...]`), waits until the headline metrics are drawn, closes the assistant panel, scrolls the
parameters table to the paper's names (flow_model, lambda1, lambda2, lambda3, lambda_flow_smooth,
lambda_rigid, ...) and saves the page from its top to the end of the metrics table. The server is stopped
at the end. Chromium missing: one line saying how to install it (exit 3).

MLflow 3.17's UI chooses the start page of an experiment from its own "GenAI / Model training" switch (by
default GenAI: the traces overview), not from the experiment's kind tag: the runs URL printed by --serve
carries `workflowType=machine_learning` (the switch, once set, is remembered by the browser).
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.parse
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from f2depth import tracking  # noqa: E402

CHROMIUM = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
INSTALL = "install Chromium (Debian/Ubuntu: sudo apt-get install chromium) or give --chromium PATH"
#: what the page must show before it is saved: every run's column and the first headline metric
READY_JS = "document.body && document.body.innerText.includes(%s) && document.querySelectorAll(" \
           "'.mlflow-compare-run-table').length >= 2 && !document.querySelector('.ant-skeleton')"
#: close the assistant panel, scroll the parameters table (its first table of at most 500 px) to the
#: paper's names, and return how far down the metrics table ends (the top of the Artifacts section)
ARRANGE_JS = """(async () => {
  const pause = ms => new Promise(done => setTimeout(done, ms));
  document.querySelector('button[aria-label="Close"]')?.click();
  await pause(800);
  const params = [...document.querySelectorAll('table.mlflow-compare-run-table')]
    .find(t => getComputedStyle(t).maxHeight !== 'none');
  const first = params && [...params.querySelectorAll('th')].find(th => th.innerText.trim() === 'flow_model');
  if (first) params.scrollTop += first.getBoundingClientRect().top - params.getBoundingClientRect().top;
  await pause(300);
  const texts = document.createTreeWalker(document.body, NodeFilter.SHOW_TEXT);
  while (texts.nextNode()) {
    if (texts.currentNode.nodeValue.trim() === 'Artifacts')
      return Math.round(texts.currentNode.parentElement.getBoundingClientRect().top + window.scrollY) - 12;
  }
  return document.documentElement.scrollHeight;
})()"""


def evaluate_runs(client: Any, experiment_id: str) -> list[Any]:
    """The `evaluate` runs of the newest pipeline (parent run) that has any, in the order they started."""
    runs = client.search_runs([experiment_id], filter_string="tags.stage = 'evaluate'",
                              order_by=["attributes.start_time DESC"], max_results=5000)
    if not runs:
        return []
    parent = runs[0].data.tags.get("mlflow.parentRunId")
    return sorted((r for r in runs if r.data.tags.get("mlflow.parentRunId") == parent),
                  key=lambda r: r.info.start_time)


def compare_url(base: str, run_ids: list[str], experiment_id: str) -> str:
    """MLflow's compare view of ``run_ids`` (its route `/compare-runs`, JSON lists in the query)."""
    query = (f"runs={urllib.parse.quote(json.dumps(run_ids))}"
             f"&experiments={urllib.parse.quote(json.dumps([experiment_id]))}")
    return f"{base}/#/compare-runs?{query}&workflowType=machine_learning"


def runs_url(base: str, experiment_id: str) -> str:
    """The experiment's `evaluate` runs, best NYU δ1 first, with the UI's switch on machine learning (module
    docstring; clear the search box for every run)."""
    query = urllib.parse.urlencode({
        "workflowType": "machine_learning", "searchFilter": "tags.stage = 'evaluate'",
        "orderByKey": f"metrics.`{next(iter(tracking.HEADLINES['evaluate']))}`", "orderByAsc": "false"})
    return f"{base}/#/experiments/{experiment_id}/runs?{query}"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def mlflow_server(uri: str, port: int, timeout: float = 120.0) -> Iterator[str]:
    """`mlflow server` on 127.0.0.1:``port`` for the store ``uri`` (its base URL), stopped on exit."""
    with tempfile.TemporaryFile() as log:
        proc = subprocess.Popen([sys.executable, "-m", "mlflow", "server", "--backend-store-uri", uri,
                                 "--host", "127.0.0.1", "--port", str(port), "--workers", "1"],
                                stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        base = f"http://127.0.0.1:{port}"
        try:
            deadline = time.monotonic() + timeout
            while True:
                with contextlib.suppress(OSError), urllib.request.urlopen(base + "/health", timeout=2):
                    break
                if proc.poll() is not None or time.monotonic() > deadline:
                    log.seek(0)
                    tail = log.read().decode(errors="replace").strip().splitlines()[-5:]
                    raise RuntimeError(f"mlflow server did not start on {base}: " + " | ".join(tail))
                time.sleep(0.5)
            yield base
        finally:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGTERM)  # the server and the workers it started
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()


class Chromium:
    """Headless Chromium driven through the DevTools protocol on a pipe (fds 3 and 4 of the browser,
    messages of JSON ending in a NUL byte)."""

    def __init__(self, exe: str, width: int, height: int) -> None:
        to_browser, self._out = os.pipe()
        self._in, from_browser = os.pipe()

        def pipes_on_3_and_4() -> None:  # in the child, before exec
            import fcntl

            high = [fcntl.fcntl(fd, fcntl.F_DUPFD, 10) for fd in (to_browser, from_browser)]
            os.dup2(high[0], 3)
            os.dup2(high[1], 4)

        self._profile = tempfile.mkdtemp(prefix="mlflow-compare-")
        self.proc = subprocess.Popen(
            [exe, "--headless=new", "--remote-debugging-pipe", "--no-sandbox", "--disable-gpu",
             "--hide-scrollbars", "--no-first-run", "--no-default-browser-check",
             f"--user-data-dir={self._profile}", f"--window-size={width},{height}", "about:blank"],
            preexec_fn=pipes_on_3_and_4, close_fds=False, stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL)
        os.close(to_browser)
        os.close(from_browser)
        self._buffer, self._id, self._session = b"", 0, None
        target = self.call("Target.createTarget", url="about:blank")["targetId"]
        self._session = self.call("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
        self.call("Emulation.setDeviceMetricsOverride", width=width, height=height, deviceScaleFactor=1,
                  mobile=False)

    def call(self, method: str, **params: Any) -> dict[str, Any]:
        self._id += 1
        message = {"id": self._id, "method": method, "params": params}
        if self._session:
            message["sessionId"] = self._session
        os.write(self._out, json.dumps(message).encode() + b"\0")
        while True:  # events arrive on the same pipe: skip to this call's answer
            while b"\0" not in self._buffer:
                chunk = os.read(self._in, 1 << 20)
                if not chunk:
                    raise RuntimeError("Chromium closed its DevTools pipe")
                self._buffer += chunk
            raw, self._buffer = self._buffer.split(b"\0", 1)
            reply = json.loads(raw)
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error'].get('message')}")
                return reply["result"]

    def evaluate(self, expression: str) -> Any:
        result = self.call("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        return result["result"].get("value")

    def close(self) -> None:
        with contextlib.suppress(RuntimeError, OSError):
            self.call("Browser.close")
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        for fd in (self._in, self._out):
            os.close(fd)
        shutil.rmtree(self._profile, ignore_errors=True)


def screenshot(exe: str, url: str, out: Path, width: int, wait_for: str, timeout: float = 90.0) -> int:
    """Save the compare view at ``url`` (module docstring) to ``out``; returns the image's height."""
    browser = Chromium(exe, width, height=3200)  # the UI scrolls inside a frame as high as the window
    try:
        browser.call("Page.navigate", url=url)
        deadline = time.monotonic() + timeout
        while not browser.evaluate(READY_JS % json.dumps(wait_for)):
            if time.monotonic() > deadline:
                raise RuntimeError(f"the compare view did not show {wait_for} within {timeout:g} s: {url}")
            time.sleep(0.5)
        time.sleep(2.0)  # the parallel-coordinates plot draws after the tables
        height = int(browser.evaluate(ARRANGE_JS))
        shot = browser.call("Page.captureScreenshot", format="png", captureBeyondViewport=True,
                            clip={"x": 0, "y": 0, "width": width, "height": height, "scale": 1})
    finally:
        browser.close()
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(base64.b64decode(shot["data"]))
    return height


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tracking-uri", default=None, help="default: the mirror's (f2depth/tracking.py)")
    ap.add_argument("--out", default=str(ROOT / "docs" / "images" / "mlflow_compare.png"))
    ap.add_argument("--runs", nargs="+", help="run ids (default: the newest pipeline's evaluate runs)")
    ap.add_argument("--width", type=int, default=1600, help="page width in pixels")
    ap.add_argument("--chromium", default=None,
                    help=f"the browser (default: the first of {', '.join(CHROMIUM)} on PATH)")
    ap.add_argument("--serve", action="store_true", help="serve the UI until Ctrl-C instead of the PNG")
    ap.add_argument("--port", type=int, default=None, help="the server's port (default: a free one)")
    args = ap.parse_args(argv[1:])
    from mlflow.tracking import MlflowClient

    uri = args.tracking_uri or tracking.tracking_uri()
    if uri.startswith("sqlite:///") and not Path(uri.removeprefix("sqlite:///")).is_file():
        print(f"{uri}: no MLflow store; run `make repro` (or `dvc repro`) first", file=sys.stderr)
        return 1
    client = MlflowClient(tracking_uri=uri)
    experiment = client.get_experiment_by_name(tracking.EXPERIMENT)
    if experiment is None:
        print(f"{uri}: no experiment '{tracking.EXPERIMENT}'; run `make repro` (or `dvc repro`) first",
              file=sys.stderr)
        return 1
    run_ids = args.runs or [r.info.run_id for r in evaluate_runs(client, experiment.experiment_id)]
    if not run_ids:
        print(f"{uri}: no evaluate runs in '{tracking.EXPERIMENT}'; run `make repro` first", file=sys.stderr)
        return 1
    exe = args.chromium or next((found for name in CHROMIUM if (found := shutil.which(name))), None)
    if not args.serve and exe is None:
        print(f"mlflow_compare: Chromium not found: {INSTALL}", file=sys.stderr)
        return 3
    with mlflow_server(uri, args.port or free_port()) as base:
        compare = compare_url(base, run_ids, experiment.experiment_id)
        if args.serve:
            print(f"MLflow UI of {uri}\n  runs:    {runs_url(base, experiment.experiment_id)}\n"
                  f"  compare: {compare}\nCtrl-C stops it.", flush=True)
            with contextlib.suppress(KeyboardInterrupt):
                while True:
                    time.sleep(3600)
            return 0
        first = next(iter(tracking.HEADLINES["evaluate"]))
        height = screenshot(exe, compare, Path(args.out), args.width, first)
    names = [client.get_run(r).info.run_name for r in run_ids]
    print(f"{args.out}: {args.width}x{height} px, the compare view of {len(run_ids)} runs: "
          f"{', '.join(names)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
