"""Microsoft 7-Scenes: ``<scene>/seq-XX/frame-XXXXXX.{color.png,depth.png,pose.txt}``.

``<scene>/TestSplit.txt`` and ``TrainSplit.txt`` list ``sequenceN`` lines (→ ``seq-0N``). Depth is
uint16 millimetres with 65535 (and 0) invalid; it is read as float32 metres with 0 = invalid. Poses
are 4×4 camera-to-world matrices (read by ``f2depth.inference``; evaluation needs none). The official
depth is not registered to the colour camera.
"""

from __future__ import annotations

import io
import os
import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from f2depth.errors import DataError
from f2depth.formats.images import read_image, read_png16
from f2depth.formats.samples import EvalSample

#: Nominal intrinsics of the 7-Scenes colour camera at 640×480.
SEVENSCENES_K = np.array([[585.0, 0.0, 320.0], [0.0, 585.0, 240.0], [0.0, 0.0, 1.0]])
SEVENSCENES_SIZE_HW = (480, 640)
SPLIT_FILES = {"test": "TestSplit.txt", "train": "TrainSplit.txt"}
_SEQ_LINE = re.compile(r"^sequence(\d+)$")
_FRAME = re.compile(r"^frame-(\d{6})\.color\.png$")
_FIX = "point data.sevenscenes at the 7-Scenes root (or run `dvc repro synth`)"


@dataclass(frozen=True)
class _Entry:
    scene: str
    seq: str
    frame: int
    stem: Path  # .../seq-XX/frame-XXXXXX


def read_split_file(path: Path) -> list[str]:
    """``TestSplit.txt`` → sequence folder names ``["seq-03", "seq-05"]``."""
    if not path.is_file():
        raise DataError(path, "split file not found", _FIX)
    seqs = []
    for lineno, line in enumerate(path.read_text().splitlines(), 1):
        text = line.strip()
        if not text:
            continue
        m = _SEQ_LINE.match(text)
        if m is None:
            raise DataError(path, f"line {lineno} is {text!r}, expected 'sequenceN'")
        seqs.append(f"seq-{int(m.group(1)):02d}")
    if not seqs:
        raise DataError(path, "lists no sequences")
    return seqs


def read_pose(path: str | os.PathLike) -> np.ndarray:
    """A ``.pose.txt`` → float64 (4, 4) world_T_cam, checked to be a rigid transform."""
    p = Path(path)
    if not p.is_file():
        raise DataError(p, "pose file not found", _FIX)
    text = p.read_text(errors="replace")
    if not text.strip():
        raise DataError(p, "empty pose file (no matrix)", _FIX)
    try:
        with warnings.catch_warnings():  # numpy's own warnings would add lines to our one
            warnings.simplefilter("ignore")
            T = np.loadtxt(io.StringIO(text), dtype=np.float64)
    except ValueError as exc:
        raise DataError(p, f"not a text matrix ({exc})", _FIX) from exc
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise DataError(p, f"expected a finite 4×4 matrix, found shape {T.shape}", _FIX)
    R = T[:3, :3]
    if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-6) or not np.allclose(R.T @ R, np.eye(3), atol=1e-2):
        raise DataError(p, "not a rigid transform (rotation not orthonormal or last row not 0 0 0 1)", _FIX)
    return T


def read_depth_mm(path: str | os.PathLike, expect_hw: tuple[int, int] = SEVENSCENES_SIZE_HW) -> np.ndarray:
    """uint16 millimetre PNG → float32 metres; 65535 and 0 → 0 (invalid)."""
    d = read_png16(path, expect_hw)
    out = d.astype(np.float32) / 1000.0
    out[(d == 65535) | (d == 0)] = 0.0
    return out


class SevenScenesSet:
    """Every ``stride``-th frame of the ``split`` sequences of ``scenes`` (default: all scene folders).

    Samples: :class:`~f2depth.formats.samples.EvalSample` with rgb uint8 (480, 640, 3), depth float32
    (480, 640) m (0 = invalid) and key ``(scene, seq, frame)``, e.g. ``("chess", "seq-03", 5)``."""

    def __init__(self, root: str | os.PathLike, split: str = "test", stride: int = 1,
                 scenes: Sequence[str] | None = None):
        if split not in SPLIT_FILES:
            raise ValueError(f"split must be one of {tuple(SPLIT_FILES)}, got {split!r}")
        if int(stride) < 1:
            raise ValueError(f"stride must be ≥ 1, got {stride}")
        self.root, self.split, self.stride = Path(root), split, int(stride)
        if not self.root.is_dir():
            raise DataError(self.root, "7-Scenes folder not found", _FIX)
        if scenes is None:
            scenes = sorted(d.name for d in self.root.iterdir() if d.is_dir() and not d.name.startswith("."))
            if not scenes:
                raise DataError(self.root, "no scene folders", _FIX)
        self.scenes = list(scenes)
        self.K = SEVENSCENES_K.copy()
        self._entries: list[_Entry] = []
        for scene in self.scenes:
            sdir = self.root / scene
            if not sdir.is_dir():
                raise DataError(sdir, "scene folder not found", _FIX)
            for seq in read_split_file(sdir / SPLIT_FILES[split]):
                self._entries.extend(self._list_sequence(scene, seq))

    def _list_sequence(self, scene: str, seq: str) -> list[_Entry]:
        qdir = self.root / scene / seq
        if not qdir.is_dir():
            raise DataError(qdir, f"sequence folder listed in {SPLIT_FILES[self.split]} not found", _FIX)
        frames = sorted(int(m.group(1)) for m in (_FRAME.match(e.name) for e in qdir.iterdir()) if m)
        if not frames:
            raise DataError(qdir, "no frame-XXXXXX.color.png files", _FIX)
        out = []
        for n in frames[:: self.stride]:
            stem = qdir / f"frame-{n:06d}"
            depth = stem.with_name(stem.name + ".depth.png")
            if not depth.is_file():
                raise DataError(depth, "missing (its colour frame exists)", _FIX)
            out.append(_Entry(scene, seq, n, stem))
        return out

    def __len__(self) -> int:
        return len(self._entries)

    def scene(self, i: int) -> str:
        return self._entries[i].scene

    def __getitem__(self, i: int) -> EvalSample:
        if not -len(self) <= i < len(self):
            raise IndexError(f"sample {i} of {len(self)}")
        e = self._entries[i]
        rgb = read_image(f"{e.stem}.color.png", SEVENSCENES_SIZE_HW)
        return EvalSample(rgb, e.scene, (e.scene, e.seq, e.frame), depth=read_depth_mm(f"{e.stem}.depth.png"))
