"""File writers for the generated frames, one per on-disk format (docs/formats.md), all atomic."""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from f2depth.io import atomic_path, imwrite, write_text


def write_depth_mm(path: str | Path, depth: np.ndarray, invalid: int = 65535) -> None:
    """7-Scenes depth PNG: uint16 millimetres, ``invalid`` where depth <= 0 or beyond the range."""
    mm = np.rint(depth * 1000.0)
    out = np.where((depth > 0) & (mm < invalid), mm, invalid).astype(np.uint16)
    imwrite(path, out)


def write_pose_txt(path: str | Path, world_T_cam: np.ndarray) -> None:
    """4×4 camera-to-world matrix as text, 7-Scenes style (tab separated, %.7e)."""
    lines = ["\t".join(f"{v:.7e}" for v in row) for row in np.asarray(world_T_cam, np.float64)]
    write_text(path, "\n".join(lines) + "\n")


def write_mask(path: str | Path, mask: np.ndarray) -> None:
    """Boolean mask → single-channel PNG, 255 where True (Sintel occlusion maps)."""
    imwrite(path, np.where(mask, 255, 0).astype(np.uint8))


#: with ``compress=True`` the side-car ground truth is put on dyadic grids first so that zlib can
#: compress it 2.6x (float32 mantissas of exact renders are incompressible noise): depth to 2^-14 m
#: (error <= 3.1e-5 m), flow to 2^-10 px (error <= 4.9e-4 px). Uncompressed files hold the exact values.
DEPTH_STEP = 2.0**-14
FLOW_STEP = 2.0**-10


def quantize(a: np.ndarray, step: float) -> np.ndarray:
    """Round to multiples of the power of two ``step`` (exact in float32) → float32."""
    return (np.rint(np.asarray(a, np.float64) / step) * step).astype(np.float32)


def save_npz(path: str | Path, compress: bool, **arrays: np.ndarray) -> None:
    """``.npz`` as ``np.savez`` (or zlib level 1, several times faster than ``np.savez_compressed``),
    atomic and byte-deterministic (fixed member timestamps)."""
    mode = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with (atomic_path(path, suffix=".npz") as tmp,
          zipfile.ZipFile(tmp, "w", compression=mode, compresslevel=1 if compress else None) as zf):
        for name, arr in arrays.items():
            with zf.open(f"{name}.npy", "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.asanyarray(arr), allow_pickle=False)


def write_gt(path: str | Path, depth: np.ndarray, world_T_cam: np.ndarray, K: np.ndarray,
             flow: np.ndarray | None = None, occluded: np.ndarray | None = None,
             compress: bool = False) -> None:
    """Side-car ground truth ``.npz`` (docs/formats.md): depth, world_T_cam, K [, flow, occluded]."""
    depth = np.asarray(depth, np.float32)
    arrays = {"depth": quantize(depth, DEPTH_STEP) if compress else depth,
              "world_T_cam": np.asarray(world_T_cam, np.float64), "K": np.asarray(K, np.float64)}
    if flow is not None:
        flow = np.asarray(flow, np.float32)
        arrays["flow"] = quantize(flow, FLOW_STEP) if compress else flow
        arrays["occluded"] = np.asarray(occluded, bool)
    save_npz(path, compress, **arrays)

