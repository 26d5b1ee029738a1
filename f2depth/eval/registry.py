"""The test sets, one line each: what `evaluate` scores, `tables` reports and `synth` makes a stand-in of.

A line names the set (its ``evaluate.datasets`` entry, the headline groups ``<name>`` and ``<name>_pp``,
``reports/eval/<variant>/<name>.csv``), the module whose ``PROTOCOL`` (``f2depth.eval.protocol.Protocol``)
opens, scores and reports it, and the synthetic dataset that stands in for it (written by ``f2depth.synth``
below ``synth.root``). Protocol modules are imported only when asked for, so `synth` reads this file
without depending on them. docs/evaluation.md, "Adding a test set", walks through a new one.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from f2depth.eval.protocol import Protocol


@dataclass(frozen=True)
class Entry:
    name: str
    module: str
    standin: str


ENTRIES: tuple[Entry, ...] = (
    Entry("nyu", "f2depth.eval.nyu", standin="nyu_labeled"),
    Entry("sevenscenes", "f2depth.eval.sevenscenes", standin="sevenscenes"),
    Entry("campus", "f2depth.eval.campus", standin="campus"),
)
NAMES: tuple[str, ...] = tuple(e.name for e in ENTRIES)


def protocol(name: str) -> Protocol:
    """The :class:`~f2depth.eval.protocol.Protocol` of test set ``name``."""
    entry = next((e for e in ENTRIES if e.name == name), None)
    if entry is None:
        raise ValueError(f"unknown test set {name!r}; f2depth/eval/registry.py has {list(NAMES)}")
    found = importlib.import_module(entry.module).PROTOCOL
    if found.name != name:
        raise ValueError(f"{entry.module}.PROTOCOL is named {found.name!r}, registered as {name!r}")
    return found


def protocols() -> list[Protocol]:
    """Every registered protocol, in registry order."""
    return [protocol(name) for name in NAMES]
