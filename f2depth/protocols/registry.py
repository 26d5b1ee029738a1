"""The test sets, one line each: what `evaluate` scores, `tables` reports and `synth` makes a stand-in of.

A line names the set (its ``evaluate.datasets`` entry, the headline groups ``<name>`` and ``<name>_pp``,
``reports/eval/<variant>/<name>.csv``), the module whose ``PROTOCOL``
(``f2depth.protocols.protocol.Protocol``) opens and scores it, and the synthetic dataset that stands in for it
(one of ``f2depth.synth.plan.STANDINS``, written below ``synth.root``; tests/test_eval_registry.py checks that
synth makes it). How the tables show the set is its ``f2depth.report.layouts`` entry. docs/evaluation.md,
"Adding a test set", walks through a new one.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import ModuleType

from f2depth.protocols import campus, nyu, sevenscenes
from f2depth.protocols.protocol import Protocol


@dataclass(frozen=True)
class Entry:
    name: str
    module: ModuleType
    standin: str


ENTRIES: tuple[Entry, ...] = (
    Entry("nyu", nyu, standin="nyu_labeled"),
    Entry("sevenscenes", sevenscenes, standin="sevenscenes"),
    Entry("campus", campus, standin="campus"),
)
NAMES: tuple[str, ...] = tuple(e.name for e in ENTRIES)


def protocol(name: str) -> Protocol:
    """The :class:`~f2depth.protocols.protocol.Protocol` of test set ``name``."""
    entry = next((e for e in ENTRIES if e.name == name), None)
    if entry is None:
        raise ValueError(f"unknown test set {name!r}; f2depth/protocols/registry.py has {list(NAMES)}")
    found = entry.module.PROTOCOL
    if found.name != name:
        raise ValueError(f"{entry.module.__name__}.PROTOCOL is named {found.name!r}, registered as {name!r}")
    return found


def protocols() -> list[Protocol]:
    """Every registered protocol, in registry order."""
    return [protocol(name) for name in NAMES]
