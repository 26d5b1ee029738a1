"""MPI-Sintel layout (real Sintel or the synthetic ``animated`` set) and Middlebury ``.flo`` files.

Layout (docs/formats.md)::

    <root>/training/{clean,final}/<seq>/frame_XXXX.png      1-based, 4 digits
    <root>/training/flow/<seq>/frame_XXXX.flo               flow frame i → i+1 (Middlebury .flo)
    <root>/training/occlusions/<seq>/frame_XXXX.png         255 = occluded

``.flo``: float32 magic 202021.25 (b"PIEH"), int32 width, int32 height, then H·W·2 float32 (u, v
interleaved, row-major), little-endian.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch

from f2depth.errors import DataError
from f2depth.formats.images import read_bytes, read_image, to_tensor

FLO_MAGIC = 202021.25
PASSES = ("clean", "final")
_FRAME = re.compile(r"^frame_(\d{4})\.png$")
_FIX_LAYOUT = ("point data.sintel at a folder holding training/{clean,final}/<seq>/frame_XXXX.png "
               "(MPI-Sintel layout), or run `dvc repro synth` for the synthetic animated set")
_FIX_REGEN = "re-copy it from MPI-Sintel (or regenerate the synthetic set with `dvc repro synth`)"


def read_flo(path: str | os.PathLike) -> np.ndarray:
    """Middlebury ``.flo`` → float32 ``(H, W, 2)``; missing file, bad magic, bad size → DataError."""
    p = Path(path)
    data = read_bytes(p, "flow file")
    if len(data) < 12:
        raise DataError(p, f"not a .flo file: {len(data)} bytes, the header alone needs 12", _FIX_REGEN)
    magic = np.frombuffer(data, "<f4", 1, 0)[0]
    if magic != np.float32(FLO_MAGIC):
        raise DataError(p, f"not a .flo file: magic {data[:4]!r} ({magic}), expected b'PIEH' (202021.25)",
                        _FIX_REGEN)
    w, h = (int(x) for x in np.frombuffer(data, "<i4", 2, 4))
    if w <= 0 or h <= 0 or w > 100_000 or h > 100_000:
        raise DataError(p, f"bad .flo header: width {w}, height {h}", _FIX_REGEN)
    need = 12 + 8 * w * h
    if len(data) != need:
        raise DataError(p, f"bad .flo size: {len(data)} bytes, a {w}×{h} flow needs {need}", _FIX_REGEN)
    return np.frombuffer(data, "<f4", 2 * w * h, 12).reshape(h, w, 2).astype(np.float32)


def write_flo(path: str | os.PathLike, flow: np.ndarray) -> None:
    """Write ``flow (H, W, 2)`` as Middlebury ``.flo`` (atomically)."""
    from f2depth.io import write_bytes

    f = np.asarray(flow)
    if f.ndim != 3 or f.shape[2] != 2:
        raise ValueError(f"write_flo: expected (H, W, 2), got {f.shape}")
    h, w = f.shape[:2]
    header = np.array([FLO_MAGIC], "<f4").tobytes() + np.array([w, h], "<i4").tobytes()
    write_bytes(path, header + np.ascontiguousarray(f, dtype="<f4").tobytes())


def read_occlusion(path: str | os.PathLike, expect_hw: tuple[int, int] | None = None) -> np.ndarray:
    """Occlusion PNG (255 = occluded) → bool ``(H, W)``."""
    return read_image(path, expect_hw)[..., 0] > 127


@dataclass(frozen=True)
class SintelPair:
    """Frames i and i+1 of one sequence and pass; ``flow`` / ``occlusion`` are None when absent."""

    sequence: str
    frame: int            # 1-based index of the first frame
    pass_name: str
    image1: Path
    image2: Path
    flow: Path | None
    occlusion: Path | None


def _training(root: str | os.PathLike) -> Path:
    base = Path(root) / "training"
    if not Path(root).is_dir():
        raise DataError(root, "Sintel folder not found", _FIX_LAYOUT)
    if not base.is_dir():
        raise DataError(base, "missing 'training' folder", _FIX_LAYOUT)
    return base


def list_sequences(root: str | os.PathLike, pass_name: str = "clean") -> list[str]:
    """Sorted sequence names under ``training/<pass_name>``."""
    if pass_name not in PASSES:
        raise ValueError(f"pass must be one of {PASSES}, got {pass_name!r}")
    folder = _training(root) / pass_name
    if not folder.is_dir():
        raise DataError(folder, f"missing '{pass_name}' pass folder", _FIX_LAYOUT)
    seqs = sorted(p.name for p in folder.iterdir() if p.is_dir())
    if not seqs:
        raise DataError(folder, "no sequence folders", _FIX_LAYOUT)
    return seqs


def _frames(folder: Path) -> list[int]:
    if not folder.is_dir():
        raise DataError(folder, "missing sequence folder", _FIX_LAYOUT)
    numbers = sorted(int(m.group(1)) for p in folder.iterdir() if (m := _FRAME.match(p.name)))
    if len(numbers) < 2:
        raise DataError(folder, f"{len(numbers)} frame_XXXX.png file(s); a sequence needs at least 2",
                        _FIX_LAYOUT)
    expected = list(range(numbers[0], numbers[0] + len(numbers)))
    if numbers != expected:
        gaps = sorted(set(expected) - set(numbers))[:5]
        raise DataError(folder, f"frame numbers are not consecutive (missing frame_{gaps[0]:04d}.png"
                                f"{' …' if len(gaps) > 1 else ''})", _FIX_REGEN)
    return numbers


def list_pairs(root: str | os.PathLike, passes: Iterable[str] = ("clean",),
               sequences: Sequence[str] | None = None, require_flow: bool = False) -> list[SintelPair]:
    """All consecutive frame pairs of the chosen passes and sequences (default: all sequences).

    With ``require_flow`` every pair must have its ``.flo`` and occlusion file, else DataError.
    """
    base = _training(root)
    pairs: list[SintelPair] = []
    for pass_name in passes:
        names = list_sequences(root, pass_name) if sequences is None else list(sequences)
        for seq in names:
            folder = base / pass_name / seq
            for i in _frames(folder)[:-1]:
                flo = base / "flow" / seq / f"frame_{i:04d}.flo"
                occ = base / "occlusions" / seq / f"frame_{i:04d}.png"
                if require_flow:
                    for path, what in ((flo, "flow"), (occ, "occlusions")):
                        if not path.is_file():
                            raise DataError(path, f"missing ground truth ({what}) for frame {i} of {seq}",
                                            "ground-truth evaluation needs training/flow and "
                                            "training/occlusions; " + _FIX_REGEN)
                pairs.append(SintelPair(seq, i, pass_name, folder / f"frame_{i:04d}.png",
                                        folder / f"frame_{i + 1:04d}.png",
                                        flo if flo.is_file() else None, occ if occ.is_file() else None))
    return pairs


def load_pair(pair: SintelPair) -> dict[str, np.ndarray | None]:
    """``{"image1", "image2"}`` RGB uint8 (H,W,3), ``"flow"`` float32 (H,W,2) or None, ``"occluded"`` bool
    (H,W) or None; sizes are checked against each other."""
    im1 = read_image(pair.image1)
    hw = im1.shape[:2]
    im2 = read_image(pair.image2, hw)
    flow = read_flo(pair.flow) if pair.flow is not None else None
    if flow is not None and flow.shape[:2] != hw:
        raise DataError(pair.flow, f"flow is {flow.shape[0]}×{flow.shape[1]}, its frames are {hw[0]}×{hw[1]}",
                        _FIX_REGEN)
    occ = read_occlusion(pair.occlusion, hw) if pair.occlusion is not None else None
    return {"image1": im1, "image2": im2, "flow": flow, "occluded": occ}


def resized_tensor(rgb: np.ndarray, size: tuple[int, int] | None = None) -> torch.Tensor:
    """RGB uint8 ``(H,W,3)`` → float ``(3,h,w)`` in [0,1], area-resized to ``size = (h, w)`` if given."""
    if size is not None and tuple(rgb.shape[:2]) != tuple(size):
        rgb = cv2.resize(rgb, (size[1], size[0]), interpolation=cv2.INTER_AREA)
    return to_tensor(rgb)


class SintelPairs(torch.utils.data.Dataset):
    """Unsupervised training pairs: ``(img1, img2)`` float ``(3,h,w)`` in [0,1] resized to ``size``.

    Unaugmented: ARFlow's flips and swaps are drawn per batch from the epoch's generator
    (:func:`f2depth.flow.augment.flip_and_swap`), never from a global one.
    """

    def __init__(self, pairs: Sequence[SintelPair], size: tuple[int, int]) -> None:
        if not pairs:
            raise ValueError("SintelPairs: no pairs")
        self.pairs = list(pairs)
        self.size = size

    def __len__(self) -> int:
        return len(self.pairs)

    def __getitem__(self, index: int) -> tuple[torch.Tensor, torch.Tensor]:
        pair = self.pairs[index]
        im1 = read_image(pair.image1)
        im2 = read_image(pair.image2, im1.shape[:2])
        return resized_tensor(im1, self.size), resized_tensor(im2, self.size)
