"""The tests read nothing outside the repository: a user's clone has no reference data beside it.

Two guards: ``tests/conftest.py`` refuses, while the tests run, every open or listing of a path beside the
repository (its parent folder, outside the clone); and a scan of the code that runs from a clone (tests,
benchmarks, tools, stages) for paths that climb out of it.
"""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

import pytest
from conftest import ROOT, OutsideRepositoryError, outside_repository

SCANNED = ("tests", "benchmarks", "tools", "stages")
# ``Path(__file__).resolve().parents[k]`` of a file d folders below the root leaves the clone for k > d.
PARENTS = re.compile(r"__file__\)(?:\.resolve\(\))?\.parents\[(\d+)\]")
SCANNERS = {"test_no_outside_paths.py", "test_docs_citations.py"}  # their probe strings climb on purpose
CLIMB = re.compile(r"""["']\.\.["']|["']\.\./""")


def test_guard_refuses_a_sibling_folder_and_allows_the_clone_and_temp():
    root = Path("/home/user/f2depth")
    temp = Path(tempfile.gettempdir()).resolve()
    assert outside_repository("/home/user/sibling/data/x.npz", root)
    assert outside_repository(b"/home/user/other", root)
    assert outside_repository("/home/user/f2depth/../shared", root)
    assert not outside_repository("/home/user/f2depth/tests/data/x.npz", root)
    assert not outside_repository("/home/user/.cache/matplotlib", root)
    assert not outside_repository("/usr/lib/python3/os.py", root)
    assert not outside_repository(3, root)
    assert not outside_repository(temp / "x", temp / "f2depth", (temp,))  # a clone right in the temp folder
    assert outside_repository(temp / "ci" / "shared" / "x", temp / "ci" / "f2depth", (temp,))  # CI's clone
    assert not outside_repository(temp / "pytest-of-x" / "y", temp / "ci" / "f2depth", (temp,))
    assert not outside_repository("/home/user/venv/lib/os.py", root, (Path("/home/user/venv"),))
    assert not outside_repository("/sibling/x", Path("/f2depth"))


def test_guard_is_live_in_this_session():
    sibling = ROOT.parent / "f2depth-outside-probe.txt"
    with pytest.raises(OutsideRepositoryError, match="copy the file into tests/data/"):
        open(sibling)  # noqa: SIM115 - the guard refuses before anything is opened
    with pytest.raises(OutsideRepositoryError):
        list(ROOT.parent.iterdir())
    assert (ROOT / "tests" / "data" / "README.md").read_text()


def _depth(path: Path) -> int:
    return len(path.relative_to(ROOT).parts) - 1


def test_no_code_climbs_out_of_the_clone():
    files = [p for folder in SCANNED for p in (ROOT / folder).rglob("*.py") if "__pycache__" not in p.parts]
    assert len(files) > 100
    hits = []
    for path in files:
        if path.name in SCANNERS:
            continue
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            leaves = any(int(k) > _depth(path) for k in PARENTS.findall(line))
            if leaves or CLIMB.search(line):
                hits.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()[:100]}")
    assert not hits, "paths that leave the repository (copy the data into tests/data/):\n" + "\n".join(hits)


def test_scan_catches_the_old_reference_paths():
    old = 'REF = Path(__file__).resolve().parents[2] / "shared" / "data"'
    test_file = ROOT / "tests" / "test_x.py"
    assert int(PARENTS.findall(old)[0]) > _depth(test_file)
    assert int(PARENTS.findall("ROOT = Path(__file__).resolve().parents[1]")[0]) <= _depth(test_file)
    assert CLIMB.search('REFERENCE = ROOT / ".." / "shared"') and CLIMB.search('open("../sibling/x")')
    assert not CLIMB.search('name = "a..b"')
