"""Contact sheet of the generated world: one row per dataset style, columns RGB | depth | flow.

Reads what the ``synth`` stage wrote (the files in their real formats plus the side-car ground truth).
Rows without flow (single images) show Kinect-like raw depth (NYU labeled) or the measured points
(Campus) in the third column instead.

Usage: python -m f2depth.synth.contact_sheet [params.yaml] [--out docs/images/synth_contact_sheet.png]
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import cv2
import h5py
import numpy as np

from f2depth import params as P
from f2depth.colour import flow_to_color
from f2depth.io import imwrite
from f2depth.synth.config import OutputPaths

TILE = (320, 240)  # w, h


def depth_to_color(depth: np.ndarray, d_max: float | None = None) -> np.ndarray:
    """Depth (H, W) metres → RGB uint8 (turbo colour map of inverse depth, near = red); 0 → black."""
    valid = depth > 0
    inv = np.where(valid, 1.0 / np.maximum(depth, 1e-3), 0.0)
    hi = float(np.percentile(inv[valid], 99)) if valid.any() else 1.0
    lo = 1.0 / d_max if d_max else float(np.percentile(inv[valid], 1)) if valid.any() else 0.0
    x = np.clip((inv - lo) / max(hi - lo, 1e-6), 0, 1)
    bgr = cv2.applyColorMap((x * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    bgr[~valid] = 0
    return bgr[..., ::-1].copy()


def _tile(img: np.ndarray, label: str) -> np.ndarray:
    """Fit an RGB image into a TILE-sized letterboxed tile with a caption."""
    w, h = TILE
    s = min(w / img.shape[1], h / img.shape[0])
    small = cv2.resize(
        img, (max(1, round(img.shape[1] * s)), max(1, round(img.shape[0] * s))), interpolation=cv2.INTER_AREA
    )
    out = np.full((h, w, 3), 24, np.uint8)
    y0, x0 = (h - small.shape[0]) // 2, (w - small.shape[1]) // 2
    out[y0 : y0 + small.shape[0], x0 : x0 + small.shape[1]] = small
    cv2.putText(out, label, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(out, label, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.42, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def _rgb(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise FileNotFoundError(f"{path}: cannot read the image (run the synth stage first)")
    return img[..., ::-1]


def _middle(items: list) -> object:
    return items[len(items) // 2]


def _sequence_row(name: str, frames: list[Path], gt_dir: Path) -> list[np.ndarray]:
    frame = _middle(sorted(frames))
    stem = frame.name.split(".")[0] if name.startswith("7-Scenes") else frame.stem
    gt = np.load(gt_dir / f"{stem}.npz")
    flow = gt["flow"] if "flow" in gt.files else np.zeros((*gt["depth"].shape, 2), np.float32)
    mag = np.linalg.norm(flow, axis=2)
    return [
        _tile(_rgb(frame), f"{name}: {frame.parent.name}"),
        _tile(depth_to_color(gt["depth"]), f"depth {gt['depth'].min():.1f}-{gt['depth'].max():.1f} m"),
        _tile(flow_to_color(flow, float(np.percentile(mag, 99)) + 1e-6),  # saturated beyond the 99th pct
              f"flow to next, max {mag.max():.1f} px"),
    ]


def make(paths: OutputPaths) -> np.ndarray:
    """The sheet as an RGB uint8 image."""
    manifest = json.loads((paths.synth_gt / "manifest.json").read_text())
    ds = manifest["datasets"]
    rows = []
    for scene in list(ds["nyu_raw"]["scenes"])[:2]:
        rows.append(
            _sequence_row(
                "NYU raw", list((paths.nyu_raw / scene).glob("r-*.ppm")), paths.synth_gt / "nyu_raw" / scene
            )
        )
    with h5py.File(paths.nyu_labeled, "r") as f:
        test = set(ds["nyu_labeled"]["test_scenes"])
        scenes = ["".join(map(chr, np.asarray(f[r]).ravel())) for r in np.asarray(f["scenes"]).ravel()]
        i = next((k for k, s in enumerate(scenes) if s in test), 0)
        img = np.asarray(f["images"][i]).transpose(2, 1, 0)
        depth, raw = np.asarray(f["depths"][i]).T, np.asarray(f["rawDepths"][i]).T
    rows.append(
        [
            _tile(img, f"NYU labeled: {scenes[i]} (test)"),
            _tile(depth_to_color(depth), "depths"),
            _tile(depth_to_color(raw), "rawDepths (0 = hole)"),
        ]
    )
    seq = _middle(sorted(ds["sevenscenes"]["scenes"]))
    rows.append(
        _sequence_row(
            "7-Scenes",
            list((paths.sevenscenes / seq).glob("*.color.png")),
            paths.synth_gt / "sevenscenes" / seq,
        )
    )
    scene = _middle(sorted(ds["campus"]["scenes"]))
    image = sorted((paths.campus / scene).glob("*.jpg"))[0]
    rgb = _rgb(image)
    gt = np.load(paths.synth_gt / "campus" / scene / f"{image.stem}.npz")
    marked = rgb.copy()
    with open(paths.campus / "points.csv", newline="") as fh:
        for row in csv.DictReader(fh):
            if row["scene"] == scene and row["image"] == image.stem:
                c = (round(float(row["u"])), round(float(row["v"])))
                cv2.circle(marked, c, 6, (255, 40, 40), 2, cv2.LINE_AA)
                cv2.putText(
                    marked,
                    f"{float(row['depth_m']):.1f}",
                    (c[0] + 7, c[1] - 4),
                    cv2.FONT_HERSHEY_SIMPLEX,
                    0.5,
                    (255, 255, 0),
                    1,
                    cv2.LINE_AA,
                )
    rows.append(
        [
            _tile(rgb, f"Campus: {scene}"),
            _tile(depth_to_color(gt["depth"]), "depth"),
            _tile(marked, "measured points (m)"),
        ]
    )
    seq = _middle(sorted(ds["animated"]["scenes"]))
    clean = sorted((paths.animated / "training" / "clean" / seq).glob("*.png"))[:-1]  # frames with flow
    row = _sequence_row("animated", clean, paths.synth_gt / "animated" / seq)
    row[1] = _tile(_rgb(paths.animated / "training" / "final" / seq / _middle(clean).name), "final pass")
    rows.append(row)
    grid = [np.concatenate(r, axis=1) for r in rows]
    return np.concatenate(grid, axis=0)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("params", nargs="?", default=str(P.DEFAULT_PARAMS))
    ap.add_argument("--out", default="docs/images/synth_contact_sheet.png")
    args = ap.parse_args(argv)
    params = P.load(args.params)
    sheet = make(OutputPaths.from_params(P.get(params, "data"), params["_file"]))
    imwrite(args.out, sheet[..., ::-1].copy())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
