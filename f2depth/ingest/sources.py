"""Where frames come from: one image, a folder of images (sorted by name) or a video file (OpenCV).

Every source yields :class:`Frame` objects lazily (a long video is never held in memory) and raises
:class:`~f2depth.errors.DataError` naming the file on anything it cannot read.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import tempfile
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from f2depth.errors import DataError
from f2depth.formats.images import read_image

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".jpe", ".bmp", ".ppm", ".pgm", ".pnm", ".tif", ".tiff", ".webp")
VIDEO_EXTENSIONS = (".avi", ".mp4", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg", ".wmv", ".mjpg",
                    ".mjpeg")
_FIX_IMAGE = "replace the file or remove it from the input"
_FIX_VIDEO = "check that the file is a complete video that FFmpeg can decode (e.g. MJPG .avi, H.264 .mp4)"


@dataclass(frozen=True)
class Frame:
    """One input frame: ``name`` is the stem of its output files, ``rgb`` (H,W,3) uint8, ``origin`` says
    where it came from (a file path, or ``<video>#<index>``)."""

    name: str
    rgb: np.ndarray
    origin: str


@contextlib.contextmanager
def captured_stderr_fd() -> Iterator[list[str]]:
    """Collect what C libraries (OpenCV's container parsers, FFmpeg) write to file descriptor 2, so that
    decoder chatter does not reach the terminal. Yields a list that holds the text (whitespace
    collapsed) once the block has ended."""
    sys.stderr.flush()
    saved = os.dup(2)
    text: list[str] = []
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield text
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            text.append(" ".join(tmp.read().decode(errors="replace").split()))


def read_input_image(path: str | os.PathLike) -> np.ndarray:
    """An input image → RGB uint8 (H, W, 3); missing, truncated or undecodable → DataError."""
    try:
        return read_image(path)
    except DataError as exc:
        raise DataError(exc.path, exc.problem, _FIX_IMAGE) from None


def image_files(folder: str | os.PathLike) -> list[Path]:
    """Images directly inside ``folder`` with a supported extension, sorted by name (hidden files and
    other extensions ignored); possibly none."""
    return sorted(p for p in Path(folder).iterdir()
                  if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in IMAGE_EXTENSIONS)


def list_images(folder: str | os.PathLike) -> list[Path]:
    """:func:`image_files` of ``folder``; none → DataError."""
    root = Path(folder)
    files = image_files(root)
    if not files:
        raise DataError(root, f"no images in this folder (supported: {' '.join(IMAGE_EXTENSIONS)})",
                        "point --input at a folder of images, an image or a video")
    return files


def output_names(paths: list[Path]) -> list[str]:
    """Output stems, unique even where the file system ignores case: the file stem where no other input
    has it (compared case-insensitively), else ``<stem>_<ext>`` (a.png, a.jpg → a_png, a_jpg), and
    ``_2``, ``_3``, … after that where it is still taken (a.png, a.PNG → a_png, a_png_2; b.jpg beside
    b_jpg.png → b_jpg_2). Deterministic in the order given."""
    counts = Counter(p.stem.casefold() for p in paths)
    unique = [counts[p.stem.casefold()] == 1 for p in paths]
    taken = {p.stem.casefold() for p, u in zip(paths, unique) if u}
    names = []
    for p, u in zip(paths, unique):
        name = p.stem if u else f"{p.stem}_{p.suffix[1:].lower()}"
        base, k = name, 2
        while not u and name.casefold() in taken:
            name, k = f"{base}_{k}", k + 1
        taken.add(name.casefold())
        names.append(name)
    return names


class ImageSource:
    """Frames from image files, read one at a time in the given order."""

    kind = "images"

    def __init__(self, paths: list[Path]) -> None:
        self.paths = list(paths)
        self.names = output_names(self.paths)
        #: input path → output stem, for the inputs whose stem another input shares (output_names)
        self.renamed = {str(p): n for p, n in zip(self.paths, self.names) if n != p.stem}

    def __len__(self) -> int:
        return len(self.paths)

    def __iter__(self) -> Iterator[Frame]:
        for path, name in zip(self.paths, self.names):
            yield Frame(name, read_input_image(path), str(path))


class VideoSource:
    """Frames of a video file decoded by OpenCV (``cv2.VideoCapture``), named ``frame_000000``, ….

    Opening checks that the first frame decodes; ``len`` is the frame count the container reports
    (0 when it reports none). ``fps`` is the container's frame rate (0 when it gives none),
    ``rotation_deg`` its rotation metadata and ``rotation_applied`` whether OpenCV rotates the decoded
    frames by it. Decoding stops at the first frame that does not decode.
    """

    kind = "video"

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self.renamed: dict[str, str] = {}  # frames are numbered: no stems to share
        if not self.path.is_file():
            raise DataError(self.path, "video not found", "check --input")
        with captured_stderr_fd() as chatter:
            cap = cv2.VideoCapture(str(self.path))
            opened = cap.isOpened()
            ok, frame = cap.read() if opened else (False, None)
            self.frame_count = max(int(cap.get(cv2.CAP_PROP_FRAME_COUNT)), 0) if opened else 0
            fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0) if opened else 0.0
            self.fps = fps if math.isfinite(fps) and fps > 0 else 0.0
            self.rotation_deg = float(cap.get(cv2.CAP_PROP_ORIENTATION_META) or 0.0) if opened else 0.0
            self.rotation_applied = bool(cap.get(cv2.CAP_PROP_ORIENTATION_AUTO)) if opened else False
            cap.release()
        detail = f" (decoder: {chatter[0][:200]})" if chatter[0] else ""
        if not opened:
            raise DataError(self.path, "cannot open video: no OpenCV backend reads it" + detail, _FIX_VIDEO)
        if not ok or frame is None or not frame.size:
            raise DataError(self.path, "cannot decode video: OpenCV read no frame" + detail, _FIX_VIDEO)

    def __len__(self) -> int:
        return self.frame_count

    def __iter__(self) -> Iterator[Frame]:
        with captured_stderr_fd():
            cap = cv2.VideoCapture(str(self.path))
        try:
            index = 0
            while True:
                with captured_stderr_fd():
                    ok, frame = cap.read()
                if not ok or frame is None or not frame.size:
                    break
                rgb = cv2.cvtColor(frame, cv2.COLOR_BGR2RGB) if frame.ndim == 3 else cv2.cvtColor(
                    frame, cv2.COLOR_GRAY2RGB)
                yield Frame(f"frame_{index:06d}", rgb, f"{self.path}#{index}")
                index += 1
        finally:
            cap.release()


def check_output_apart(source: str | os.PathLike, output: str | os.PathLike) -> None:
    """Refuse an output folder that is the input folder (also through links): our depth maps and colour
    maps are PNGs that a second run would read as photos. DataError naming the output."""
    src, out = Path(source), Path(output)
    if src.is_dir() and out.exists() and out.resolve() == src.resolve():
        raise DataError(out, "the output folder is the input folder, so a later run would read these depth "
                             "and colour maps as photos", f"give --output another folder (e.g. {src}_depth)")


def decode_shortfall(where: str | os.PathLike, decoded: int, announced: int, done: str = "wrote those"
                     ) -> str | None:
    """The one warning line of a source that decoded fewer frames than it announced (``len`` of a
    :class:`VideoSource`: a truncated or damaged video), ``done`` saying what was made of the rest
    (``predict``: "wrote those", ``ingest``: "ingested from those"); None when nothing is missing."""
    if not announced or decoded >= announced:
        return None
    return (f"{where}: only {decoded} of the {announced} frames its container announces could be decoded (a "
            f"truncated or damaged file?); {done} {decoded}")


def open_source(path: str | os.PathLike) -> ImageSource | VideoSource:
    """An image, a folder of images or a video → its frame source (nothing decoded yet except, for a
    video, the first frame as a check). Unknown paths and extensions → DataError."""
    p = Path(path)
    if p.is_dir():
        return ImageSource(list_images(p))
    if not p.exists():
        raise DataError(p, "input not found", "give an image, a folder of images or a video")
    suffix = p.suffix.lower()
    if suffix in IMAGE_EXTENSIONS:
        return ImageSource([p])
    if suffix in VIDEO_EXTENSIONS:
        return VideoSource(p)
    raise DataError(p, f"unsupported input type '{suffix or '(no extension)'}'",
                    f"images: {' '.join(IMAGE_EXTENSIONS)}; videos: {' '.join(VIDEO_EXTENSIONS)}")
