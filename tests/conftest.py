"""Session settings of the test suite.

`make test` runs two pytest workers on a 2-core machine: each process (and every stage it starts) gets one
thread unless a test sets its own, as f2depth.threads reads ``$OMP_NUM_THREADS``. Two workers at two
threads each ran torch several times slower (docs/experiments/2026-12-04-shared-cpu.md).
"""

import os
import sys
import tempfile
from pathlib import Path

import pytest

os.environ.setdefault("OMP_NUM_THREADS", "1")


def pytest_collection_modifyitems(config, items):
    """The long tests (marked ``e2e`` or ``slow``) first, in their collected order. `make test` hands tests
    to its two workers two at a time (``--maxschedchunk 2``), so the workers start on the long ones together
    and share them, instead of one of them starting a five-minute test when the other is nearly done."""
    items.sort(key=lambda item: not (item.get_closest_marker("e2e") or item.get_closest_marker("slow")))


@pytest.fixture
def restore_threads():
    """Put torch's and OpenCV's thread counts and f2depth.threads' free-core watch back after a test that
    sets them."""
    import cv2
    import torch

    from f2depth import threads

    before_torch, before_cv2, before_free = torch.get_num_threads(), cv2.getNumThreads(), threads._free
    yield
    threads._free = before_free
    torch.set_num_threads(before_torch)
    cv2.setNumThreads(before_cv2)


# ---- no test reads outside the repository (a user's clone has nothing beside it) -----------------------
ROOT = Path(__file__).resolve().parents[1]
_AUDITED = frozenset({"open", "os.listdir", "os.scandir"})


class OutsideRepositoryError(PermissionError):
    """A test opened a file beside the repository: copy what it needs into tests/data/ instead."""


def outside_repository(path, root: Path = ROOT, allowed: tuple[Path, ...] = ()) -> bool:
    """True for a path beside the repository: in its parent folder, not inside the repository (a sibling
    checkout such as ``../shared``, which a user's clone does not have). Allowed: the system temp folder,
    the interpreter and its packages (``allowed``), hidden entries of the parent (``~/.cache`` when the
    clone is in a home folder) and everything when the parent is the file-system root."""
    if isinstance(path, int) or root.parent == root.parent.parent:
        return False
    absolute = Path(os.path.abspath(os.fsdecode(path)))
    if not absolute.is_relative_to(root.parent) or absolute.is_relative_to(root):
        return False
    # A folder the machine needs that lies beside the clone is allowed; one that holds the clone's parent (the
    # temp folder when the clone is in a folder of its own below it, as in CI) is not: the parent's entries
    # are what this guard is for. A clone right in the temp folder cannot tell them apart: allowed.
    if any(absolute.is_relative_to(folder)
           and (folder == root.parent or not root.parent.is_relative_to(folder)) for folder in allowed):
        return False
    parts = absolute.relative_to(root.parent).parts
    return not parts or not parts[0].startswith(".")


_ALLOWED = tuple({Path(tempfile.gettempdir()).resolve(), Path(sys.prefix).resolve(),
                  Path(sys.base_prefix).resolve(), Path(sys.exec_prefix).resolve()})


def _refuse_outside(event: str, args: tuple) -> None:
    if event in _AUDITED and args and args[0] is not None and outside_repository(args[0], ROOT, _ALLOWED):
        raise OutsideRepositoryError(
            f"{os.fsdecode(args[0])}: tests read nothing outside the repository {ROOT} "
            "(a user's clone has nothing beside it); copy the file into tests/data/")


sys.addaudithook(_refuse_outside)
