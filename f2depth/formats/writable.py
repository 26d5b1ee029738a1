"""Output locations checked before any work: a run that cannot write its outputs fails at once, with one
line naming the folder and the option or params key that sets it, not after minutes (or hours) of work."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterable
from pathlib import Path

from f2depth.errors import DataError


def check_output_folder(folder: str | os.PathLike, option: str = "--output") -> Path:
    """Create ``folder`` when needed and check that files can be created in it (a probe file, removed
    at once), so that a run fails before any work with the folder's name — not with the name of the
    temporary file the first atomic write would have used. Problems → DataError naming the folder."""
    p = Path(folder)
    if p.exists() and not p.is_dir():
        raise DataError(p, "exists and is not a folder", f"give {option} a folder (it is created if missing)")
    try:
        p.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".f2depth-write-test.", dir=p)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise DataError(p, f"output folder is not writable ({exc.strerror or exc})",
                        f"give {option} a folder you can write to") from None
    return p


def check_output_file(path: str | os.PathLike, option: str = "--output") -> Path:
    """The folder of output file ``path`` must be writable (:func:`check_output_folder`) and ``path``
    must not be a folder itself. Returns ``path``."""
    p = Path(path)
    if p.is_dir():
        raise DataError(p, "is a directory", f"give {option} a file name, not a folder")
    check_output_folder(p.parent if str(p.parent) else ".", option)
    return p


def check_apart(inputs: Iterable[str | os.PathLike | None], output: str | os.PathLike,
                option: str = "--output", inside_ok: bool = False) -> None:
    """Refuse an output folder that is an input, holds one (replacing the folder with the run's output
    would delete it) or — unless ``inside_ok`` — lies inside an input folder; links are followed, None
    inputs skipped. DataError naming the output, the input and ``option``, before anything is written."""
    out = Path(output).resolve()
    lost = "which replacing the output folder with this run's would delete"
    for given in inputs:
        if given is None:
            continue
        src = Path(given).resolve()
        if src == out:
            problem = f"is the input {given}, {lost}"
        elif out in src.parents:
            problem = f"holds the input {given}, {lost}"
        elif src in out.parents and not inside_ok:
            problem = f"lies inside the input {given}"
        else:
            continue
        raise DataError(output, problem,
                        f"give {option} a folder apart from the inputs (nothing was changed)")
