"""Named selector settings: ``dso`` (DSO's keyframe defaults) and ``p2net`` (P²Net's call)."""

from __future__ import annotations

from dataclasses import dataclass, fields, replace


@dataclass(frozen=True)
class Preset:
    """Selector settings.

    density: points wanted (absolute, not per area); recursions: makeMaps re-selections;
    direction: DSO's random-direction score (False: the squared gradient, P²Net);
    th_factor: multiplies the squared thresholds; pot: initial cell size of a fresh selector;
    work_size: (height, width) the grey image is resized to (bilinear) before selecting, points are
    mapped back with ``y·H // height``, ``x·W // width`` (P²Net's integer arithmetic), None = as given;
    max_points: keep at most this many points (the first ones in raster order at the working size);
    hist_add: added to the block median of |∇I| (DSO: 7; 3 for perfect synthetic photometry).
    """

    name: str
    density: float = 1500
    recursions: int = 1
    direction: bool = True
    th_factor: float = 1.0
    pot: int = 3
    work_size: tuple[int, int] | None = None
    max_points: int | None = None
    hist_add: float = 7.0

    def with_overrides(self, **overrides) -> Preset:
        known = {f.name for f in fields(self)} - {"name"}
        unknown = set(overrides) - known
        if unknown:
            raise TypeError(f"unknown selector option(s) {sorted(unknown)}; known: {sorted(known)}")
        if "work_size" in overrides and overrides["work_size"] is not None:
            overrides["work_size"] = tuple(int(v) for v in overrides["work_size"])
        out = replace(self, **overrides)
        if not out.density > 0 or out.recursions < 0 or out.pot < 1 or not out.th_factor > 0:
            raise ValueError(f"invalid selector options {out}: need density > 0, recursions >= 0, pot >= 1, "
                             "th_factor > 0")
        return out


PRESETS: dict[str, Preset] = {
    # FullSystem::makeNewTraces: density 1500 per keyframe, one re-selection, direction test on.
    "dso": Preset("dso"),
    # P²Net (its datasets/nyu_dataset.py, extract_svo_point.py, main2.cpp): grey 640×480,
    # makeMaps(2000, recursions 3), no direction test, at most 2500 points, rescaled to the training
    # size with integer arithmetic; duplicates kept.
    "p2net": Preset("p2net", density=2000, recursions=3, direction=False, work_size=(480, 640),
                    max_points=2500),
}


def get_preset(preset: str | Preset, **overrides) -> Preset:
    """A preset by name (or as given) with ``overrides`` applied."""
    if isinstance(preset, Preset):
        base = preset
    elif preset in PRESETS:
        base = PRESETS[preset]
    else:
        raise ValueError(f"unknown keypoint preset '{preset}'; choose one of {sorted(PRESETS)}")
    return base.with_overrides(**overrides) if overrides else base
