"""params.yaml is the one source of defaults: every config a stage builds from params.yaml equals, field by
field, the defaults of its dataclass wherever the dataclass has one (a library caller that leaves a field
out gets what the pipeline runs with), and the check itself fails on a planted contradiction."""

from __future__ import annotations

import dataclasses
import importlib.util
from pathlib import Path
from typing import Any

import pytest

from f2depth import params as P
from f2depth.ingest.run import IngestConfig
from f2depth.synth.config import SynthConfig
from f2depth.train.run import loop_config
from f2depth.train.settings import settings_from_params

ROOT = Path(__file__).resolve().parents[1]
STAGES = ("flow_pretrain", "flow_finetune", "evaluate", "prepare", "keypoints", "poses", "flow_figure")


def stage_module(name: str):
    spec = importlib.util.spec_from_file_location(f"defaults_stage_{name}", ROOT / f"stages/{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def contradictions(obj: Any, node: dict | None, where: str) -> list[str]:
    """Fields of dataclass ``obj`` (built from the params section ``node``; None: every field came from
    params) whose dataclass default differs from the built value. Fields a stage gives from elsewhere
    (``device``, ``progress``; not keys of ``node``) are not params defaults and are left out."""
    out = []
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        sub = node.get(f.name) if isinstance(node, dict) else None
        if dataclasses.is_dataclass(value) and not isinstance(value, type):
            out += contradictions(value, sub if isinstance(sub, dict) else None, f"{where}.{f.name}")
            continue
        if node is not None and f.name not in node:
            continue
        if f.default is not dataclasses.MISSING:
            default = f.default
        elif f.default_factory is not dataclasses.MISSING:
            default = f.default_factory()
        else:
            continue
        same = list(default) == list(value) if isinstance(default, (list, tuple)) else default == value
        if not same:
            out.append(f"{where}.{f.name}: dataclass default {default!r}, params.yaml {value!r}")
    return out


def built_configs(p: dict) -> list[tuple[Any, dict | None, str]]:
    """(config, its params section, label) for every config the stages build from ``p``."""
    out: list[tuple[Any, dict | None, str]] = []
    for name in STAGES:
        built = stage_module(name).config_from_params(p)
        for cfg in built if isinstance(built, tuple) else (built,):
            out.append((cfg, P.get(p, name), f"{name}: {type(cfg).__name__}"))
    out.append((SynthConfig.from_params(p["synth"]), None, "synth: SynthConfig"))
    for variant in p["variants"]:
        settings, section = settings_from_params(p, variant), P.get(p, "train_depth")
        out.append((settings, section, f"train_depth@{variant}"))
        out.append((loop_config(settings, 0, True), section, f"train_depth@{variant}: LoopConfig"))
    out.append((P.section(p, "ingest", IngestConfig), P.get(p, "ingest"), "ingest: IngestConfig"))
    return out


def test_no_dataclass_default_contradicts_params_yaml():
    p = P.load(ROOT / "params.yaml")
    configs = built_configs(p)
    assert len(configs) >= 15
    found = [line for cfg, node, label in configs for line in contradictions(cfg, node, label)]
    fix = "make the dataclass default params.yaml's value (or drop it)"
    assert found == [], fix + ":\n  " + "\n  ".join(found)


PLANTED = [("flow_finetune.occlusion", "forward_backward"), ("evaluate.timing_repeats", 3),
           ("poses.tracker.detect_every", 2)]


@pytest.mark.parametrize(("key", "value"), PLANTED)
def test_a_planted_contradiction_is_named(tmp_path, key, value):
    text = (ROOT / "params.yaml").read_text()
    path = tmp_path / "params.yaml"
    path.write_text(text)
    p = P.load(path)
    section, *inner, last = key.split(".")
    node = p[section]
    for part in inner:
        node = node[part]
    node[last] = value
    found = [line for cfg, n, label in built_configs(p) for line in contradictions(cfg, n, label)]
    assert any(f".{last}: dataclass default" in line and repr(value) in line for line in found), found
