"""Code and docs cite the paper, P²Net, ARFlow or DSO (docs/method.md §10), never files a clone lacks.

Scans every ``*.py``, ``*.md``, ``*.yaml`` and ``*.toml`` file of the repository (outside hidden folders and
the top-level ``data``, ``models``, ``mlruns`` and ``tmp``) for references to the project's internal
specification and research notes, and to the folder of reference data next to the repository: the tests
read theirs from ``tests/data/`` (tests/test_no_outside_paths.py).
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SUFFIXES = {".py", ".md", ".yaml", ".toml"}
SKIP_TOP = {"data", "models", "mlruns", "tmp"}
# Spelled in pieces so that this file does not match its own patterns.
_NOTES = "|".join(("arflow", "p2net", "dso", "evalpeers"))
PATTERNS = (
    ("internal spec", re.compile(r"\bSP" + r"EC\b")),
    ("research notes", re.compile(r"\bresearch(/| §)")),
    ("research note file", re.compile(r"\b(" + _NOTES + r")\.md\b")),
    ("folder outside the repository", re.compile(r"\bshared/")),
    ("session notes", re.compile(r"/work/" + "notes")),
)


def offending(line: str) -> list[str]:
    """Names of the patterns ``line`` matches."""
    return [name for name, pattern in PATTERNS if pattern.search(line)]


def scanned_files(root: Path = ROOT) -> list[Path]:
    files = []
    for path in root.rglob("*"):
        rel = path.relative_to(root)
        if (path.suffix not in SUFFIXES or not path.is_file() or rel.parts[0] in SKIP_TOP
                or any(part.startswith(".") or part == "__pycache__" for part in rel.parts)):
            continue
        files.append(path)
    return sorted(files)


def test_matcher_flags_internal_references():
    assert offending("Terms (SP" + "EC §4.4), all on") == ["internal spec"]
    assert offending("see research/" + "p2net.md §3") == ["research notes", "research note file"]
    assert offending("(research §3.6)") == ["research notes"]
    assert offending("written from ../shared/" + "research/dso.md") == [
        "research notes", "research note file", "folder outside the repository"]
    assert offending('REF = "../shared/data/dso_reference"') == ["folder outside the repository"]
    assert offending("the paper §3.2; P²Net's code (`trainer_geo.py`)") == []
    assert offending("_LATEX_SPECIAL = {") == []


def test_no_reference_to_files_a_clone_lacks():
    files = scanned_files()
    names = {p.relative_to(ROOT).as_posix() for p in files}
    assert "docs/method.md" in names and "f2depth/losses/flow_losses.py" in names and len(files) > 100
    hits = []
    for path in files:
        rel = path.relative_to(ROOT).as_posix()
        if rel == "tests/test_docs_citations.py":
            continue
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            found = offending(line)
            if found:
                hits.append(f"{rel}:{number}: {', '.join(found)}: {line.strip()[:100]}")
    assert not hits, (
        "cite the paper, P²Net, ARFlow or DSO by name and section or by their code's file "
        "(docs/method.md §10), not these:\n" + "\n".join(hits)
    )
