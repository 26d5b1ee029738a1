"""File writers for the generated frames, one per on-disk format (docs/formats.md), all atomic."""

from __future__ import annotations

import zipfile
from pathlib import Path

import cv2
import numpy as np

from f2depth.io import atomic_path, imwrite, write_bytes, write_text

FLO_MAGIC = 202021.25


def write_rgb(path: str | Path, rgb: np.ndarray, jpeg_quality: int = 95) -> None:
    """RGB uint8 (H, W, 3) → PNG / binary PPM / JPEG by extension (stored BGR by OpenCV)."""
    params = (
        [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality] if str(path).lower().endswith((".jpg", ".jpeg")) else None
    )
    imwrite(path, np.ascontiguousarray(rgb[..., ::-1]), params)


def write_depth_mm(path: str | Path, depth: np.ndarray, invalid: int = 65535) -> None:
    """7-Scenes depth PNG: uint16 millimetres, ``invalid`` where depth <= 0 or beyond the range."""
    mm = np.rint(depth * 1000.0)
    out = np.where((depth > 0) & (mm < invalid), mm, invalid).astype(np.uint16)
    imwrite(path, out)


def write_pose_txt(path: str | Path, world_T_cam: np.ndarray) -> None:
    """4×4 camera-to-world matrix as text, 7-Scenes style (tab separated, %.7e)."""
    lines = ["\t".join(f"{v:.7e}" for v in row) for row in np.asarray(world_T_cam, np.float64)]
    write_text(path, "\n".join(lines) + "\n")


def encode_flo(flow: np.ndarray) -> bytes:
    """Middlebury .flo bytes: b'PIEH' (float32 202021.25), int32 width, int32 height, (H, W, 2) float32."""
    h, w = flow.shape[:2]
    if flow.shape != (h, w, 2):
        raise ValueError(f"flow must be (H, W, 2), got {flow.shape}")
    head = np.array([FLO_MAGIC], "<f4").tobytes() + np.array([w, h], "<i4").tobytes()
    return head + np.ascontiguousarray(flow, "<f4").tobytes()


def write_flo(path: str | Path, flow: np.ndarray) -> None:
    write_bytes(path, encode_flo(flow))


def read_flo(path: str | Path) -> np.ndarray:
    """Read a Middlebury .flo file → (H, W, 2) float32 (for tests and tools)."""
    data = Path(path).read_bytes()
    if len(data) < 12 or np.frombuffer(data[:4], "<f4")[0] != np.float32(FLO_MAGIC):
        raise ValueError(f"{path}: not a Middlebury .flo file (bad magic)")
    w, h = (int(v) for v in np.frombuffer(data[4:12], "<i4"))
    if len(data) != 12 + 8 * w * h:
        raise ValueError(f"{path}: size {len(data)} does not match {w}x{h} flow")
    return np.frombuffer(data[12:], "<f4").reshape(h, w, 2).copy()


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
    with (
        atomic_path(path, suffix=".npz") as tmp,
        zipfile.ZipFile(tmp, "w", compression=mode, compresslevel=1 if compress else None) as zf,
    ):
        for name, arr in arrays.items():
            with zf.open(f"{name}.npy", "w", force_zip64=True) as fh:
                np.lib.format.write_array(fh, np.asanyarray(arr), allow_pickle=False)


def write_gt(
    path: str | Path,
    depth: np.ndarray,
    world_T_cam: np.ndarray,
    K: np.ndarray,
    flow: np.ndarray | None = None,
    occluded: np.ndarray | None = None,
    compress: bool = False,
) -> None:
    """Side-car ground truth ``.npz`` (docs/formats.md): depth, world_T_cam, K [, flow, occluded]."""
    depth = np.asarray(depth, np.float32)
    arrays = {
        "depth": quantize(depth, DEPTH_STEP) if compress else depth,
        "world_T_cam": np.asarray(world_T_cam, np.float64),
        "K": np.asarray(K, np.float64),
    }
    if flow is not None:
        flow = np.asarray(flow, np.float32)
        arrays["flow"] = quantize(flow, FLOW_STEP) if compress else flow
        arrays["occluded"] = np.asarray(occluded, bool)
    save_npz(path, compress, **arrays)


def points_csv(rows: list[tuple[str, str, float, float, float]]) -> str:
    """Campus ``points.csv`` text: header ``scene,image,u,v,depth_m``."""
    lines = ["scene,image,u,v,depth_m"]
    lines += [f"{s},{i},{u:g},{v:g},{d:.4f}" for s, i, u, v, d in rows]
    return "\n".join(lines) + "\n"
