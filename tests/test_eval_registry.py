"""The registry of test sets (f2depth.protocols.registry) is the one list `evaluate` and `tables` read: every
line resolves to its protocol and has a layout in the tables (f2depth.report.layouts), every stand-in it
names is one synth makes, and the DVC stages that read the registry depend on every module and data path
the registered test sets bring."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from f2depth.errors import DataError
from f2depth.eval import suite
from f2depth.protocols import registry
from f2depth.protocols.protocol import Protocol
from f2depth.report import layouts
from f2depth.synth import FINISH, SynthConfig, plan

ROOT = Path(__file__).resolve().parents[1]


def test_every_line_resolves_to_its_protocol():
    assert registry.NAMES == ("nyu", "sevenscenes", "campus") == suite.DATASETS
    assert [p.name for p in registry.protocols()] == list(registry.NAMES)
    assert all(isinstance(p, Protocol) for p in registry.protocols())
    with pytest.raises(ValueError, match="unknown test set 'kitti'"):
        registry.protocol("kitti")
    datasets = yaml.safe_load((ROOT / "params.yaml").read_text())["evaluate"]["datasets"]
    assert set(datasets) <= set(registry.NAMES)


def test_every_registered_test_set_has_a_layout_in_the_tables():
    assert tuple(layouts.LAYOUTS) == registry.NAMES
    assert layouts.layout("sevenscenes").column == "s7"
    with pytest.raises(ValueError, match="no layout in f2depth/report/layouts.py"):
        layouts.layout("kitti")


def test_synth_makes_the_stand_ins_the_registry_names():
    assert plan.standins() == ["nyu_labeled", "sevenscenes", "campus"]
    assert [e.standin for e in registry.ENTRIES] == plan.standins()
    assert set(plan.STANDINS) == set(FINISH)
    datasets = {job.dataset for job in plan.jobs(SynthConfig())}
    assert set(plan.standins()) <= datasets


def data_keys(protocol: Protocol) -> list[str]:
    """The params keys ``protocol.open`` reads (its loader then fails on the made-up paths)."""
    keys: list[str] = []

    def get(key: str) -> str:
        keys.append(key)
        return "1" if key.startswith("evaluate.") else "/nonexistent/test-set"

    with pytest.raises((DataError, ValueError)):
        protocol.open(get)
    return keys


IMPORTS = """
import importlib.util, sys
spec = importlib.util.spec_from_file_location("stage", "stages/{stage}.py")
spec.loader.exec_module(importlib.util.module_from_spec(spec))
from f2depth.protocols import registry
registry.protocols()
print("\\n".join(m.__file__ for n, m in sys.modules.items() if n.startswith("f2depth") and m.__file__))
"""


def imported_files(stage: str) -> set[str]:
    """The f2depth modules a stage script imports (in a fresh interpreter), every protocol loaded."""
    out = subprocess.run([sys.executable, "-c", IMPORTS.format(stage=stage)], cwd=ROOT, capture_output=True,
                         text=True, check=True).stdout.split()
    return {str(Path(f).relative_to(ROOT)) for f in out if Path(f).name != "__init__.py"}


@pytest.mark.parametrize("stage", ["evaluate", "tables"])
def test_stages_depend_on_what_the_registered_test_sets_bring(stage):
    dvc = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"][stage]
    deps = dvc.get("do", dvc)["deps"]

    def covered(path: str) -> bool:
        return any(path == d or path.startswith(d.rstrip("/") + "/") for d in deps)

    scoring = ("f2depth/eval/", "f2depth/protocols/", "f2depth/formats/")
    eval_and_data = {f for f in imported_files(stage) if f.startswith(scoring)}
    assert sorted(f for f in eval_and_data if not covered(f)) == []
    if stage == "evaluate":
        for protocol in registry.protocols():
            paths = [k for k in data_keys(protocol) if k.startswith("data.")]
            assert paths and all(f"${{{k}}}" in deps for k in paths), (protocol.name, paths)
