"""How far self-calibration's focal length is from the truth, and how often its printed error bar holds it.

Run: ``python benchmarks/bench_selfcal_coverage.py [--seeds 0 1] [--frames N] [--size WxH] [--out file.json]``
(one process, about 6 minutes at the defaults, 72 clips; writes a short .md beside the JSON). The error bar
ingest prints (``f2depth.ingest.selfcal.ERROR_BAR``) is this run's 90th-percentile |error|, rounded up.

Renders ``len(FACTORS) × len(LENSES) × len(MOTIONS)`` short clips per seed of the project's synthetic rooms
(:mod:`f2depth.synth`: ray-cast room, handheld camera path, sensor noise) with known intrinsics, encodes each
as an MP4 (``mp4v``, as a phone hands a video over) and self-calibrates it exactly as ``f2depth ingest``
does without a camera file (:func:`f2depth.ingest.selfcal.estimate_focal` on the decoded frames). Varied:

* fx: ``FACTORS`` × the NYU focal length (518.9 px at 640 px wide), scaled to the clip's width;
* lens (``LENSES``): ``ideal`` (no distortion, principal point at the centre); ``nyu`` (NYU Depth V2's
  RGB distortion, its coefficients rescaled so the displacement over the frame has NYU's profile at this
  field of view, about 2 % at the corners, and NYU's principal point offset, ±1 % / ±3 % of w / h);
  ``strong`` (a wide lens's barrel, k1 r² = −8 % at the corners, and the same offset);
* motion (``MOTIONS``): ``walking`` (the synthetic NYU camera path: 24–34 cm/s, looking at a point of the
  room), ``sideways`` (the same path, the camera looking 90° off the direction of travel), ``slow``
  (8–12 cm/s). 120 frames (4 s) at 320×240 by default.

Per clip: true fx, the estimate, its relative error, the bootstrap ±half-range (what ingest printed before
issue 53), the error bar ingest prints now (``FocalEstimate.error_bar``), and whether the truth lies in
each; refusals are counted, not scored. Overall: the coverage of both bars, median and 90th-percentile
|relative error|.
"""

from __future__ import annotations

import argparse
import itertools
import math
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from f2depth.camera import NYU_RGB_DIST, NYU_RGB_K, NYU_SIZE_HW, distortion_maps  # noqa: E402
from f2depth.errors import DataError  # noqa: E402
from f2depth.ingest.selfcal import estimate_focal  # noqa: E402
from f2depth.ingest.sources import open_source  # noqa: E402
from f2depth.io import write_json, write_text  # noqa: E402
from f2depth.synth.camera_path import PathStyle, handheld_path, rotation  # noqa: E402
from f2depth.synth.jobs import room  # noqa: E402
from f2depth.synth.layout import NYU_KINDS  # noqa: E402
from f2depth.synth.render import render  # noqa: E402
from f2depth.synth.sensor import expose  # noqa: E402

FACTORS = (0.6, 0.85, 1.1, 1.4)
LENSES = ("ideal", "nyu", "strong")
MOTIONS = ("walking", "sideways", "slow")
NYU_FX = float(NYU_RGB_K[0, 0])
NYU_OFFSET = (NYU_RGB_K[0, 2] - (NYU_SIZE_HW[1] - 1) / 2) / NYU_SIZE_HW[1], \
             (NYU_RGB_K[1, 2] - (NYU_SIZE_HW[0] - 1) / 2) / NYU_SIZE_HW[0]
STRONG_K1_CORNER = -0.08  # k1 r² at the image corner: a wide lens's barrel
NOISE = 1.5  # sensor noise, 8-bit levels at mid-grey
SLOW = PathStyle(speed=(0.08, 0.12))


def lens(kind: str, fx: float, hw: tuple[int, int], rng: np.random.Generator
         ) -> tuple[np.ndarray, np.ndarray]:
    """K (3,3) and OpenCV distortion (5,) of lens ``kind`` (module docstring) with focal length ``fx``."""
    h, w = hw
    cx, cy = (w - 1) / 2, (h - 1) / 2
    dist = np.zeros(5)
    if kind != "ideal":
        sx, sy = rng.choice([-1.0, 1.0], 2)
        cx, cy = cx + sx * NYU_OFFSET[0] * w, cy + sy * NYU_OFFSET[1] * h
        corner_r2 = (w * w + h * h) / 4 / fx ** 2
        if kind == "nyu":  # NYU's profile over the frame: k_i r^2i the same at the same share of the corner
            nyu_r2 = (NYU_SIZE_HW[0] ** 2 + NYU_SIZE_HW[1] ** 2) / 4 / NYU_FX ** 2
            s = nyu_r2 / corner_r2
            k1, k2, p1, p2, k3 = NYU_RGB_DIST
            dist = np.array([k1 * s, k2 * s * s, p1 * s, p2 * s, k3 * s ** 3])
        else:
            dist[0] = STRONG_K1_CORNER / corner_r2
    return np.array([[fx, 0.0, cx], [0.0, fx, cy], [0.0, 0.0, 1.0]]), dist


def poses(scene, motion: str, n: int, rng: np.random.Generator) -> np.ndarray:
    """world_T_cam (n,4,4) of ``motion`` (module docstring)."""
    path, _ = handheld_path(scene, n, rng, SLOW if motion == "slow" else PathStyle())
    if motion == "sideways":  # keep the positions and the pitch; look 90° off the direction of travel
        d = np.gradient(path[:, :2, 3], axis=0)
        yaw = np.unwrap(np.arctan2(d[:, 1], d[:, 0])) + math.pi / 2
        yaw = np.convolve(np.pad(yaw, 3, mode="edge"), np.ones(7) / 7, mode="valid")  # no jitter from tremor
        for k in range(n):
            path[k, :3, :3] = rotation(yaw[k], math.radians(-10.0), 0.0)
    return path


def write_clip(path: Path, scene, world_T_cam: np.ndarray, K: np.ndarray, dist: np.ndarray,
               hw: tuple[int, int], rng: np.random.Generator) -> None:
    maps = distortion_maps(K, dist, hw) if dist.any() else None
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (hw[1], hw[0]))
    if not writer.isOpened():
        raise RuntimeError(f"{path}: OpenCV cannot write mp4v video here")
    try:
        for T in world_T_cam:
            radiance, _ = render(scene, T, K, hw, 1)
            if maps is not None:
                radiance = cv2.remap(radiance, *maps, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            rgb = expose(radiance, scene.exposure, None, NOISE, rng)
            writer.write(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    finally:
        writer.release()


def self_calibrate(path: Path):
    """What ``f2depth ingest`` does without a camera file (f2depth.ingest.run.ingest, ``self_calibrate``)."""
    return estimate_focal([(frame.rgb for frame in open_source(path))], path)


def summary(rows: list[dict], key: str) -> dict:
    scored = [r for r in rows if "error" in r]
    errors = np.abs([r["error"] for r in scored])
    inside = [r[key] for r in scored]
    return {"clips": len(rows), "scored": len(scored), "refused": len(rows) - len(scored),
            "coverage": round(float(np.mean(inside)), 3) if inside else None,
            "median_abs_error": round(float(np.median(errors)), 4) if len(errors) else None,
            "p90_abs_error": round(float(np.percentile(errors, 90)), 4) if len(errors) else None,
            "max_abs_error": round(float(errors.max()), 4) if len(errors) else None}


def cross_seed(rows: list[dict], seeds: list[int]) -> dict:
    """Per seed: the 90th percentile |error| of the other seeds' clips as a bar, and its coverage here."""
    out = {}
    for seed in seeds if len(seeds) > 1 else []:
        other = [abs(r["error"]) for r in rows if "error" in r and r["seed"] != seed]
        here = [abs(r["error"]) for r in rows if "error" in r and r["seed"] == seed]
        if other and here:
            bar = float(np.percentile(other, 90))
            inside = float(np.mean(np.array(here) <= bar))
            out[str(seed)] = {"bar": round(bar, 4), "coverage": round(inside, 3), "clips": len(here)}
    return out


def markdown(doc: dict) -> str:
    b, a = doc["bootstrap"], doc["printed"]
    seeds = " ".join(str(s) for s in doc["seeds"])
    lines = [f"# Self-calibration coverage ({doc['clips']} rendered clips, {doc['size']}, "
             f"{doc['frames']} frames)", "",
             f"`python benchmarks/bench_selfcal_coverage.py --seeds {seeds} --out {doc['out']}` "
             f"({doc['seconds']:.0f} s).",
             "", "| interval | coverage | median \\|error\\| | p90 \\|error\\| | max \\|error\\| | refused |",
             "|---|---|---|---|---|---|",
             f"| bootstrap 16–84 % ± half-range (before) | {100 * b['coverage']:.0f} % | "
             f"{100 * b['median_abs_error']:.1f} % | {100 * b['p90_abs_error']:.1f} % | "
             f"{100 * b['max_abs_error']:.1f} % | {b['refused']} |",
             f"| printed error bar (now) | {100 * a['coverage']:.0f} % | | | | |", "",
             "Printed bar fitted on the other seeds' clips (90th percentile), coverage on this seed's: "
             + ", ".join(f"seed {k} {100 * v['coverage']:.0f} % (bar ±{100 * v['bar']:.1f} %)"
                         for k, v in doc["cross_seed"].items()), "",
             "| clip | true fx | estimate | error | bootstrap ± | inside | printed ± | inside | pairs |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in doc["rows"]:
        if "error" not in r:
            lines.append(f"| {r['clip']} | {r['fx_true']:.1f} | refused: {r['refused']} | | | | | | |")
            continue
        lines.append(f"| {r['clip']} | {r['fx_true']:.1f} | {r['fx']:.1f} | {100 * r['error']:+.1f} % | "
                     f"{100 * r['bootstrap_half']:.1f} % | {'yes' if r['in_bootstrap'] else 'no'} | "
                     f"{100 * r['printed_half']:.1f} % | {'yes' if r['in_printed'] else 'no'} | "
                     f"{r['pairs']} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=120, help="frames per clip (30 fps)")
    parser.add_argument("--size", default="320x240", help="clip size WxH")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="one set of clips per seed")
    parser.add_argument("--out", type=Path, default=Path("reports/benchmarks/selfcal_coverage.json"))
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    w, h = (int(v) for v in args.size.lower().split("x"))
    hw = (h, w)
    start = time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        combos = [(m, le, f) for m in MOTIONS for le in LENSES for f in FACTORS]
        for seed, (index, (motion, lens_kind, factor)) in itertools.product(args.seeds, enumerate(combos)):
            rng = np.random.default_rng([seed, index])
            kind = NYU_KINDS[index % len(NYU_KINDS)]
            scene = room("nyu", kind, f"selfcal_{kind}_{index}", seed)
            fx = factor * NYU_FX * w / NYU_SIZE_HW[1]
            K, dist = lens(lens_kind, fx, hw, rng)
            name = f"s{seed}-{index:02d}-{motion}-{lens_kind}-{factor:g}"
            clip = Path(tmp) / f"{name}.mp4"
            write_clip(clip, scene, poses(scene, motion, args.frames, rng), K, dist, hw, rng)
            row = {"clip": name, "seed": seed, "room": kind, "motion": motion, "lens": lens_kind,
                   "fx_true": fx, "cx": K[0, 2], "cy": K[1, 2], "dist": dist.round(5).tolist()}
            try:
                est = self_calibrate(clip)
            except DataError as e:
                row["refused"] = str(e).split(": ", 1)[-1].split(" (")[0][:120]
            else:
                err = est.fx / fx - 1
                printed = getattr(est, "error_bar", est.spread / 2)
                row.update(fx=est.fx, error=err, pairs=est.pairs, spread=est.spread,
                           reprojection_px=est.reprojection_px, bootstrap_half=est.spread / 2,
                           in_bootstrap=bool(abs(err) <= est.spread / 2), printed_half=printed,
                           in_printed=bool(abs(err) <= printed))
            rows.append(row)
            shown = (f"{row['fx']:.1f} ({100 * row['error']:+.1f} %, bootstrap ±"
                     f"{50 * row['spread']:.1f} %)") if "error" in row else f"refused: {row['refused']}"
            print(f"{name:31s} fx {fx:6.1f} → {shown}", flush=True)
    doc = {"cross_seed": cross_seed(rows, args.seeds),
           "clips": len(rows), "size": f"{w}x{h}", "frames": args.frames, "seeds": args.seeds,
           "out": str(args.out), "seconds": round(time.perf_counter() - start, 1),
           "bootstrap": summary(rows, "in_bootstrap"), "printed": summary(rows, "in_printed"), "rows": rows}
    for label, key in (("bootstrap ± half-range", "bootstrap"), ("printed error bar", "printed")):
        s = doc[key]
        print(f"{label}: coverage {s['coverage']} over {s['scored']} clips ({s['refused']} refused); "
              f"|error| median {s['median_abs_error']}, p90 {s['p90_abs_error']}, max {s['max_abs_error']}")
    write_json(args.out, doc)
    write_text(args.out.with_suffix(".md"), markdown(doc))
    print(f"→ {args.out}, {args.out.with_suffix('.md')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
