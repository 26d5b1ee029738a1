"""Atomic file output: nothing half-written survives a crash.

Every writer goes to a temporary file in the destination folder and is renamed into place
(``os.replace`` is atomic on POSIX and Windows within one file system). A folder output is built in a
temporary sibling (:func:`atomic_dir`) and swapped in at the end: the previous good folder stays until the
new one is complete. Every swapped-in folder holds a marker file (:data:`OUTPUT_MARKER`) naming the command or
stage that wrote it, and :func:`atomic_dir` replaces no other non-empty folder (:func:`check_replaceable`):
a mistyped output path never deletes a user's files.
"""

from __future__ import annotations

import contextlib
import csv
import errno
import fcntl
import hashlib
import io
import json
import math
import os
import pickle
import re
import shutil
import struct
import tempfile
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
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


#: the file in every folder :func:`atomic_dir` swaps in: one line, the command or stage that wrote the folder
OUTPUT_MARKER = ".f2depth-output"


def output_kind(path: str | os.PathLike) -> str | None:
    """The command or stage that the marker of folder ``path`` names, or None (no marker)."""
    try:
        return (Path(path) / OUTPUT_MARKER).read_text().strip() or None
    except (OSError, UnicodeDecodeError):
        return None


def check_replaceable(path: str | os.PathLike, kind: str, option: str = "--output",
                      previous: Callable[[Path], bool] | None = None) -> None:
    """Refuse to replace ``path`` unless it is missing, an empty folder or a previous output of ``kind``: its
    marker names ``kind``, or — outputs written before the marker existed — ``previous(path)`` says that its
    entries all look like one. Else ``FileExistsError`` naming the folder and the option that sets it (the
    command line prints it as one line)."""
    dest = Path(path)
    if not dest.exists():
        return
    if not dest.is_dir():
        raise FileExistsError(errno.EEXIST, f"exists and is not a folder; give {option} a folder", str(dest))
    found = output_kind(dest)
    earlier = found is None and previous is not None and previous(dest)  # written before the marker existed
    if found == kind or earlier or not any(dest.iterdir()):
        return
    what = (f"holds the output of f2depth {found}, not of {kind}" if found is not None else
            f"holds files that f2depth {kind} did not write (no {OUTPUT_MARKER} marker)")
    raise FileExistsError(errno.EEXIST, f"{what}, and this run would replace the whole folder; give {option} "
                                        "a new or empty folder (nothing was changed)", str(dest))


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike, kind: str, *, owned: bool = False, option: str = "--output",
               previous: Callable[[Path], bool] | None = None, keep_partial: bool = False) -> Iterator[Path]:
    """Yield an empty temporary sibling folder of ``path``; on success it replaces ``path`` (two renames,
    the old folder deleted last), on any error it is deleted and ``path`` is left as it was. Temporaries
    that killed runs left for ``path`` are cleared first (:func:`clear_stale_temporaries`).

    The new folder holds :data:`OUTPUT_MARKER` naming ``kind`` (the command or stage). An existing ``path``
    is replaced only when :func:`check_replaceable` allows it (``option``, ``previous``: its arguments),
    checked before anything is written — unless ``owned``: a DVC stage's output, whose path params.yaml
    sets and which DVC itself removes before it runs the stage. ``keep_partial``: on an error or interrupt
    the temporary still replaces ``path`` when it holds anything besides the marker (a command that keeps
    the complete files written so far, never mixed with an older run's). A link to a folder stays: the
    folder it points to is replaced."""
    dest = Path(path)
    if dest.is_symlink():
        dest = dest.resolve()
    clear_stale_temporaries(dest)
    if not owned:
        check_replaceable(dest, kind, option, previous)
    tmp = dest.parent / f".{dest.name}.tmp-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)

    def swap() -> None:
        old = dest.parent / f".{dest.name}.old-{os.getpid()}"
        if dest.exists():
            dest.rename(old)
        tmp.rename(dest)
        shutil.rmtree(old, ignore_errors=True)

    try:
        write_text(tmp / OUTPUT_MARKER, f"{kind}\n")
        yield tmp
        swap()
    except BaseException as exc:
        inside = str(getattr(exc, "filename", None) or "")
        if isinstance(exc, OSError) and inside.startswith(f"{tmp}{os.sep}"):  # name the file as the user will
            exc.filename = f"{dest}{inside[len(str(tmp)):]}"
        with contextlib.suppress(OSError):  # a failing swap keeps the previous folder: raise the first error
            if keep_partial and tmp.is_dir() and any(e.name != OUTPUT_MARKER for e in tmp.iterdir()):
                swap()
        shutil.rmtree(tmp, ignore_errors=True)
        raise


@contextlib.contextmanager
def folder_lock(path: str | os.PathLike, option: str = "--output") -> Iterator[None]:
    """Hold an exclusive lock on output folder ``path`` for the block: ``fcntl.flock`` on ``.<name>.lock``
    beside it, which holds the holder's pid and is removed on the way out. A second run into the same
    folder meanwhile → ``BlockingIOError`` naming the folder, the holder and ``option`` (one line)."""
    dest = Path(path)
    dest.parent.mkdir(parents=True, exist_ok=True)
    lock = dest.parent / f".{dest.name}.lock"
    while True:
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, _FILE_MODE)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(fd, 32).decode("ascii", "replace").strip()
            os.close(fd)
            raise BlockingIOError(errno.EAGAIN, f"another f2depth run{f' (pid {holder})' if holder else ''} "
                                                "is writing this folder now; wait for it to end or give "
                                                f"{option} another folder (nothing was changed)",
                                  str(dest)) from None
        try:  # the holder may have removed the file between our open and our lock: lock the new one
            current = os.path.samestat(os.fstat(fd), os.stat(lock))
        except FileNotFoundError:
            current = False
        if current:
            break
        os.close(fd)
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        yield
    finally:
        lock.unlink(missing_ok=True)  # while still locked: a run that opened it meanwhile sees it gone
        os.close(fd)


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


def json_values(obj: Any) -> Any:
    """``obj`` with what JSON cannot hold made JSON: NumPy scalars and arrays as numbers and lists, paths as
    strings, and every non-finite number (NaN, ±inf, which ``json`` would write as the non-JSON ``NaN`` /
    ``Infinity``) as null."""
    if isinstance(obj, dict):
        return {k: json_values(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_values(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_values(obj.tolist())
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_json(path: str | os.PathLike, obj: Any) -> None:
    """Write ``obj`` as indented, valid JSON (:func:`json_values`: NumPy values converted, NaN and ±inf
    written as null)."""

    def default(o: Any) -> Any:
        raise TypeError(f"not JSON serialisable: {type(o).__name__}")

    text = json.dumps(json_values(obj), indent=2, sort_keys=False, default=default, allow_nan=False)
    write_text(path, text + "\n")


def save_npz(path: str | os.PathLike, compressed: bool = True, **arrays: np.ndarray) -> None:
    with atomic_path(path, suffix=".npz") as tmp:
        (np.savez_compressed if compressed else np.savez)(tmp, **arrays)


def save_npy(path: str | os.PathLike, array: np.ndarray) -> None:
    with atomic_path(path, suffix=".npy") as tmp:
        np.save(tmp, array)


def imwrite(path: str | os.PathLike, image: np.ndarray, params: list[int] | None = None) -> None:
    """``cv2.imwrite`` made atomic; ``image`` is in OpenCV's channel order (BGR). The image is encoded in
    memory (``cv2.imencode``, the format from the extension) and written by Python, so a failed write is
    the OSError the system gave (a full disk: ENOSPC, :func:`no_space`), never "OpenCV could not write"."""
    suffix = Path(path).suffix
    try:
        ok, encoded = cv2.imencode(suffix, image, params or [])
    except cv2.error as exc:
        ok, detail = False, str(exc).strip().splitlines()[-1]
    else:
        detail = ""
    if not ok:
        raise OSError(f"{path}: OpenCV could not write this image type (no encoder for extension {suffix!r} "
                      f"or dtype {image.dtype}) {detail}".strip())
    write_bytes(path, encoded.tobytes())


def write_rgb(path: str | os.PathLike, rgb: np.ndarray, jpeg_quality: int = 95) -> None:
    """RGB uint8 (H, W, 3) → PNG / binary PPM / JPEG by extension, atomically (stored BGR by OpenCV)."""
    jpeg = [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality] if str(path).lower().endswith((".jpg", ".jpeg")) else []
    imwrite(path, np.ascontiguousarray(rgb[..., ::-1]), jpeg)


def weights_digest(state: Mapping[str, Any]) -> str:
    """sha256 of a state dict: every tensor's name, dtype, shape and bytes, in sorted name order. Checkpoints
    store it (``weights_sha256``) and loaders compare, so a damaged file (flipped bytes in a weight) is
    refused instead of predicting wrong depth. Anything but a dict of tensors → TypeError."""
    import torch

    if not isinstance(state, Mapping):
        raise TypeError(f"weights_digest: a {type(state).__name__}, not a state dict")
    h = hashlib.sha256()
    for name in sorted(state):
        t = state[name]
        if not isinstance(t, torch.Tensor):
            raise TypeError(f"weights_digest: {name} is a {type(t).__name__}, not a tensor")
        t = t.detach().cpu().contiguous().reshape(-1)
        h.update(f"{name}|{t.dtype}|{tuple(state[name].shape)}|".encode())
        h.update(t.view(torch.uint8).numpy())
    return h.hexdigest()


def damaged_weights(path: str | os.PathLike, ckpt: Mapping[str, Any], fix: str) -> str | None:
    """The one-line error for checkpoint ``ckpt`` (read from ``path``) whose ``weights_sha256`` differs from
    the :func:`weights_digest` of its ``state_dict``: the file changed after it was written (a flipped byte
    in a weight leaves the file readable). None when they agree, and for files written before the digest
    existed (no ``weights_sha256``)."""
    stored = ckpt.get("weights_sha256")
    if stored is None:
        return None
    try:
        actual = weights_digest(ckpt.get("state_dict"))
    except TypeError:  # not a dict of tensors: damaged too
        actual = None
    if stored == actual:
        return None
    return (f"{path}: damaged: its weights do not match the sha256 digest written with them (the file "
            f"changed after it was written); {fix}")


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
