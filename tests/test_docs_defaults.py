"""Every default a doc states equals params.yaml, the one source of defaults.

A doc quotes a setting as `dotted.key: value` in backticks, and most quotes are not defaults ("set
`prepare.val_share: 0.2`", the paper profile's value). The convention this test holds: a quote *states the
default* when it is in **bold** (docs/method.md §9's bullets) or when "the CPU default" follows it in the
same parenthesis or clause (", the CPU default", "(the CPU default"). Such a quote names the full dotted key
from the top of params.yaml and its value is params.yaml's."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
DOCS = ["README.md", "CONTRIBUTING.md", *sorted(f"docs/{p.name}" for p in (ROOT / "docs").glob("*.md"))]
QUOTE = re.compile(r"`([a-z_0-9]+(?:\.[a-z_0-9]+)*): ([^`\n]+)`")
BOLD = re.compile(r"\*\*([^*\n]+?)\*\*")  # within a line
CPU_DEFAULT_AFTER = re.compile(r"`([a-z_0-9]+(?:\.[a-z_0-9]+)*): ([^`\n]+)`[,;]? \(?the CPU default\b")


def stated_defaults(text: str) -> list[tuple[str, str]]:
    """The (dotted key, value text) of every quote of ``text`` that states a default (module docstring)."""
    found = [m.groups() for b in BOLD.finditer(text) for m in QUOTE.finditer(b.group(1))]
    found += [m.groups() for m in CPU_DEFAULT_AFTER.finditer(text)]
    return found


def lookup(params: dict, dotted: str) -> Any:
    node: Any = params
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            raise KeyError(dotted)
        node = node[part]
    return node


def contradictions(text: str, params: dict, where: str) -> list[str]:
    out = []
    for key, value in stated_defaults(text):
        try:
            current = lookup(params, key)
        except KeyError:
            out.append(f"{where}: `{key}: {value}` is no dotted key of params.yaml; quote the full key")
            continue
        if yaml.safe_load(value) != current:
            out.append(f"{where}: `{key}: {value}` but params.yaml has {current!r}")
    return out


def test_the_convention_finds_bold_and_cpu_default_quotes_only():
    text = ("* **`a.b: 1`** (paper 2): ... set `a.c: 5` to ...; `a.d: x`, the CPU default; "
            "(`a.e: y`, the CPU default) and `a.f: z` (paper).")
    assert stated_defaults(text) == [("a.b", "1"), ("a.d", "x"), ("a.e", "y")]


def test_a_stale_default_is_named():
    params = {"train_depth": {"flow_fade_epochs": 6}}
    text = "* **`train_depth.flow_fade_epochs: 12`** (paper: `null`)"
    assert contradictions(text, params, "doc.md") == [
        "doc.md: `train_depth.flow_fade_epochs: 12` but params.yaml has 6"]
    assert contradictions("(`fade: 6`, the CPU default)", params, "doc.md")[0].endswith("quote the full key")


@pytest.mark.parametrize("doc", DOCS)
def test_every_stated_default_is_params_yaml(doc):
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    found = contradictions((ROOT / doc).read_text(), params, doc)
    assert found == [], "\n".join(found)


def test_the_docs_state_defaults():
    """The convention is in use: method.md §9 alone states more than ten."""
    assert len(stated_defaults((ROOT / "docs/method.md").read_text())) > 10
