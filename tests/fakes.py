"""Tiny datasets in the real on-disk formats (docs/formats.md), written by the tests into tmp_path.

Import from a test module as ``import fakes``. Every writer is deterministic for a given seed.
"""

from __future__ import annotations

import struct
import zipfile
from pathlib import Path

import cv2
import h5py
import numpy as np
import scipy.io

from f2depth.camera import NYU_RGB_DIST, NYU_RGB_K, NYU_SIZE_HW, distortion_maps

H, W = NYU_SIZE_HW


def smooth_image(hw: tuple[int, int], seed: int, cells: int = 12) -> np.ndarray:
    """A smooth random colour image, RGB uint8 (H, W, 3): bicubic upsampling of a coarse random grid."""
    rng = np.random.default_rng(seed)
    coarse = rng.uniform(30, 225, size=(cells, int(cells * hw[1] / hw[0]) + 1, 3)).astype(np.float32)
    return np.clip(cv2.resize(coarse, (hw[1], hw[0]), interpolation=cv2.INTER_CUBIC), 0, 255).astype(np.uint8)


def blocky_image(hw: tuple[int, int], seed: int, blocks: int = 6) -> np.ndarray:
    """Flat colour rectangles (so superpixels have something to find), RGB uint8 (H, W, 3)."""
    rng = np.random.default_rng(seed)
    img = np.empty((*hw, 3), np.uint8)
    ys = np.linspace(0, hw[0], blocks + 1).astype(int)
    xs = np.linspace(0, hw[1], blocks + 1).astype(int)
    for i in range(blocks):
        for j in range(blocks):
            img[ys[i]:ys[i + 1], xs[j]:xs[j + 1]] = rng.integers(20, 235, 3)
    return img


def write_ppm(path: Path, rgb: np.ndarray) -> None:
    """Binary P6 PPM written by hand (RGB order, as the NYU dump)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    h, w = rgb.shape[:2]
    path.write_bytes(f"P6\n{w} {h}\n255\n".encode() + np.ascontiguousarray(rgb, np.uint8).tobytes())


def write_rgb(path: Path, rgb: np.ndarray, params: list[int] | None = None) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), params or [])


def truncate(path: Path, keep: float = 0.6) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])


def flip_weight_bytes(path: Path, count: int = 64) -> None:
    """Damage a ``torch.save`` file as a bad disk or copy does: XOR ``count`` bytes (the lowest byte of as
    many float32 values) in the middle of its largest tensor record. The zip structure stays intact and
    torch does not check the records' CRC, so the file still loads — with other weights."""
    with zipfile.ZipFile(path) as zf:
        record = max((i for i in zf.infolist() if "/data/" in i.filename), key=lambda i: i.file_size)
    raw = bytearray(path.read_bytes())
    name_len, extra_len = struct.unpack_from("<HH", raw, record.header_offset + 26)  # the local header
    start = record.header_offset + 30 + name_len + extra_len + record.file_size // 2
    for k in range(count):
        raw[start + 4 * k] ^= 0xFF
    path.write_bytes(bytes(raw))


# ---- NYU raw ---------------------------------------------------------------------------------------

def raw_timestamps(n: int, start: float = 999.95) -> list[float]:
    """30 Hz timestamps that cross 1000 s, so the file names' text order differs from time order."""
    return [round(start + k / 30.0, 6) for k in range(n)]


def write_nyu_raw(root: Path, scenes: dict[str, int], seed: int = 0, gt_root: Path | None = None,
                  extras: bool = True) -> dict[str, list[np.ndarray]]:
    """``root/<scene>/r-<ts>-<n>.ppm`` frames, distorted with the NYU lens; returns the ideal images.

    Each frame is a horizontally shifted window of one smooth scene image; with ``gt_root`` the side-car
    ground truth ``gt_root/nyu_raw/<scene>/<stem>.npz`` (depth, world_T_cam, K) is written as well.
    """
    map_x, map_y = distortion_maps(NYU_RGB_K, NYU_RGB_DIST, (H, W))
    ideal: dict[str, list[np.ndarray]] = {}
    for s_idx, (scene, n) in enumerate(scenes.items()):
        wide = blocky_image((H, W + 4 * n), seed + s_idx, blocks=8)
        wide = cv2.GaussianBlur(wide, (0, 0), 1.5)
        ideal[scene] = []
        for k, ts in enumerate(raw_timestamps(n)):
            img = np.ascontiguousarray(wide[:, 4 * k: 4 * k + W])
            ideal[scene].append(img)
            stem = f"r-{ts:.6f}-{1000 + 7 * k}"
            write_ppm(root / scene / f"{stem}.ppm",
                      cv2.remap(img, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE))
            if extras:
                (root / scene / f"d-{ts:.6f}-{2000 + k}.pgm").write_bytes(b"P5\n2 1\n65535\n\0\0\0\0")
                (root / scene / f"a-{ts:.6f}-{3000 + k}.dump").write_bytes(b"\0" * 16)
            if gt_root is not None:
                depth = np.full((H, W), 2.0 + s_idx + 0.01 * k, np.float32)
                depth[: H // 2] = 3.0  # a step edge to check the crop/resize alignment
                pose = np.eye(4)
                pose[0, 3] = 0.01 * k
                d = gt_root / "nyu_raw" / scene
                d.mkdir(parents=True, exist_ok=True)
                np.savez_compressed(d / f"{stem}.npz", depth=depth, world_T_cam=pose, K=NYU_RGB_K)
        if extras:
            (root / scene / "INDEX.txt").write_text("index\n")
    return ideal


# ---- NYU labeled -----------------------------------------------------------------------------------

def write_labeled_mat(path: Path, scenes: list[str], seed: int = 0, userblock: bool = True) -> dict:
    """An HDF5 ``nyu_depth_v2_labeled.mat`` in MATLAB v7.3 layout (axes reversed, cellstr references).

    Returns the arrays in image axes: ``rgb`` (N, 480, 640, 3), ``depths`` / ``rawDepths`` (N, 480, 640).
    """
    rng = np.random.default_rng(seed)
    n = len(scenes)
    rgb = rng.integers(0, 256, (n, H, W, 3), dtype=np.uint8)
    depths = rng.uniform(0.5, 9.0, (n, H, W)).astype(np.float32)
    raw = depths.copy()
    raw[:, ::7, ::5] = 0.0
    path.parent.mkdir(parents=True, exist_ok=True)
    kwargs = {"userblock_size": 512} if userblock else {}
    with h5py.File(path, "w", **kwargs) as f:
        f.create_dataset("images", data=rgb.transpose(0, 3, 2, 1))
        f.create_dataset("depths", data=depths.transpose(0, 2, 1))
        f.create_dataset("rawDepths", data=raw.transpose(0, 2, 1))
        refs_group = f.create_group("#refs#")
        refs = np.empty((1, n), dtype=h5py.ref_dtype)
        for i, name in enumerate(scenes):
            ds = refs_group.create_dataset(f"s{i}", data=np.array([[ord(c)] for c in name], np.uint16))
            ds.attrs["MATLAB_class"] = np.bytes_("char")
            refs[0, i] = ds.ref
        f.create_dataset("scenes", data=refs, dtype=h5py.ref_dtype)
    if userblock:
        with path.open("r+b") as fh:
            fh.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created by: f2depth tests HDF5 schema 1.00 .")
    return {"rgb": rgb, "depths": depths, "rawDepths": raw}


def write_splits(path: Path, train: list[int], test: list[int]) -> None:
    """``splits.mat`` (MATLAB v5) with one-based ``trainNdxs`` / ``testNdxs`` (k, 1)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    scipy.io.savemat(str(path), {"trainNdxs": np.array(train, np.uint16).reshape(-1, 1),
                                 "testNdxs": np.array(test, np.uint16).reshape(-1, 1)})


# ---- 7-Scenes --------------------------------------------------------------------------------------

def write_sevenscenes(root: Path, scenes: dict[str, tuple[list[int], list[int]]], frames: int = 3,
                      seed: int = 0) -> None:
    """``root/<scene>/seq-XX/frame-XXXXXX.{color.png,depth.png,pose.txt}``; scenes map to (test, train)."""
    base = smooth_image((H, W), seed, cells=4)
    fast_png = [cv2.IMWRITE_PNG_COMPRESSION, 1]
    for scene, (test, train) in scenes.items():
        sdir = root / scene
        sdir.mkdir(parents=True, exist_ok=True)
        (sdir / "TestSplit.txt").write_text("".join(f"sequence{s}\n" for s in test))
        (sdir / "TrainSplit.txt").write_text("".join(f"sequence{s}\n" for s in train))
        for seq in test + train:
            qdir = sdir / f"seq-{seq:02d}"
            qdir.mkdir()
            for k in range(frames):
                stem = qdir / f"frame-{k:06d}"
                write_rgb(Path(f"{stem}.color.png"), np.roll(base, 8 * seq + k, axis=1), fast_png)
                depth = np.full((H, W), 1500 + 10 * k, np.uint16)
                depth[0, :] = 65535
                depth[1, :] = 0
                assert cv2.imwrite(f"{stem}.depth.png", depth, fast_png)
                pose = np.eye(4)
                pose[:3, 3] = [0.1 * k, 0.0, 0.5]
                np.savetxt(f"{stem}.pose.txt", pose, fmt="%.6e")


# ---- Campus ----------------------------------------------------------------------------------------

CAMPUS_HW = (64, 48)


def write_campus(root: Path, scenes: dict[str, int], points_per_image: int = 4, seed: int = 0) -> list[list]:
    """``root/<scene>/<image>.jpg`` (64×48 portrait) and ``root/points.csv``; returns the CSV rows."""
    rng = np.random.default_rng(seed)
    rows = []
    for scene, n_images in scenes.items():
        for i in range(n_images):
            name = f"img_{i:03d}"
            img = smooth_image(CAMPUS_HW, int(rng.integers(1 << 30)), cells=3)
            write_rgb(root / scene / f"{name}.jpg", img)
            for _ in range(points_per_image):
                u, v = int(rng.integers(0, CAMPUS_HW[1])), int(rng.integers(0, CAMPUS_HW[0]))
                rows.append([scene, name, u, v, round(float(rng.uniform(0.5, 12.0)), 3)])
    write_points_csv(root / "points.csv", rows)
    return rows


def write_points_csv(path: Path, rows: list[list], header: str = "scene,image,u,v,depth_m") -> None:
    path.write_text(header + "\n" + "".join(",".join(str(c) for c in r) + "\n" for r in rows))
