"""dvc.yaml declares, for every stage, exactly the library files its script imports (directly or through
other library modules, at module level or inside a function; not under TYPE_CHECKING) and nothing more:
a change to one of them re-runs the stage, a change to any other file does not. tools/dvc_deps.py writes
the lists; these tests fail on a missing and on a superfluous dep, and on a dvc.yaml the tool would write
differently."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))
import dvc_deps  # noqa: E402

from f2depth.train.step import TERMS, WEIGHT_KEYS  # noqa: E402


def test_the_checker_follows_imports_inside_functions_and_packages_but_not_type_checking(tmp_path):
    script = tmp_path / "s.py"
    script.write_text("from typing import TYPE_CHECKING\n"
                      "if TYPE_CHECKING:\n    from f2depth.report.published import Pair\n"
                      "def main():\n    from f2depth.train.run import run_variant\n")
    files = {p.relative_to(ROOT).as_posix() for p in dvc_deps.closure(script)}
    assert {"f2depth/__init__.py", "f2depth/train/__init__.py", "f2depth/train/run.py",
            "f2depth/geometry.py"} <= files
    assert "f2depth/report/published.py" not in files  # TYPE_CHECKING only: it never runs
    lazy = tmp_path / "lazy.py"
    lazy.write_text("from f2depth.keypoints import KeypointFile\n")
    assert ROOT / "f2depth/keypoints/store.py" in dvc_deps.closure(lazy)  # imported on first use


def test_every_stage_declares_exactly_the_library_files_it_imports():
    assert len(dvc_deps.stage_scripts(ROOT / "dvc.yaml")) >= 10
    assert not dvc_deps.imported_modules(ROOT / dvc_deps.PACKAGE_ROOT)  # the version string only
    left = dvc_deps.differences()
    assert not left, "run python tools/dvc_deps.py --write:\n  " + "\n  ".join(left)


def planted_root(tmp_path: Path, edit) -> Path:
    """A copy of the repository's pipeline definition (code linked, dvc.yaml edited by ``edit``)."""
    for name in ("f2depth", "stages"):
        (tmp_path / name).symlink_to(ROOT / name)
    (tmp_path / "params.yaml").write_text((ROOT / "params.yaml").read_text())
    (tmp_path / "dvc.yaml").write_text(edit((ROOT / "dvc.yaml").read_text()))
    return tmp_path


def _in_stage(text: str, stage: str, old: str, new: str) -> str:
    """``text`` with ``old`` replaced by ``new`` once, in ``stage``'s entry only."""
    head, rest = text.split(f"\n  {stage}:\n", 1)
    assert old in rest, old
    return head + f"\n  {stage}:\n" + rest.replace(old, new, 1)


def test_a_missing_and_a_superfluous_dep_are_both_named(tmp_path):
    declared = dvc_deps.declared_code_deps(ROOT / "dvc.yaml")
    assert "f2depth/superpixels.py" in declared["prepare"]
    assert "f2depth/report/published.py" not in declared["prepare"]

    def plant(t: str) -> str:
        return _in_stage(t, "prepare", " f2depth/superpixels.py,", " f2depth/report/published.py,")

    left = dvc_deps.differences(planted_root(tmp_path, plant))
    assert left == ["prepare: missing f2depth/superpixels.py",
                    "prepare: superfluous f2depth/report/published.py"]


def test_a_whole_folder_dep_is_superfluous(tmp_path):
    def plant(t: str) -> str:
        return _in_stage(t, "prepare", " f2depth/superpixels.py,", " f2depth/superpixels.py, f2depth/eval/,")

    left = dvc_deps.differences(planted_root(tmp_path, plant))
    assert len(left) == 1 and left[0].startswith("prepare: superfluous f2depth/eval/ (holds f2depth/eval/")


def test_a_folder_is_written_only_when_the_script_imports_every_file_in_it(tmp_path):
    """Folded deps stay exact: a folder stands for its files when all are imported (bytecode caches aside, as
    .dvcignore tells DVC); one more module in it, not imported, and the files are listed one by one."""
    pkg = tmp_path / "f2depth" / "pkg"
    (pkg / "__pycache__").mkdir(parents=True)
    for name in ("__init__.py", "a.py", "b.py", "__pycache__/a.cpython-311.pyc"):
        (pkg / name).write_text("")
    files = ["f2depth/io.py", "f2depth/pkg/__init__.py", "f2depth/pkg/a.py", "f2depth/pkg/b.py"]
    assert dvc_deps.folded(files, tmp_path) == ["f2depth/io.py", "f2depth/pkg/"]
    assert dvc_deps.expanded("f2depth/pkg/", tmp_path) == set(files[1:])
    (pkg / "c.py").write_text("")
    assert dvc_deps.folded(files, tmp_path) == files
    assert "__pycache__/" in (ROOT / ".dvcignore").read_text().split()


def test_each_stage_lists_its_code_in_a_few_lines():
    """dvc.yaml stays readable (issue 56: 749 lines before, 250 at most after): each stage's deps are a short
    flow list, a folder where the stage imports all of it, and no line is wider than the tool writes."""
    lines = (ROOT / "dvc.yaml").read_text().splitlines()
    assert max(map(len, lines)) <= dvc_deps.WIDTH
    starts = [i for i, line in enumerate(lines) if line.strip().startswith("deps: [")]
    assert len(starts) == len(dvc_deps.stage_scripts(ROOT / "dvc.yaml"))
    for i in starts:
        end = next(j for j in range(i, len(lines)) if lines[j].rstrip().endswith("]"))
        assert end - i < 16, lines[i]


def test_dvc_yaml_is_what_the_tool_writes():
    text = (ROOT / "dvc.yaml").read_text()
    assert dvc_deps.rewrite(text) == text, "run python tools/dvc_deps.py --write"
    for stage in yaml.safe_load(text)["stages"].values():  # what a user edits comes first
        body = stage.get("do", stage)
        keys = [k for k in body if k in dvc_deps.KEY_ORDER]
        assert keys == sorted(keys, key=dvc_deps.KEY_ORDER.index)


def test_each_variant_depends_on_the_weights_it_trains_with_only():
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    stage = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]["train_depth"]
    assert list(stage["foreach"]) == list(params["variants"])
    for name, variant in params["variants"].items():
        item = stage["foreach"][name]
        assert item["flow"] == (variant["flow"] or "stages/train_depth.py")
        used = {t for t in TERMS if item[t] == WEIGHT_KEYS[t]}
        assert used == set(TERMS) - set(variant["without"]), name
        assert all(item[t] == f"variants.{name}" for t in set(TERMS) - used), name
    assert params["variants"]["baseline"]["without"] == ["rigid", "feature"]  # the case that matters
    body = stage["do"]
    assert not {*WEIGHT_KEYS.values()} & set(body["params"])  # a weight for all would re-train every variant
    assert [f"${{item.{t}}}" for t in TERMS] == [p for p in body["params"] if str(p).startswith("${item.")]
    assert "${item.flow}" in body["deps"]


@pytest.mark.parametrize("stage", ["flow_pretrain", "train_depth", "evaluate"])
def test_the_papers_numbers_reach_the_tables_stage_only(stage):
    deps = dvc_deps.declared_code_deps(ROOT / "dvc.yaml")

    def files(name: str) -> set[str]:
        return set().union(*(dvc_deps.expanded(d) for d in deps[name]))

    assert "f2depth/report/published.py" in files("tables")
    assert not any(d.startswith("f2depth/report/") for d in files(stage))


def _rerun_sets() -> dict[str, set[str]]:
    """For each top-level weight key of params.yaml: the stages `dvc exp run -S <key>=…` re-runs, read with
    DVC's own index (the stages that list the key and every stage downstream of them)."""
    import networkx as nx
    from dvc.dependency.param import ParamsDependency
    from dvc.repo import Repo

    with Repo(str(ROOT)) as repo:
        graph, stages = repo.index.graph, repo.index.stages
        sets = {}
        for key in (*WEIGHT_KEYS.values(), "lambda_flow_smooth"):
            direct = [s for s in stages
                      if any(key in (d.params or ()) for d in s.deps if isinstance(d, ParamsDependency))]
            sets[key] = {s.addressing for s in direct}.union(
                *({a.addressing for a in nx.ancestors(graph, s)} for s in direct))
    return sets


def test_each_paper_weight_reruns_exactly_the_stages_that_train_with_it():
    """The design card's `dvc exp run -S lambda3=0` re-trains and re-evaluates the three variants with
    L_feature and re-makes the tables; λ1 and λ2 every variant; the fine-tuning's λ both flow models and every
    flow variant after them."""
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    variants = params["variants"]
    sets = _rerun_sets()

    def trained(names):
        return {f"{stage}@{n}" for n in names for stage in ("train_depth", "evaluate")} | {"tables"}

    with_feature = [n for n, v in variants.items() if "feature" not in v["without"]]
    assert with_feature == ["full", "flow_pretrained", "flow_full_ft"]
    assert sets["lambda3"] == trained(with_feature)
    assert sets["lambda_rigid"] == trained(n for n, v in variants.items() if "rigid" not in v["without"])
    assert sets["lambda1"] == sets["lambda2"] == trained(variants)
    assert {"flow_finetune@patch", "flow_finetune@full", "train_depth@full"} <= sets["lambda_flow_smooth"]
    assert "train_depth@baseline" not in sets["lambda_flow_smooth"]


def test_the_paper_weights_are_top_level_keys_with_the_cpu_defaults():
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    assert "loss_weights" not in params  # one copy of each weight, by the paper's name
    cpu = {"lambda1": 0.001, "lambda2": 0.05, "lambda3": 0.3, "lambda_rigid": 0.1, "lambda_flow_smooth": 50}
    assert {key: params[key] for key in cpu} == cpu
