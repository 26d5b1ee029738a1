"""Output locations checked before any work: a run that cannot write its outputs fails at once, with one
line naming the folder and the option or params key that sets it, not after minutes (or hours) of work."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from f2depth.data.errors import DataError


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
