"""Campus Indoor: ``<root>/<scene>/<image>.jpg`` plus one ``<root>/points.csv``.

``points.csv`` has the header ``scene,image,u,v,depth_m``: one laser-measured point per row, pixel
(u, v) = (column, row) with centres at integer coordinates, depth in metres. ``image`` is the file
name inside the scene folder; when it has no extension, ``.jpg`` is appended. Every image file of a
scene folder must have points and every row must point into its image with a positive depth.
"""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path

import cv2
import numpy as np

from f2depth.errors import DataError
from f2depth.formats.images import decode, read_bytes, read_image
from f2depth.formats.samples import EvalSample

HEADER = ["scene", "image", "u", "v", "depth_m"]
IMAGE_EXTS = (".jpg", ".jpeg", ".png")
_FIX = "point data.campus at the Campus folder (or run `dvc repro synth`)"


def _image_file(name: str) -> str:
    return name if Path(name).suffix.lower() in IMAGE_EXTS else name + ".jpg"


def _image_hw(path: Path) -> tuple[int, int]:
    """(H, W) of a labelled image, decoded once so that a damaged or oversized file fails here."""
    img = decode(path, read_bytes(path, "image"), cv2.IMREAD_COLOR)
    return img.shape[0], img.shape[1]


class CampusSet:
    """One sample per labelled image, sorted by (scene, image): :class:`~f2depth.formats.samples.EvalSample`
    with rgb uint8 (H, W, 3), points float64 (P, 3) = u, v, depth_m and key ``(scene, image file name)``."""

    def __init__(self, root: str | os.PathLike):
        self.root = Path(root)
        if not self.root.is_dir():
            raise DataError(self.root, "Campus folder not found", _FIX)
        self.csv_path = self.root / "points.csv"
        points: dict[tuple[str, str], list[tuple[float, float, float]]] = {}
        sizes: dict[tuple[str, str], tuple[int, int]] = {}
        for row_no, row in self._rows():
            key = (row["scene"], _image_file(row["image"]))
            if key not in sizes:
                img_path = self.root / key[0] / key[1]
                if not img_path.is_file():
                    raise DataError(self.csv_path, f"row {row_no}: image {img_path} does not exist",
                                    "fix the scene/image columns or add the image")
                sizes[key] = _image_hw(img_path)
            h, w = sizes[key]
            u, v, d = self._numbers(row_no, row)
            if not (-0.5 <= u < w - 0.5 and -0.5 <= v < h - 0.5):
                raise DataError(self.csv_path, f"row {row_no}: point (u={u:g}, v={v:g}) lies outside its "
                                               f"{w}×{h} image {key[0]}/{key[1]}",
                                "u is the column and v the row, in pixels of that image")
            if not d > 0:
                raise DataError(self.csv_path, f"row {row_no}: depth_m = {d:g} is not positive",
                                "depths are metres > 0")
            points.setdefault(key, []).append((u, v, d))
        self._check_unlabelled(points)
        self._keys = sorted(points)
        self._points = {k: np.asarray(p, dtype=np.float64) for k, p in points.items()}
        self._sizes = sizes
        self.scenes = sorted({k[0] for k in self._keys})

    def _rows(self):
        if not self.csv_path.is_file():
            raise DataError(self.csv_path, "points file not found", _FIX)
        with self.csv_path.open(newline="") as fh:
            reader = csv.reader(fh)
            header = next(reader, None)
            if header is None or [h.strip() for h in header] != HEADER:
                raise DataError(self.csv_path, f"header is {header}, expected {','.join(HEADER)}")
            n = 0
            for row_no, cells in enumerate(reader, 2):
                if not cells or all(not c.strip() for c in cells):
                    continue
                if len(cells) != len(HEADER):
                    raise DataError(self.csv_path,
                                    f"row {row_no}: {len(cells)} columns, expected {len(HEADER)}")
                n += 1
                yield row_no, dict(zip(HEADER, (c.strip() for c in cells)))
            if n == 0:
                raise DataError(self.csv_path, "no points")

    def _numbers(self, row_no: int, row: dict[str, str]) -> tuple[float, float, float]:
        try:
            u, v, d = float(row["u"]), float(row["v"]), float(row["depth_m"])
        except ValueError as exc:
            raise DataError(self.csv_path, f"row {row_no}: u, v, depth_m must be numbers ({exc})") from exc
        if not all(math.isfinite(x) for x in (u, v, d)):
            raise DataError(self.csv_path, f"row {row_no}: non-finite u, v or depth_m")
        return u, v, d

    def _check_unlabelled(self, points: dict) -> None:
        for sdir in sorted(d for d in self.root.iterdir() if d.is_dir() and not d.name.startswith(".")):
            for f in sorted(sdir.iterdir()):
                if f.suffix.lower() in IMAGE_EXTS and (sdir.name, f.name) not in points:
                    raise DataError(self.csv_path, f"image {sdir.name}/{f.name} has no points",
                                    "add its points or move the image out of the Campus folder")

    def __len__(self) -> int:
        return len(self._keys)

    def scene(self, i: int) -> str:
        return self._keys[i][0]

    def __getitem__(self, i: int) -> EvalSample:
        if not -len(self) <= i < len(self):
            raise IndexError(f"sample {i} of {len(self)}")
        key = self._keys[i]
        rgb = read_image(self.root / key[0] / key[1], self._sizes[key])
        return EvalSample(rgb, key[0], key, points=self._points[key].copy())
