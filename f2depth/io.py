"""Atomic file output: nothing half-written survives a crash.

Every writer goes to a temporary file in the destination folder and is renamed into place
(``os.replace`` is atomic on POSIX and Windows within one file system). A folder output is built in a
temporary sibling (:func:`atomic_dir`) and swapped in at the end: the previous good folder stays until the
new one is complete.
"""

from __future__ import annotations

import contextlib
import csv
import errno
import io
import json
import os
import pickle
import re
import shutil
import struct
import tempfile
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np


def _file_mode() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return 0o666 & ~umask


_FILE_MODE = _file_mode()


#: Below this many free bytes a failed write is taken for a full disk (writers say it in their own words:
#: numpy "30000 requested and 23520 written", torch "[enforce fail at inline_container.cc]", OpenCV False)
FULL_DISK_BYTES = 1 << 20


def no_space(path: str | os.PathLike, exc: BaseException) -> OSError | None:
    """The error to raise instead of ``exc`` when writing ``path`` failed because its disk is full: an
    ``OSError(ENOSPC)`` whose message names the file, the free space and the fix; else None."""
    if not isinstance(exc, (OSError, RuntimeError)):
        return None
    try:
        free: int | None = shutil.disk_usage(Path(path).parent).free
    except OSError:
        free = None
    said = isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT)
    if not said and (free is None or free >= FULL_DISK_BYTES):
        return None
    room = f"{free / 1e6:.1f} MB free" if free is not None else "free space unknown"
    return OSError(errno.ENOSPC, f"no space left on device ({room}); nothing half-written was kept: free "
                                 "some space or write to another disk", str(path))


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success rename it onto ``path``. A write that fails
    on a full disk is raised as ``OSError(ENOSPC)`` naming ``path`` (:func:`no_space`).

    ``suffix`` defaults to the destination's suffix so that writers that infer the format from
    the file name (OpenCV, numpy) keep working.
    """
    dest = Path(path)
    dest.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=suffix if suffix is not None else dest.suffix,
                               dir=dest.parent)
    os.close(fd)
    os.chmod(tmp, _FILE_MODE)  # mkstemp makes 0600 files; give them the mode open() would
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.replace(tmp_path, dest)
    except BaseException as exc:
        full = no_space(dest, exc)  # asked before the temporary's space is freed again
        tmp_path.unlink(missing_ok=True)
        if full is not None:
            raise full from exc
        raise


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's live process
        return True
    return True


def clear_stale_temporaries(path: str | os.PathLike) -> list[Path]:
    """Remove the temporary siblings :func:`atomic_dir` left for ``path`` in processes that no longer run
    (killed with -9, or a power cut): ``.<name>.tmp-<pid>`` folders are deleted; an ``.<name>.old-<pid>``
    folder — the previous good output, moved aside in the instant before the new one was renamed in — is
    renamed back when ``path`` is missing, else deleted. Folders of live processes are left alone. Returns
    what was removed or restored."""
    dest = Path(path)
    if not dest.parent.is_dir():
        return []
    pattern = re.compile(rf"\.{re.escape(dest.name)}\.(tmp|old)-(\d+)")
    done = []
    for entry in sorted(dest.parent.iterdir()):
        m = pattern.fullmatch(entry.name)
        if not m or int(m.group(2)) == os.getpid() or _pid_alive(int(m.group(2))):
            continue
        if m.group(1) == "old" and not dest.exists():
            entry.rename(dest)
        else:
            shutil.rmtree(entry, ignore_errors=True)
        done.append(entry)
    return done


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike) -> Iterator[Path]:
    """Yield an empty temporary sibling folder of ``path``; on success it replaces ``path`` (two renames,
    the old folder deleted last), on any error it is deleted and ``path`` is left as it was. Temporaries
    that killed runs left for ``path`` are cleared first (:func:`clear_stale_temporaries`)."""
    dest = Path(path)
    clear_stale_temporaries(dest)
    tmp = dest.parent / f".{dest.name}.tmp-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        yield tmp
        old = dest.parent / f".{dest.name}.old-{os.getpid()}"
        if dest.exists():
            dest.rename(old)
        tmp.rename(dest)
        shutil.rmtree(old, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def write_bytes(path: str | os.PathLike, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def write_text(path: str | os.PathLike, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def csv_text(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> str:
    """CSV text with ``\n`` line ends: the header, then the rows (None and "" are empty cells)."""
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(header)
    writer.writerows(rows)
    return buf.getvalue()


def write_json(path: str | os.PathLike, obj: Any) -> None:
    """Write ``obj`` as indented JSON (NumPy scalars and arrays converted)."""

    def default(o: Any) -> Any:
        if isinstance(o, np.generic):
            return o.item()
        if isinstance(o, np.ndarray):
            return o.tolist()
        if isinstance(o, Path):
            return str(o)
        raise TypeError(f"not JSON serialisable: {type(o).__name__}")

    write_text(path, json.dumps(obj, indent=2, sort_keys=False, default=default) + "\n")


def save_npz(path: str | os.PathLike, compressed: bool = True, **arrays: np.ndarray) -> None:
    with atomic_path(path, suffix=".npz") as tmp:
        (np.savez_compressed if compressed else np.savez)(tmp, **arrays)


def save_npy(path: str | os.PathLike, array: np.ndarray) -> None:
    with atomic_path(path, suffix=".npy") as tmp:
        np.save(tmp, array)


def imwrite(path: str | os.PathLike, image: np.ndarray, params: list[int] | None = None) -> None:
    """``cv2.imwrite`` made atomic; ``image`` is in OpenCV's channel order (BGR)."""
    with atomic_path(path) as tmp:
        try:
            ok = cv2.imwrite(str(tmp), image, params or [])
        except cv2.error as exc:
            ok = False
            detail = str(exc).strip().splitlines()[-1]
        else:
            detail = ""
        if not ok:
            raise OSError(f"{path}: OpenCV could not write (unsupported extension or dtype {image.dtype}) "
                          f"{detail}".strip())


def write_rgb(path: str | os.PathLike, rgb: np.ndarray, jpeg_quality: int = 95) -> None:
    """RGB uint8 (H, W, 3) → PNG / binary PPM / JPEG by extension, atomically (stored BGR by OpenCV)."""
    jpeg = [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality] if str(path).lower().endswith((".jpg", ".jpeg")) else []
    imwrite(path, np.ascontiguousarray(rgb[..., ::-1]), jpeg)


def torch_save(path: str | os.PathLike, obj: Any) -> None:
    import torch

    with atomic_path(path) as tmp:
        torch.save(obj, tmp)


_ANSI = re.compile(r"\x1b\[[0-9;]*m")  # torch colours parts of its load errors
_UNSUPPORTED = re.compile(r"Unsupported global: GLOBAL (\S+)")
_UNPICKLER = re.compile(r"WeightsUnpickler error: (.*?) Check the documentation")
_LOAD_ERRORS = (pickle.UnpicklingError, RuntimeError, EOFError, ValueError, OSError, AttributeError,
                TypeError, KeyError, IndexError, struct.error)


def load_weights(path: str | os.PathLike, kind: str, fix: str) -> Any:
    """``torch.load(path, weights_only=True)`` on CPU; a file it cannot read raises a ValueError of one line:
    ``<path>: not <kind>: it holds pickled Python objects (...) ...; <fix>`` or ``<path>: not a readable
    torch checkpoint (<reason>); <fix>``. torch's advice to retry with ``weights_only=False`` (which would
    run whatever code the file pickled) is never passed on."""
    import torch

    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except _LOAD_ERRORS as exc:
        text = " ".join(_ANSI.sub("", str(exc)).split())
        found = _UNSUPPORTED.search(text)
        if found:
            raise ValueError(f"{path}: not {kind}: it holds pickled Python objects ({found.group(1)}), "
                             f"which a weights_only load refuses and f2depth never unpickles; {fix}") from exc
        reason = _UNPICKLER.search(text)
        first = (f"WeightsUnpickler: {reason.group(1)}" if reason
                 else text[:200] if text and "weights_only" not in text else type(exc).__name__)
        raise ValueError(f"{path}: not a readable torch checkpoint ({first}); {fix}") from exc
