"""Generation of the whole synthetic world: every job of :mod:`f2depth.synth.plan`, then the per-set files
written once all of a stand-in's jobs ran, the manifest and the metrics (the `synth` stage's
:func:`generate`)."""


from __future__ import annotations

import functools
import time
from dataclasses import asdict

import numpy as np

from f2depth.io import csv_text, write_json, write_text
from f2depth.synth import jobs as _jobs
from f2depth.synth import matfiles, plan
from f2depth.synth.cleanup import remove_previous
from f2depth.synth.clips import write_clips
from f2depth.synth.config import OutputPaths, SynthConfig
from f2depth.workers import map_jobs

MANIFEST_VERSION = 1


def generate(cfg: SynthConfig, paths: OutputPaths, progress: bool = True) -> dict:
    """Generate every dataset below ``paths`` and the side-car ground truth; returns the metrics.

    The output is a function of ``cfg`` only (byte-identical for the same settings, whatever the number
    of workers). What a previous generation wrote is removed first (:mod:`f2depth.synth.cleanup`);
    other files in the folders are left alone.
    """
    t0 = time.perf_counter()
    removed = remove_previous(paths)
    run = functools.partial(_jobs.run, cfg=cfg, paths=paths)
    results = map_jobs(run, plan.jobs(cfg), cfg.workers, "synth", progress, size=lambda job: job.frames)
    by_ds: dict[str, list[dict]] = {}
    for r in results:
        by_ds.setdefault(r["dataset"], []).append(r)

    for name in plan.standins():  # the files a test set's stand-in has besides its frames
        FINISH[name](cfg, paths, by_ds.get(name, []))
    clips = write_clips(paths.nyu_raw, sorted({r["room"] for r in by_ds.get("nyu_raw", [])}), paths.clips,
                        cfg.clips)
    manifest = _manifest(cfg, by_ds)
    # which raw frame each clip frame shows: how prepare finds the ingested clips' ground truth
    manifest["clips"] = {scene: c["raw_frames"] for scene, c in sorted(clips.items())}
    write_json(paths.synth_gt / "manifest.json", manifest)
    metrics = _metrics(cfg, by_ds, manifest, time.perf_counter() - t0)
    metrics["clips"] = {"scenes": len(clips), "frames": sum(c["frames"] for c in clips.values()),
                        "static_frames": cfg.clips.static_frames}
    metrics["stale_files_removed"] = removed
    return metrics


def _finish_labeled(cfg: SynthConfig, paths: OutputPaths, results: list[dict]) -> None:
    """NYU labeled: one .mat from all labeled jobs, in index order, and the split."""
    items = sorted((it for r in results for it in r["labeled"]), key=lambda it: it[0])
    images = plan.labeled_images(cfg)
    if [it[0] for it in items] != [im.index for im in images]:
        raise RuntimeError("labeled images missing from the job results")
    matfiles.write_nyu_labeled(paths.nyu_labeled, np.stack([it[1] for it in items]),
                               np.stack([it[2] for it in items]), np.stack([it[3] for it in items]),
                               [im.scene for im in images], [im.kind for im in images])
    test = [im.index for im in images if im.test]
    train = [im.index for im in images if not im.test]
    matfiles.write_splits(paths.nyu_splits, np.array(train), np.array(test))


def _finish_sevenscenes(cfg: SynthConfig, paths: OutputPaths, results: list[dict]) -> None:
    """7-Scenes: each scene's split files."""
    for scene, (test_seq, train_seq) in plan.sevenscenes_sequences(cfg).items():
        write_text(paths.sevenscenes / scene / "TestSplit.txt", "".join(f"sequence{q}\n" for q in test_seq))
        write_text(paths.sevenscenes / scene / "TrainSplit.txt", "".join(f"sequence{q}\n" for q in train_seq))


def _finish_campus(cfg: SynthConfig, paths: OutputPaths, results: list[dict]) -> None:
    """Campus: points.csv."""
    points = sorted(p for r in results for p in r["points"])
    rows = [(s, i, f"{u:g}", f"{v:g}", f"{d:.4f}") for s, i, u, v, d in points]
    write_text(paths.campus / "points.csv", csv_text(["scene", "image", "u", "v", "depth_m"], rows))


FINISH = {"nyu_labeled": _finish_labeled, "sevenscenes": _finish_sevenscenes, "campus": _finish_campus}
"""What each stand-in of :data:`f2depth.synth.plan.STANDINS` writes once all its jobs ran."""


def _manifest(cfg: SynthConfig, by_ds: dict[str, list[dict]]) -> dict:
    datasets: dict[str, dict] = {}
    for ds, rs in sorted(by_ds.items()):
        scenes: dict[str, int] = {}
        for r in rs:
            key = f"{r['room']}/{r['seq']}" if ds == "sevenscenes" else r["room"]
            scenes[key] = scenes.get(key, 0) + r["frames"]
        datasets[ds] = {"scenes": dict(sorted(scenes.items())), "frames": sum(scenes.values())}
    labeled = plan.labeled_images(cfg)
    datasets.setdefault("nyu_labeled", {})["test_scenes"] = sorted({im.scene for im in labeled if im.test})
    params = {k: v for k, v in asdict(cfg).items() if k != "workers"}  # the output does not depend on it
    return {"generator": "f2depth.synth", "version": MANIFEST_VERSION, "params": params, "datasets": datasets}


def _metrics(cfg: SynthConfig, by_ds: dict[str, list[dict]], manifest: dict, seconds: float) -> dict:
    out: dict = {"data_source": "synthetic", "seconds": round(seconds, 2), "workers": cfg.workers,
                 "datasets": {}}
    for ds, rs in sorted(by_ds.items()):
        depth_n = max(1, sum(r["depth_count"] for r in rs))
        m = {"scenes": len(manifest["datasets"][ds]["scenes"]), "frames": sum(r["frames"] for r in rs),
             "mean_depth_m": round(sum(r["depth_sum"] for r in rs) / depth_n, 4),
             "worker_seconds": round(sum(r["seconds"] for r in rs), 2)}
        flow_n = sum(r.get("flow_count", 0) for r in rs)
        if flow_n:
            m["mean_flow_px"] = round(sum(r["flow_abs_sum"] for r in rs) / flow_n, 4)
            m["occluded_fraction"] = round(sum(r["occluded_sum"] for r in rs) / flow_n, 5)
            speeds = np.concatenate([np.asarray(r["speeds"]) * r["fps"] for r in rs])
            m["camera_speed_m_s"] = {k: round(float(f(speeds)), 4) for k, f in
                                     (("mean", np.mean), ("min", np.min), ("max", np.max))}
        if ds == "campus":
            m["points"] = sum(len(r["points"]) for r in rs)
        out["datasets"][ds] = m
    out["frames"] = sum(m["frames"] for m in out["datasets"].values())
    return out
