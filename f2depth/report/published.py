"""The F²Depth paper's published numbers, as data (quoted beside our results in the tables).

Copied from the paper's LaTeX source (F²Depth, Guo et al., arXiv 2403.18443); every row carries the LaTeX
label of its table in ``source`` (``tab:tab1`` = Table 1, ``tab:tab7scenes`` = Table 2, ``tab:tab3`` …
``tab:tab6`` = Tables 3–6), and ``quoted: True`` so the table renderers mark it. "-" in the paper is None.
Method names use Unicode (P²Net, F²Depth). All NYU rows are on the 654 official test images with
per-image median scaling. 7-Scenes rows are with post-processing (the table's header says "+ PP");
Campus rows are without.

Metric keys follow ``f2depth.protocols.metrics.METRIC_NAMES``; the paper reports no SqRel or RMS-log.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

_NYU_KEYS = ("abs_rel", "rmse", "log10", "a1", "a2", "a3")
_7S_KEYS = ("abs_rel", "rmse", "a1", "a2", "a3")

# tab:tab1 — NYU Depth V2. method, supervised, transformer, post_process, REL, RMS, log10, δ1, δ2, δ3
_TABLE1: tuple[tuple[Any, ...], ...] = (
    ("Make3D", True, False, False, 0.349, 1.214, None, 0.447, 0.745, 0.897),
    ("Liu (2014)", True, False, False, 0.335, 1.06, 0.127, None, None, None),
    ("Li (2015)", True, False, False, 0.232, 0.821, 0.094, 0.621, 0.886, 0.968),
    ("Liu (2015)", True, False, False, 0.213, 0.759, 0.087, 0.650, 0.906, 0.976),
    ("Eigen", True, False, False, 0.158, 0.641, None, 0.769, 0.950, 0.988),
    ("Li (2017)", True, False, False, 0.143, 0.635, 0.063, 0.788, 0.958, 0.991),
    ("PlaneNet", True, False, False, 0.142, 0.514, 0.060, 0.827, 0.963, 0.990),
    ("PlaneReg", True, False, False, 0.134, 0.503, 0.057, 0.827, 0.963, 0.990),
    ("Laina", True, False, False, 0.127, 0.573, 0.055, 0.811, 0.953, 0.988),
    ("DORN", True, False, False, 0.115, 0.509, 0.051, 0.828, 0.965, 0.992),
    ("VNL", True, False, False, 0.108, 0.416, 0.048, 0.875, 0.976, 0.994),
    ("P3Depth", True, False, False, 0.104, 0.356, 0.043, 0.898, 0.981, 0.996),
    ("Jun", True, True, False, 0.100, 0.362, 0.043, 0.907, 0.986, 0.997),
    ("MonoIndoor++", False, True, False, 0.132, 0.517, None, 0.834, 0.961, 0.990),
    ("GasMono", False, True, False, 0.113, 0.459, None, 0.871, 0.973, 0.992),
    ("Moving Indoor", False, False, False, 0.208, 0.712, 0.086, 0.674, 0.900, 0.968),
    ("TrianFlow", False, False, False, 0.189, 0.686, 0.079, 0.701, 0.912, 0.978),
    ("Zhang", False, False, False, 0.177, 0.634, None, 0.733, 0.936, None),
    ("Monodepth2", False, False, False, 0.170, 0.617, 0.072, 0.748, 0.942, 0.986),
    ("ADPDepth", False, False, False, 0.165, 0.592, 0.071, 0.753, 0.934, 0.981),
    ("SC-Depth", False, False, False, 0.159, 0.608, 0.068, 0.772, 0.939, 0.982),
    ("P²Net", False, False, False, 0.159, 0.599, 0.068, 0.772, 0.942, 0.984),
    ("F²Depth", False, False, False, 0.158, 0.583, 0.067, 0.779, 0.947, 0.987),
    ("P²Net", False, False, True, 0.157, 0.592, 0.067, 0.777, 0.944, 0.985),
    ("F²Depth", False, False, True, 0.153, 0.569, 0.065, 0.787, 0.950, 0.987),
)

# tab:tab5 — losses ablation on NYU. variant, post_process, L_rigid, L_feature, REL, RMS, log10, δ1, δ2, δ3
_TABLE5: tuple[tuple[Any, ...], ...] = (
    ("baseline", False, False, False, 0.159, 0.599, 0.068, 0.772, 0.942, 0.984),
    ("no_feature", False, True, False, 0.158, 0.586, 0.067, 0.778, 0.946, 0.986),
    ("full", False, True, True, 0.158, 0.583, 0.067, 0.779, 0.947, 0.987),
    ("baseline", True, False, False, 0.157, 0.592, 0.067, 0.777, 0.944, 0.985),
    ("no_feature", True, True, False, 0.156, 0.577, 0.066, 0.783, 0.947, 0.986),
    ("full", True, True, True, 0.153, 0.569, 0.065, 0.787, 0.950, 0.987),
)

# tab:tab6 — flow weights (no PP). variant, paper's label, REL, RMS, log10, δ1, δ2, δ3
_TABLE6: tuple[tuple[Any, ...], ...] = (
    ("flow_pretrained", "Pretrained original network", 0.159, 0.591, 0.068, 0.775, 0.946, 0.986),
    ("flow_full_ft", "Finetuned original network", 0.160, 0.596, 0.068, 0.773, 0.945, 0.986),
    ("full", "Our finetuned network", 0.158, 0.583, 0.067, 0.779, 0.947, 0.987),
)

# tab:tab7scenes — 7-Scenes zero-shot, both + PP. scene → (REL, RMS, δ1, δ2, δ3)
_SEVENSCENES: dict[str, dict[str, tuple[float, ...]]] = {
    "F²Depth": {"chess": (0.18, 0.4, 0.689, 0.942, 0.994), "fire": (0.172, 0.315, 0.713, 0.955, 0.992),
                "heads": (0.18, 0.19, 0.725, 0.93, 0.987), "office": (0.154, 0.35, 0.781, 0.97, 0.997),
                "pumpkin": (0.12, 0.335, 0.86, 0.981, 0.996),
                "redkitchen": (0.162, 0.396, 0.751, 0.954, 0.995),
                "stairs": (0.162, 0.468, 0.754, 0.911, 0.967),
                "Average": (0.159, 0.361, 0.758, 0.956, 0.993)},
    "P²Net": {"chess": (0.184, 0.41, 0.67, 0.94, 0.993), "fire": (0.159, 0.294, 0.763, 0.964, 0.994),
              "heads": (0.188, 0.198, 0.701, 0.924, 0.982), "office": (0.156, 0.35, 0.774, 0.97, 0.997),
              "pumpkin": (0.141, 0.378, 0.798, 0.977, 0.995),
              "redkitchen": (0.165, 0.403, 0.734, 0.952, 0.994),
              "stairs": (0.157, 0.455, 0.769, 0.911, 0.971), "Average": (0.163, 0.367, 0.747, 0.955, 0.993)},
}
SEVENSCENES_TITLES = {"chess": "Chess", "fire": "Fire", "heads": "Heads", "office": "Office",
                      "pumpkin": "Pumpkin", "redkitchen": "RedKitchen", "stairs": "Stairs"}  # fmt: skip

# tab:tab3 — Campus Indoor, mean of 18 scenes (last row: F²Depth on NYU, for reference).
# method, supervised, REL, RMS, log10, δ1, δ2, δ3
_CAMPUS: tuple[tuple[Any, ...], ...] = (
    ("VNL", True, 0.132, 0.586, 0.054, 0.852, 0.978, 0.995),
    ("Jun", True, 0.116, 0.525, 0.048, 0.867, 0.977, 0.999),
    ("TrianFlow", False, 0.204, 0.803, 0.080, 0.695, 0.910, 0.975),
    ("P²Net", False, 0.174, 0.783, 0.072, 0.733, 0.939, 0.991),
    ("F²Depth", False, 0.164, 0.753, 0.069, 0.760, 0.950, 0.991),
    ("F²Depth on NYU", False, 0.158, 0.583, 0.067, 0.779, 0.947, 0.987),
)

# tab:tab4 — Campus Indoor per scene (No. 1-18). Each row: F²Depth (REL, RMS, log10, δ1, δ2, δ3),
# then P²Net (same six).
_CAMPUS_SCENES: tuple[tuple[float, ...], ...] = (
    (0.164, 0.592, 0.064, 0.766, 0.947, 1, 0.161, 0.663, 0.067, 0.676, 1, 1),
    (0.135, 0.949, 0.060, 0.798, 0.981, 1, 0.171, 1.036, 0.074, 0.726, 0.968, 1),
    (0.215, 0.889, 0.084, 0.644, 0.973, 1, 0.254, 0.956, 0.093, 0.684, 0.822, 1),
    (0.134, 0.588, 0.058, 0.777, 1, 1, 0.169, 0.645, 0.068, 0.709, 0.986, 1),
    (0.159, 1.091, 0.067, 0.746, 0.946, 1, 0.172, 1.051, 0.070, 0.733, 0.893, 1),
    (0.154, 1.625, 0.073, 0.757, 0.919, 0.932, 0.140, 1.544, 0.068, 0.812, 0.932, 0.959),
    (0.266, 2.321, 0.122, 0.436, 0.802, 0.96, 0.237, 2.104, 0.108, 0.528, 0.817, 0.961),
    (0.149, 0.699, 0.063, 0.772, 0.929, 1, 0.154, 0.778, 0.062, 0.77, 0.943, 1),
    (0.088, 0.372, 0.037, 0.946, 1, 1, 0.122, 0.514, 0.050, 0.88, 1, 1),
    (0.193, 0.686, 0.076, 0.717, 0.917, 1, 0.183, 0.637, 0.069, 0.733, 0.933, 1),
    (0.168, 0.667, 0.072, 0.787, 0.973, 1, 0.181, 0.784, 0.078, 0.680, 0.960, 1),
    (0.143, 0.536, 0.066, 0.736, 1, 1, 0.143, 0.545, 0.065, 0.775, 1, 1),
    (0.147, 0.594, 0.067, 0.803, 0.974, 1, 0.142, 0.613, 0.066, 0.802, 0.962, 1),
    (0.135, 0.422, 0.060, 0.880, 1, 1, 0.158, 0.526, 0.072, 0.667, 1, 1),
    (0.236, 0.409, 0.084, 0.720, 0.867, 0.946, 0.253, 0.450, 0.092, 0.640, 0.867, 0.946),
    (0.202, 0.647, 0.079, 0.707, 0.920, 1, 0.233, 0.773, 0.090, 0.653, 0.880, 0.987),
    (0.114, 0.244, 0.047, 0.893, 0.960, 1, 0.129, 0.268, 0.050, 0.933, 0.947, 0.987),
    (0.144, 0.230, 0.061, 0.787, 0.987, 1, 0.136, 0.209, 0.058, 0.787, 1, 1),
)

CAMPUS_IMAGES = 99
"""Images of Campus Indoor's 18 scenes (the paper §4.1)."""

INFERENCE_MS = {"no_pp": 9.4, "pp": 13.5, "device": "NVIDIA GeForce RTX 3090", "height": 288, "width": 384,
                "source": "text of §4.2.1 (Evaluation of depth estimation on NYU Depth V2), beside tab:tab1"}


def _row(source: str, keys: tuple[str, ...], values: Sequence[Any], **fields: Any) -> dict[str, Any]:
    """``fields``, the metrics ``keys`` → ``values`` ("-" = None), then ``source`` and ``quoted: True``."""
    metrics = {k: (None if v is None else float(v)) for k, v in zip(keys, values, strict=True)}
    return {**fields, **metrics, "source": source, "quoted": True}


def table1() -> list[dict[str, Any]]:
    """All rows of tab:tab1 in the paper's order: ``method, supervised, transformer, post_process``,
    the six metrics, ``source``, ``quoted``."""
    return [_row("tab:tab1", _NYU_KEYS, v, method=m, supervised=s, transformer=t, post_process=pp)
            for m, s, t, pp, *v in _TABLE1]


def table5() -> list[dict[str, Any]]:
    """tab:tab5 (losses on/off × PP): ``variant`` (our ablation name), ``post_process``, ``rigid``
    (optical-flow consistency loss), ``feature`` (feature-map synthesis loss), the six metrics."""
    return [_row("tab:tab5", _NYU_KEYS, v, variant=var, post_process=pp, rigid=rg, feature=ft)
            for var, pp, rg, ft, *v in _TABLE5]


def table6() -> list[dict[str, Any]]:
    """tab:tab6 (flow weights, no PP): ``variant`` (our ablation name), ``weights`` (paper's label)."""
    return [_row("tab:tab6", _NYU_KEYS, v, variant=var, weights=label) for var, label, *v in _TABLE6]


def sevenscenes(method: str = "F²Depth") -> list[dict[str, Any]]:
    """tab:tab7scenes rows of ``method`` (``F²Depth`` or ``P²Net``, both + PP): seven scenes then
    ``Average`` (which matches the frame-weighted mean of the scene rows, see
    f2depth.protocols.sevenscenes)."""
    if method not in _SEVENSCENES:
        raise KeyError(f"tab:tab7scenes has no method {method!r}; use one of {sorted(_SEVENSCENES)}")
    rows = _SEVENSCENES[method].items()
    return [_row("tab:tab7scenes", _7S_KEYS, v, scene=s, method=method, post_process=True) for s, v in rows]


def campus() -> list[dict[str, Any]]:
    """tab:tab3 (Campus Indoor, mean of the 18 scene rows; last row is F²Depth on NYU for reference)."""
    return [_row("tab:tab3", _NYU_KEYS, v, method=m, supervised=s) for m, s, *v in _CAMPUS]


def campus_scenes(method: str = "F²Depth") -> list[dict[str, Any]]:
    """tab:tab4 rows of ``method`` (``F²Depth`` or ``P²Net``): ``scene`` "1" … "18" and six metrics."""
    offset = {"F²Depth": 0, "P²Net": 6}.get(method)
    if offset is None:
        raise KeyError(f"tab:tab4 has no method {method!r}; use 'F²Depth' or 'P²Net'")
    return [_row("tab:tab4", _NYU_KEYS, row[offset : offset + 6], scene=str(i + 1), method=method)
            for i, row in enumerate(_CAMPUS_SCENES)]


Pair = tuple[str, "int | None", dict[str, Any], dict[str, Any]]
"""A quoted row of a per-scene table: (scene label, image count, F²Depth's row, P²Net's row)."""


def sevenscenes_pairs() -> list[Pair]:
    """tab:tab7scenes as F²Depth beside P²Net per scene (titled as the paper), then ``Average``."""
    theirs = {r["scene"]: r for r in sevenscenes("P²Net")}
    return [(SEVENSCENES_TITLES.get(r["scene"], r["scene"]), None, r, theirs[r["scene"]])
            for r in sevenscenes("F²Depth")]


def campus_pairs() -> list[Pair]:
    """tab:tab4's 18 scenes (``No. k``), F²Depth beside P²Net, then tab:tab3's average over the 99 images."""
    avg = {r["method"]: r for r in campus()}
    scenes = zip(campus_scenes("F²Depth"), campus_scenes("P²Net"))
    return [*((f"No. {a['scene']}", None, a, b) for a, b in scenes),
            ("Average of 18 scenes", CAMPUS_IMAGES, avg["F²Depth"], avg["P²Net"])]


def inference_ms() -> dict[str, Any]:
    """The paper's inference times (ms per image, no PP / PP) and where they were measured."""
    return dict(INFERENCE_MS)
