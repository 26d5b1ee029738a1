"""Resumable training state, written atomically after every epoch.

File: ``{"format": "f2depth.train_state", "version": 1, "fingerprint", "epoch", "model", "config",
"optimizer", "scaler", "rng", "sampler", "history"}`` — plain tensors and Python values only, so it loads
with ``torch.load(weights_only=True)``. ``epoch`` is the number of finished epochs; ``sampler`` holds the
seed the data order is drawn from (the order of epoch e is a function of (seed, e), see
``data.epoch_order``), ``rng`` the torch / numpy / Python generator states, ``history`` the per-epoch rows
so far (epoch 0 = the untrained network's validation).

``fingerprint`` identifies the run (a hash of its settings and input files, made by the caller): a state
whose fingerprint differs is never resumed, so changed parameters or data start a fresh run.
"""

from __future__ import annotations

import hashlib
import json
import os
import pickle
import random
from pathlib import Path
from typing import Any

import numpy as np
import torch

from f2depth.io import torch_save

FORMAT = "f2depth.train_state"
VERSION = 1


def fingerprint(settings: dict[str, Any], files: dict[str, str | os.PathLike | None] | None = None) -> str:
    """sha256 of the JSON of ``settings`` plus the sha256 of each named file (None = no file)."""
    digests = {k: file_digest(v) if v else None for k, v in (files or {}).items()}
    digest = {"settings": settings, "files": digests}
    return hashlib.sha256(json.dumps(digest, sort_keys=True, default=str).encode()).hexdigest()


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


def rng_state() -> dict[str, Any]:
    np_state = np.random.get_state()  # noqa: NPY002 (the legacy global generator is what we save)
    return {
        "torch": torch.get_rng_state(),
        "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else [],
        "numpy": {"name": np_state[0], "key": torch.from_numpy(np_state[1].astype(np.int64)),
                  "pos": int(np_state[2]), "has_gauss": int(np_state[3]), "cached": float(np_state[4])},
        "python": random.getstate(),
    }


def set_rng_state(state: dict[str, Any]) -> None:
    torch.set_rng_state(state["torch"])
    if state.get("cuda") and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])
    n = state["numpy"]
    key = n["key"].numpy().astype(np.uint32)
    np.random.set_state((n["name"], key, n["pos"], n["has_gauss"], n["cached"]))  # noqa: NPY002
    version, internal, gauss = state["python"]
    random.setstate((version, tuple(internal), gauss))


def save_state(path: str | os.PathLike, *, fingerprint: str, epoch: int, model: torch.nn.Module,
               config: dict[str, Any], optimizer: torch.optim.Optimizer,
               scaler: torch.amp.GradScaler | None, sampler: dict[str, Any],
               history: list[dict[str, Any]]) -> None:
    """Write the state after ``epoch`` finished epochs (atomically: a crash leaves the previous file)."""
    torch_save(path, {
        "format": FORMAT, "version": VERSION, "fingerprint": fingerprint, "epoch": int(epoch),
        "model": {k: v.detach().cpu() for k, v in model.state_dict().items()},
        "config": dict(config),
        "optimizer": optimizer.state_dict(),
        "scaler": scaler.state_dict() if scaler is not None and scaler.is_enabled() else {},
        "rng": rng_state(), "sampler": dict(sampler), "history": [dict(r) for r in history],
    })  # fmt: skip


def load_state(path: str | os.PathLike, expected_fingerprint: str) -> tuple[dict[str, Any] | None, str]:
    """(state, "") when ``path`` holds a resumable state of this run, else (None, reason)."""
    p = Path(path)
    if not p.is_file():
        return None, f"no checkpoint at {p}"
    try:
        state = torch.load(p, map_location="cpu", weights_only=True)
    except (RuntimeError, OSError, EOFError, ValueError, pickle.UnpicklingError) as exc:
        return None, f"{p} is unreadable ({exc}); starting afresh"
    if not isinstance(state, dict) or state.get("format") != FORMAT or state.get("version") != VERSION:
        return None, f"{p} is not a {FORMAT} v{VERSION} file; starting afresh"
    if state.get("fingerprint") != expected_fingerprint:
        return None, f"{p} belongs to a run with other settings or inputs; starting afresh"
    return state, ""
