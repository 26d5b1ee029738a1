"""What to generate: scene and sequence names, the NYU labeled split, and one job per sequence or scene.

The test sets' stand-ins are those ``f2depth.protocols.registry`` names (:data:`STANDINS` has their jobs).

Every random draw of a job comes from :func:`rng_for` keyed by the global seed and the job's names, so a
job's output does not depend on which worker runs it or in which order.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from f2depth.synth.config import SynthConfig
from f2depth.synth.layout import CAMPUS_KINDS, NYU_KINDS, SEVENSCENES_NAMES

#: official 7-Scenes test sequences (each scene's TestSplit.txt, Shotton et al., CVPR 2013)
SEVENSCENES_TEST = {"chess": (3, 5), "fire": (3, 4), "heads": (1,), "office": (2, 6, 7, 9), "pumpkin": (1, 7),
                    "redkitchen": (3, 4, 6, 12, 14), "stairs": (1, 4)}
ANIMATED_NAMES = ("atrium", "bazaar", "cellar", "dune", "grotto", "harbor", "kiln", "lagoon", "quarry",
                  "spire")


def rng_for(seed: int, *parts: str | int) -> np.random.Generator:
    """A generator determined by ``seed`` and the names/numbers in ``parts`` only."""
    key = [int(seed) & 0xFFFFFFFF]
    for p in parts:
        key.append(zlib.crc32(p.encode()) if isinstance(p, str) else int(p) & 0xFFFFFFFF)
    return np.random.default_rng(key)


@dataclass(frozen=True)
class Job:
    """One unit of work: a sequence (nyu_raw, sevenscenes, animated) or a scene's views (campus, labeled).

    ``room`` names the room (rooms with the same style and name are identical); ``items`` lists the
    views of a campus scene (image names) or of a labeled scene (one-based indices in the .mat file).
    """

    dataset: str
    room: str
    kind: str
    seq: str = ""
    frames: int = 1
    items: tuple = ()
    hw: tuple[int, int] = (480, 640)

    @property
    def cost(self) -> float:
        return self.frames * self.hw[0] * self.hw[1] / 307200.0 + 3.0


@dataclass(frozen=True)
class LabeledImage:
    index: int  # one-based position in the .mat file
    scene: str
    kind: str
    test: bool


def nyu_raw_scenes(cfg: SynthConfig) -> list[tuple[str, str]]:
    """(scene folder, kind) of the raw training scenes: ``<kind>_<NNNN>`` with an occasional letter."""
    out = []
    for i in range(cfg.nyu_raw_scenes):
        kind = NYU_KINDS[i % len(NYU_KINDS)]
        suffix = "a" if i % 4 == 3 else ""
        out.append((f"{kind}_{i // len(NYU_KINDS) + 1:04d}{suffix}", kind))
    return out


def labeled_images(cfg: SynthConfig) -> list[LabeledImage]:
    """The labeled set: test images from scenes that are not raw scenes (three per scene), train images
    half from raw scenes (same rooms, other views) and half from further scenes; ordered by scene name."""
    n = cfg.labeled_images
    n_test = int(round(n * cfg.labeled_test_fraction))
    n_test = min(max(n_test, 1), n - 1)
    items: list[tuple[str, str, bool]] = []
    for j in range(n_test):
        s = j // 3
        kind = NYU_KINDS[s % len(NYU_KINDS)]
        items.append((f"{kind}_{101 + s:04d}", kind, True))
    raw = nyu_raw_scenes(cfg)
    n_train = n - n_test
    for j in range(n_train):
        if j < (n_train + 1) // 2:
            name, kind = raw[j % len(raw)]
        else:
            s = (j - (n_train + 1) // 2) // 3
            kind = NYU_KINDS[(s + 3) % len(NYU_KINDS)]
            name = f"{kind}_{201 + s:04d}"
        items.append((name, kind, False))
    items.sort(key=lambda x: x[0])  # stable: grouped by scene like the real file
    return [LabeledImage(i + 1, name, kind, test) for i, (name, kind, test) in enumerate(items)]


def sevenscenes_sequences(cfg: SynthConfig) -> dict[str, tuple[list[int], list[int]]]:
    """scene → (test sequence numbers, train sequence numbers) for the first ``sevenscenes_scenes``."""
    out = {}
    for name in SEVENSCENES_NAMES[: cfg.sevenscenes_scenes]:
        test = list(SEVENSCENES_TEST[name])
        train = [next(k for k in range(1, 20) if k not in test)]
        out[name] = (test, train)
    return out


def campus_scenes(cfg: SynthConfig) -> list[tuple[str, str, list[str]]]:
    """(scene, kind, image names) of the campus set."""
    out = []
    for i in range(cfg.campus_scenes):
        kind = CAMPUS_KINDS[i % len(CAMPUS_KINDS)]
        out.append((f"{kind}_{i + 1:02d}", kind, [f"img_{k + 1:02d}" for k in range(cfg.campus_images)]))
    return out


def animated_sequences(cfg: SynthConfig) -> list[str]:
    n = len(ANIMATED_NAMES)
    return [f"{ANIMATED_NAMES[i % n]}_{i // n + 1}" for i in range(cfg.animated_sequences)]


def _labeled_jobs(cfg: SynthConfig) -> list[Job]:
    groups: dict[tuple[str, str], list[int]] = {}
    for im in labeled_images(cfg):
        groups.setdefault((im.scene, im.kind), []).append(im.index)
    return [Job("nyu_labeled", s, k, s, len(ix), tuple(ix)) for (s, k), ix in groups.items()]


def _sevenscenes_jobs(cfg: SynthConfig) -> list[Job]:
    return [Job("sevenscenes", scene, scene, f"seq-{q:02d}", cfg.sevenscenes_frames)
            for scene, (test, train) in sevenscenes_sequences(cfg).items() for q in sorted(test + train)]


def _campus_jobs(cfg: SynthConfig) -> list[Job]:
    return [Job("campus", s, k, s, len(im), tuple(im), cfg.campus_hw) for s, k, im in campus_scenes(cfg)]


STANDINS: dict[str, Callable[[SynthConfig], list[Job]]] = {
    "nyu_labeled": _labeled_jobs,
    "sevenscenes": _sevenscenes_jobs,
    "campus": _campus_jobs,
}
"""The jobs of each synthetic stand-in of a test set, by the name ``f2depth.protocols.registry`` gives it."""


def standins() -> list[str]:
    """Every stand-in synth makes, in order (``f2depth.protocols.registry`` names the one of each test
    set)."""
    return list(STANDINS)


def jobs(cfg: SynthConfig) -> list[Job]:
    """All jobs, most expensive first (a better balance over the workers)."""
    out = [Job("nyu_raw", name, kind, name, cfg.nyu_raw_frames) for name, kind in nyu_raw_scenes(cfg)]
    for name in standins():
        out += STANDINS[name](cfg)
    out += [Job("animated", s, "animated", s, cfg.animated_frames, (), cfg.animated_hw)
            for s in animated_sequences(cfg)]
    return sorted(out, key=lambda j: -j.cost)
