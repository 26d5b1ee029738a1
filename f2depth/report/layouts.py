"""How the `tables` stage shows each test set besides NYU's paper tables: its columns in the variants
overview and its per-scene table beside the paper's rows (``f2depth.report.published``).

One :class:`Layout` per name of ``f2depth.protocols.registry`` (tests/test_eval_registry.py checks that the
two lists agree). The scoring side of a test set (``f2depth.protocols.<name>``) knows nothing of this file, so
editing a caption or the paper's numbers re-runs `tables` only.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from f2depth.report import published


@dataclass(frozen=True)
class SceneTable:
    """A per-scene table in reports/tables: our F²Depth (``full``) beside our P²Net (``baseline``) per
    scene of headline ``group``, the ``summaries`` rows ((label, ``headline`` | ``scene_mean``): the
    group's headline or the mean of its scene rows), then the paper's rows from ``published()``."""

    stem: str
    group: str
    metrics: tuple[str, ...]
    summaries: tuple[tuple[str, str], ...]
    title: str
    caption: str
    label: str
    notes: tuple[str, ...] = ()
    scene_titles: Mapping[str, str] = field(default_factory=dict)
    published: Callable[[], list[published.Pair]] = list


@dataclass(frozen=True)
class Layout:
    """A test set in the tables: ``column``, the prefix of its columns in the variants overview (empty:
    none, NYU has its own tables); ``note``, what its headline is; ``table``, its per-scene table."""

    column: str = ""
    note: str = ""
    table: SceneTable | None = None


LAYOUTS: dict[str, Layout] = {
    "nyu": Layout(),
    "sevenscenes": Layout(
        column="s7", note="mean over all test frames",
        table=SceneTable(
            stem="sevenscenes_scenes", group="sevenscenes_pp", metrics=("abs_rel", "rmse", "a1", "a2", "a3"),
            summaries=(("Average (frame-weighted, as the paper)", "headline"),
                       ("Mean of scene rows", "scene_mean")),
            title="7-Scenes per scene (zero-shot, + PP): F²Depth (ours: full) vs P²Net (ours: baseline)",
            caption="Zero-shot depth on the 7-Scenes test sequences, with post-processing",
            label="tab:sevenscenes",
            notes=("The paper's Average row equals the frame-weighted mean of its scene rows (official test "
                   "frame counts); compare it with our frame-weighted row.",),
            scene_titles=published.SEVENSCENES_TITLES, published=published.sevenscenes_pairs)),
    "campus": Layout(
        column="campus", note="mean of the scene rows",
        table=SceneTable(
            stem="campus_scenes", group="campus", metrics=("abs_rel", "rmse", "log10", "a1", "a2", "a3"),
            summaries=(("Average of scenes", "headline"),),
            title="Campus Indoor per scene (zero-shot, no PP): F²Depth (ours: full) vs P²Net "
                  "(ours: baseline)",
            caption="Zero-shot depth at the laser-measured points of Campus Indoor", label="tab:campus",
            notes=("With the synthetic Campus stand-in, our scenes are not the paper's scenes No. 1-18.",),
            published=published.campus_pairs)),
}  # fmt: skip


def layout(name: str) -> Layout:
    """The :class:`Layout` of registered test set ``name``."""
    if name not in LAYOUTS:
        raise ValueError(f"test set {name!r} has no layout in f2depth/report/layouts.py; add one (it has "
                         f"{list(LAYOUTS)})")
    return LAYOUTS[name]
