"""The one epoch skeleton of every trainer — flow pretraining, flow fine-tuning, depth training: the epoch
loop, resume, the history and the non-finite policy. A trainer supplies only what differs: the batches of
an epoch, one step, its optimiser, and the per-epoch hooks.

**Epochs** are numbered from 1 (a history row ``{"epoch": 0, ...}`` may hold the untrained network's
validation). Each row holds the mean of every step statistic over the steps taken, ``steps``,
``skipped_steps``, ``seconds`` (training time of the epoch) and what the ``end_epoch`` hook adds.
:func:`write_history` writes them as CSV, one file per group of columns measured on the same epochs.

**Non-finite policy** (all three trainers). A step whose loss is NaN or infinite raises
``FloatingPointError`` before any update (depth training: ``NonFiniteLossError`` naming the term; under DDP
the ranks agree first, so all of them skip the same step). The skeleton skips that step — no update — and
counts it in the row's ``skipped_steps``. An epoch in which every step was skipped, or whose means are not
finite, stops the run with :class:`NonFiniteEpochError`: one line naming the run, the epoch and the last
cause. Its state is not saved, so the resume file keeps the last good epoch.

**Resume.** After every epoch the main process writes, atomically (``f2depth.io.torch_save``), the file
``{"format": "f2depth.train_state", "version", "run", "fingerprint", "fingerprint_parts", "epoch", "history",
"parts"}`` —
``parts`` the ``state_dict()`` of each named part (model, optimizer, grad scaler, RNG state), plain tensors
and Python values, so it loads with ``torch.load(weights_only=True)``. ``fingerprint`` (:func:`fingerprint`:
a hash of the settings and the contents of the input files) identifies the run: a state whose fingerprint,
format or version differs is never resumed, so changed parameters or data start afresh, with one warning
naming what changed (``fingerprint_parts``: the digest of each setting and input). A finished run's caller
deletes the file (:func:`clear_state`) once its own outputs are written, never before.

**Hooks.** ``end_epoch(row) → dict`` (main process, before the state is saved) adds columns to the
epoch's row: validation, the learning rate. ``on_epoch(row)`` (main process, after the save) mirrors each
row, e.g. to MLflow; on resume it first replays every row already in the history, so a new logger gets
the whole curve.

**Random streams.** No trainer draws from a global generator: every epoch's shuffling and augmentation
come from generators derived from ``(seed, epoch)`` alone — :func:`epoch_generator` (torch: an epoch's
order and batch-level draws), :func:`epoch_rng` (numpy: generated training pairs) and
:func:`sample_generator` (one per sample and stream, independent of DataLoader workers and batch order) —
so a resumed run draws exactly what an unbroken one draws.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import pickle
import random
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from f2depth.io import csv_text, damaged_weights, torch_save, weights_digest, write_text

FORMAT = "f2depth.train_state"
VERSION = 2
log = logging.getLogger(__name__)


def epoch_generator(seed: int, epoch: int) -> torch.Generator:
    """The torch stream of (1-based) ``epoch`` of a run seeded ``seed``: its order and batch-level draws."""
    return torch.Generator().manual_seed(seed * 1_000_003 + epoch - 1)


def epoch_rng(seed: int, epoch: int) -> np.random.Generator:
    """The numpy stream of (1-based) ``epoch`` (SeedSequence hashing of ``[seed, epoch]``)."""
    return np.random.default_rng([seed, epoch])


def sample_seed(seed: int, epoch: int, index: int, stream: int) -> int:
    """A 63-bit seed that depends only on (seed, epoch, index, stream) (numpy SeedSequence hashing)."""
    ss = np.random.SeedSequence([int(seed) & 0xFFFFFFFF, int(epoch), int(index), int(stream)])
    return int(ss.generate_state(1, dtype=np.uint64)[0] >> np.uint64(1))


def sample_generator(seed: int, epoch: int, index: int, stream: int) -> torch.Generator:
    """The torch stream of sample ``index`` in ``epoch`` for one purpose ``stream`` (augmentation,
    points…)."""
    return torch.Generator().manual_seed(sample_seed(seed, epoch, index, stream))


class NonFiniteEpochError(FloatingPointError):
    """Every step of an epoch had a non-finite loss (or its means are not finite): the run stops."""


class RNGState:
    """The torch / CUDA / numpy / Python generators as a resumable part."""

    def state_dict(self) -> dict[str, Any]:
        np_state = np.random.get_state()  # noqa: NPY002 (the legacy global generator is what we save)
        return {
            "torch": torch.get_rng_state(),
            "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else [],
            "numpy": {"name": np_state[0], "key": torch.from_numpy(np_state[1].astype(np.int64)),
                      "pos": int(np_state[2]), "has_gauss": int(np_state[3]), "cached": float(np_state[4])},
            "python": random.getstate(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        torch.set_rng_state(state["torch"])
        if state.get("cuda") and torch.cuda.is_available():
            torch.cuda.set_rng_state_all(state["cuda"])
        n = state["numpy"]
        np.random.set_state((n["name"], n["key"].numpy().astype(np.uint32), n["pos"], n["has_gauss"],  # noqa: NPY002
                             n["cached"]))
        version, internal, gauss = state["python"]
        random.setstate((version, tuple(internal), gauss))


class Fingerprint(str):
    """A run's fingerprint (the hex digest) that keeps the digest of each of its parts — every top-level
    setting and every input file or folder — so that a state of another run can say what differs."""

    parts: dict[str, str]


def _digest(obj: Any) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()


def fingerprint(settings: Mapping[str, Any],
                files: Mapping[str, str | os.PathLike | None] | None = None) -> Fingerprint:
    """sha256 of the JSON of ``settings`` plus the sha256 of each named file or folder (its contents,
    :func:`file_digest`; None = no file). ``.parts``: the digest of each setting and each file."""
    return fingerprints({None: settings}, files)[None]


def fingerprints(runs: Mapping[Any, Mapping[str, Any]],
                 files: Mapping[str, str | os.PathLike | None] | None = None) -> dict[Any, Fingerprint]:
    """:func:`fingerprint` of each run's settings (``runs``: key → settings) over the same input files,
    which are read once."""
    digests = {k: file_digest(v) if v else None for k, v in (files or {}).items()}
    out = {}
    for key, settings in runs.items():
        fp = Fingerprint(_digest({"settings": dict(settings), "files": digests}))
        fp.parts = {**{f"setting {k}": _digest(v) for k, v in settings.items()},
                    **{f"input {k}": str(v) for k, v in digests.items()}}
        out[key] = fp
    return out


def file_digest(path: str | os.PathLike) -> str:
    """sha256 of a file's bytes, or of a folder's (relative path, bytes) pairs in sorted order."""
    p = Path(path)
    h = hashlib.sha256()
    files = [p] if p.is_file() else sorted(q for q in p.rglob("*") if q.is_file())
    if not files:
        raise FileNotFoundError(f"{p}: nothing to fingerprint (missing input)")
    for f in files:
        h.update(str(f.relative_to(p) if f != p else f.name).encode())
        with f.open("rb") as fh:
            for chunk in iter(lambda: fh.read(1 << 20), b""):
                h.update(chunk)
    return h.hexdigest()


def save_state(path: str | os.PathLike, *, run: str, fingerprint: str, epoch: int,
               history: list[dict[str, Any]], parts: Mapping[str, Any]) -> None:
    """Write the state after ``epoch`` finished epochs (atomically: a crash leaves the previous file)."""
    states = {name: {k: v.detach().cpu() for k, v in p.state_dict().items()}
              if isinstance(p, torch.nn.Module) else p.state_dict() for name, p in parts.items()}
    digests = {name: weights_digest(states[name]) for name, part in parts.items()
               if isinstance(part, torch.nn.Module)}  # load_state refuses a damaged file
    torch_save(path, {"format": FORMAT, "version": VERSION, "run": run, "fingerprint": str(fingerprint),
                      "fingerprint_parts": dict(getattr(fingerprint, "parts", {})),
                      "epoch": int(epoch), "history": [dict(r) for r in history], "parts": states,
                      "weights_sha256": digests})


def load_state(path: str | os.PathLike, expected_fingerprint: str) -> tuple[dict[str, Any] | None, str]:
    """(state, "") when ``path`` holds a resumable state of this run, else (None, reason)."""
    p = Path(path)
    if not p.is_file():
        return None, f"no training state at {p}"
    try:
        state = torch.load(p, map_location="cpu", weights_only=True)
    except (RuntimeError, OSError, EOFError, ValueError, pickle.UnpicklingError) as exc:
        return None, f"{p} is unreadable ({exc}); starting afresh"
    if not isinstance(state, dict) or state.get("format") != FORMAT or state.get("version") != VERSION:
        return None, f"{p} is not a {FORMAT} v{VERSION} file; starting afresh"
    if state.get("fingerprint") != expected_fingerprint:
        return None, (f"{p} belongs to a run with other {_changed(state, expected_fingerprint)}; "
                      "starting afresh")
    digests, parts = state.get("weights_sha256") or {}, state.get("parts")
    for name, digest in dict(digests).items():  # states written before the digests existed have none
        weights = parts.get(name) if isinstance(parts, dict) else None
        damage = damaged_weights(f"{p} ({name})", {"weights_sha256": digest, "state_dict": weights},
                                 "starting afresh")
        if damage:
            return None, damage
    return state, ""


def _changed(state: dict[str, Any], expected: str) -> str:
    """What differs between a saved state's fingerprint and ``expected`` (a :class:`Fingerprint`), as
    "settings or inputs: input prepared, setting lr" — or "settings or inputs" where it cannot tell."""
    old, new = state.get("fingerprint_parts"), getattr(expected, "parts", None)
    if not isinstance(old, dict) or not new:
        return "settings or inputs"
    names = sorted(k for k in set(old) | set(new) if old.get(k) != new.get(k))
    return "settings or inputs" + (f" ({', '.join(names)} changed)" if names else "")


def clear_state(path: str | os.PathLike) -> None:
    """Delete a finished run's state file, and its folder when that is left empty."""
    p = Path(path)
    p.unlink(missing_ok=True)
    if p.parent.is_dir() and not any(p.parent.iterdir()):
        p.parent.rmdir()


def history_csv(rows: Iterable[Mapping[str, Any]], columns: Iterable[str]) -> str:
    """The rows as CSV text with ``columns`` (floats with 6 significant digits, blanks for gaps)."""
    columns = list(columns)
    cells = ((row.get(c) for c in columns) for row in rows)
    return csv_text(columns, (["" if v is None else f"{v:.6g}" if isinstance(v, float) else v for v in r]
                              for r in cells))


def measured_rows(rows: Iterable[Mapping[str, Any]], columns: Iterable[str]) -> list[Mapping[str, Any]]:
    """The rows with a value in one of ``columns`` other than ``epoch``: the epochs that measured them."""
    names = [c for c in columns if c != "epoch"]
    return [row for row in rows if any(row.get(c) is not None for c in names)]


def write_history(path: str | os.PathLike, rows: Iterable[Mapping[str, Any]], columns: Iterable[str]) -> None:
    """A history file: ``columns`` of the rows that measured one of them (:func:`measured_rows`). A trainer
    puts what it measures every epoch in one file and what it measures on some epochs only (validation)
    in another, so that no row has a gap where a curve would fall (DVC's plots draw an empty cell as 0);
    a column stays empty on every row only where the run never measures it (a term the variant is without)."""
    columns = list(columns)
    write_text(path, history_csv(measured_rows(rows, columns), columns))


@dataclass
class EpochLoop:
    """The epochs of one run (module docstring). ``parts``: what the resume file holds, by name (objects
    with ``state_dict()`` / ``load_state_dict()``); ``main``: this process saves, measures and logs (rank 0
    under DDP)."""

    run: str
    epochs: int
    parts: Mapping[str, Any]
    state_file: str | os.PathLike | None = None
    fingerprint: str = ""
    main: bool = True
    progress: bool = True
    state_every: int = 1  # write the resume file after every N-th epoch and after the last
    history: list[dict[str, Any]] = field(default_factory=list)
    resumed_from: int = 0  # finished epochs taken from the state file (0 = fresh start)
    note: str = ""

    def saves_after(self, epoch: int) -> bool:
        """Whether the resume file is written after ``epoch`` (1-based): each ``state_every``-th, the last."""
        return epoch % self.state_every == 0 or epoch == self.epochs

    def restore(self, enabled: bool = True) -> int:
        """Load the parts, epoch and history of a matching state file → the finished epochs (0 = fresh)."""
        if self.state_file is None or not enabled:
            self.note = "resume disabled"
            return 0
        state, self.note = load_state(self.state_file, self.fingerprint)
        if state is None:
            if Path(self.state_file).exists():
                log.warning("%s: %s", self.run, self.note)
            return 0
        for name, part in self.parts.items():
            if state["parts"][name]:  # a disabled GradScaler saves {}
                part.load_state_dict(state["parts"][name])
        self.history = [dict(r) for r in state["history"]]
        self.resumed_from = int(state["epoch"])
        return self.resumed_from

    def run_epochs(self, batches: Callable[[int], Iterable[Any]], step: Callable[[Any], Mapping[str, float]],
                   *,
                   end_epoch: Callable[[dict[str, Any]], Mapping[str, Any]] | None = None,
                   on_epoch: Callable[[dict[str, Any]], None] | None = None,
                   reduce: Callable[[dict[str, float]], dict[str, float]] | None = None,
                   barrier: Callable[[], None] | None = None) -> list[dict[str, Any]]:
        """Train the remaining epochs: ``batches(epoch)`` in order, ``step(batch)`` → statistics (raises
        ``FloatingPointError`` for a non-finite loss); ``reduce`` averages the means over DDP ranks and
        ``barrier`` waits for the main process's save. Returns the history."""
        if self.main and on_epoch is not None:
            for row in self.history:
                on_epoch(row)
        for epoch in range(self.resumed_from + 1, self.epochs + 1):
            t0 = time.perf_counter()
            sums: dict[str, float] = {}
            steps = skipped = 0
            last: FloatingPointError | None = None
            bar = tqdm(batches(epoch), desc=f"{self.run} {epoch}/{self.epochs}", leave=False,
                       disable=not (self.progress and self.main))
            for batch in bar:
                try:
                    stats = step(batch)
                except FloatingPointError as exc:
                    skipped, last = skipped + 1, exc
                    continue
                steps += 1
                for k, v in stats.items():
                    sums[k] = sums.get(k, 0.0) + v
                bar.set_postfix(skipped=skipped, **{k: f"{v:.4f}" for k, v in list(stats.items())[:1]})
            if skipped and not steps:
                raise NonFiniteEpochError(f"{self.run}: all {skipped} steps of epoch {epoch} had a "
                                          f"non-finite loss (last: {last})") from last
            means = {k: v / steps for k, v in sums.items()}
            means = reduce(means) if reduce is not None else means
            bad = [k for k, v in means.items() if not math.isfinite(v)]
            if bad:
                raise NonFiniteEpochError(f"{self.run}: epoch {epoch} has non-finite means of {bad}")
            row: dict[str, Any] = {"epoch": epoch, **means, "steps": steps, "skipped_steps": skipped,
                                   "seconds": time.perf_counter() - t0}
            if self.main and end_epoch is not None:
                row.update(end_epoch(row))
            self.history.append(row)
            if self.main and self.state_file is not None and self.saves_after(epoch):
                save_state(self.state_file, run=self.run, fingerprint=self.fingerprint, epoch=epoch,
                           history=self.history, parts=self.parts)
            if barrier is not None:
                barrier()
            if self.main and on_epoch is not None:
                on_epoch(row)
        return self.history
