"""The README's `dvc exp show` command reads as the ablation table in a 200-column terminal, after the
design card's `dvc exp run -S lambda3=0`: run for real on a small DVC repository that has the project's
params.yaml and writes metrics/tables.json with the tables stage's own `headline` (no training: its numbers
move with λ3 for the variants that train with L_feature)."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

STAGE = '''
import json, pathlib, yaml
from f2depth.report.results import VariantResults, headline
p = yaml.safe_load(open("params.yaml"))
results = {}
for i, (name, v) in enumerate(p["variants"].items()):
    base = 0.40 + 0.01 * i + (0.1 * p["lambda3"] if "feature" not in v["without"] else 0.0)
    scores = {g: {"a1": base + k / 10, "abs_rel": 1 - base}
              for k, g in enumerate(("nyu", "sevenscenes", "campus"))}
    results[name] = VariantResults(name, {**scores, "per_seed": {"seed0": scores}})
floors = {"val_untrained": {"a1": 0.36, "abs_rel": 0.38}, "val_constant_depth": {"a1": 0.35, "abs_rel": 0.39}}
train = {name: floors for name in results}
teacher = {"prepared_epe": 2.25, "prepared_swap": 0.77, "prepared_zero_flow_epe": 4.14,
           "heldout_epe": {"pretrained": 3.2, "patch": 3.5, "full": 2.9},
           "heldout_swap": {"pretrained": 0.73, "patch": 0.6, "full": 0.58}, "heldout_zero_flow_epe": 3.47}
pathlib.Path("metrics").mkdir(exist_ok=True)
pathlib.Path("metrics/tables.json").write_text(json.dumps(headline(results, train, teacher)))
'''


def _readme_command() -> list[str]:
    lines = [line for line in (ROOT / "README.md").read_text().splitlines()
             if line.startswith("dvc exp show --drop")]
    assert len(lines) == 1, "README: one `dvc exp show --drop ... --keep ...` line"
    return shlex.split(line.split("  #")[0]) if (line := lines[0]) else []


def _run(args: list[str], cwd: Path, env: dict[str, str]) -> str:
    done = subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, f"{args}: {done.stderr[-2000:]}"
    return done.stdout


@pytest.mark.slow
def test_readme_exp_show_fits_a_200_column_terminal_after_a_lambda3_experiment(tmp_path):
    repo = tmp_path / "repo"
    repo.mkdir()
    (repo / "params.yaml").write_text((ROOT / "params.yaml").read_text())
    (repo / "stage.py").write_text(STAGE)
    params = ", ".join(("lambda1", "lambda2", "lambda3", "lambda_rigid", "lambda_flow_smooth", "variants",
                        "train_depth", "evaluate", "flow_finetune"))
    (repo / "dvc.yaml").write_text(
        f"stages:\n  tables:\n    cmd: {sys.executable} stage.py\n    deps: [stage.py]\n"
        f"    params: [{params}]\n    metrics:\n      - metrics/tables.json:\n          cache: false\n")
    env = {**os.environ, "COLUMNS": "200", "GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@t",
           "GIT_COMMITTER_NAME": "t", "GIT_COMMITTER_EMAIL": "t@t", "DVC_NO_ANALYTICS": "1",
           "F2DEPTH_MLFLOW": "0"}
    dvc = [sys.executable, "-m", "dvc"]
    _run(["git", "init", "-q"], repo, env)
    _run([*dvc, "init", "-q"], repo, env)
    _run([*dvc, "repro", "-q"], repo, env)
    _run(["git", "add", "-A"], repo, env)
    _run(["git", "commit", "-qm", "default"], repo, env)
    _run([*dvc, "exp", "run", "-q", "-S", "lambda3=0"], repo, env)

    command = _readme_command()
    assert command[:3] == ["dvc", "exp", "show"]
    table = _run([*dvc, *command[1:], "--no-pager"], repo, env)
    lines = table.splitlines()
    assert max(len(line) for line in lines) <= 200, table
    header = next(line for line in lines if "Experiment" in line).split()
    variants = ["full", "no_feature", "baseline", "flow_pretrained", "flow_full_ft"]
    assert header == ["Experiment", *(f"{v}.nyu_a1" for v in variants),
                      "lambda1", "lambda2", "lambda3", "lambda_rigid", "lambda_flow_smooth"]
    named = ("workspace", "master", "main", "└──")
    rows = {cells[0] if cells[0] != "└──" else "exp": cells for line in lines
            if (cells := re.sub(r"\[[^]]*\]", "", line).split()) and cells[0] in named}
    default = next(rows[k] for k in ("main", "master") if k in rows)
    experiment = rows["exp"][1:]  # its first cell is the commit
    assert default[-3] == "0.3" and experiment[-3] == "0"  # lambda3
    moved = [v for v, a, b in zip(variants, default[1:6], experiment[1:6]) if a != b]
    assert moved == ["full", "flow_pretrained", "flow_full_ft"]  # the variants with L_feature
